"""What a mock autopilot does with each message addressed to it: heartbeats, commands (with their
COMMAND_ACK), position targets, modes, parameters, the fence protocol, pings (part of MockAutopilot,
swarmctl.sim.autopilot)."""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any, cast

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.mavlink.codec import from_deg_e7, offset_m, to_deg_e7
from swarmctl.mavlink.transport import valid_frame
from swarmctl.sim.fence import FENCE
from swarmctl.sim.mock_base import MockBase, dropping
from swarmctl.sim.mock_telemetry import STREAMABLE

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.sim.autopilot import MockAutopilot

MAV = mavlink2

MAV_RESULT_UNSUPPORTED_MAV_FRAME = 9  # newer than this pymavlink dialect


class MockCommands(MockBase):
    """MockAutopilot's input side: `_handle(msg)` acts on one received message, with the lock held."""

    def _for_me(self, msg: Any) -> bool:
        ts = getattr(msg, "target_system", None)
        return ts is None or ts in (0, self.sysid)

    def _handle(self, msg: Any) -> None:
        if not valid_frame(msg):
            return
        mtype = msg.get_type()
        if msg.get_srcSystem() == self.sysid:
            return  # our own echo (several vehicles on one channel)
        if not self._for_me(msg):
            self.ignored += 1  # addressed to another vehicle on the same channel
            return
        if dropping(self._drop_received, mtype):
            return
        cmd = getattr(msg, "command", 0) if mtype in ("COMMAND_LONG", "COMMAND_INT") else 0
        self.received.append((mtype, msg.get_srcSystem(), cmd))
        if mtype == "HEARTBEAT":
            if msg.autopilot == MAV.MAV_AUTOPILOT_INVALID:
                self.last_gcs_heartbeat = time.monotonic()
        elif mtype in ("COMMAND_LONG", "COMMAND_INT"):
            self._command(msg)
        elif mtype == "SET_POSITION_TARGET_GLOBAL_INT":
            self._position_target(msg)
        elif mtype == "SET_POSITION_TARGET_LOCAL_NED":
            self._local_target(msg)
        elif mtype == "SET_MODE":
            self._set_custom_mode(msg.custom_mode)
        elif mtype in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"):
            self._param(msg)
        elif mtype.startswith("MISSION_") and getattr(msg, "mission_type", None) == FENCE:
            self.fence.handle(msg)
        elif mtype in ("MISSION_REQUEST_LIST",):  # no mission and no rally points are kept
            self.send_message(
                self.mav.mission_count_encode(
                    msg.get_srcSystem(), msg.get_srcComponent(), 0, getattr(msg, "mission_type", 0)
                )
            )
        elif mtype == "MISSION_CLEAR_ALL":
            self.send_message(
                self.mav.mission_ack_encode(
                    msg.get_srcSystem(),
                    msg.get_srcComponent(),
                    MAV.MAV_MISSION_ACCEPTED,
                    getattr(msg, "mission_type", 0),
                )
            )
        elif mtype == "PING":
            if msg.target_system == 0:
                self.send_message(
                    self.mav.ping_encode(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent())
                )
        elif mtype == "TIMESYNC":
            if msg.tc1 == 0:
                self.send_message(self.mav.timesync_encode(time.monotonic_ns(), msg.ts1))
        elif mtype == "TUNNEL" and self.tunnel_handler is not None:
            self.tunnel_handler(cast("MockAutopilot", self), msg)  # a part of one

    # commands ------------------------------------------------------------------------------------------

    def _command(self, msg: Any) -> None:
        command = msg.command
        if command in self._drop_commands:
            left = self._drop_commands[command]
            if left is None:
                return
            if left > 0:
                self._drop_commands[command] = left - 1
                return
            del self._drop_commands[command]
        if command in self.forced_results:
            self._ack(msg, command, self.forced_results[command])
            return
        p = [msg.param1, msg.param2, msg.param3, msg.param4]
        if msg.get_type() == "COMMAND_INT":
            p += [msg.x, msg.y, msg.z]
            frame = msg.frame
            if command == MAV.MAV_CMD_DO_REPOSITION and not self._takes_frame(frame):
                self._ack(msg, command, MAV_RESULT_UNSUPPORTED_MAV_FRAME)
                return
        else:
            p += [msg.param5, msg.param6, msg.param7]
            frame = MAV.MAV_FRAME_GLOBAL
            if command == MAV.MAV_CMD_DO_REPOSITION:
                p[4], p[5] = (
                    to_deg_e7(p[4]) if math.isfinite(p[4]) else 0,
                    to_deg_e7(p[5]) if math.isfinite(p[5]) else 0,
                )
        result = self._run_command(msg, command, p, frame)
        if result is not None:
            self._ack(msg, command, result)

    def _takes_frame(self, frame: int) -> bool:
        return self.reposition_frames is None or frame in self.reposition_frames

    def _run_command(self, msg: Any, command: int, p: list[float], frame: int) -> int | None:
        R = MAV
        if command == R.MAV_CMD_SET_MESSAGE_INTERVAL:
            msg_id, interval_us = int(p[0]), p[1]
            if msg_id not in STREAMABLE:
                return R.MAV_RESULT_FAILED
            if self._forget.get(msg_id, 0) > 0:
                self._forget[msg_id] -= 1
                return R.MAV_RESULT_ACCEPTED
            if interval_us < 0:
                self.intervals.pop(msg_id, None)
            elif interval_us == 0:
                default = self.personality.default_streams.get(msg_id)
                if default:
                    self.intervals[msg_id] = default
                else:
                    self.intervals.pop(msg_id, None)
            else:
                self.intervals[msg_id] = max(interval_us / 1e6, 0.005)
            self.next_due[msg_id] = 0.0
            return R.MAV_RESULT_ACCEPTED
        if command in (
            R.MAV_CMD_REQUEST_MESSAGE,
            R.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
            R.MAV_CMD_GET_HOME_POSITION,
        ):
            msg_id = {
                R.MAV_CMD_REQUEST_MESSAGE: int(p[0]),
                R.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: R.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
                R.MAV_CMD_GET_HOME_POSITION: R.MAVLINK_MSG_ID_HOME_POSITION,
            }[command]
            if msg_id not in STREAMABLE:
                return self.personality.request_refused
            reply = self._build(msg_id)
            if reply is None:
                return R.MAV_RESULT_FAILED  # e.g. home not set yet (as in the SITL log)
            self._ack(msg, command, R.MAV_RESULT_ACCEPTED)
            self.send_message(reply)
            return None
        if command == R.MAV_CMD_DO_SET_MODE:
            return self._set_custom_mode(self.personality.autopilot.custom_mode_from_command(p[1], p[2]))
        if command == R.MAV_CMD_COMPONENT_ARM_DISARM:
            return self._arm(p[0] >= 0.5, p[1] == 21196)
        if command == R.MAV_CMD_NAV_TAKEOFF:
            result = self.personality.takeoff(self, p[6])
            if result == R.MAV_RESULT_ACCEPTED and self.target is not None:
                for text in self.personality.takeoff_texts:
                    self.statustext(text.format(alt=self.target[2]))
            return result
        if command == R.MAV_CMD_NAV_LAND:
            return self._set_mode_name("LAND")
        if command == R.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._set_mode_name("RTL")
        if command == R.MAV_CMD_DO_REPOSITION:
            return self._reposition(p, frame)
        if command == R.MAV_CMD_DO_FENCE_ENABLE and self.personality.fence_enable_command:
            return self.fence.enable(p[0])
        if command == R.MAV_CMD_DO_CHANGE_SPEED:
            if p[1] > 0:
                self.speed = p[1]
            return R.MAV_RESULT_ACCEPTED
        if command == R.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN:
            if self.armed:
                return self.personality.reboot_refused
            if int(p[0]) == 1:
                self._ack(msg, command, R.MAV_RESULT_ACCEPTED)
                self.reboot(1.0)
                return None
            return R.MAV_RESULT_UNSUPPORTED
        return R.MAV_RESULT_UNSUPPORTED

    def _set_mode_name(self, name: str) -> int:
        return self._set_custom_mode(self.personality.custom_mode(name))

    def _set_custom_mode(self, custom_mode: int) -> int:
        refused = self.personality.refuse_mode(self, custom_mode)
        if refused is not None:
            return refused
        previous = self.mode_name
        self.custom_mode = custom_mode
        now_name = self.mode_name
        if now_name == self.personality.autopilot.command_mode and previous != now_name:
            # hold where we are until told otherwise
            self.target = (self.lat, self.lon, self.rel_alt) if self.rel_alt > 0.05 else None
        return MAV.MAV_RESULT_ACCEPTED

    def _arm(self, arm: bool, force: bool) -> int:
        p = self.personality
        if not arm:
            if self.armed and self.rel_alt > 0.05 and not force:
                self.statustext(p.disarm_flying_text, MAV.MAV_SEVERITY_CRITICAL)
                return p.arm_refused
            self.armed = False
            self.target = None
            return MAV.MAV_RESULT_ACCEPTED
        if self.armed:
            return MAV.MAV_RESULT_ACCEPTED
        reason = None
        if self.arming_refusal is not None:
            reason = self.arming_refusal
        elif (not_armable := self._not_armable()) is not None:
            reason = not_armable
        elif not self.fence.allows(self.lat, self.lon):
            reason = p.outside_fence_reason
        elif p.armable_modes is not None and self.mode_name not in p.armable_modes:
            self.statustext("Arm: Mode not armable", MAV.MAV_SEVERITY_CRITICAL)
            return p.arm_refused
        if reason is not None and not force:
            self.statustext(f"{p.arm_prefix}: {reason}", MAV.MAV_SEVERITY_CRITICAL)
            return p.arm_refused
        self.armed = True
        return MAV.MAV_RESULT_ACCEPTED

    def _reposition(self, p: list[float], frame: int) -> int:
        if not self.armed or self.rel_alt <= 0.05:
            return self.personality.reposition_refused
        lat = from_deg_e7(int(p[4])) if p[4] else self.lat
        lon = from_deg_e7(int(p[5])) if p[5] else self.lon
        alt = self._relative_alt(p[6], frame) if math.isfinite(p[6]) else self.rel_alt
        if not self.fence.allows(lat, lon):
            self.fence.refused += 1
            return self.personality.reposition_outside_fence(self)
        if p[0] > 0:
            self.speed = p[0]
        self._set_mode_name(self.personality.autopilot.command_mode)
        self.target = (lat, lon, alt)
        return MAV.MAV_RESULT_ACCEPTED

    def _relative_alt(self, alt: float, frame: int) -> float:
        if frame in (MAV.MAV_FRAME_GLOBAL, MAV.MAV_FRAME_GLOBAL_INT):
            return alt - self.home[2]
        return alt  # relative (and terrain frames, treated as relative over flat ground)

    def _position_target(self, msg: Any) -> None:
        self.last_setpoint = time.monotonic()
        if msg.type_mask & 0b111:  # position ignored: velocity/acceleration targets not modelled
            return
        if not self.armed or self.rel_alt <= 0.05 or self.mode_name not in self.personality.setpoint_modes:
            return  # ArduCopter ignores position targets outside GUIDED; PX4 outside OFFBOARD
        self._fenced_target(
            from_deg_e7(msg.lat_int), from_deg_e7(msg.lon_int), self._relative_alt(msg.alt, msg.coordinate_frame)
        )

    def _fenced_target(self, lat: float, lon: float, alt: float) -> None:
        """Take a position target, unless an enforced fence excludes it: then it is ignored and the
        vehicle keeps its previous target (or holds), as ArduCopter's GUIDED mode refuses a
        destination outside the fence (no ack exists for SET_POSITION_TARGET_*; it only logs it)."""
        if not self.fence.allows(lat, lon):
            self.fence.refused += 1
            return
        self.target = (lat, lon, alt)

    def _local_target(self, msg: Any) -> None:
        self.last_setpoint = time.monotonic()
        if msg.type_mask & 0b111 or self.mode_name not in self.personality.setpoint_modes or not self.armed:
            return
        lat, lon = offset_m(self.home[0], self.home[1], msg.x, msg.y)
        self._fenced_target(lat, lon, -msg.z)

    def _param(self, msg: Any) -> None:
        names = sorted(self.params)

        def value(name: str) -> None:
            self.send_message(
                self.mav.param_value_encode(
                    name.encode(), float(self.params[name]), MAV.MAV_PARAM_TYPE_REAL32, len(names), names.index(name)
                )
            )

        mtype = msg.get_type()
        if mtype == "PARAM_REQUEST_LIST":
            for n in names:
                value(n)
        elif mtype == "PARAM_REQUEST_READ":
            pid = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
            name = (
                pid.rstrip("\x00")
                if msg.param_index < 0
                else (names[msg.param_index] if msg.param_index < len(names) else "")
            )
            if name in self.params:
                value(name)
        else:
            pid = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
            name = pid.rstrip("\x00")
            if name in self.params:
                self.params[name] = float(msg.param_value)
                physics = self.personality.physics_params.get(name)
                if physics is not None and msg.param_value > 0:
                    attribute, scale = physics
                    setattr(self, attribute, float(msg.param_value) * scale)
                    for other, (attr, sc) in self.personality.physics_params.items():
                        if attr == attribute:
                            self.params[other] = getattr(self, attr) / sc
                value(name)
