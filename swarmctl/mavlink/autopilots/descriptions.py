"""The firmwares swarmctl flies: ArduPilot Copter (over pymavlink) and PX4 (over MAVSDK).

Each class answers the questions of `Autopilot` for its firmware; `ARDUPILOT` and `PX4` are the
registered descriptions (`autopilot_for_heartbeat` and `autopilot_named` find them).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType

from swarmctl.mavlink.autopilots.base import Autopilot, register
from swarmctl.mavlink.limits import FlightLimits


def _value(values: Mapping[str, float], name: str, default: float, scale: float = 1.0) -> float:
    """values[name] x scale; the default (already in SI units) when it is missing, negative or not finite."""
    raw = values.get(name)
    if raw is None or not math.isfinite(raw) or raw < 0:
        return default
    return float(raw) * scale


def _speed(values: Mapping[str, float], name: str, default: float, scale: float = 1.0) -> float:
    """A speed (or acceleration): as `_value`, and 0 counts as missing too."""
    value = _value(values, name, default, scale)
    return value if value > 0 else default


# --- ArduCopter flight modes (HEARTBEAT.custom_mode = the mode number) -------------------------------

COPTER_MODES: Mapping[str, int] = MappingProxyType(
    {
        "STABILIZE": 0,
        "ACRO": 1,
        "ALT_HOLD": 2,
        "AUTO": 3,
        "GUIDED": 4,
        "LOITER": 5,
        "RTL": 6,
        "CIRCLE": 7,
        "LAND": 9,
        "DRIFT": 11,
        "SPORT": 13,
        "FLIP": 14,
        "AUTOTUNE": 15,
        "POSHOLD": 16,
        "BRAKE": 17,
        "THROW": 18,
        "AVOID_ADSB": 19,
        "GUIDED_NOGPS": 20,
        "SMART_RTL": 21,
    }
)
_COPTER_MODE_NAMES = {number: name for name, number in COPTER_MODES.items()}


class ArduPilotAutopilot(Autopilot):
    """ArduPilot Copter: flown in GUIDED with SET_POSITION_TARGET_GLOBAL_INT; any other mode the vehicle
    reports means the pilot (or the vehicle's own failsafe) has it."""

    name = "ardupilot"
    label = "ArduPilot"
    mav_autopilot = 3  # MAV_AUTOPILOT_ARDUPILOTMEGA
    command_mode = "GUIDED"
    mode_debounce_s = 0.0  # heartbeats carry the mode as it is
    failsafe_modes = frozenset({"RTL", "SMART_RTL", "LAND"})  # FS_GCS_ENABLE 1-5, the battery failsafe's actions
    signs_link = True
    signing = "MAVLink 2 signing on the link: the mission's signing key signs every message both ways"
    arm_refusal = "FAILED"  # with an "Arm: ..." STATUSTEXT (the periodic pre-arm checks say "PreArm: ...")
    driver_path = "swarmctl.mavlink.autopilots.ardupilot:ArduPilotVehicle"
    # ArduCopter 4.7 (copter.parm) defaults in the comments; speeds in cm/s, distances in cm
    limit_parameters = (
        "WPNAV_SPEED",  # 1000: horizontal speed to a GUIDED target
        "WPNAV_ACCEL",  # 250 cm/s^2
        "WPNAV_SPEED_UP",  # 250: climb (take-off)
        "WPNAV_SPEED_DN",  # 150: descent
        "LAND_SPEED",  # 50: the landing's final descent, below LAND_ALT_LOW
        "LAND_SPEED_HIGH",  # 0: the landing's descent above it (0: WPNAV_SPEED_DN)
        "LAND_ALT_LOW",  # 1000
        "RTL_ALT",  # 1500: the return's minimum altitude
        "RTL_SPEED",  # 0: the return's speed (0: WPNAV_SPEED)
        "RTL_LOIT_TIME",  # 5000 ms over home before descending
    )
    # SITL: it leaves the ground 4.5 s after NAV_TAKEOFF's ack, disarms 3.4-3.6 s after touching down, and
    # holds within 0.5 m of a target 0.2 s after coming within 1 m
    spool_s, disarm_s, settle_s = 5.0, 4.0, 0.5
    # the failsafes (ArduCopter 4.7's parameter documentation); FS_GCS_ENABLE's default is 0: off
    gcs_failsafe_parameter = "FS_GCS_ENABLE"
    battery_failsafe_parameter = "BATT_FS_LOW_ACT"
    fence_failsafe_parameter = "FENCE_ACTION"
    gcs_failsafe_fix = "set FS_GCS_ENABLE to 1 (RTL) or 5 (land), with FS_GCS_TIMEOUT (seconds)"
    failsafe_actions = MappingProxyType(
        {
            "FS_GCS_ENABLE": {
                0: "nothing (GCS failsafe off)",
                1: "RTL",
                2: "RTL (2: continue an AUTO mission; removed in 4.0)",
                3: "SmartRTL, else RTL",
                4: "SmartRTL, else land",
                5: "land",
                6: "DO_LAND_START, else RTL",
                7: "brake, else land",
            },
            "BATT_FS_LOW_ACT": {
                0: "nothing (warning only)",
                1: "land",
                2: "RTL",
                3: "SmartRTL, else RTL",
                4: "SmartRTL, else land",
                5: "terminate (motors off)",
                6: "DO_LAND_START, else RTL",
                7: "brake, else land",
            },
            "FENCE_ACTION": {
                0: "nothing (report only)",
                1: "RTL, else land",
                2: "land",
                3: "SmartRTL, else RTL, else land",
                4: "brake, else land",
                5: "SmartRTL, else land",
            },
        }
    )

    @property
    def modes(self) -> Mapping[str, int]:
        return COPTER_MODES

    def mode_name(self, custom_mode: int) -> str:
        return _COPTER_MODE_NAMES.get(custom_mode, f"MODE{custom_mode}")

    def is_pilot_mode(self, mode: str) -> bool:
        return mode not in (self.command_mode, "UNKNOWN")

    def set_mode_params(self, name: str) -> tuple[float, float]:
        return float(self.custom_mode(name)), 0.0  # param2 is the mode number

    def custom_mode_from_command(self, param2: float, param3: float) -> int:
        return int(param2)

    def flight_limits(self, values: Mapping[str, float]) -> FlightLimits:
        speed = _speed(values, "WPNAV_SPEED", 10.0, 0.01)
        descent = _speed(values, "WPNAV_SPEED_DN", 1.5, 0.01)
        return FlightLimits(
            speed=speed,
            accel=_speed(values, "WPNAV_ACCEL", 2.5, 0.01),
            climb=_speed(values, "WPNAV_SPEED_UP", 2.5, 0.01),
            descent=_speed(values, "LAND_SPEED_HIGH", descent, 0.01),
            land_speed=_speed(values, "LAND_SPEED", 0.5, 0.01),
            land_alt_low=_value(values, "LAND_ALT_LOW", 10.0, 0.01),
            rtl_alt=_value(values, "RTL_ALT", 15.0, 0.01),
            rtl_speed=_speed(values, "RTL_SPEED", speed, 0.01),
            rtl_loiter_s=_value(values, "RTL_LOIT_TIME", 5.0, 0.001),
            spool_s=self.spool_s,
            disarm_s=self.disarm_s,
            settle_s=self.settle_s,
            read=tuple(n for n in self.limit_parameters if n in values),
        )


ARDUPILOT = register(ArduPilotAutopilot())


# --- PX4 custom mode: main mode in bits 16..23, sub mode in bits 24..31 --------------------------------

MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_INT = 0, 5  # AMSL altitude; x, y in degE7 in COMMAND_INT for both
REPOSITION_FRAME_REFUSED = 9  # MAV_RESULT_UNSUPPORTED_MAV_FRAME (newer than pymavlink's dialect here)

# The modes swarmctl names, with their (main, sub) pair; sub modes belong to AUTO (4).
PX4_MODES: Mapping[str, tuple[int, int]] = MappingProxyType(
    {
        "MANUAL": (1, 0),
        "ALTCTL": (2, 0),
        "POSCTL": (3, 0),
        "OFFBOARD": (6, 0),
        "STABILIZED": (7, 0),
        "ACRO": (5, 0),
        "READY": (4, 1),
        "TAKEOFF": (4, 2),
        "HOLD": (4, 3),
        "MISSION": (4, 4),
        "RTL": (4, 5),
        "LAND": (4, 6),
    }
)
_PX4_MODE_NAMES = {pair: name for name, pair in PX4_MODES.items()}


def px4_encode(main_mode: int, sub_mode: int = 0) -> int:
    """PX4's HEARTBEAT.custom_mode for a main and sub mode (each 0..255)."""
    if not (0 <= main_mode <= 255 and 0 <= sub_mode <= 255):
        raise ValueError(f"PX4 main/sub mode out of range: {main_mode}, {sub_mode}")
    return (sub_mode << 24) | (main_mode << 16)


def px4_decode(custom_mode: int) -> tuple[int, int]:
    """The (main, sub) mode of PX4's HEARTBEAT.custom_mode."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


class PX4Autopilot(Autopilot):
    """PX4 multicopter: flown through MAVSDK in OFFBOARD with a streamed position target, or in HOLD
    (AUTO.LOITER) with MAV_CMD_DO_REPOSITION where OFFBOARD is not used; the stick modes mean the pilot has it."""

    name = "px4"
    label = "PX4"
    mav_autopilot = 12  # MAV_AUTOPILOT_PX4
    command_mode = "HOLD"
    # MAVSDK's flight-mode subscription was seen to report the pre-take-off POSCTL for a moment after the
    # take-off (of the mock, which then booted in POSCTL; PX4 SITL boots in AUTO.LOITER and reported no
    # stick mode in its flights): a pilot's mode counts once it has been reported for 1.5 s.
    mode_debounce_s = 1.5
    signs_link = False
    signing = (
        "not available: MAVSDK's Python binding exposes no MAVLink signing, so the mission's signing key "
        "is not used for PX4 vehicles; sign at a router (mavlink-router) if the link needs it"
    )
    arm_refusal = "TEMPORARILY_REJECTED"  # MAVSDK reports it as COMMAND_DENIED
    driver_path = "swarmctl.mavlink.autopilots.px4:PX4Vehicle"
    # read through MAVSDK's param plugin (it reads PX4 SITL's); PX4 main defaults in the comments (SI units)
    limit_parameters = (
        "MPC_XY_CRUISE",  # 5 m/s: horizontal speed of a reposition
        "MPC_ACC_HOR",  # 3 m/s^2
        "MPC_TKO_SPEED",  # 1.5 m/s: the take-off's climb (MPC_Z_VEL_MAX_UP, 3, is the limit in other modes)
        "MPC_Z_V_AUTO_DN",  # 1.5 m/s: descent
        "MPC_LAND_SPEED",  # 0.7 m/s: the landing's final descent, below MPC_LAND_ALT2
        "MPC_LAND_ALT2",  # 5 m
        "RTL_RETURN_ALT",  # 30 m
        "RTL_LAND_DELAY",  # 0 s over home before landing (< 0: hover there, not land)
    )
    # SITL (SIH): it leaves 1 m 3-4.8 s after the take-off, disarms 7-8 s after touching down, and takes
    # up to 5 s more to come from 1 m to 0.5 m of a target (NAV_ACC_RAD is 2 m)
    spool_s, disarm_s, settle_s = 5.0, 8.0, 5.0
    own_connection = True  # MAVSDK opens the connection; one PX4 per connection
    # MAV_CMD_DO_REPOSITION goes as COMMAND_INT with an AMSL altitude in one of these frames, tried in this
    # order until one is not refused with REPOSITION_FRAME_REFUSED; the driver keeps the first accepted one
    # for the vehicle. PX4 releases up to 1.16 and the SITL build in ../shared/px4 take both; stock PX4 main
    # since February 2026 refuses one of them with 9 (../shared/px4/README says GLOBAL_INT; MAVSDK 4.1's
    # goto_location, which it says fails there, sends GLOBAL). GLOBAL_RELATIVE_ALT is refused (SITL: 9).
    reposition_frames = (MAV_FRAME_GLOBAL_INT, MAV_FRAME_GLOBAL)
    # Steering in OFFBOARD: the position target goes as SET_POSITION_TARGET_GLOBAL_INT (AMSL, yaw left as it
    # is) through MAVSDK's offboard plugin, which sends it again at 20 Hz from its own thread (PX4 leaves
    # OFFBOARD when the stream stops for COM_OF_LOSS_T, 1 s). The driver enters OFFBOARD only where it has
    # read what the vehicle then does (offboard_loss_parameter) and that is one of offboard_loss_safe:
    # position mode (a pilot's sticks; with no manual control PX4 applies its RC-loss action, NAV_RCL_ACT:
    # SITL returned), return, land, hold. Else, and after offboard_refusals refused starts in a row, it
    # repositions (MAV_CMD_DO_REPOSITION in HOLD).
    offboard_loss_parameter = "COM_OBL_RC_ACT"
    offboard_loss_safe = frozenset({0, 3, 4, 5})
    offboard_refusals = 3
    # reached: horizontally within the mission's reach tolerance, vertically within the larger of it and
    # this: PX4 SITL's altitude estimate wandered up to 1.9 m either side of the target in a steady hover
    # (GLOBAL_POSITION_INT at 10 Hz), so a 3-D 0.5 m tolerance was met late or never (docs/mavlink.md,
    # "Where a PX4 round's time went")
    reach_vertical_m = 2.0
    # the API (offboard) link of SITL instance N sends to UDP 14540 + N for N 0..9, and to 14549 above 9
    # (px4-rc.mavlink: "use the same ports for more than 10 instances")
    api_port_base, api_port_wrapped, api_instances = 14540, 14549, 10
    # the modes a pilot selects with the sticks, as MAVSDK names them
    pilot_modes = frozenset({"MANUAL", "ALTCTL", "POSCTL", "ACRO", "STABILIZED", "RATTITUDE"})
    # the failsafes (PX4's parameter reference); NAV_DLL_ACT's default is 0: off
    gcs_failsafe_parameter = "NAV_DLL_ACT"
    battery_failsafe_parameter = "COM_LOW_BAT_ACT"
    fence_failsafe_parameter = "GF_ACTION"
    gcs_failsafe_fix = "set NAV_DLL_ACT to 2 (return) or 3 (land), with COM_DL_LOSS_T (seconds)"
    failsafe_actions = MappingProxyType(
        {
            "NAV_DLL_ACT": {
                0: "nothing (data-link loss failsafe off)",
                1: "hold",
                2: "return",
                3: "land",
                5: "terminate (motors off)",
                6: "lockdown (motors off)",
            },
            "COM_LOW_BAT_ACT": {
                0: "nothing (warning only)",
                1: "return",
                2: "land",
                3: "return at critical level, land at emergency level",
            },
            "COM_OBL_RC_ACT": {  # the setpoint stream of OFFBOARD lost for COM_OF_LOSS_T
                0: "position mode (without manual control: the RC-loss action, NAV_RCL_ACT)",
                1: "altitude mode",
                2: "stabilized mode",
                3: "return",
                4: "land",
                5: "hold",
                6: "terminate (motors off)",
                7: "disarm (motors off)",
            },
            "GF_ACTION": {
                0: "nothing",
                1: "nothing (warning only)",
                2: "hold",
                3: "return",
                4: "terminate (motors off)",
                5: "land",
            },
        }
    )

    @property
    def modes(self) -> Mapping[str, int]:
        return _PX4_CUSTOM_MODES

    def mode_name(self, custom_mode: int) -> str:
        main, sub = px4_decode(custom_mode)
        return _PX4_MODE_NAMES.get((main, sub)) or _PX4_MODE_NAMES.get((main, 0)) or f"PX4({main},{sub})"

    def is_pilot_mode(self, mode: str) -> bool:
        return mode in self.pilot_modes

    def retries_arm(self, result: str) -> bool:
        return True  # MAVSDK names its refusals its own way (COMMAND_DENIED, ...): every one is retried

    def silent_port_hint(self, port: int | None, sysid: int | None) -> str:
        """Why no PX4 may be heard on UDP `port` (the mission's connection) and how to fix it; "" when the
        port is not one a PX4 SITL instance above 9 would have been given."""
        base, wrapped, count = self.api_port_base, self.api_port_wrapped, self.api_instances
        instance = port - base if port is not None else (sysid - 1 if sysid else -1)
        if not count <= instance < 256:
            return ""
        return (
            f"a PX4 SITL instance above {count - 1} (here {instance}: port {base}+{instance}, system id "
            f"{instance + 1}) sends its API link to UDP {wrapped}, not {base + instance}; connect it with "
            f"udpin:0.0.0.0:{wrapped} (one such instance at a time) or start it as an instance 0-{count - 1}"
        )

    def set_mode_params(self, name: str) -> tuple[float, float]:
        main, sub = px4_decode(self.custom_mode(name))  # param2 the main mode, param3 the sub mode
        return float(main), float(sub)

    def custom_mode_from_command(self, param2: float, param3: float) -> int:
        return px4_encode(int(param2), int(param3))

    def flight_limits(self, values: Mapping[str, float]) -> FlightLimits:
        speed = _speed(values, "MPC_XY_CRUISE", 5.0)
        return FlightLimits(
            speed=speed,
            accel=_speed(values, "MPC_ACC_HOR", 3.0),
            climb=_speed(values, "MPC_TKO_SPEED", 1.5),
            descent=_speed(values, "MPC_Z_V_AUTO_DN", 1.5),
            land_speed=_speed(values, "MPC_LAND_SPEED", 0.7),
            land_alt_low=_value(values, "MPC_LAND_ALT2", 5.0),
            rtl_alt=_value(values, "RTL_RETURN_ALT", 30.0),
            rtl_speed=speed,
            rtl_loiter_s=_value(values, "RTL_LAND_DELAY", 0.0),
            spool_s=self.spool_s,
            disarm_s=self.disarm_s,
            settle_s=self.settle_s,
            read=tuple(n for n in self.limit_parameters if n in values),
        )


_PX4_CUSTOM_MODES: Mapping[str, int] = MappingProxyType({n: px4_encode(*pair) for n, pair in PX4_MODES.items()})
PX4 = register(PX4Autopilot())
