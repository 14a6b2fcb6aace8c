"""ArduPilot Copter over pymavlink: every ArduPilot quirk the controller depends on lives here.

Sequence (as ArduCopter 4.7 SITL showed it, docs/mavlink.md):
- connect: wait for the first HEARTBEAT, then ask for telemetry with MAV_CMD_SET_MESSAGE_INTERVAL, once
  per message (a request sent before the first heartbeat is acknowledged and then lost, and the
  streams only start at "ArduPilot Ready", 1.4 s after it). A message that does not come within its
  patience, or stops (a reboot), is asked for again, alone; an ACCEPTED ack proves nothing.
- preflight (`wait_ready`): GUIDED first (ArduCopter takes any mode while disarmed), then wait until
  it reports it can arm in GUIDED: a GPS fix (GPS_RAW_INT), the EKF's absolute horizontal position
  without constant-position mode (EKF_STATUS_REPORT), home (HOME_POSITION), and the SYS_STATUS
  pre-arm bit healthy in a report sent after the switch (in STABILIZE it reads healthy 18 s before
  GUIDED can arm). Its STATUSTEXTs are reported meanwhile; a timeout names the last reason.
- arm -> MAV_CMD_NAV_TAKEOFF to the altitude above home -> wait for the altitude ->
  SET_POSITION_TARGET_GLOBAL_INT (frame GLOBAL_RELATIVE_ALT_INT, position-only type_mask 3576) ->
  LAND or RTL. A position target has no ack; ArduCopter reports the target it flies to
  (POSITION_TARGET_GLOBAL_INT, asked for with the first one), so a lost one is sent again as soon as two
  reports show the old target, and once a second while none confirms it.
The speed parameters (descriptions.ARDUPILOT.limit_parameters) are read with PARAM_REQUEST_READ. A
geofence goes up with the mission protocol (mission_type FENCE) and is switched on with
MAV_CMD_DO_FENCE_ENABLE (see upload_fence).
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from swarmctl.geo.fence import farthest_metres
from swarmctl.mavlink.autopilots.descriptions import ARDUPILOT
from swarmctl.mavlink.codec import distance_m, from_deg_e7, to_deg_e7
from swarmctl.mavlink.errors import CommandRejected, CommandTimeout, MavlinkError, WaitTimeout
from swarmctl.mavlink.network import MAV, MavlinkLink
from swarmctl.mavlink.vehicle import Home, Odometer, Position, ReadyWait, Target, Vehicle

log = logging.getLogger(__name__)

# Position-only: ignore velocity (bits 3-5), acceleration (6-8), yaw (10) and yaw rate (11).
TYPE_MASK_POSITION_ONLY = 3576
PREARM_BIT = MAV.MAV_SYS_STATUS_PREARM_CHECK  # 0x10000000 in SYS_STATUS present/health
EKF_POSITION_OK = MAV.EKF_POS_HORIZ_ABS  # and not EKF_CONST_POS_MODE
GPS_3D_FIX = MAV.GPS_FIX_TYPE_3D_FIX
# ArduPilot runs its pre-arm checks at 1 Hz: the pre-arm bit counts from a SYS_STATUS sent this long
# after the switch to GUIDED (an earlier one may still carry the STABILIZE result)
PREARM_LAG_S = 1.0
# a requested message that has not come (or has stopped) for this long, or three of its periods, is
# asked for again: SITL starts its streams 1.4 s after the first heartbeat
STREAM_PATIENCE_S = 3.0
KEEP_TELEMETRY_S = 1.0  # how often the driver looks for telemetry that is overdue (patience: 3 s)
# a position target is sent again after this long while no report of the vehicle's target confirms it
TARGET_RESEND_S = 1.0
# ... and at once when this many of its target reports since it was sent show another target: the first
# may have left the vehicle before the target reached it
STALE_TARGET_REPORTS = 2
TARGET_MATCH_M = 0.3  # a reported target this close (horizontally) to the one sent is that one (cm rounding)
TARGET_REPORT_ASKS = 3  # a vehicle asked this often that never reports its target is not asked again
# PARAM_REQUEST_READ is sent this many more times without an answer (6 in all: on a link losing 20 % each
# way a read goes unanswered 4 times in a row once in 60, and the GCS failsafe's refuses the mission);
# ArduPilot answers no name it does not have, so that case costs 2 s more than with 3
PARAMETER_RETRIES = 5
# after a take-off unanswered, how long the vehicle has to show its climb (ArduCopter: the motors spool
# up first) before the take-off is sent again
TAKEOFF_SHOWS_S = 3.0
_WARNING = MAV.MAV_SEVERITY_WARNING  # STATUSTEXTs this severe or worse are reasons (PreArm:, Arm:, ...)


def whole_parameter(name: str, value: float, vehicle: str) -> int:
    """A parameter that holds a whole number (a bit mask, an enum), as an int; MavlinkError when the
    vehicle answered something else (NaN, infinity, a fraction: not a value ArduPilot sends)."""
    if not math.isfinite(value) or value != int(value):
        raise MavlinkError(f"{vehicle}: {name} reads as {value}, not a whole number")
    return int(value)


@dataclass(frozen=True)
class Stream:
    """A telemetry message the driver asks for with SET_MESSAGE_INTERVAL."""

    name: str  # the message type
    rate_hz: float | None  # None: the vehicle's telemetry rate
    required: bool = True  # a vehicle refusing it cannot be flown; otherwise the check it serves is skipped
    after_ekf: bool = False  # sent only once home is set: expected once the EKF has an absolute position
    while_guided: bool = False  # sent only while flying to a target in GUIDED: expected once one is sent

    @property
    def msg_id(self) -> int:
        return getattr(MAV, f"MAVLINK_MSG_ID_{self.name}")


TELEMETRY = (
    Stream("GLOBAL_POSITION_INT", None),  # position, for everything
    Stream("SYS_STATUS", 2.0),  # battery, the pre-arm bit (2 Hz: a fresh one soon after PREARM_LAG_S)
    Stream("EKF_STATUS_REPORT", 1.0, required=False),  # readiness: the EKF's position estimate
    Stream("GPS_RAW_INT", 1.0, required=False),  # readiness: the GPS fix
    Stream("HOME_POSITION", 0.5, after_ekf=True),  # home, which ArduCopter sets again at arming
)

# the target the vehicle flies to (ArduCopter: GCS_MAVLINK_Copter::send_position_target_global_int, AMSL,
# for a mode with a target), the receipt of a position target; asked for with the first target sent
TARGET_REPORTS = Stream("POSITION_TARGET_GLOBAL_INT", None, required=False, while_guided=True)

_UPLOAD_ANSWERS = ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK")


def fence_items(mav: Any, target_system: int, target_component: int, vertices: list[tuple[float, float]]) -> list[Any]:
    """The MISSION_ITEM_INT messages of one inclusion polygon (mission_type FENCE): one per vertex,
    MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, param1 = the vertex count, frame MAV_FRAME_GLOBAL,
    x/y = lat/lon in degE7."""
    n = float(len(vertices))
    return [
        mav.mission_item_int_encode(
            target_system,
            target_component,
            seq,
            MAV.MAV_FRAME_GLOBAL,
            MAV.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
            0,
            0,
            n,
            0.0,
            0.0,
            0.0,
            to_deg_e7(lat),
            to_deg_e7(lon),
            0.0,
            MAV.MAV_MISSION_TYPE_FENCE,
        )
        for seq, (lat, lon) in enumerate(vertices)
    ]


class ArduPilotVehicle(Vehicle):
    """One ArduCopter (sysid) on a MavlinkLink that may carry other vehicles too."""

    autopilot_info = ARDUPILOT
    armed_report = "the armed flag in HEARTBEAT"

    def __init__(
        self,
        link: MavlinkLink,
        sysid: int,
        *,
        name: str | None = None,
        telemetry_rate_hz: float = 5.0,
        command_timeout: float = 1.0,
        retries: int = 3,
        parameter_retries: int = PARAMETER_RETRIES,
        mission_timeout: float = 1.5,
        owns_link: bool = False,
    ):
        self.link, self.sysid = link, sysid
        self.name = name or f"vehicle {sysid}"
        self.telemetry_rate_hz = telemetry_rate_hz
        self.command_timeout, self.retries, self.parameter_retries = command_timeout, retries, parameter_retries
        # mission protocol: longer than ArduPilot's own 1 s re-request, so resends do not race it
        self.mission_timeout = mission_timeout
        self.owns_link = owns_link
        self.target: Target | None = None
        self.odometer = Odometer()
        self._target_sent = 0.0
        self._target_confirmed = False  # a report of the vehicle's target has shown the one sent last
        self._stale_reports = 0  # reports of its target showing another one since (sent, or confirmed)
        self.resent: Counter[str] = Counter()  # position targets sent again: "stale" (reports), "silent" (none)
        self._telemetry_timer: asyncio.TimerHandle | None = None  # the check for overdue telemetry
        self._asking: asyncio.Task | None = None  # asking again for overdue telemetry
        self.unsupported: set[str] = set()  # telemetry messages the vehicle refused to stream
        self.requests: Counter[str] = Counter()  # SET_MESSAGE_INTERVAL sent, per message
        self._asked: dict[str, float] = {}  # message -> when it was last asked for (time.monotonic())
        self._expected_since: dict[str, float] = {}  # after_ekf messages: since when they are due
        self._mode_since: tuple[int | None, float] = (None, 0.0)  # the reported mode and since when
        self._listening = False
        self._position_of: Any = None  # the GLOBAL_POSITION_INT `_position` was made from
        self._position: Position | None = None

    @classmethod
    async def open(
        cls, connection: str, sysid: int, *, signing_key: bytes | None = None, **kw: Any
    ) -> ArduPilotVehicle:
        """A vehicle on its own link (use MavlinkLink + the constructor to share a link)."""
        link = await MavlinkLink(connection, signing_key=signing_key).open()
        return cls(link, sysid, owns_link=True, **kw)

    def add_listener(self, callback: Any, types: Any = None) -> bool:
        """Every message of the link (which may carry other vehicles too), or those of `types`, goes to
        callback(msg)."""
        self.link.add_listener(callback, types)
        return True

    def write_frame(self, frame: bytes) -> bool:
        """The frame, as it is (its own system id and signature), onto the link's transport."""
        writer = getattr(getattr(self.link, "mav", None), "file", None)
        if writer is None:
            return False
        try:
            writer.write(frame)  # the link's transport, through the recorder's tap (tlog)
        except (OSError, ValueError, AttributeError):  # a link closing
            return False
        return True

    # --- commands ------------------------------------------------------------------------------------

    async def _command(self, command: int, *params: float, **kw: Any) -> Any:
        kw.setdefault("timeout", self.command_timeout)
        kw.setdefault("retries", self.retries)
        return await self.link.command(self.sysid, command, params, vehicle=self.name, **kw)

    async def connect(self, timeout: float = 15.0) -> None:
        """Wait for the first HEARTBEAT, then ask for the telemetry (TELEMETRY) once; a task asks again
        for a message that does not come or stops."""
        await self.link.wait_heartbeat(self.sysid, timeout)
        if not self._listening:
            self.link.add_listener(self._on_position, ("GLOBAL_POSITION_INT",))
            self.link.add_listener(self._on_heartbeat, ("HEARTBEAT",))
            self.link.add_listener(self._on_target_report, (TARGET_REPORTS.name,))
            self._listening = True
        await self.request_telemetry()
        if self._telemetry_timer is None:
            self._telemetry_timer = asyncio.get_running_loop().call_later(KEEP_TELEMETRY_S, self._keep_telemetry)

    def _on_position(self, msg: Any) -> None:
        """This vehicle's position reports into the odometer (with the figures `position` gives)."""
        if msg._header.srcSystem == self.sysid and (msg.lat != 0 or msg.lon != 0):  # 0, 0: no position yet
            self.odometer.add_fix(msg.lat / 1e7, msg.lon / 1e7, msg.relative_alt / 1000.0)
            self._position_reported()

    def _on_target_report(self, msg: MAV.MAVLink_position_target_global_int_message) -> None:
        """The vehicle's report of the target it flies to, against the one sent last."""
        t = self.target
        if msg._header.srcSystem != self.sysid or t is None or not self._target_sent:
            return
        there = distance_m(from_deg_e7(msg.lat_int), from_deg_e7(msg.lon_int), t.lat, t.lon)
        if there <= TARGET_MATCH_M:
            self._target_confirmed, self._stale_reports = True, 0
        else:
            self._stale_reports += 1

    def _on_heartbeat(self, msg: Any) -> None:
        """This vehicle's mode changes, with when they were first reported."""
        if msg._header.srcSystem == self.sysid and msg.custom_mode != self._mode_since[0]:
            self._mode_since = (msg.custom_mode, time.monotonic())

    async def request_telemetry(self, streams: tuple[Stream, ...] | list[Stream] = TELEMETRY) -> None:
        """Ask for these messages (SET_MESSAGE_INTERVAL each). A refusal of a required one raises
        CommandRejected; an optional one refused is not asked for again (its check is skipped)."""
        for stream in streams:
            if stream.name in self.unsupported:
                continue
            self._asked[stream.name] = time.monotonic()
            self.requests[stream.name] += 1
            try:
                await self.link.set_message_interval(
                    self.sysid,
                    stream.msg_id,
                    stream.rate_hz or self.telemetry_rate_hz,
                    vehicle=self.name,
                    timeout=self.command_timeout,
                    retries=self.retries,
                )
            except CommandRejected as exc:
                if stream.required:
                    raise
                self.unsupported.add(stream.name)
                log.info("%s: no %s (%s)", self.name, stream.name, exc.result)
            except CommandTimeout as exc:
                # the request may have gone through with its answers lost; whether the message comes is
                # what counts, and one that does not is asked for again (_keep_telemetry)
                log.info("%s: %s; asked again if %s does not come", self.name, exc, stream.name)
            self._asked[stream.name] = time.monotonic()

    def overdue(self, stream: Stream, now: float) -> bool:
        """The message should be arriving but has not for its patience (STREAM_PATIENCE_S or three of
        its periods) since it was asked for, since it was last received, and (HOME_POSITION) since the
        EKF has had an absolute position."""
        peer = self.link.peers.get(self.sysid)
        if peer is None or stream.name in self.unsupported:
            return False
        since = 0.0
        if stream.while_guided:
            if not self._target_sent or not self.armed or self.mode != ARDUPILOT.command_mode:
                return False
            since = self._target_sent
        if stream.after_ekf and "EKF_STATUS_REPORT" not in self.unsupported:
            if not self._ekf_ok(fresh=True):
                self._expected_since.pop(stream.name, None)
                return False
            since = self._expected_since.setdefault(stream.name, now)
        patience = max(STREAM_PATIENCE_S, 3.0 / (stream.rate_hz or self.telemetry_rate_hz))
        last = max(peer.received_at.get(stream.name, 0.0), self._asked.get(stream.name, 0.0), since)
        return now - last > patience

    def _keep_telemetry(self) -> None:
        """Every KEEP_TELEMETRY_S (a timer, not a task: it runs for every vehicle all the time), while the
        vehicle's heartbeats come: ask again for the messages that are overdue, each alone (one request
        at a time; the checks pause while it is in flight)."""
        self._telemetry_timer = asyncio.get_running_loop().call_later(KEEP_TELEMETRY_S, self._keep_telemetry)
        if self.lost or (self._asking is not None and not self._asking.done()):
            return
        now = time.monotonic()
        due = [s for s in TELEMETRY if self.overdue(s, now)]
        if TARGET_REPORTS.name in self._asked and self.overdue(TARGET_REPORTS, now):
            if self._gives_up(TARGET_REPORTS):
                log.info(
                    "%s: no %s after %d requests: position targets are confirmed by none",
                    self.name,
                    TARGET_REPORTS.name,
                    self.requests[TARGET_REPORTS.name],
                )
            else:
                due.append(TARGET_REPORTS)
        if due:
            self._asking = asyncio.ensure_future(self._ask_again(due))

    def _gives_up(self, stream: Stream) -> bool:
        """A stream asked for TARGET_REPORT_ASKS times and never received is not asked for again (a firmware
        that takes the request but does not send it): True when it is given up now."""
        if self.requests[stream.name] < TARGET_REPORT_ASKS or stream.name in self.link.peer(self.sysid).received_at:
            return False
        self.unsupported.add(stream.name)
        return True

    async def _ask_again(self, due: list[Stream], again: bool = True) -> None:
        log.info("%s: asking%s for %s", self.name, " again" if again else "", ", ".join(s.name for s in due))
        try:
            await self.request_telemetry(due)
        except MavlinkError as exc:
            log.info("%s: telemetry request failed: %s", self.name, exc)

    # --- readiness -------------------------------------------------------------------------------------

    def _ekf_ok(self, fresh: bool = False) -> bool:
        """EKF_STATUS_REPORT says: an absolute horizontal position, not in constant-position mode
        (`fresh`: and the report is recent, STREAM_PATIENCE_S)."""
        ekf = self._msg("EKF_STATUS_REPORT")
        if ekf is None:
            return False
        if fresh:
            at = self.link.peer(self.sysid).received_at.get("EKF_STATUS_REPORT", 0.0)
            if time.monotonic() - at > STREAM_PATIENCE_S:
                return False
        return bool(ekf.flags & EKF_POSITION_OK) and not ekf.flags & MAV.EKF_CONST_POS_MODE

    def not_ready(self) -> list[str]:
        """What the vehicle still lacks to arm in GUIDED (empty: ready)."""
        if self.lost:
            return ["its heartbeat"]
        missing = []
        mode, since = self._mode_since
        if self.booting():
            missing.append("the end of its boot (HEARTBEAT system_status BOOT)")
        if self._custom_mode() != ARDUPILOT.custom_mode(ARDUPILOT.command_mode):
            missing.append(f"mode {ARDUPILOT.command_mode} (in {self.mode})")
        gps = self._msg("GPS_RAW_INT")
        if "GPS_RAW_INT" not in self.unsupported and (gps is None or gps.fix_type < GPS_3D_FIX):
            missing.append("a GPS fix" + ("" if gps is None else f" (fix type {gps.fix_type})"))
        ekf = self._msg("EKF_STATUS_REPORT")
        if "EKF_STATUS_REPORT" not in self.unsupported and not self._ekf_ok():
            flags = "" if ekf is None else f" (EKF_STATUS_REPORT flags {ekf.flags})"
            missing.append(f"the EKF's position estimate{flags}")
        if self.home is None:
            missing.append("home")
        if self.position is None:
            missing.append("a position")
        st = self._msg("SYS_STATUS")
        if st is None:
            missing.append("the pre-arm checks (no SYS_STATUS yet)")
        elif st.onboard_control_sensors_present & PREARM_BIT:
            at = self.link.peer(self.sysid).received_at.get("SYS_STATUS", 0.0)
            if at < since + PREARM_LAG_S or not st.onboard_control_sensors_health & PREARM_BIT:
                missing.append("the pre-arm checks")
        return missing

    def booting(self) -> bool:
        """The autopilot's heartbeat says MAV_STATE_BOOT. ArduCopter accepts a mode then, and its
        initialisation ends by setting its initial mode (INITIAL_MODE, STABILIZE): a mode asked for
        during the boot is undone (measured on SITL, docs/mavlink.md)."""
        hb = self.link.peer(self.sysid).heartbeat
        return hb is not None and hb.system_status == MAV.MAV_STATE_BOOT

    def ready(self) -> bool:
        """The vehicle reports it can arm in GUIDED (see not_ready)."""
        return not self.not_ready()

    async def _await_vehicle(self, timeout: float) -> None:
        await self.link.wait_heartbeat(self.sysid, timeout)

    async def _towards_ready(self, wait: ReadyWait) -> None:
        """GUIDED first (once the autopilot has booted): a refused mode, or one its heartbeat does not
        report in time, is asked for again a second later. Each STATUSTEXT the vehicle sends goes to the
        report; the last of warning severity or worse (PreArm: ..., Arm: ...) is the reason NotReady
        names."""
        if (
            self._custom_mode() != ARDUPILOT.custom_mode(ARDUPILOT.command_mode)
            and not self.lost
            and not self.booting()
            and time.monotonic() - wait.refused > 1.0
        ):
            try:
                await self.set_mode(ARDUPILOT.command_mode)
            except (CommandRejected, CommandTimeout, WaitTimeout) as exc:  # e.g. firmware that wants a position
                wait.refused = time.monotonic()
                if isinstance(exc, CommandRejected):
                    wait.reason = f"{exc.command} {ARDUPILOT.command_mode} refused: {exc.result}"
                elif isinstance(exc, CommandTimeout):
                    wait.reason = f"mode {ARDUPILOT.command_mode} not answered ({self.mode})"
                else:
                    wait.reason = f"mode {ARDUPILOT.command_mode} accepted but not reported ({self.mode})"
                wait.say(wait.reason + ", asking again")
        for at, severity, text in list(self.link.peer(self.sysid).statustexts):
            if at > wait.heard:
                wait.heard = at
                if severity <= _WARNING:
                    wait.reason = text
                wait.say(text)

    async def _await_news(self) -> None:
        """The vehicle's next message, or 0.2 s."""
        try:
            await self.link.wait_message(lambda m: m.get_srcSystem() == self.sysid, 0.2)
        except TimeoutError:
            pass

    async def set_mode(self, mode: str, timeout: float = 3.0) -> None:
        name = mode.upper()
        number = ARDUPILOT.custom_mode(name)  # ValueError naming the known modes
        param2, param3 = ARDUPILOT.set_mode_params(name)
        try:
            await self._command(MAV.MAV_CMD_DO_SET_MODE, float(MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), param2, param3)
        except CommandTimeout as exc:
            # unanswered, perhaps taken with its answers lost: the heartbeat's mode says which
            if not await self._shows(lambda: self._custom_mode() == number, timeout):
                raise exc from None
            log.info("%s: %s, but the vehicle reports %s", self.name, exc, name)
            return
        await self._poll(lambda: self._custom_mode() == number, timeout, f"mode {name}")

    async def _send_arm(self) -> None:
        # ArduPilot answers FAILED (and an "Arm: ..." STATUSTEXT) while it cannot: `arm` retries
        await self._command(MAV.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)

    async def disarm(self) -> None:
        await self._command(MAV.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)

    async def read_parameter(self, name: str) -> float:
        """PARAM_REQUEST_READ by name (CommandTimeout when unanswered: ArduPilot does not answer a name
        it does not have)."""
        return await self.link.read_param(
            self.sysid, name, timeout=self.command_timeout, retries=self.parameter_retries, vehicle=self.name
        )

    async def takeoff(self, rel_alt: float) -> None:
        try:
            await self._command(MAV.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, float(rel_alt))
        except CommandRejected:
            # When the first ACK is lost, the retry reaches a vehicle that is already climbing, and
            # ArduCopter refuses a take-off in the air: that refusal means the first one worked.
            await asyncio.sleep(0.3)  # let a position report of the climb arrive
            pos = self.position
            if not (self.armed and pos is not None and pos.rel_alt > 0.3):
                raise

    async def _take_off(self, rel_alt: float, left: Callable[[], float]) -> None:
        climbing = lambda: self.armed and (p := self.position) is not None and p.rel_alt > 0.3  # noqa: E731
        while True:
            try:
                await self.takeoff(rel_alt)
                break
            except CommandTimeout as exc:
                # unanswered, perhaps taken with its answers lost: the climb says which; else again
                if await self._shows(climbing, min(TAKEOFF_SHOWS_S, left())):
                    log.info("%s: %s, but the vehicle climbs", self.name, exc)
                    break
                if left() <= self.command_timeout * (1 + self.retries):
                    raise exc from None
        # a report of 0, 0 (no position) can come between the ready check and now, from the vehicle or
        # in its name: wait for a real one instead of failing on it
        await self._aim_above(rel_alt, left(), "after take-off")

    async def goto(self, lat: float, lon: float, rel_alt: float) -> None:
        self.goto_nowait(lat, lon, rel_alt)

    def goto_nowait(self, lat: float, lon: float, rel_alt: float) -> bool:
        """SET_POSITION_TARGET_GLOBAL_INT has no answer: sent at once."""
        self.target = Target(lat, lon, rel_alt)
        self._send_target()
        return True

    def _send_target(self) -> None:
        t = self.target
        assert t is not None
        if TARGET_REPORTS.name not in self._asked and (self._asking is None or self._asking.done()):
            self._asked[TARGET_REPORTS.name] = time.monotonic()  # asked once, here; later as any stream
            self._asking = asyncio.ensure_future(self._ask_again([TARGET_REPORTS], again=False))
        peer = self.link.peer(self.sysid)
        self.link.send(
            self.link.mav.set_position_target_global_int_encode(
                int(time.monotonic() * 1000) & 0xFFFFFFFF,
                self.sysid,
                peer.compid,
                MAV.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                TYPE_MASK_POSITION_ONLY,
                to_deg_e7(t.lat),
                to_deg_e7(t.lon),
                float(t.rel_alt),
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
            )
        )
        self._target_sent = time.monotonic()
        self._target_confirmed, self._stale_reports = False, 0

    async def _on_wait(self) -> None:
        # SET_POSITION_TARGET has no ack: while waiting in GUIDED it is sent again when the vehicle's
        # reports of its target show another one, or once a second while none has shown this one
        if self.target is None or self.mode != ARDUPILOT.command_mode or not self._target_sent:
            return
        if self._stale_reports >= STALE_TARGET_REPORTS:
            self.resent["stale"] += 1
            self._send_target()
        elif not self._target_confirmed and time.monotonic() - self._target_sent > TARGET_RESEND_S:
            self.resent["silent"] += 1
            self._send_target()

    async def land(self) -> None:
        self._target_sent = 0.0
        await self.set_mode("LAND")

    async def rtl(self) -> None:
        self._target_sent = 0.0
        await self.set_mode("RTL")

    async def resume(self) -> None:
        self.target = None  # GUIDED with no target holds position
        self._target_sent = 0.0
        await self.set_mode(ARDUPILOT.command_mode)

    async def _send_fence(self, vertices: list[tuple[float, float]]) -> None:
        """The inclusion fence with the mission protocol (mission_type FENCE), then switched on with
        MAV_CMD_DO_FENCE_ENABLE. What a breach does is the vehicle's FENCE_ACTION."""
        peer = self.link.peer(self.sysid)
        items = fence_items(self.link.mav, self.sysid, peer.compid, vertices)
        await self._upload(items, MAV.MAV_MISSION_TYPE_FENCE, "the fence upload")
        await self._command(MAV.MAV_CMD_DO_FENCE_ENABLE, 1.0)

    async def _check_fence_settings(self, vertices: list[tuple[float, float]]) -> None:
        """Refuse a fence the vehicle's own settings would spoil, before anything is uploaded: a
        FENCE_TYPE without the polygon (4; the polygon would not be enforced), or, once home is known, a
        circle fence round home (FENCE_TYPE 2, radius FENCE_RADIUS, default 300 m) that does not hold
        the polygon (the vehicle would breach it inside the search area). swarmctl never changes these
        parameters itself."""
        read = self.read_parameter
        fence_type = whole_parameter("FENCE_TYPE", await read("FENCE_TYPE"), self.name)
        if not fence_type & 4:
            raise MavlinkError(
                f"{self.name}: FENCE_TYPE is {fence_type}, without the polygon (4): the vehicle "
                f"would not enforce the uploaded fence; set FENCE_TYPE to {fence_type | 4}"
            )
        home = self.home
        if fence_type & 2 and home is not None:
            radius = await read("FENCE_RADIUS")
            reach = farthest_metres(vertices, home.lat, home.lon)
            if not math.isfinite(radius):
                raise MavlinkError(f"{self.name}: FENCE_RADIUS reads as {radius}, not a number of metres")
            if radius < reach:
                raise MavlinkError(
                    f"{self.name}: FENCE_RADIUS is {radius:g} m but the fence reaches {reach:.0f} m from home, so "
                    f"the circle fence would cut the search area; set FENCE_RADIUS to at least "
                    f"{math.ceil(reach / 10) * 10} or take the circle (2) out of FENCE_TYPE (now {fence_type})"
                )

    async def _upload(self, items: list[Any], mission_type: int, what: str) -> None:
        """The mission protocol's upload: MISSION_COUNT, then each item the vehicle asks for with
        MISSION_REQUEST_INT (ArduPilot may ask with MISSION_REQUEST: it gets MISSION_ITEM_INT too),
        until MISSION_ACK. Without an answer within mission_timeout, the last message is sent again
        (up to `retries` times); if the final MISSION_ACK is what never comes, the upload starts over
        once. An INVALID_SEQUENCE ack is ArduPilot's answer to a duplicate item and does not end the
        transfer; any other refusal raises CommandRejected, silence CommandTimeout."""
        peer = self.link.peer(self.sysid)
        count = self.link.mav.mission_count_encode(self.sysid, peer.compid, len(items), mission_type)
        answers: asyncio.Queue = asyncio.Queue()
        me = self.link.system_id

        def listen(m: Any) -> None:
            if (
                m.get_type() in _UPLOAD_ANSWERS
                and m.get_srcSystem() == self.sysid
                and m.mission_type == mission_type
                and m.target_system in (0, me)
            ):
                answers.put_nowait(m)

        started = time.monotonic()
        resend, sent, attempts, restarted = count, -1, 1, False
        self.link.add_listener(listen, _UPLOAD_ANSWERS)
        try:
            self.link.send(count)
            while True:
                try:
                    m = await asyncio.wait_for(answers.get(), self.mission_timeout)
                except TimeoutError:
                    waiting = (
                        f"a request for item {sent + 1}" if sent < len(items) - 1 else "MISSION_ACK after the last item"
                    )
                    if attempts <= self.retries:
                        attempts += 1
                        log.info("%s: %s: no answer, sending again (waiting for %s)", self.name, what, waiting)
                        self.link.send(resend)
                        continue
                    if sent == len(items) - 1 and not restarted:  # the final ack was lost: start over
                        resend, sent, attempts, restarted = count, -1, 1, True
                        self.link.send(count)
                        continue
                    raise CommandTimeout(
                        f"{what} (waiting for {waiting})", self.name, attempts, self.mission_timeout
                    ) from None
                if m.get_type() != "MISSION_ACK":
                    if not 0 <= m.seq < len(items):
                        raise MavlinkError(f"{self.name}: {what}: the vehicle asked for item {m.seq} of {len(items)}")
                    resend, sent, attempts = items[m.seq], max(sent, m.seq), 1
                    self.link.send(resend)
                elif m.type == MAV.MAV_MISSION_ACCEPTED and sent == len(items) - 1:
                    return
                elif m.type != MAV.MAV_MISSION_INVALID_SEQUENCE:
                    entry = MAV.enums["MAV_MISSION_RESULT"].get(m.type)
                    result = entry.name.removeprefix("MAV_MISSION_") if entry is not None else str(m.type)
                    if m.type == MAV.MAV_MISSION_ACCEPTED:
                        result = f"ACCEPTED after {sent + 1} of {len(items)} items"
                    if not peer.texts_since(started):  # a STATUSTEXT saying why may trail the ack
                        try:
                            await self.link.wait_message(
                                lambda t: t.get_type() == "STATUSTEXT" and t.get_srcSystem() == self.sysid, 0.2
                            )
                        except TimeoutError:
                            pass
                    raise CommandRejected(what, self.name, result, peer.texts_since(started))
        finally:
            self.link.remove_listener(listen)

    async def close(self) -> None:
        if self._telemetry_timer is not None:
            self._telemetry_timer.cancel()
            self._telemetry_timer = None
        if self._asking is not None:
            self._asking.cancel()
            try:
                await self._asking
            except asyncio.CancelledError:
                pass
            self._asking = None
        if self._listening:
            self.link.remove_listener(self._on_position)
            self.link.remove_listener(self._on_heartbeat)
            self.link.remove_listener(self._on_target_report)
            self._listening = False
        if self.owns_link:
            await self.link.close()

    # --- state ----------------------------------------------------------------------------------------

    def _msg(self, mtype: str) -> Any:
        peer = self.link.peers.get(self.sysid)
        return None if peer is None else peer.messages.get(mtype)

    def _custom_mode(self) -> int | None:
        hb = self._msg("HEARTBEAT")
        return None if hb is None else hb.custom_mode

    @property
    def position(self) -> Position | None:
        m = self._msg("GLOBAL_POSITION_INT")
        if m is None or (m.lat == 0 and m.lon == 0):
            return None  # ArduPilot reports 0,0 until its EKF has an origin
        if m is not self._position_of:  # converted once per report, when first read
            self._position_of = m
            self._position = Position(from_deg_e7(m.lat), from_deg_e7(m.lon), m.relative_alt / 1000.0, m.alt / 1000.0)
        return self._position

    @property
    def home(self) -> Home | None:
        m = self._msg("HOME_POSITION")
        if m is None:
            return None
        return Home(from_deg_e7(m.latitude), from_deg_e7(m.longitude), m.altitude / 1000.0)

    @property
    def armed(self) -> bool:
        hb = self._msg("HEARTBEAT")
        return bool(hb is not None and hb.base_mode & MAV.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def mode(self) -> str:
        cm = self._custom_mode()
        return "UNKNOWN" if cm is None else ARDUPILOT.mode_name(cm)

    @property
    def lost(self) -> bool:
        return self.link.is_lost(self.sysid)

    @property
    def silenced(self) -> str | None:
        return self.link.silenced.get(self.sysid)

    @property
    def battery_remaining(self) -> int | None:
        st = self._msg("SYS_STATUS")
        return None if st is None or st.battery_remaining < 0 else int(st.battery_remaining)

    @property
    def clock_s(self) -> float | None:
        m = self._msg("GLOBAL_POSITION_INT")
        return None if m is None else m.time_boot_ms / 1000.0
