"""A mock ArduCopter / PX4 multicopter: a real MAVLink 2 endpoint (pymavlink bytes over UDP/TCP/serial).

What differs between the two firmwares comes from the mock's personality (personality.py), built on
the same autopilot descriptions the controller flies by; this module and its parts hold what they
share: what it sends (mock_telemetry.py), how it flies (mock_flight.py), what it does with each
message (mock_commands.py).

It behaves like the real autopilot as far as a controller can see (checked against ArduCopter 4.7
SITL, docs/mavlink.md): HEARTBEAT type/autopilot/base_mode/custom_mode/system_status, a boot through
the stages a real one passes (boot.py: streams from "ArduPilot Ready", positions 0, 0 until the GPS
fix, home with the EKF origin, the EKF's absolute position last), pre-arm checks judged in the current
mode (healthy in STABILIZE before GUIDED can arm; "PreArm:" texts; an arm refused with FAILED + "Arm:
Need Position Estimate"), any mode taken while disarmed, takeoff only when armed in GUIDED,
COMMAND_ACK results, SET_MESSAGE_INTERVAL (a fresh ArduPilot sends only heartbeats), parameters (its
speeds among them), simple kinematics, a draining battery (swapped on the ground: `swap_battery`), a
GCS failsafe, signing, faults injected from tests (the slow EKF among them), a TCP port served as SITL
serves SERIAL0 (serial0.py: boot on the first client, console text before MAVLink), and a geofence
(uploaded with the mission protocol, see fence.py) that it enforces: a position target outside it is
refused, as ArduCopter's GUIDED mode and PX4's reposition refuse one.

Time: physics (speeds, climb, battery, the boot) runs `speedup` times faster than the wall clock; link
timing (heartbeat 1 Hz, message intervals, failsafe timeout, latency, faults' durations) stays in
wall-clock seconds, because the controller on the other side runs in real time.

It runs in its own thread: ``with MockAutopilot(sysid=1, connect="udpout:127.0.0.1:14550") as v: ...``;
or, on UDP, in a `MockRunner`'s thread (swarmctl.sim.mock_runner) shared with other mocks
(``start(runner)``: SimSwarm flies its mocks so, one thread for all of them instead of one each).
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
import threading
import time
from collections import deque
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.mavlink.transport import Transport, UdpTransport, open_transport, parse_bytes, valid_frame
from swarmctl.signing import setup_signing
from swarmctl.sim.boot import Boot
from swarmctl.sim.fence import MockFence
from swarmctl.sim.mock_base import dropping
from swarmctl.sim.mock_commands import MockCommands
from swarmctl.sim.mock_flight import MockFlight
from swarmctl.sim.mock_telemetry import MockTelemetry
from swarmctl.sim.personality import Personality, personality_named
from swarmctl.sim.serial0 import SCHEME as TCPIN
from swarmctl.sim.serial0 import Serial0Server, parse_tcpin

if TYPE_CHECKING:
    from swarmctl.sim.mock_runner import MockRunner

MAV = mavlink2
log = logging.getLogger(__name__)


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


class MockAutopilot(MockTelemetry, MockFlight, MockCommands):
    """A mock autopilot (module docstring). Its parts: what it sends (MockTelemetry,
    swarmctl.sim.mock_telemetry), how it flies (MockFlight, swarmctl.sim.mock_flight) and what it does
    with each message (MockCommands, swarmctl.sim.mock_commands); life cycle, faults, the loop and
    sending are here."""

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
        params: Mapping[str, float] | None = None,
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
        self._drop_received: dict[str, int | None] = {}  # message type -> how many to ignore (None: all)
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
        # parameters set otherwise than the personality's defaults (e.g. FS_GCS_ENABLE=0: no GCS failsafe)
        self.params.update({name: float(value) for name, value in (params or {}).items()})
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

    @property
    def landed_disarmed(self) -> bool:
        """On the ground and disarmed: where a crew may swap its battery."""
        return not self.armed and self.rel_alt <= 0.05

    def swap_battery(self, charge: float = 100.0, downtime: float = 1.0) -> bool:
        """A fresh battery of `charge` %, as a crew swaps one at the launch point: only while landed and
        disarmed (False, and nothing changes, otherwise). The autopilot loses power with the old battery
        and boots on the new one: silent for `downtime` wall seconds, then `reboot`'s boot, reporting the
        new charge, as ArduCopter restarts with a fresh battery (SITL: restarted, its simulated battery
        full again)."""
        if not 0.0 <= charge <= 100.0:
            raise ValueError(f"a battery's charge is 0..100 %, not {charge!r}")
        with self._lock:
            if not self.landed_disarmed:
                return False
            self.battery = float(charge)
        self.reboot(downtime)
        return True

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

    def drop_received(self, mtype: str, count: int | None = 1) -> None:
        """Ignore the next `count` messages of this type addressed to the vehicle, as if lost on the way,
        e.g. "SET_POSITION_TARGET_GLOBAL_INT" (None: all of them; 0: take them again)."""
        if count == 0:
            self._drop_received.pop(mtype, None)
        else:
            self._drop_received[mtype] = count

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
            transport = self._transport
            assert transport is not None  # it receives only while started
            msgs = parse_bytes(self.mav, data, transport.datagrams)
            if any(valid_frame(m) for m in msgs):
                transport.accept_source()  # udpin: answer this address from now on
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
        if dropping(self._drop_sent, msg.get_type()):
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
