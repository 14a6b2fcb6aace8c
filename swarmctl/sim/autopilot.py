"""A mock ArduCopter / PX4 multicopter: a real MAVLink 2 endpoint (pymavlink bytes over UDP/TCP/serial).

What differs between the two firmwares comes from the mock's personality (personality.py), built on
the same autopilot descriptions the controller flies by; this module holds what they share.

It behaves like the real autopilot as far as a controller can see (checked against ArduCopter 4.7
SITL, docs/mavlink.md): HEARTBEAT type/autopilot/base_mode/custom_mode/system_status, a boot through
the stages a real one passes (boot.py: streams from "ArduPilot Ready", positions 0, 0 until the GPS
fix, home with the EKF origin, the EKF's absolute position last), pre-arm checks judged in the current
mode (healthy in STABILIZE before GUIDED can arm; "PreArm:" texts; an arm refused with FAILED + "Arm:
Need Position Estimate"), any mode taken while disarmed, takeoff only when armed in GUIDED,
COMMAND_ACK results, SET_MESSAGE_INTERVAL (a fresh ArduPilot sends only heartbeats), parameters (its
speeds among them), simple kinematics, a draining battery, a GCS failsafe, signing, faults injected
from tests (the slow EKF among them), a TCP port served as SITL serves SERIAL0 (serial0.py: boot on the
first client, console text before MAVLink), and a geofence (uploaded with the mission protocol, see
fence.py) that it enforces: a position target outside it is refused, as ArduCopter's GUIDED mode and
PX4's reposition refuse one.

Time: physics (speeds, climb, battery, the boot) runs `speedup` times faster than the wall clock; link
timing (heartbeat 1 Hz, message intervals, failsafe timeout, latency, faults' durations) stays in
wall-clock seconds, because the controller on the other side runs in real time.

It runs in its own thread: ``with MockAutopilot(sysid=1, connect="udpout:127.0.0.1:14550") as v: ...``;
or, on UDP, in a `MockRunner`'s thread shared with other mocks (``start(runner)``: SimSwarm flies its
mocks so, one thread for all of them instead of one each).
Hooks for later simulation layers: `tunnel_handler(mock, msg)` sees every TUNNEL message addressed to
the vehicle, `step_hooks` are called as hook(mock, dt_sim) after each physics step, and
`send_message(msg)` sends any message built with ``mock.mav.<name>_encode(...)``.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import random
import selectors
import threading
import time
from collections import deque
from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.mavlink.codec import distance_m, from_deg_e7, ne_m, offset_m, to_deg_e7
from swarmctl.mavlink.transport import Transport, UdpTransport, open_transport, parse_bytes, valid_frame
from swarmctl.signing import setup_signing
from swarmctl.sim.boot import Boot
from swarmctl.sim.fence import FENCE, MockFence
from swarmctl.sim.personality import Personality, personality_named
from swarmctl.sim.serial0 import SCHEME as TCPIN
from swarmctl.sim.serial0 import Serial0Server, parse_tcpin

MAV = mavlink2
log = logging.getLogger(__name__)

# SYS_STATUS sensor bits the mock reports (gyro, accel, mag, baro, GPS, motors, battery, pre-arm).
_SENSORS = (
    MAV.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | MAV.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | MAV.MAV_SYS_STATUS_SENSOR_3D_MAG
    | MAV.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | MAV.MAV_SYS_STATUS_SENSOR_GPS
    | MAV.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | MAV.MAV_SYS_STATUS_SENSOR_BATTERY
    | MAV.MAV_SYS_STATUS_PREARM_CHECK
)

_STREAMABLE = {
    MAV.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    MAV.MAVLINK_MSG_ID_HOME_POSITION,
    MAV.MAVLINK_MSG_ID_SYS_STATUS,
    MAV.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
    MAV.MAVLINK_MSG_ID_BATTERY_STATUS,
    MAV.MAVLINK_MSG_ID_HEARTBEAT,
    MAV.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
    MAV.MAVLINK_MSG_ID_GPS_RAW_INT,
    MAV.MAVLINK_MSG_ID_EKF_STATUS_REPORT,
    MAV.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN,
}
MAV_RESULT_UNSUPPORTED_MAV_FRAME = 9  # newer than this pymavlink dialect
PREARM_DISPLAY_S = 30.0  # simulated seconds between two "PreArm: ..." texts with the same reason


class _Outbox:
    """File-like target for MAVLink.send(): collects packed bytes for the mock's delivery logic."""

    def __init__(self) -> None:
        self.items: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.items.append(bytes(data))


@dataclass
class MockState:
    """A snapshot of the mock's state, for tests."""

    lat: float
    lon: float
    rel_alt: float
    armed: bool
    mode: str
    battery: float
    ready: bool  # can arm in the mode swarmctl flies it in (ArduPilot: the EKF uses the GPS)
    gcs_failsafe: bool
    fence: tuple[tuple[tuple[float, float], ...], ...] = ()  # stored inclusion polygons, (lat, lon)
    fence_enabled: bool = False  # the fence is enforced
    fence_refused: int = 0  # position targets refused because they lie outside it


class MockAutopilot:
    def __init__(
        self,
        sysid: int = 1,
        connect: str = "udpout:127.0.0.1:14550",
        *,
        home: tuple[float, float, float] = (-35.363262, 149.165237, 584.0),
        autopilot: str = "ardupilot",
        speed: float = 5.0,
        climb_rate: float = 2.5,
        descent_rate: float = 1.5,
        speedup: float = 1.0,
        signing_key: bytes | None = None,
        ready_after: float = 2.0,
        gcs_failsafe_timeout: float | None = 5.0,
        rtl_alt: float | None = None,
        battery_drain: float = 0.08,
        compid: int = 1,
        seed: int | None = None,
        tick: float = 0.02,
        reposition_frames: Collection[int] | None = None,
    ):
        self.personality: Personality = personality_named(autopilot)  # ValueError naming the choices
        if not 1 <= sysid <= 255:
            raise ValueError("sysid must be 1..255")
        self.sysid, self.compid, self.connect = sysid, compid, connect
        self.home = home
        self.speed, self.climb_rate, self.descent_rate = speed, climb_rate, descent_rate
        self.speedup = speedup
        self.signing_key = signing_key
        self.ready_after = ready_after  # simulated seconds after boot before it can arm (boot.py)
        self.ekf_after: float | None = None  # the slow-EKF fault (slow_ekf); None: ready_after
        self.gcs_failsafe_timeout = gcs_failsafe_timeout  # wall seconds; None disables the failsafe
        self.rtl_alt = self.personality.rtl_alt if rtl_alt is None else rtl_alt  # m above home
        self.battery_drain = battery_drain  # % per simulated second while flying
        self.tick = tick
        self.rng = random.Random(seed)
        # hooks for later layers (e.g. a simulated detector riding on TUNNEL messages)
        self.tunnel_handler: Callable[[MockAutopilot, Any], None] | None = None
        self.step_hooks: list[Callable[[MockAutopilot, float], None]] = []
        # faults (set from the test thread; plain attribute writes)
        self.packet_loss = 0.0
        self.latency = 0.0
        self.arming_refusal: str | None = None
        self._no_heartbeat_until = 0.0
        self._down_until = 0.0
        self._reboot_pending = False
        self._glitch: tuple[float, float, float] | None = None  # north, east, until (wall)
        self.forced_results: dict[int, int] = {}  # command -> MAV_RESULT to answer with
        self._drop_commands: dict[int, int | None] = {}  # command -> how many to ignore (None: all)
        self._drop_sent: dict[str, int | None] = {}  # message type -> how many not to send (None: all)
        self._forget: dict[int, int] = {}  # message id -> SET_MESSAGE_INTERVAL requests to acknowledge and forget
        # observation for tests
        # the latest messages addressed to us, (type, src sysid, command or 0), and the answers given
        self.received: deque[tuple[str, int, int]] = deque(maxlen=10_000)
        self.commands: deque[tuple[int, int]] = deque(maxlen=10_000)  # (command, MAV_RESULT)
        self.ignored = 0  # messages seen that were addressed to another system
        self.fence = MockFence(self)  # made here, not at boot: the stored fence survives reboots
        # parameters are stored too (the fence polygon is enforced; the circle and altitude are not);
        # the ones that are its speeds say what the mock flies at
        self.params = dict(self.personality.params)
        for name, (attribute, scale) in self.personality.physics_params.items():
            self.params[name] = getattr(self, attribute) / scale
        for name in ("MAV_SYSID", "MAV_SYS_ID"):  # ArduPilot 4.7, PX4
            if name in self.params:
                self.params[name] = float(sysid)
        # the frames a COMMAND_INT reposition is taken in (None: the personality's; e.g. {MAV_FRAME_GLOBAL}
        # for a PX4 that refuses GLOBAL_INT)
        self.reposition_frames = (
            self.personality.reposition_frames if reposition_frames is None else frozenset(reposition_frames)
        )
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._runner: MockRunner | None = None
        self._transport: Transport | None = None
        self._last_step = 0.0
        self._outbox = _Outbox()
        self.mav: Any = None
        self._delayed: list[tuple[float, int, str, Any]] = []
        self._seq = itertools.count()
        self._console_after_heartbeat = b""
        self._boot()

    # --- life cycle ------------------------------------------------------------------------------------

    def _boot(self) -> None:
        now = time.monotonic()
        self.boot_wall = now
        self.sim_time = 0.0
        lat, lon = (self.lat, self.lon) if hasattr(self, "lat") else self.home[:2]
        self.lat, self.lon, self.rel_alt = lat, lon, 0.0
        self.vel = (0.0, 0.0, 0.0)  # north, east, down m/s
        self.armed = False
        self.custom_mode = self.personality.custom_mode(self.personality.boot_mode)
        self.target: tuple[float, float, float] | None = None  # lat, lon, rel_alt
        self.battery = getattr(self, "battery", 100.0)
        self.boot = Boot(self.personality.stages, self.ready_after, self.ekf_after)
        self._prearm_shown: tuple[str | None, float] = (None, -math.inf)  # reason, sim time
        self.last_gcs_heartbeat: float | None = None
        self.gcs_failsafe = False
        self._failsafe_done = False
        self.last_setpoint = -1e9
        # DO_FENCE_ENABLE is not saved: after a reboot a stored fence is off until enabled again (where
        # the personality's fence_enforced follows the switch at all)
        self.fence.enabled = False
        self.intervals = dict(self.personality.default_streams)
        self.next_due: dict[int, float] = {}
        self.next_heartbeat = now

    def start(self, runner: MockRunner | None = None) -> MockAutopilot:
        """Open the connection and run: in a thread of its own, or (a UDP connection) in `runner`'s."""
        if self.connect.startswith(TCPIN):
            server = Serial0Server(*parse_tcpin(self.connect))
            server.on_connect = self._client_connected
            self._transport = server
        else:
            self._transport = open_transport(self.connect)
        self.mav = MAV.MAVLink(self._outbox, srcSystem=self.sysid, srcComponent=self.compid)
        self.mav.robust_parsing = True
        if self.signing_key is not None:
            setup_signing(self.mav, self.signing_key, accept_unsigned={MAV.MAVLINK_MSG_ID_RADIO_STATUS})
        self._stop.clear()
        self._last_step = time.monotonic()
        if runner is not None and isinstance(self._transport, UdpTransport):
            self._runner = runner.add(self)
        else:
            self._thread = threading.Thread(target=self._run, name=f"mock-autopilot-{self.sysid}", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._runner is not None:
            self._runner.remove(self)
            self._runner = None
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    def __enter__(self) -> MockAutopilot:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def local_port(self) -> int | None:
        return getattr(self._transport, "local_port", None)

    def _client_connected(self) -> None:
        """A client on the TCP port (serial0.py): the first one boots the vehicle, as SITL boots when
        its SERIAL0 gets one; each gets the console text before MAVLink."""
        transport = self._transport
        assert isinstance(transport, Serial0Server)
        if transport.clients == 1:
            with self._lock:
                self._boot()
            self._console_after_heartbeat = self.personality.console[1]
        transport.write(self.personality.console[0])

    @property
    def ready(self) -> bool:
        """It can arm in the mode swarmctl flies it in (ArduPilot: GUIDED, once the EKF uses the GPS)."""
        return self.boot.has("ready")

    @property
    def home_set(self) -> bool:
        return self.boot.has("origin")

    @property
    def rejected_unsigned(self) -> int:
        """Messages dropped because they were unsigned or wrongly signed."""
        return 0 if self.mav is None else self.mav.signing.reject_count

    # --- faults ------------------------------------------------------------------------------------------

    def drop_heartbeats(self, seconds: float) -> None:
        """Send no HEARTBEAT for the next `seconds` (wall clock); other messages still flow."""
        self._no_heartbeat_until = time.monotonic() + seconds

    def blackout(self, seconds: float) -> None:
        """Neither send nor receive anything for `seconds` (a radio out of range); 0 ends a blackout now."""
        self._down_until = time.monotonic() + seconds

    def reboot(self, downtime: float = 1.0) -> None:
        """Go silent for `downtime` s, then boot again: disarmed, on the ground, streams reset."""
        self._down_until = time.monotonic() + downtime
        self._reboot_pending = True

    def refuse_arming(self, reason: str | None = "Hardware safety switch") -> None:
        """Fail every arm command with an "<arm prefix>: <reason>" STATUSTEXT (ArduPilot "Arm:", PX4
        "Arming denied:"; None: arm normally again)."""
        self.arming_refusal = reason

    def slow_ekf(self, seconds: float) -> None:
        """The EKF uses the GPS only `seconds` simulated seconds after boot (scaled by speedup like the
        rest of the physics): until then GUIDED cannot arm ("PreArm: Need Position Estimate", the
        pre-arm bit unhealthy in GUIDED); the GPS fix and home come as usual. Set before it is ready
        (it also holds through a reboot)."""
        with self._lock:
            self.ekf_after = float(seconds)
            self.boot.slow_ekf(seconds)

    def slow_boot(self, seconds: float) -> None:
        """The initialisation ends (HEARTBEAT leaves BOOT, "standby") only `seconds` simulated seconds
        after boot, as on a loaded machine; the later stages come no sooner. Call again with
        `sim_time` to end it now."""
        with self._lock:
            self.boot.slow_boot(seconds)

    def gps_glitch(self, north_m: float, east_m: float, seconds: float = 2.0) -> None:
        """Report a position jumped by north/east metres for `seconds` (wall clock)."""
        self._glitch = (north_m, east_m, time.monotonic() + seconds)

    def drop_commands(self, command: int, count: int | None = None) -> None:
        """Silently ignore the next `count` COMMAND_LONG/INT of this id (None: all of them)."""
        self._drop_commands[command] = count

    def drop_sent(self, mtype: str, count: int | None = 1) -> None:
        """Do not send the next `count` messages of this type, e.g. "MISSION_ACK" (None: none of them;
        0: send them again)."""
        if count == 0:
            self._drop_sent.pop(mtype, None)
        else:
            self._drop_sent[mtype] = count

    def forget_intervals(self, mtype: str, count: int = 1) -> None:
        """Acknowledge the next `count` SET_MESSAGE_INTERVAL for this message type ACCEPTED and then not
        stream it, as ArduCopter SITL does with a request sent before its first heartbeat."""
        self._forget[getattr(MAV, f"MAVLINK_MSG_ID_{mtype}")] = count

    def force_result(self, command: int, result: int | None) -> None:
        """Answer this command with the given MAV_RESULT without acting on it (None: normal)."""
        if result is None:
            self.forced_results.pop(command, None)
        else:
            self.forced_results[command] = result

    # --- observation -----------------------------------------------------------------------------------

    @property
    def autopilot(self) -> str:
        """The firmware the mock plays ("ardupilot", "px4")."""
        return self.personality.name

    @property
    def mode_name(self) -> str:
        return self.personality.mode_name(self.custom_mode)

    def state(self) -> MockState:
        with self._lock:
            f = self.fence
            return MockState(
                self.lat,
                self.lon,
                self.rel_alt,
                self.armed,
                self.mode_name,
                self.battery,
                self.ready,
                self.gcs_failsafe,
                fence=tuple(tuple(p) for p in f.polygons),
                fence_enabled=f.active,
                fence_refused=f.refused,
            )

    def wait_for(self, condition: Callable[[MockAutopilot], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition(self):
                return True
            time.sleep(0.01)
        return condition(self)

    # --- main loop -----------------------------------------------------------------------------------

    def _run(self) -> None:
        assert self._transport is not None
        while not self._stop.is_set():
            try:
                data = self._transport.read(self.tick / 2)
            except (OSError, ValueError):
                data = b""
            now = time.monotonic()
            if data:
                self._receive(data, now)
            self._advance(now)

    def _receive(self, data: bytes, now: float) -> None:
        """One read's bytes (a datagram on UDP), subject to the blackout and packet-loss faults."""
        if now >= self._down_until and self.rng.random() >= self.packet_loss:
            msgs = parse_bytes(self.mav, data, self._transport.datagrams)
            if any(valid_frame(m) for m in msgs):
                self._transport.accept_source()  # udpin: answer this address from now on
            for msg in msgs:
                if self.latency > 0:
                    heapq.heappush(self._delayed, (now + self.latency, next(self._seq), "in", msg))
                else:
                    self._handle_safely(msg)

    def _advance(self, now: float) -> None:
        """What is due at `now`: delayed messages, a pending reboot, the physics step (every `tick`) and
        the telemetry it sends."""
        while self._delayed and self._delayed[0][0] <= now:
            _, _, kind, item = heapq.heappop(self._delayed)
            if kind == "in":
                self._handle_safely(item)
            else:
                self._write(item)
        if self._reboot_pending and now >= self._down_until:
            with self._lock:
                self._reboot_pending = False
                self._boot()
            self._last_step = now
        if now - self._last_step >= self.tick:
            dt = now - self._last_step
            self._last_step = now
            if not self._reboot_pending:  # a blackout cuts the radio, not the flight
                with self._lock:
                    self._step(dt * self.speedup, now)
                for hook in list(self.step_hooks):
                    hook(self, dt * self.speedup)
                self._emit(now)

    def _handle_safely(self, msg: Any) -> None:
        try:
            with self._lock:
                self._handle(msg)
        except Exception:  # a malformed or unexpected message must not stop the vehicle
            log.exception("mock vehicle %d: error handling %s", self.sysid, msg.get_type())

    # --- sending -------------------------------------------------------------------------------------

    def send_message(self, msg: Any) -> None:
        """Pack, sign and deliver one message (subject to the loss/latency/blackout faults)."""
        if self.mav is None:
            return
        mtype = msg.get_type()
        if mtype in self._drop_sent:
            left = self._drop_sent[mtype]
            if left is None or left > 1:
                self._drop_sent[mtype] = None if left is None else left - 1
            else:
                del self._drop_sent[mtype]
            return
        now = time.monotonic()
        self.mav.send(msg)
        items, self._outbox.items = self._outbox.items, []
        if now < self._down_until:
            return
        for buf in items:
            if self.packet_loss and self.rng.random() < self.packet_loss:
                continue
            if self.latency > 0:
                heapq.heappush(self._delayed, (now + self.latency, next(self._seq), "out", buf))
            else:
                self._write(buf)

    def _write(self, buf: bytes) -> None:
        if self._transport is not None:
            try:
                self._transport.write(buf)
            except OSError:
                pass

    def statustext(self, text: str, severity: int = MAV.MAV_SEVERITY_INFO) -> None:
        self.send_message(self.mav.statustext_encode(severity, text.encode()[:50]))

    def _ack(self, msg: Any, command: int, result: int) -> None:
        self.commands.append((command, result))
        self.send_message(
            self.mav.command_ack_encode(command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        )

    # --- periodic output --------------------------------------------------------------------------------

    def _emit(self, now: float) -> None:
        if now >= self.next_heartbeat:
            self.next_heartbeat = now + 1.0
            if now >= self._no_heartbeat_until:
                self.send_message(self._heartbeat())
                if self._console_after_heartbeat:  # SITL's "Init Gyro**" between its first heartbeats
                    self._write(self._console_after_heartbeat)
                    self._console_after_heartbeat = b""
        if not self.boot.has("streams"):
            return  # requests are kept; the streams start at "ArduPilot Ready"
        for msg_id, interval in list(self.intervals.items()):
            due = self.next_due.get(msg_id, 0.0)
            if now >= due:
                m = self._build(msg_id)
                if m is not None:  # nothing to report yet (no home): try again next tick
                    self.next_due[msg_id] = max(due + interval, now)
                    self.send_message(m)

    def _heartbeat(self) -> Any:
        base = self.personality.base_mode(self.custom_mode)
        if self.armed:
            base |= MAV.MAV_MODE_FLAG_SAFETY_ARMED
        status = (
            MAV.MAV_STATE_ACTIVE
            if self.armed
            else MAV.MAV_STATE_STANDBY
            if self.boot.has("standby")
            else self.personality.boot_status
        )
        if self.gcs_failsafe and self.armed:
            status = MAV.MAV_STATE_CRITICAL  # PX4 SITL: from the link loss until the link is back
        autopilot = self.personality.autopilot.mav_autopilot
        return self.mav.heartbeat_encode(MAV.MAV_TYPE_QUADROTOR, autopilot, base, self.custom_mode, status)

    def _reported_latlon(self) -> tuple[float, float]:
        if self._glitch is not None:
            n, e, until = self._glitch
            if time.monotonic() < until:
                return offset_m(self.lat, self.lon, n, e)
            self._glitch = None
        return self.lat, self.lon

    def _time_boot_ms(self) -> int:
        return int((time.monotonic() - self.boot_wall) * 1000) & 0xFFFFFFFF

    def _build(self, msg_id: int) -> Any:
        home_lat, home_lon, home_alt = self.home
        gps = self.boot.has("gps")
        if msg_id == MAV.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            if not gps and not self.personality.position_before_ready:
                return None
            if gps:
                lat, lon = self._reported_latlon()
                lat_i, lon_i = to_deg_e7(lat), to_deg_e7(lon)
            else:
                lat_i = lon_i = 0  # no GPS fix yet: ArduPilot reports zeros
            vn, ve, vd = self.vel
            hdg = int(math.degrees(math.atan2(ve, vn)) % 360 * 100) if (vn or ve) else 65535
            return self.mav.global_position_int_encode(
                self._time_boot_ms(),
                lat_i,
                lon_i,
                int(round((home_alt + self.rel_alt) * 1000)),
                int(round(self.rel_alt * 1000)),
                int(vn * 100),
                int(ve * 100),
                int(vd * 100),
                hdg,
            )
        if msg_id == MAV.MAVLINK_MSG_ID_HOME_POSITION:
            if not self.home_set:
                return None
            return self.mav.home_position_encode(
                to_deg_e7(home_lat),
                to_deg_e7(home_lon),
                int(round(home_alt * 1000)),
                0,
                0,
                0,
                [1.0, 0.0, 0.0, 0.0],
                0,
                0,
                0,
                int((time.monotonic() - self.boot_wall) * 1e6),
            )
        if msg_id == MAV.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN:
            if not self.home_set:
                return None
            t_us = int((time.monotonic() - self.boot_wall) * 1e6)
            return self.mav.gps_global_origin_encode(
                to_deg_e7(home_lat), to_deg_e7(home_lon), int(round(home_alt * 1000)), t_us
            )
        if msg_id == MAV.MAVLINK_MSG_ID_GPS_RAW_INT:
            lat, lon = self._reported_latlon() if gps else (0.0, 0.0)
            vn, ve, _vd = self.vel
            return self.mav.gps_raw_int_encode(
                int((time.monotonic() - self.boot_wall) * 1e6),
                MAV.GPS_FIX_TYPE_RTK_FIXED if gps else MAV.GPS_FIX_TYPE_NO_FIX,  # what SITL reports: 6
                to_deg_e7(lat),
                to_deg_e7(lon),
                int(round((home_alt + self.rel_alt) * 1000)) if gps else 0,
                121 if gps else 65535,
                200 if gps else 65535,
                int(math.hypot(vn, ve) * 100),
                int(math.degrees(math.atan2(ve, vn)) % 360 * 100) if (vn or ve) else 65535,
                10 if gps else 0,
            )
        if msg_id == MAV.MAVLINK_MSG_ID_EKF_STATUS_REPORT:
            return self.mav.ekf_status_report_encode(self.boot.ekf_flags(), 0.02, 0.03, 0.02, 0.01, 0.0)
        if msg_id == MAV.MAVLINK_MSG_ID_SYS_STATUS:
            health = _SENSORS
            if not self.armed and self._not_armable() is not None:  # always healthy when armed
                health &= ~MAV.MAV_SYS_STATUS_PREARM_CHECK
            if not gps:
                health &= ~MAV.MAV_SYS_STATUS_SENSOR_GPS
            volts = 4 * (3.5 + 0.7 * self.battery / 100.0)
            current = 1500 if self.rel_alt > 0.1 else (100 if self.armed else 50)
            return self.mav.sys_status_encode(
                _SENSORS, _SENSORS, health, 200, int(volts * 1000), current, int(self.battery), 0, 0, 0, 0, 0, 0
            )
        if msg_id == MAV.MAVLINK_MSG_ID_BATTERY_STATUS:
            cell_mv = int(1000 * (3.5 + 0.7 * self.battery / 100.0))
            return self.mav.battery_status_encode(
                0,
                MAV.MAV_BATTERY_FUNCTION_ALL,
                MAV.MAV_BATTERY_TYPE_LIPO,
                32767,
                [cell_mv] * 4 + [65535] * 6,
                1500 if self.rel_alt > 0.1 else 50,
                -1,
                -1,
                int(self.battery),
            )
        if msg_id == MAV.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
            return self.mav.extended_sys_state_encode(MAV.MAV_VTOL_STATE_UNDEFINED, self._landed_state())
        if msg_id == MAV.MAVLINK_MSG_ID_HEARTBEAT:
            return self._heartbeat()
        if msg_id == MAV.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            p = self.personality
            return self.mav.autopilot_version_encode(
                p.capabilities, p.version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x5357_0000 + self.sysid
            )
        return None

    def _landed_state(self) -> int:
        if not self.armed and self.rel_alt <= 0.05:
            return MAV.MAV_LANDED_STATE_ON_GROUND
        if self.mode_name == "LAND" and self.vel[2] > 0:
            return MAV.MAV_LANDED_STATE_LANDING
        if self.target is not None and self.rel_alt < self.target[2] - 0.5 and self.vel[2] < 0 and self.rel_alt < 2.0:
            return MAV.MAV_LANDED_STATE_TAKEOFF
        return MAV.MAV_LANDED_STATE_IN_AIR if self.rel_alt > 0.05 else MAV.MAV_LANDED_STATE_ON_GROUND

    # --- physics ---------------------------------------------------------------------------------------

    def _step(self, dt: float, now: float) -> None:
        self.sim_time += dt
        self.fence.tick(now)
        for stage in self.boot.advance(self.sim_time):
            if stage == "standby" and self.personality.boot_resets_mode and not self.armed:
                self.custom_mode = self.personality.custom_mode(self.personality.boot_mode)
                self.target = None
            for text in self.personality.stage_texts.get(stage, ()):
                self.statustext(text.format(alt=self.home[2]))
        self._prearm_texts()
        self._failsafe(now)
        if self.armed:
            self.battery = max(
                0.0, self.battery - dt * (self.battery_drain if self.rel_alt > 0.1 else self.battery_drain / 10)
            )
        if not self.armed:
            self.vel = (0.0, 0.0, 0.0)
            return
        mode = self.mode_name
        home_lat, home_lon, _ = self.home
        if mode == "LAND":
            self._move(self.lat, self.lon, 0.0, dt)
        elif mode == "RTL":
            away = distance_m(self.lat, self.lon, home_lat, home_lon)
            if away > 0.01 and self.rel_alt < self.rtl_alt - 0.01:
                self._move(self.lat, self.lon, self.rtl_alt, dt)
            elif away > 0.01:
                self._move(home_lat, home_lon, self.rel_alt, dt)
            else:
                self._move(home_lat, home_lon, 0.0, dt)
        elif self.target is not None and mode in self.personality.target_modes:
            self._move(*self.target, dt)
            if mode == self.personality.takeoff_mode and abs(self.rel_alt - self.target[2]) < 0.01:
                self.personality.takeoff_reached(self)
        else:
            self.vel = (0.0, 0.0, 0.0)
        self._fence_breach()
        if mode in ("LAND", "RTL") and self.rel_alt <= 0.0 and self.vel[2] >= 0:
            self.armed = False  # landed: disarm, as both autopilots do
            self.target = None
            self.vel = (0.0, 0.0, 0.0)
            self.statustext(self.personality.landed_text)
            if self.personality.landed_mode is not None:
                self.custom_mode = self.personality.custom_mode(self.personality.landed_mode)

    def _not_armable(self) -> str | None:
        """Why the vehicle could not arm now in its current mode (None: it could), as its pre-arm
        checks see it: a mode that needs a position needs "ready", another one the "manual" stage."""
        p = self.personality
        if not p.position_modes or self.mode_name in p.position_modes:
            return None if self.ready else p.not_ready_reason
        return None if self.boot.has("manual") else p.boot_reason

    def _prearm_texts(self) -> None:
        """The periodic pre-arm failure text ("PreArm: Need Position Estimate"), when the reason
        changes and again every PREARM_DISPLAY_S while it lasts, disarmed, once booted."""
        prefix = self.personality.prearm_prefix
        if prefix is None or self.armed or not self.boot.has("streams"):
            return
        reason = self._not_armable()
        shown, at = self._prearm_shown
        if reason is not None and (reason != shown or self.sim_time - at >= PREARM_DISPLAY_S):
            self.statustext(f"{prefix}: {reason}", MAV.MAV_SEVERITY_CRITICAL)
            self._prearm_shown = (reason, self.sim_time)
        elif reason is None:
            self._prearm_shown = (None, -math.inf)

    def _fence_breach(self) -> None:
        """Outside an enforced fence in flight: the breach action, once per breach: the personality's
        breach_mode (ArduPilot's FENCE_ACTION default, RTL; PX4's GF_ACTION default, Hold)."""
        f = self.fence
        if f.allows(self.lat, self.lon):
            f.breached = False
            return
        if f.breached or self.rel_alt <= 0.05:
            return
        f.breached = True
        f.breaches += 1
        if self.mode_name in ("RTL", "LAND"):
            return
        self._set_mode_name(self.personality.breach_mode)
        self.statustext(self.personality.breach_text, MAV.MAV_SEVERITY_CRITICAL)

    def _move(self, lat: float, lon: float, alt: float, dt: float) -> None:
        """Fly toward (lat, lon, alt): horizontal speed limit, climb and descent rates, exact arrival."""
        n, e = ne_m(self.lat, self.lon, lat, lon)
        dist = math.hypot(n, e)
        step = min(dist, self.speed * dt)
        if dist > 0 and step >= dist:
            self.lat, self.lon = lat, lon
        elif dist > 0:
            self.lat, self.lon = offset_m(self.lat, self.lon, n * step / dist, e * step / dist)
        dz = alt - self.rel_alt
        rate = self.climb_rate if dz > 0 else self.descent_rate
        dz_step = max(-rate * dt, min(rate * dt, dz))
        self.rel_alt = alt if abs(dz_step) >= abs(dz) else self.rel_alt + dz_step
        self.rel_alt = max(0.0, self.rel_alt)
        if dt > 0:
            self.vel = ((n * step / dist / dt) if dist else 0.0, (e * step / dist / dt) if dist else 0.0, -dz_step / dt)

    def _failsafe(self, now: float) -> None:
        """GCS failsafe: no controller heartbeat for the personality's loss timeout -> hold for its delay,
        then its action (ArduPilot RTL at once; PX4 NAV_DLL_ACT), or disarm on the ground. The mode stays
        when the heartbeats come back."""
        loss = self.personality.gcs_loss(self)
        if loss is None or self.last_gcs_heartbeat is None:
            self.gcs_failsafe = False
            return
        timeout, hold_s, action = loss
        silent_s = now - self.last_gcs_heartbeat
        if silent_s <= timeout:
            self.gcs_failsafe = False
            return
        if not self.gcs_failsafe:
            self.gcs_failsafe = True
            self._failsafe_done = False
            if self.armed and self.rel_alt <= 0.05:
                self.armed = False
                self.statustext("GCS Failsafe: disarming", MAV.MAV_SEVERITY_CRITICAL)
                self._failsafe_done = True
            elif self.armed and hold_s > 0 and self.mode_name not in ("RTL", "LAND"):
                self._set_mode_name(self.personality.autopilot.command_mode)
        if self._failsafe_done or silent_s < timeout + hold_s:
            return
        self._failsafe_done = True
        if self.armed and self.mode_name not in ("RTL", "LAND", action):
            self._set_mode_name(action)
            self.statustext(self.personality.failsafe_text, MAV.MAV_SEVERITY_CRITICAL)

    # --- receiving ----------------------------------------------------------------------------------------

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
            self.tunnel_handler(self, msg)

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
            if msg_id not in _STREAMABLE:
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
            if msg_id not in _STREAMABLE:
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


class MockRunner:
    """One thread for many mock vehicles on UDP (as 50 vehicles' threads each waking a hundred times a
    second cost a small machine more than the mocks' work): it waits on all their sockets at once, hands
    each datagram to its mock, and advances every mock at least every half tick, as a mock's own
    thread does. ``with MockRunner() as runner: mock.start(runner)``."""

    def __init__(self) -> None:
        self._sockets = selectors.DefaultSelector()
        self._mocks: dict[MockAutopilot, None] = {}
        self._lock = threading.RLock()  # held while the mocks are served: remove() waits for it
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def add(self, mock: MockAutopilot) -> MockRunner:
        assert isinstance(mock._transport, UdpTransport), "a MockRunner serves UDP mocks"
        with self._lock:
            self._sockets.register(mock._transport.sock, selectors.EVENT_READ, mock)
            self._mocks[mock] = None
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="mock-autopilots", daemon=True)
            self._thread.start()
        return self

    def remove(self, mock: MockAutopilot) -> None:
        with self._lock:
            if self._mocks.pop(mock, 1) is None:
                self._sockets.unregister(mock._transport.sock)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        self._sockets.close()

    def __enter__(self) -> MockRunner:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                mocks = list(self._mocks)
            if not mocks:
                self._stop.wait(0.01)
                continue
            ready = self._sockets.select(min(m.tick for m in mocks) / 2)
            now = time.monotonic()
            with self._lock:
                for key, _ in ready:
                    if key.data in self._mocks:
                        self._serve(key.data, self._read, now)
                for mock in list(self._mocks):
                    self._serve(mock, MockAutopilot._advance, now)

    def _serve(self, mock: MockAutopilot, work: Callable[[MockAutopilot, float], None], now: float) -> None:
        try:
            work(mock, now)
        except Exception:  # one mock's failure stops that mock, as it would stop its own thread
            log.exception("mock vehicle %d stopped", mock.sysid)
            self.remove(mock)

    @staticmethod
    def _read(mock: MockAutopilot, now: float) -> None:
        """What the mock's socket holds, up to 64 datagrams (the rest at the next turn)."""
        for _ in range(64):
            try:
                data = mock._transport.read(0)
            except (OSError, ValueError):
                return
            if not data:
                return
            mock._receive(data, now)
