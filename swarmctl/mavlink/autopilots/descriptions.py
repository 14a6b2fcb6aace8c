"""The firmwares swarmctl flies: ArduPilot Copter (over pymavlink) and PX4 (over MAVSDK).

Each class answers the questions of `Autopilot` for its firmware; `ARDUPILOT` and `PX4` are the
registered descriptions (`autopilot_for_heartbeat` and `autopilot_named` find them).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

from swarmctl.mavlink.autopilots.base import Autopilot, register

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
    signs_link = True
    signing = "MAVLink 2 signing on the link: the mission's signing key signs every message both ways"
    arm_refusal = "FAILED"  # with a "PreArm: ..." STATUSTEXT
    driver_path = "swarmctl.mavlink.autopilots.ardupilot:ArduPilotVehicle"

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


ARDUPILOT = register(ArduPilotAutopilot())


# --- PX4 custom mode: main mode in bits 16..23, sub mode in bits 24..31 --------------------------------

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
    """PX4 multicopter: flown through MAVSDK in HOLD (AUTO.LOITER) with MAV_CMD_DO_REPOSITION; the stick
    modes mean the pilot has it."""

    name = "px4"
    label = "PX4"
    mav_autopilot = 12  # MAV_AUTOPILOT_PX4
    command_mode = "HOLD"
    # MAVSDK's flight-mode subscription was seen to report the pre-take-off POSCTL for a moment after
    # the take-off: a pilot's mode counts once it has been reported for 1.5 s.
    mode_debounce_s = 1.5
    signs_link = False
    signing = (
        "not available: MAVSDK's Python binding exposes no MAVLink signing, so the mission's signing key "
        "is not used for PX4 vehicles; sign at a router (mavlink-router) if the link needs it"
    )
    arm_refusal = "TEMPORARILY_REJECTED"  # MAVSDK reports it as COMMAND_DENIED
    driver_path = "swarmctl.mavlink.autopilots.px4:PX4Vehicle"
    own_connection = True  # MAVSDK opens the connection; one PX4 per connection
    # the modes a pilot selects with the sticks, as MAVSDK names them
    pilot_modes = frozenset({"MANUAL", "ALTCTL", "POSCTL", "ACRO", "STABILIZED", "RATTITUDE"})

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

    def set_mode_params(self, name: str) -> tuple[float, float]:
        main, sub = px4_decode(self.custom_mode(name))  # param2 the main mode, param3 the sub mode
        return float(main), float(sub)

    def custom_mode_from_command(self, param2: float, param3: float) -> int:
        return px4_encode(int(param2), int(param3))


_PX4_CUSTOM_MODES: Mapping[str, int] = MappingProxyType({n: px4_encode(*pair) for n, pair in PX4_MODES.items()})
PX4 = register(PX4Autopilot())
