"""What makes the mock autopilot an ArduCopter or a PX4: one personality object per firmware.

A personality is built on the firmware's description (swarmctl/mavlink/autopilots: the MAV_AUTOPILOT
id, the mode table, the mode swarmctl commands in, the answer to an arm that is not ready) and adds
what only the vehicle side shows: heartbeat flags, the streams sent unasked, parameter defaults,
status texts, the rules for changing mode, take-off and reposition, the fence's switch and its breach
action, the answers to a reboot, and the AUTOPILOT_VERSION it reports. `MockAutopilot` asks its
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
    from swarmctl.sim.autopilot import MockAutopilot

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
    position_before_ready: ClassVar[bool]  # GLOBAL_POSITION_INT (zeros) is sent before a position fix
    ready_texts: ClassVar[tuple[str, ...]] = ()  # STATUSTEXTs when the pre-arm checks pass
    armable_modes: ClassVar[frozenset[str] | None] = None  # None: arming is not limited by mode
    arm_prefix: ClassVar[str]  # STATUSTEXT prefix of a refused arm
    not_ready_reason: ClassVar[str]  # why arming is refused before the pre-arm checks pass
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
    def refuse_mode(self, mock: MockAutopilot, custom_mode: int) -> int | None:
        """The MAV_RESULT refusing a change to custom_mode (saying why in a STATUSTEXT), or None to allow it."""

    @abc.abstractmethod
    def takeoff(self, mock: MockAutopilot, param7: float) -> int:
        """MAV_CMD_NAV_TAKEOFF with this param7: start the climb (mock.target) or refuse."""

    def takeoff_reached(self, mock: MockAutopilot) -> None:  # noqa: B027 - without a takeoff_mode, never called
        """The take-off altitude is reached in the takeoff_mode."""

    @abc.abstractmethod
    def reposition_outside_fence(self, mock: MockAutopilot) -> int:
        """DO_REPOSITION to a point the enforced fence excludes: the MAV_RESULT, and what the vehicle does."""

    @abc.abstractmethod
    def fence_enforced(self, enabled: bool, params: Mapping[str, float]) -> bool:
        """A stored fence is enforced, given the DO_FENCE_ENABLE switch and the parameters."""


class ArduPilotPersonality(Personality):
    """ArduCopter, as a real ArduCopter 4.7 SITL log shows it."""

    autopilot = ARDUPILOT
    boot_mode = "STABILIZE"
    default_streams: Mapping[int, float] = {}  # a fresh ArduPilot sends only heartbeats
    params: Mapping[str, float] = {  # ArduCopter's fence parameters, at their defaults
        "FENCE_ENABLE": 0.0,
        "FENCE_TYPE": 7.0,  # 1 max altitude + 2 circle round home + 4 polygon
        "FENCE_RADIUS": 300.0,
        "FENCE_ACTION": 1.0,
        "FENCE_MARGIN": 2.0,
    }
    position_before_ready = True  # zeros until the EKF has an origin
    ready_texts = ("EKF3 IMU0 origin set", "ArduPilot Ready")
    armable_modes = frozenset({"STABILIZE", "GUIDED", "LOITER", "ALT_HOLD", "POSHOLD"})
    arm_prefix = "PreArm"
    not_ready_reason = "Need Position Estimate"
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
    _needs_position = frozenset({"GUIDED", "RTL", "LOITER", "AUTO", "SMART_RTL"})

    def base_mode(self, custom_mode: int) -> int:
        # as ArduCopter SITL sends them: 89 disarmed, 217 armed (log reference)
        return (
            MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            | MAV.MAV_MODE_FLAG_STABILIZE_ENABLED
            | MAV.MAV_MODE_FLAG_GUIDED_ENABLED
            | MAV.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        )

    def refuse_mode(self, mock: MockAutopilot, custom_mode: int) -> int | None:
        name = self.autopilot.mode_name(custom_mode)
        if custom_mode not in self.autopilot.modes.values():
            mock.statustext("Flight mode change failed", MAV.MAV_SEVERITY_WARNING)
            return MAV.MAV_RESULT_FAILED
        if name in self._needs_position and not mock.ready:
            mock.statustext(f"Flight mode change failed: {name} requires position", MAV.MAV_SEVERITY_WARNING)
            return MAV.MAV_RESULT_FAILED
        return None

    def takeoff(self, mock: MockAutopilot, param7: float) -> int:
        # GUIDED (or AUTO), armed, on the ground; param7 is metres above home
        if mock.mode_name != self.autopilot.command_mode or not mock.armed or mock.rel_alt > 0.05:
            return MAV.MAV_RESULT_FAILED
        if not math.isfinite(param7) or param7 <= 0:
            return MAV.MAV_RESULT_FAILED
        mock.target = (mock.lat, mock.lon, float(param7))
        return MAV.MAV_RESULT_ACCEPTED

    def reposition_outside_fence(self, mock: MockAutopilot) -> int:
        return MAV.MAV_RESULT_FAILED  # the guided destination is refused

    def fence_enforced(self, enabled: bool, params: Mapping[str, float]) -> bool:
        return enabled


class PX4Personality(Personality):
    """PX4 multicopter, as MAVSDK sees it."""

    autopilot = PX4
    boot_mode = "POSCTL"
    default_streams: Mapping[int, float] = {  # PX4 streams telemetry unasked
        MAV.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 0.2,
        MAV.MAVLINK_MSG_ID_HOME_POSITION: 2.0,
        MAV.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
        MAV.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    }
    params: Mapping[str, float] = {  # the few parameters a PX4 ground station touches
        "MIS_TAKEOFF_ALT": 2.5,
        "MPC_XY_CRUISE": 5.0,
        "RTL_RETURN_ALT": 30.0,
        "NAV_DLL_ACT": 2.0,
        "COM_OF_LOSS_T": 1.0,
        "SYS_AUTOSTART": 4001.0,
        "GF_ACTION": 2.0,  # geofence breach: 2 = Hold (PX4's default)
    }
    position_before_ready = False  # PX4 publishes no global position before it has one
    arm_prefix = "Arming denied"
    not_ready_reason = "Global position required"
    outside_fence_reason = "Geofence violation"
    disarm_flying_text = "Disarming denied: not landed"
    landed_text = "Disarmed"
    failsafe_text = "Failsafe: no connection to ground station, returning"
    target_modes = frozenset({"TAKEOFF", "HOLD", "OFFBOARD"})
    takeoff_mode = "TAKEOFF"  # AUTO.TAKEOFF, then HOLD
    setpoint_modes = frozenset({"OFFBOARD"})
    request_refused = MAV.MAV_RESULT_UNSUPPORTED
    reboot_refused = MAV.MAV_RESULT_DENIED
    reposition_refused = MAV.MAV_RESULT_DENIED
    fence_enable_command = False  # an uploaded fence is enforced while GF_ACTION is not 0
    fence_inside_all = False
    breach_mode = "HOLD"  # GF_ACTION's default
    breach_text = "Geofence violated: holding"
    version = (1 << 24) | (15 << 16)
    capabilities = _CAPABILITIES | MAV.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    _needs_ready = frozenset({"HOLD", "RTL", "LAND", "MISSION", "TAKEOFF", "POSCTL"})

    def base_mode(self, custom_mode: int) -> int:
        main, _sub = px4_decode(custom_mode)
        base = MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | MAV.MAV_MODE_FLAG_STABILIZE_ENABLED
        if main in (4, 6):  # AUTO, OFFBOARD
            return base | MAV.MAV_MODE_FLAG_GUIDED_ENABLED | MAV.MAV_MODE_FLAG_AUTO_ENABLED
        return base | MAV.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED

    def refuse_mode(self, mock: MockAutopilot, custom_mode: int) -> int | None:
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

    def takeoff(self, mock: MockAutopilot, param7: float) -> int:
        # param7 is AMSL (NaN: MIS_TAKEOFF_ALT above home); switches to AUTO.TAKEOFF
        if not mock.armed:
            return MAV.MAV_RESULT_TEMPORARILY_REJECTED
        rel = mock.params["MIS_TAKEOFF_ALT"] if not math.isfinite(param7) else param7 - mock.home[2]
        if rel <= 0:
            return MAV.MAV_RESULT_DENIED
        mock.custom_mode = self.autopilot.custom_mode("TAKEOFF")
        mock.target = (mock.lat, mock.lon, float(rel))
        return MAV.MAV_RESULT_ACCEPTED

    def takeoff_reached(self, mock: MockAutopilot) -> None:
        mock.custom_mode = self.autopilot.custom_mode(self.autopilot.command_mode)  # AUTO.TAKEOFF -> HOLD

    def reposition_outside_fence(self, mock: MockAutopilot) -> int:
        # the commander acks, the navigator holds and says why
        mock._set_mode_name(self.autopilot.command_mode)
        mock.statustext("Reposition is outside geofence", MAV.MAV_SEVERITY_CRITICAL)
        return MAV.MAV_RESULT_ACCEPTED

    def fence_enforced(self, enabled: bool, params: Mapping[str, float]) -> bool:
        return params.get("GF_ACTION", 0.0) != 0.0


PERSONALITIES: Mapping[str, Personality] = {p.name: p for p in (ArduPilotPersonality(), PX4Personality())}


def personality_named(name: str) -> Personality:
    """The personality of the autopilot with this name; ValueError naming the choices otherwise."""
    try:
        return PERSONALITIES[name]
    except KeyError:
        raise ValueError(f"autopilot must be {' or '.join(repr(n) for n in PERSONALITIES)}, not {name!r}") from None
