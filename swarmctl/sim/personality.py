"""What makes the mock autopilot an ArduCopter or a PX4: one personality object per firmware.

A personality is built on the firmware's description (swarmctl/mavlink/autopilots: the MAV_AUTOPILOT
id, the mode table, the mode swarmctl commands in, the answer to an arm that is not ready) and adds
what only the vehicle side shows: heartbeat flags, the streams sent unasked, its boot (the stages a
real one goes through before it can arm, and their status texts), parameter defaults (and the ones
that set the mock's speeds), the rules for changing mode, arming, take-off and reposition, the fence's
switch and its breach action, the answers to a reboot, and the AUTOPILOT_VERSION it reports. `MockAutopilot` asks its
personality wherever the two firmwares differ; it never compares names.
"""

from __future__ import annotations

import abc
import math
import time
from collections.abc import Mapping
from typing import TYPE_CHECKING, ClassVar

from pymavlink.dialects.v20 import ardupilotmega as MAV

from swarmctl.mavlink.autopilots.base import Autopilot
from swarmctl.mavlink.autopilots.descriptions import ARDUPILOT, PX4, px4_decode

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.sim.mock_base import MockBase

_RESULTS = {name: getattr(MAV, f"MAV_RESULT_{name}") for name in ("TEMPORARILY_REJECTED", "FAILED")}
_CAPABILITIES = (
    MAV.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | MAV.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | MAV.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | MAV.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
)


class Personality(abc.ABC):
    """The vehicle side of one firmware (data as class attributes, rules as methods)."""

    autopilot: ClassVar[Autopilot]  # the firmware's description
    boot_mode: ClassVar[str]  # the mode after boot
    default_streams: ClassVar[Mapping[int, float]]  # message id -> interval (s) sent without a request
    params: ClassVar[Mapping[str, float]]  # parameter defaults
    # parameters that are the mock's own speeds: name -> (MockAutopilot attribute, SI units per unit);
    # the mock writes its speeds into them at start and follows a PARAM_SET of one
    physics_params: ClassVar[Mapping[str, tuple[str, float]]] = {}
    # the boot, as fractions of the time the vehicle takes to be ready to arm in the mode swarmctl flies
    # it in (`ready_after`, or the slow-EKF fault's time): "streams" requested telemetry starts, "standby"
    # the heartbeat's system_status leaves BOOT, "gps" a GPS fix (positions are reported), "origin" home
    # is set (HOME_POSITION), "manual" the pre-arm checks pass in a mode that needs no position
    stages: ClassVar[Mapping[str, float]]
    stage_texts: ClassVar[Mapping[str, tuple[str, ...]]] = {}  # STATUSTEXTs at each stage (and "ready")
    position_before_ready: ClassVar[bool]  # GLOBAL_POSITION_INT (zeros) is sent before a position fix
    armable_modes: ClassVar[frozenset[str] | None] = None  # None: arming is not limited by mode
    position_modes: ClassVar[frozenset[str]] = frozenset()  # modes that need a position to arm in
    arm_prefix: ClassVar[str]  # STATUSTEXT prefix of a refused arm
    prearm_prefix: ClassVar[str | None] = None  # prefix of the periodic pre-arm failure texts (None: none)
    not_ready_reason: ClassVar[str]  # why arming is refused before the vehicle is ready
    boot_reason: ClassVar[str] = ""  # why, in a mode without position, before the "manual" stage
    console: ClassVar[tuple[bytes, bytes]] = (b"", b"")  # TCP console text: before MAVLink, during boot
    outside_fence_reason: ClassVar[str]
    disarm_flying_text: ClassVar[str]
    landed_text: ClassVar[str]  # STATUSTEXT when it disarms on landing
    failsafe_text: ClassVar[str]  # STATUSTEXT of the GCS failsafe's return
    target_modes: ClassVar[frozenset[str]]  # modes in which the vehicle flies to its target
    takeoff_mode: ClassVar[str | None] = None  # a mode of its own for the take-off climb
    setpoint_modes: ClassVar[frozenset[str]]  # modes in which SET_POSITION_TARGET_* are followed
    request_refused: ClassVar[int]  # MAV_RESULT for MAV_CMD_REQUEST_MESSAGE of a message it cannot send
    reboot_refused: ClassVar[int]  # MAV_RESULT for a reboot while armed
    reposition_refused: ClassVar[int]  # MAV_RESULT for DO_REPOSITION on the ground or disarmed
    fence_enable_command: ClassVar[bool]  # MAV_CMD_DO_FENCE_ENABLE switches the fence
    fence_inside_all: ClassVar[bool]  # with several inclusion polygons: inside all (True) or any one
    breach_mode: ClassVar[str]  # the mode a fence breach switches to (the default breach action)
    breach_text: ClassVar[str]
    version: ClassVar[int]  # AUTOPILOT_VERSION.flight_sw_version
    capabilities: ClassVar[int]  # AUTOPILOT_VERSION.capabilities
    boot_status: ClassVar[int] = MAV.MAV_STATE_BOOT  # HEARTBEAT.system_status before the "standby" stage
    # the "standby" stage puts the vehicle back in boot_mode, undoing a mode accepted during the boot
    # (ArduCopter's initialisation ends by setting INITIAL_MODE)
    boot_resets_mode: ClassVar[bool] = False
    # the MAV_FRAMEs a DO_REPOSITION sent as COMMAND_INT is taken in (others: UNSUPPORTED_MAV_FRAME);
    # None: any frame (COMMAND_LONG has none and is always taken)
    reposition_frames: ClassVar[frozenset[int] | None] = None
    takeoff_texts: ClassVar[tuple[str, ...]] = ()  # STATUSTEXTs when a take-off starts ({alt:.1f} m above home)
    landed_mode: ClassVar[str | None] = None  # the mode after a landing or return has disarmed (None: it stays)
    rtl_alt: ClassVar[float]  # the return's altitude above home by default (RTL_ALT, RTL_RETURN_ALT)

    @property
    def name(self) -> str:
        return self.autopilot.name

    @property
    def arm_refused(self) -> int:
        """The MAV_RESULT of a refused arm: the description's answer to an arm that is not ready."""
        return _RESULTS[self.autopilot.arm_refusal]

    def mode_name(self, custom_mode: int) -> str:
        return self.autopilot.mode_name(custom_mode)

    def custom_mode(self, name: str) -> int:
        return self.autopilot.custom_mode(name)

    @abc.abstractmethod
    def base_mode(self, custom_mode: int) -> int:
        """HEARTBEAT.base_mode while disarmed (MAV_MODE_FLAG_SAFETY_ARMED is added when armed)."""

    @abc.abstractmethod
    def refuse_mode(self, mock: MockBase, custom_mode: int) -> int | None:
        """The MAV_RESULT refusing a change to custom_mode (saying why in a STATUSTEXT), or None to allow it."""

    @abc.abstractmethod
    def takeoff(self, mock: MockBase, param7: float) -> int:
        """MAV_CMD_NAV_TAKEOFF with this param7: start the climb (mock.target) or refuse."""

    def takeoff_reached(self, mock: MockBase) -> None:  # noqa: B027 - without a takeoff_mode, never called
        """The take-off altitude is reached in the takeoff_mode."""

    @abc.abstractmethod
    def reposition_outside_fence(self, mock: MockBase) -> int:
        """DO_REPOSITION to a point the enforced fence excludes: the MAV_RESULT, and what the vehicle does."""

    @abc.abstractmethod
    def fence_enforced(self, enabled: bool, params: Mapping[str, float]) -> bool:
        """A stored fence is enforced, given the DO_FENCE_ENABLE switch and the parameters."""

    @abc.abstractmethod
    def gcs_loss(self, mock: MockBase) -> tuple[float, float, str] | None:
        """The failsafe on a lost ground-station link (wall seconds without its heartbeat): (the loss
        timeout, seconds of hold before the action, the action's mode); None: no failsafe."""


class ArduPilotPersonality(Personality):
    """ArduCopter, as a real ArduCopter 4.7 SITL log shows it."""

    autopilot = ARDUPILOT
    boot_mode = "STABILIZE"
    boot_resets_mode = True  # SITL: GUIDED accepted and reported in BOOT, STABILIZE at "ArduPilot Ready"
    rtl_alt = 15.0  # RTL_ALT 1500 cm
    default_streams: ClassVar[Mapping[int, float]] = {}  # a fresh ArduPilot sends only heartbeats
    params: ClassVar[Mapping[str, float]] = {  # ArduCopter 4.7's defaults: the fence, the speeds, the return
        "FENCE_ENABLE": 0.0,
        "FENCE_TYPE": 7.0,  # 1 max altitude + 2 circle round home + 4 polygon
        "FENCE_RADIUS": 300.0,
        "FENCE_ACTION": 1.0,
        "FENCE_MARGIN": 2.0,
        "WPNAV_SPEED": 1000.0,  # cm/s; WPNAV_*, LAND_SPEED*, RTL_ALT follow the mock's speeds
        "WPNAV_ACCEL": 250.0,  # the mock accelerates at once: its moves are quicker than this says
        "WPNAV_SPEED_UP": 250.0,
        "WPNAV_SPEED_DN": 150.0,
        "LAND_SPEED": 150.0,  # the mock lands at one rate (ArduCopter: 50 below LAND_ALT_LOW)
        "LAND_SPEED_HIGH": 150.0,
        "LAND_ALT_LOW": 1000.0,
        "RTL_ALT": 1500.0,
        "RTL_SPEED": 0.0,
        "RTL_LOIT_TIME": 0.0,  # ms; the mock does not wait over home (ArduCopter: 5000)
        "MAV_SYSID": 1.0,
        "MAV_GCS_SYSID": 255.0,
        # the failsafes swarmctl reads at preflight; FS_GCS_ENABLE is 1 (RTL) here, as a vehicle set up for
        # swarmctl has it (docs/vehicles.md), not ArduCopter's 0, so a default mission flies the mock; 0
        # (MockAutopilot(params=...)) turns the mock's GCS failsafe off, as on ArduCopter
        "FS_GCS_ENABLE": 1.0,
        "FS_GCS_TIMEOUT": 5.0,  # s; the mock's own timeout is its gcs_failsafe_timeout
        "BATT_FS_LOW_ACT": 0.0,  # ArduCopter's default: warn only
    }
    physics_params = {
        "WPNAV_SPEED": ("speed", 0.01),
        "WPNAV_SPEED_UP": ("climb_rate", 0.01),
        "WPNAV_SPEED_DN": ("descent_rate", 0.01),
        "LAND_SPEED": ("descent_rate", 0.01),
        "LAND_SPEED_HIGH": ("descent_rate", 0.01),
        "RTL_ALT": ("rtl_alt", 0.01),
    }
    # ArduCopter 4.7 SITL at x1, ready to arm in GUIDED 41.3 s after boot: "ArduPilot Ready" (streams)
    # 2.4 s, STANDBY 2.9 s, GPS fix 10 s, EKF origin and home 19.9 s, pre-arm checks pass in STABILIZE
    # 23.5 s, the EKF uses the GPS at 41.3 s
    stages = {"streams": 0.06, "standby": 0.07, "gps": 0.25, "origin": 0.48, "manual": 0.57}
    stage_texts = {
        "streams": ("ArduPilot Ready", "AHRS: DCM active"),
        "gps": ("GPS 1: detected u-blox",),
        "origin": ("EKF3 IMU0 origin set", "Field Elevation Set: {alt:.0f}m"),
        "ready": ("EKF3 IMU0 is using GPS",),
    }
    position_before_ready = True  # lat/lon 0 until the GPS has a fix
    armable_modes = frozenset({"STABILIZE", "GUIDED", "LOITER", "ALT_HOLD", "POSHOLD"})
    position_modes = frozenset({"GUIDED", "RTL", "LOITER", "AUTO", "POSHOLD", "SMART_RTL"})
    arm_prefix = "Arm"  # what SITL says to a refused arm command
    prearm_prefix = "PreArm"  # what its 1 Hz pre-arm checks say, every 30 s
    not_ready_reason = "Need Position Estimate"
    boot_reason = "AHRS: waiting for home"
    console = (
        b"\n\nInit ArduCopter V4.7.0-dev (mock)\n\nFree RAM: 524288\nBooting 0/0\n"
        b"Firmware change: erasing EEPROM...\ndone.\n0 0 0 AP_Logger_File: buffer size=204800\n",
        b"Init Gyro**\n",
    )
    outside_fence_reason = "vehicle outside fence"
    disarm_flying_text = "Disarm: vehicle is flying"
    landed_text = "Disarming motors"
    failsafe_text = "GCS Failsafe"
    target_modes = frozenset({"GUIDED"})
    setpoint_modes = frozenset({"GUIDED"})
    request_refused = MAV.MAV_RESULT_FAILED
    reboot_refused = MAV.MAV_RESULT_FAILED
    reposition_refused = MAV.MAV_RESULT_FAILED
    fence_enable_command = True  # not saved: after a reboot the stored fence is off until enabled again
    fence_inside_all = True  # its default FENCE_OPTIONS
    breach_mode = "RTL"  # FENCE_ACTION's default
    breach_text = "Fence breached: RTL"
    version = (4 << 24) | (5 << 16)
    capabilities = _CAPABILITIES | MAV.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST

    def base_mode(self, custom_mode: int) -> int:
        # as ArduCopter SITL sends them: 89 disarmed, 217 armed (log reference)
        return (
            MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            | MAV.MAV_MODE_FLAG_STABILIZE_ENABLED
            | MAV.MAV_MODE_FLAG_GUIDED_ENABLED
            | MAV.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        )

    def refuse_mode(self, mock: MockBase, custom_mode: int) -> int | None:
        name = self.autopilot.mode_name(custom_mode)
        if custom_mode not in self.autopilot.modes.values():
            mock.statustext("Flight mode change failed", MAV.MAV_SEVERITY_WARNING)
            return MAV.MAV_RESULT_FAILED
        # disarmed, ArduCopter takes any mode (its arming checks decide); armed, a position mode needs one
        if name in self.position_modes and not mock.ready and mock.armed:
            mock.statustext(f"Flight mode change failed: {name} requires position", MAV.MAV_SEVERITY_WARNING)
            return MAV.MAV_RESULT_FAILED
        return None

    def takeoff(self, mock: MockBase, param7: float) -> int:
        # GUIDED (or AUTO), armed, on the ground; param7 is metres above home
        if mock.mode_name != self.autopilot.command_mode or not mock.armed or mock.rel_alt > 0.05:
            return MAV.MAV_RESULT_FAILED
        if not math.isfinite(param7) or param7 <= 0:
            return MAV.MAV_RESULT_FAILED
        mock.target = (mock.lat, mock.lon, float(param7))
        return MAV.MAV_RESULT_ACCEPTED

    def reposition_outside_fence(self, mock: MockBase) -> int:
        return MAV.MAV_RESULT_FAILED  # the guided destination is refused

    def fence_enforced(self, enabled: bool, params: Mapping[str, float]) -> bool:
        return enabled

    def gcs_loss(self, mock: MockBase) -> tuple[float, float, str] | None:
        # after the mock's gcs_failsafe_timeout (None: off), the action FS_GCS_ENABLE says at once (0: off;
        # land for 4, 5 and 7, the mock's RTL for the others: it has no SmartRTL or brake)
        enable = int(mock.params.get("FS_GCS_ENABLE", 0.0))
        if enable == 0 or mock.gcs_failsafe_timeout is None:
            return None
        return mock.gcs_failsafe_timeout, 0.0, "LAND" if enable in (4, 5, 7) else "RTL"


class PX4Personality(Personality):
    """PX4 multicopter, as PX4 SITL (SIH, PX4 main of 2026-03-02, ../shared/px4) shows itself on its API link
    (docs/mavlink.md, "What PX4 SITL showed")."""

    autopilot = PX4
    boot_mode = "HOLD"  # AUTO.LOITER on the ground, custom_mode 0x03040000, base_mode 29
    boot_status = MAV.MAV_STATE_UNINIT  # system_status 0, then 3 (standby) at 4.3 s of 5.3
    default_streams: ClassVar[Mapping[int, float]] = {  # the API link's streams, unasked (PX4 SITL, Hz over 5 s)
        MAV.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 0.02,  # 49.6 Hz
        MAV.MAVLINK_MSG_ID_GPS_RAW_INT: 0.125,  # 8 Hz
        MAV.MAVLINK_MSG_ID_SYS_STATUS: 0.2,  # 5 Hz
        MAV.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 0.2,  # 5 Hz
        MAV.MAVLINK_MSG_ID_HOME_POSITION: 2.5,  # 0.4 Hz
    }
    params: ClassVar[Mapping[str, float]] = {  # PX4 SITL's defaults of the parameters a PX4 ground station touches
        "MIS_TAKEOFF_ALT": 2.5,
        "MPC_XY_CRUISE": 5.0,
        "RTL_RETURN_ALT": 30.0,
        # data-link loss action: 0 off (PX4's default), 1 hold, 2 return, 3 land; 2 here, as a vehicle set
        # up for swarmctl has it (docs/vehicles.md), so a default mission flies the mock
        "NAV_DLL_ACT": 2.0,
        "COM_LOW_BAT_ACT": 3.0,  # as PX4 SITL reads it: return at critical level, land at emergency level
        "COM_DL_LOSS_T": 10.0,  # s without a GCS heartbeat before the link counts as lost
        "COM_FAIL_ACT_T": 5.0,  # s of hold before the failsafe's action
        "COM_OF_LOSS_T": 1.0,
        "MAV_SYS_ID": 1.0,
        "SYS_AUTOSTART": 10040.0,  # sihsim_quadx
        "GF_ACTION": 2.0,  # geofence breach: 2 = Hold (PX4's default)
        "GF_MAX_HOR_DIST": 0.0,
        "GF_MAX_VER_DIST": 0.0,
        "MPC_ACC_HOR": 3.0,  # the mock accelerates at once
        "MPC_TKO_SPEED": 2.5,  # MPC_TKO_SPEED, MPC_Z_V_AUTO_DN, MPC_LAND_SPEED follow the mock's speeds
        "MPC_Z_V_AUTO_DN": 1.5,
        "MPC_LAND_SPEED": 1.5,
        "MPC_LAND_ALT2": 5.0,
        "RTL_LAND_DELAY": 0.0,
    }
    physics_params = {
        "MPC_XY_CRUISE": ("speed", 1.0),
        "MPC_TKO_SPEED": ("climb_rate", 1.0),
        "MPC_Z_V_AUTO_DN": ("descent_rate", 1.0),
        "MPC_LAND_SPEED": ("descent_rate", 1.0),
        "RTL_RETURN_ALT": ("rtl_alt", 1.0),
    }
    # PX4 SITL, ready 5.3 s after launch: HOME_POSITION (and so a global position) 2.4 s, standby 4.3 s;
    # telemetry streams from the first heartbeat
    stages = {"streams": 0.0, "gps": 0.45, "origin": 0.45, "standby": 0.81, "manual": 1.0}
    position_before_ready = False  # PX4 publishes no global position before it has one
    arm_prefix = "Arming denied"
    not_ready_reason = "Global position required"
    outside_fence_reason = "Geofence violation"
    disarm_flying_text = "Disarming denied: not landed"
    landed_text = "Disarmed by landing"
    landed_mode = "HOLD"  # SITL: AUTO.LOITER once disarmed, after a LAND and after an RTL
    rtl_alt = 30.0  # RTL_RETURN_ALT; SITL climbed from 6 m to 30 m before returning
    failsafe_text = "Failsafe activated"
    takeoff_texts = ("Takeoff detected", "Using default takeoff altitude: {alt:.1f} m")
    target_modes = frozenset({"TAKEOFF", "HOLD", "OFFBOARD"})
    takeoff_mode = "TAKEOFF"  # AUTO.TAKEOFF, then HOLD
    setpoint_modes = frozenset({"OFFBOARD"})
    request_refused = MAV.MAV_RESULT_UNSUPPORTED
    reboot_refused = MAV.MAV_RESULT_DENIED
    reposition_refused = MAV.MAV_RESULT_DENIED
    # as the SITL build: GLOBAL and GLOBAL_INT (a PX4 taking only one of them: the mock's
    # `reposition_frames`); GLOBAL_RELATIVE_ALT (3) is refused with UNSUPPORTED_MAV_FRAME
    reposition_frames = frozenset(PX4.reposition_frames)
    fence_enable_command = False  # an uploaded fence is enforced while GF_ACTION is not 0
    fence_inside_all = False
    breach_mode = "HOLD"  # GF_ACTION's default
    breach_text = "Geofence violated: holding"
    version = (1 << 24) | (16 << 16)  # v1.16.0
    capabilities = _CAPABILITIES | MAV.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    _needs_ready = frozenset({"HOLD", "RTL", "LAND", "MISSION", "TAKEOFF", "POSCTL"})

    def base_mode(self, custom_mode: int) -> int:
        main, _sub = px4_decode(custom_mode)
        base = MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | MAV.MAV_MODE_FLAG_STABILIZE_ENABLED
        if main in (4, 6):  # AUTO, OFFBOARD
            return base | MAV.MAV_MODE_FLAG_GUIDED_ENABLED | MAV.MAV_MODE_FLAG_AUTO_ENABLED
        return base | MAV.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED

    def refuse_mode(self, mock: MockBase, custom_mode: int) -> int | None:
        name = self.autopilot.mode_name(custom_mode)
        if name.startswith("PX4("):  # not a mode PX4 has
            return MAV.MAV_RESULT_UNSUPPORTED
        if name == "OFFBOARD" and time.monotonic() - mock.last_setpoint > 0.5:
            # PX4 needs a setpoint stream (> 2 Hz) before it accepts OFFBOARD
            mock.statustext("Switching to Offboard is currently not available", MAV.MAV_SEVERITY_CRITICAL)
            return MAV.MAV_RESULT_TEMPORARILY_REJECTED
        if name in self._needs_ready and not mock.ready:
            mock.statustext(f"Switching to {name} is currently not available", MAV.MAV_SEVERITY_CRITICAL)
            return MAV.MAV_RESULT_TEMPORARILY_REJECTED
        return None

    def takeoff(self, mock: MockBase, param7: float) -> int:
        # param7 is AMSL (NaN: MIS_TAKEOFF_ALT above home); switches to AUTO.TAKEOFF
        if not mock.armed:
            return MAV.MAV_RESULT_TEMPORARILY_REJECTED
        rel = mock.params["MIS_TAKEOFF_ALT"] if not math.isfinite(param7) else param7 - mock.home[2]
        if rel <= 0:
            return MAV.MAV_RESULT_DENIED
        mock.custom_mode = self.autopilot.custom_mode("TAKEOFF")
        mock.target = (mock.lat, mock.lon, float(rel))
        return MAV.MAV_RESULT_ACCEPTED

    def takeoff_reached(self, mock: MockBase) -> None:
        mock.custom_mode = self.autopilot.custom_mode(self.autopilot.command_mode)  # AUTO.TAKEOFF -> HOLD

    def reposition_outside_fence(self, mock: MockBase) -> int:
        # the commander acks, the navigator holds and says why
        mock._set_mode_name(self.autopilot.command_mode)
        mock.statustext("Reposition is outside geofence", MAV.MAV_SEVERITY_CRITICAL)
        return MAV.MAV_RESULT_ACCEPTED

    def fence_enforced(self, enabled: bool, params: Mapping[str, float]) -> bool:
        return params.get("GF_ACTION", 0.0) != 0.0

    def gcs_loss(self, mock: MockBase) -> tuple[float, float, str] | None:
        # NAV_DLL_ACT after COM_DL_LOSS_T, holding COM_FAIL_ACT_T first (SITL: critical at 11.7 s, RTL at
        # 16.7 s with the defaults 10 and 5); the mock's gcs_failsafe_timeout None switches it off too
        action = {1: "HOLD", 2: "RTL", 3: "LAND"}.get(int(mock.params.get("NAV_DLL_ACT", 0.0)))
        if action is None or mock.gcs_failsafe_timeout is None:
            return None
        return mock.params["COM_DL_LOSS_T"], mock.params["COM_FAIL_ACT_T"], action


PERSONALITIES: Mapping[str, Personality] = {p.name: p for p in (ArduPilotPersonality(), PX4Personality())}


def personality_named(name: str) -> Personality:
    """The personality of the autopilot with this name; ValueError naming the choices otherwise."""
    try:
        return PERSONALITIES[name]
    except KeyError:
        raise ValueError(f"autopilot must be {' or '.join(repr(n) for n in PERSONALITIES)}, not {name!r}") from None
