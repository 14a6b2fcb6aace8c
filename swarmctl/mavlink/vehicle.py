"""The one interface the controller flies every vehicle through, whatever its autopilot.

Every method is a coroutine on the controller's asyncio loop (see network.py for the concurrency model),
so many vehicles are flown at once with asyncio.gather / TaskGroup and a slow vehicle blocks only itself.

The command flows both firmwares share are written once here, as template methods: `wait_ready` (the
"waiting for ..." reports and the NotReady that names the last reason), `arm` (retried while the
autopilot says "not ready yet"), `arm_and_takeoff` (the climb check) and `upload_fence`. A driver
(autopilots/ardupilot.py, autopilots/px4.py) fills in only how its firmware is asked (`_send_arm`,
`_take_off`, `_send_fence`, ...) and what its messages mean (`not_ready`); the facts are in its
description (autopilots/descriptions.py).
"""

from __future__ import annotations

import abc
import asyncio
import logging
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, ClassVar

from swarmctl.mavlink.autopilots.base import Autopilot
from swarmctl.mavlink.codec import EARTH_RADIUS_M, distance_m
from swarmctl.mavlink.errors import CommandRejected, CommandTimeout, MavlinkError, NotReady, WaitTimeout
from swarmctl.mavlink.limits import AIRBORNE_M, FlightLimits

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Position:
    lat: float
    lon: float
    rel_alt: float  # metres above home
    alt_amsl: float  # metres above mean sea level


@dataclass(frozen=True)
class Home:
    lat: float
    lon: float
    alt_amsl: float


@dataclass(frozen=True)
class Target:
    lat: float
    lon: float
    rel_alt: float


class Odometer:
    """The 3-D distance flown, from position reports: the straight line between successive fixes
    (horizontal and vertical together), counted when either fix is at least AIRBORNE_M above home, so
    the climb, the search and the descent count and GPS noise on the ground does not."""

    def __init__(self) -> None:
        self.metres = 0.0
        self._last: tuple[float, float, float] | None = None  # lat, lon, rel_alt of the last fix

    def add(self, pos: Position) -> None:
        self.add_fix(pos.lat, pos.lon, pos.rel_alt)

    def add_fix(self, lat: float, lon: float, rel_alt: float) -> None:
        """`add` from the figures of a position report (degrees, metres above home), without a Position."""
        last = self._last
        self._last = (lat, lon, rel_alt)
        if last is not None and (last[2] >= AIRBORNE_M or rel_alt >= AIRBORNE_M):
            lat0 = last[0]  # codec.distance_m, inlined (the same arithmetic): it runs for every report
            north = math.radians(lat - lat0) * EARTH_RADIUS_M
            east = math.radians(lon - last[1]) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
            self.metres += math.hypot(math.hypot(north, east), rel_alt - last[2])


def fence_vertices(polygon: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The (lat, lon) vertices of a fence polygon, checked: at least 3, all distinct and in range; a
    last vertex that repeats the first (a closed ring) is dropped. ValueError otherwise."""
    vertices = [(float(lat), float(lon)) for lat, lon in polygon]
    if len(vertices) > 1 and vertices[0] == vertices[-1]:
        vertices.pop()
    for lat, lon in vertices:
        if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90.0 and abs(lon) <= 180.0):
            raise ValueError(f"fence vertex ({lat!r}, {lon!r}) is not a latitude, longitude in degrees")
    if len(set(vertices)) < 3 or len(set(vertices)) != len(vertices):
        raise ValueError(
            f"a fence polygon needs at least 3 distinct vertices, not {len(vertices)} ({len(set(vertices))} distinct)"
        )
    return vertices


class Waker:
    """What a waiter on the loop sleeps on until something `set`s it or its timeout passes: asyncio.Event
    with a timeout, for one waiter, without the task that `asyncio.wait_for(event.wait())` makes on every
    wait (a round's flights wait once per drain of the links)."""

    def __init__(self) -> None:
        self._waiting: asyncio.Future | None = None
        self._pending = False  # set while nobody waited: the next wait returns at once

    def set(self) -> None:
        """Wake the waiter (or, if none waits, the next one)."""
        waiting = self._waiting
        if waiting is None:
            self._pending = True
        elif not waiting.done():
            waiting.set_result(True)

    async def wait(self, timeout: float) -> bool:
        """Sleep until `set` (since the last wait) or `timeout` seconds; True when woken by `set`."""
        if self._pending:
            self._pending = False
            return True
        loop = asyncio.get_running_loop()
        waiting = self._waiting = loop.create_future()
        timer = loop.call_later(max(timeout, 0.0), _time_out, waiting)
        try:
            return await waiting
        finally:
            timer.cancel()
            self._waiting = None


def _time_out(waiting: asyncio.Future) -> None:
    if not waiting.done():
        waiting.set_result(False)


class ReadyWait:
    """One `wait_ready`, as far as it has gone: what its `report` was told and why the vehicle is not
    ready yet. The driver's `_towards_ready` step reads and updates it."""

    def __init__(self, report: Callable[[str], None] | None, started: float) -> None:
        self.report = report
        self.heard = started  # the vehicle's texts up to this time have been reported
        self.refused = 0.0  # when the vehicle last refused what the driver asked of it on the way (a mode)
        self.reason = ""  # the last reason the vehicle gave for not being ready
        self.waiting = ""  # "waiting for ...": what is missing, as last reported

    def say(self, text: str) -> None:
        if self.report is not None:
            self.report(text)

    def lacking(self, missing: list[str]) -> None:
        """Report what is missing, when it is not what was reported last."""
        text = "waiting for " + ", ".join(missing)
        if text != self.waiting:
            self.waiting = text
            self.say(text)

    def why(self) -> str:
        """What NotReady says: the last reason (if any) and what was still missing."""
        return f"{self.reason} ({self.waiting})" if self.reason else self.waiting


class Vehicle(abc.ABC):
    """A vehicle the controller commands. Implemented by ArduPilotVehicle and PX4Vehicle."""

    name: str
    autopilot_info: ClassVar[Autopilot | None]  # the firmware's description (None: not known yet)
    target: Target | None = None
    odometer: Odometer  # fed by the driver with every position report
    _limits: FlightLimits | None = None
    _reached_memo: tuple[Position, Target, float, bool] | None = None  # see `reached`
    fix_waker: Waker | None = None  # set at every position report while a flight waits for one
    arm_retry_period: float = 1.0  # seconds between arming attempts the autopilot refused as not ready
    armed_report: ClassVar[str]  # what says the vehicle is armed, for a timeout waiting for it
    takeoff_attempts: ClassVar[int] = 1  # arm and take-off sent again after a disarm on the ground

    def _position_reported(self) -> None:
        """The driver has a new position report: wake whatever waits for one (swarmctl.mission.flight),
        so an arrival is seen when it is reported, not at the next poll."""
        waker = self.fix_waker
        if waker is not None:
            waker.set()

    @property
    def autopilot(self) -> str | None:
        """The firmware's name ("ardupilot", "px4"), or None while it is not known."""
        return None if self.autopilot_info is None else self.autopilot_info.name

    def add_listener(self, callback: Callable[[Any], None], types: Iterable[str] | None = None) -> bool:
        """Call callback(msg) with the MAVLink messages received on this vehicle's link (or, `types`,
        those of these types only), where its driver sees them; False when it does not (MAVSDK hands out
        no raw messages)."""
        return False

    def write_frame(self, frame: bytes) -> bool:
        """Send one packed MAVLink frame (a knowledge TUNNEL) on this vehicle's own link, without waiting;
        False when the driver has no link to send it on (not connected, or the link is closing)."""
        return False

    # --- connection and readiness -------------------------------------------------------------------
    @abc.abstractmethod
    async def connect(self, timeout: float = 15.0) -> None:
        """Wait for the vehicle's heartbeat and ask it for the telemetry the controller needs."""

    async def wait_ready(self, timeout: float = 60.0, report: Callable[[str], None] | None = None) -> None:
        """Wait until the vehicle can arm in the mode swarmctl flies it in (position, home, its own
        readiness reports: `not_ready` is empty). Each round the driver's `_towards_ready` step runs
        first (ArduPilot: GUIDED, its STATUSTEXTs). `report(text)` is called with what the vehicle says
        meanwhile and with what is still missing ("waiting for ...") whenever that changes. NotReady (a
        WaitTimeout) after `timeout` names the last reason and what was still missing."""
        started = time.monotonic()
        deadline = started + timeout
        await self._await_vehicle(timeout)
        wait = ReadyWait(report, started)
        while True:
            await self._towards_ready(wait)
            missing = self.not_ready()
            if not missing:
                return
            wait.lacking(missing)
            if time.monotonic() > deadline:
                raise NotReady(self.name, timeout, wait.why())
            await self._await_news()

    @abc.abstractmethod
    def not_ready(self) -> list[str]:
        """What the vehicle still lacks to arm in the mode swarmctl flies it in (empty: ready)."""

    async def _await_vehicle(self, timeout: float) -> None:  # noqa: B027 - an optional hook
        """Hook: wait until the vehicle is heard at all, before `wait_ready` looks at it."""

    async def _towards_ready(self, wait: ReadyWait) -> None:  # noqa: B027 - an optional hook
        """Hook: one round of what the driver does itself on the way to ready (ask for a mode, report
        the vehicle's texts into `wait`)."""

    async def _await_news(self) -> None:
        """Hook: sleep until there may be news of the vehicle's readiness."""
        await asyncio.sleep(0.05)

    @abc.abstractmethod
    async def close(self) -> None:
        """Stop background tasks and release the link (if this vehicle owns it)."""

    # --- parameters and the timeouts they give -----------------------------------------------------------
    async def read_parameter(self, name: str) -> float:
        """A parameter's value (MavlinkError when the vehicle does not answer or has no such parameter)."""
        raise MavlinkError(f"{self.name}: this driver reads no parameters")

    @property
    def limits(self) -> FlightLimits:
        """The vehicle's speeds: from its parameters once `read_limits` has run, else its firmware's defaults."""
        if self._limits is None:
            assert self.autopilot_info is not None
            self._limits = self.autopilot_info.flight_limits({})
        return self._limits

    async def read_limits(self) -> FlightLimits:
        """Read the firmware's speed parameters (its description's `limit_parameters`, all at once) and
        keep the FlightLimits they give; a parameter that cannot be read counts as its default."""
        info = self.autopilot_info
        assert info is not None
        names = info.limit_parameters
        answers = await asyncio.gather(*(self.read_parameter(n) for n in names), return_exceptions=True)
        values: dict[str, float] = {}
        for name, answer in zip(names, answers):
            if isinstance(answer, MavlinkError):
                log.info("%s: %s is not read (%s); its default counts", self.name, name, answer)
            elif isinstance(answer, BaseException):
                raise answer
            else:
                values[name] = answer
        self._limits = info.flight_limits(values)
        return self._limits

    @property
    def distance_flown_m(self) -> float:
        """3-D distance flown so far, metres (see Odometer)."""
        return self.odometer.metres

    # --- commands -------------------------------------------------------------------------------------
    @abc.abstractmethod
    async def set_mode(self, mode: str) -> None:
        """Switch flight mode by name (GUIDED, LAND, RTL, ... for ArduPilot; HOLD, LAND, RTL for PX4)."""

    async def arm(self, timeout: float = 30.0) -> None:
        """Arm, retrying every `arm_retry_period` while the autopilot still refuses with what its
        description calls "not ready yet" (`retries_arm`) until timeout; then wait for the armed state.
        An arm left unanswered may have gone through with its answers lost: the armed state says so,
        else it is sent again until timeout."""
        info = self.autopilot_info
        assert info is not None
        deadline = time.monotonic() + timeout
        while True:
            try:
                await self._send_arm()
                break
            except CommandRejected as exc:
                if not info.retries_arm(exc.result) or time.monotonic() > deadline:
                    raise
                self._log.info("%s: arming refused (%s), retrying", self.name, self._refusal(exc))
                await asyncio.sleep(self.arm_retry_period)
            except CommandTimeout as exc:
                if await self._shows(lambda: self.armed, self.arm_retry_period):
                    self._log.info("%s: %s, but the vehicle reports it is armed", self.name, exc)
                    break
                if time.monotonic() > deadline:
                    raise
        await self._poll(lambda: self.armed, 3.0, self.armed_report)

    @abc.abstractmethod
    async def _send_arm(self) -> None:
        """Ask the autopilot to arm, once (CommandRejected when it refuses)."""

    def _refusal(self, exc: CommandRejected) -> str:
        """How a refused arm is logged: the autopilot's reason, else its result."""
        return exc.reason or exc.result

    async def arm_and_takeoff(self, rel_alt: float, timeout: float = 120.0) -> None:
        """Ready, arm, take off to rel_alt (metres above home, the mission's altitude) and return once it
        is (nearly) reached, 95 %. With `takeoff_attempts` above 1, a vehicle that disarms on the ground
        after the take-off is armed and sent off again, up to that many times."""
        start = time.monotonic()
        left = lambda: max(1.0, timeout - (time.monotonic() - start))  # noqa: E731
        await self.wait_ready(left())
        await self._prepare_takeoff(rel_alt, left)
        climbed = lambda: (p := self.position) is not None and p.rel_alt >= 0.95 * rel_alt  # noqa: E731
        again = self.takeoff_attempts > 1
        dropped = lambda: again and not self.armed and (p := self.position) is not None and p.rel_alt < 1.0  # noqa: E731
        for attempt in range(1, self.takeoff_attempts + 1):
            await self.arm(min(30.0, left()))
            await self._take_off(rel_alt, left)
            await self._poll(lambda: climbed() or dropped(), left(), f"take-off altitude {rel_alt:g} m")
            if climbed():
                return
            self._log.warning(
                "%s: disarmed on the ground after take-off %d of %d", self.name, attempt, self.takeoff_attempts
            )
        what = f"take-off altitude {rel_alt:g} m ({self.takeoff_attempts} take-offs, each disarmed on the ground)"
        raise WaitTimeout(what, self.name, time.monotonic() - start, self._state_text())

    async def _prepare_takeoff(self, rel_alt: float, left: Callable[[], float]) -> None:  # noqa: B027 - a hook
        """Hook: what the vehicle needs before it is armed for a take-off to rel_alt (`left()`: the
        seconds left of the take-off's timeout)."""

    @abc.abstractmethod
    async def _take_off(self, rel_alt: float, left: Callable[[], float]) -> None:
        """Send the take-off to rel_alt (the vehicle is armed); `target` is above the take-off point
        once this returns (see `_aim_above`)."""

    async def _aim_above(self, rel_alt: float, timeout: float, when: str) -> None:
        """Make the target rel_alt above the vehicle's position, once a real position report is there
        (`when`: "before take-off", "after take-off", for the errors)."""
        await self._poll(lambda: self.position is not None, timeout, f"a position report {when}")
        pos = self.position
        if pos is None:  # _poll returned on it: for the type checker
            raise MavlinkError(f"{self.name}: no position report {when}")
        self.target = Target(pos.lat, pos.lon, rel_alt)

    @abc.abstractmethod
    async def goto(self, lat: float, lon: float, rel_alt: float) -> None:
        """Send a position target (degrees, metres above home). Returns without waiting."""

    def goto_nowait(self, lat: float, lon: float, rel_alt: float) -> bool:
        """`goto` at once, for a driver that sends a position target without waiting for an answer; False
        (nothing sent) for one that waits: use `goto`."""
        return False

    @abc.abstractmethod
    async def land(self) -> None:
        """Land where the vehicle is."""

    @abc.abstractmethod
    async def rtl(self) -> None:
        """Return to launch (and land there)."""

    @abc.abstractmethod
    async def resume(self) -> None:
        """Take an airborne vehicle back from its own failsafe (RTL, LAND) and hold it where it is, so
        that position targets steer it again."""

    async def upload_fence(self, polygon: list[tuple[float, float]]) -> None:
        """Make polygon ((lat, lon) vertices, degrees) the vehicle's inclusion geofence and turn the
        fence on; the autopilot then refuses targets outside it and acts on a breach by itself. The
        vertices are checked (`fence_vertices`, ValueError), then the vehicle's own fence settings
        (`_check_fence_settings`), before anything is sent (`_send_fence`)."""
        vertices = fence_vertices(polygon)
        await self._check_fence_settings(vertices)
        await self._send_fence(vertices)

    async def _check_fence_settings(self, vertices: list[tuple[float, float]]) -> None:  # noqa: B027 - a hook
        """Hook: refuse (MavlinkError) a fence the vehicle's own settings would spoil."""

    @abc.abstractmethod
    async def _send_fence(self, vertices: list[tuple[float, float]]) -> None:
        """Upload the checked vertices as the inclusion fence and turn it on."""

    # --- state ----------------------------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def position(self) -> Position | None: ...

    @property
    @abc.abstractmethod
    def home(self) -> Home | None: ...

    @property
    @abc.abstractmethod
    def armed(self) -> bool: ...

    @property
    @abc.abstractmethod
    def mode(self) -> str: ...

    @property
    def silenced(self) -> str | None:
        """Why the vehicle's messages are no longer followed while its link is up (a listener failed on
        one: MavlinkLink._listener_failed), or None. Its GCS failsafe does not act then: the link is up."""
        return None

    @property
    @abc.abstractmethod
    def lost(self) -> bool:
        """True while the vehicle's heartbeats have stopped (link loss)."""

    @property
    def battery_remaining(self) -> int | None:
        """Battery percentage, or None when unknown."""
        return None

    @property
    def clock_s(self) -> float | None:
        """The vehicle's own clock from its latest report, seconds since it booted (a simulator's runs at
        its speed-up); None where the driver has none."""
        return None

    @property
    def on_ground(self) -> bool:
        """True when the autopilot's own land detector says the vehicle is on the ground (False when it
        says otherwise or nothing)."""
        return False

    # --- shared helpers -------------------------------------------------------------------------------
    def reached(self, tolerance: float = 1.0) -> bool:
        """True when the vehicle is within tolerance metres (3-D) of the last target."""
        pos, tgt = self.position, self.target
        if pos is None or tgt is None:
            return False
        memo = self._reached_memo  # the answer for the same position report and target (asked every poll)
        if memo is not None and memo[0] is pos and memo[1] is tgt and memo[2] == tolerance:
            return memo[3]
        horiz = distance_m(pos.lat, pos.lon, tgt.lat, tgt.lon)
        answer = (horiz**2 + (pos.rel_alt - tgt.rel_alt) ** 2) ** 0.5 <= tolerance
        self._reached_memo = (pos, tgt, tolerance, answer)
        return answer

    async def wait_reached(self, tolerance: float = 1.0, timeout: float = 120.0) -> None:
        await self._poll(lambda: self.reached(tolerance), timeout, "the position target")

    async def wait_landed(self, timeout: float = 120.0) -> None:
        """Wait until the vehicle is on the ground and disarmed."""
        await self._poll(self._landed, timeout, "landing")

    def _landed(self) -> bool:
        # disarmed and under 1 m, or disarmed where the land detector says ground: PX4 SITL's estimate
        # has been seen 1.25 m above the ground it had landed and disarmed on
        pos = self.position
        return not self.armed and (pos is None or pos.rel_alt < 1.0 or self.on_ground)

    async def _shows(self, cond: Callable[[], bool], timeout: float) -> bool:
        """Whether the vehicle's reports show cond() within timeout seconds: what an unanswered command
        did (its answers may be what was lost)."""
        try:
            await self._poll(cond, timeout, "")
        except WaitTimeout:
            return False
        return True

    async def _poll(self, cond, timeout: float, what: str, period: float = 0.05) -> None:
        deadline = time.monotonic() + timeout
        while not cond():
            if time.monotonic() > deadline:
                raise WaitTimeout(what, self.name, timeout, self._state_text())
            await self._on_wait()
            await asyncio.sleep(period)

    async def keep_going(self) -> None:
        """What the driver does while something waits for the vehicle to reach its target (the `_on_wait`
        hook of `wait_reached`): call it now and then while waiting."""
        await self._on_wait()

    async def _on_wait(self) -> None:  # noqa: B027 - an optional hook, empty by default
        """Hook run while waiting (ArduPilot resends its position target here)."""

    @property
    def _log(self) -> logging.Logger:
        """The driver's own logger (its module's), for the lines the shared flows log."""
        return logging.getLogger(type(self).__module__)

    def _state_text(self) -> str:
        pos = self.position
        where = "no position" if pos is None else f"at {pos.lat:.7f},{pos.lon:.7f} {pos.rel_alt:.1f} m"
        return f"mode {self.mode}, {'armed' if self.armed else 'disarmed'}, {where}"

    async def __aenter__(self) -> Vehicle:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()
