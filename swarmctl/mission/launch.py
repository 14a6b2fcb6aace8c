"""Getting one agent's vehicle into the search: connect, preflight, fence, take-off, the first cell;
and back into it after a link loss (rejoin).

Each vehicle goes through these on its own (a slow one delays only itself); the preflights run at
once, the take-offs are spaced by `flight.takeoff_at_once`. Preflight waits until the vehicle can arm
in the mode it is flown in (its driver's `wait_ready`: ArduPilot switches to GUIDED first), showing
what the vehicle says meanwhile (`note`: an event, a log line, the live view), then reads its speed
parameters, from which the waits the mission does not set are derived (timeouts.py). A failure fails
that vehicle only, except a vehicle whose autopilot contradicts the mission file, or whose GCS
failsafe is off where the mission does not allow it (failsafes.py: read first in preflight; no vehicle
takes off before every one is checked), which stops the mission (the file or the vehicle must change).
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from typing import TYPE_CHECKING, Any

from swarmctl.errors import InputError
from swarmctl.geo.fence import fence_contains
from swarmctl.mavlink.errors import MavlinkError
from swarmctl.mavlink.limits import RESUME_ABOVE_M
from swarmctl.mission import failsafes, timeouts
from swarmctl.mission.agent import Agent, State

if TYPE_CHECKING:
    from collections.abc import Callable

    from swarmctl.mavlink.connect import Connector
    from swarmctl.mavlink.vehicle import Position
    from swarmctl.mission.crew import Crew
    from swarmctl.mission.flight import Flight
    from swarmctl.mission.plan import MissionPlan
    from swarmctl.mission.recorder import Recorder
    from swarmctl.mission.state import MissionState

log = logging.getLogger(__name__)

NOTE_REPEAT_S = 10.0  # a preflight note repeated within this long is not shown again
FRESH_REPORT_S = 2.0  # a rejoin waits this long at most for a position report from after the link came back
FRESH_POLL_S = 0.05  # how often a rejoin looks for that report


class Launch:
    """Gets the crew's vehicles into the search and back into it: the plan (its grid, altitude, timing,
    battery and mission settings), the fence to upload (None: none), the connector that opens the
    links, how the vehicles fly (Flight), and `show`, called when the live view has news."""

    def __init__(
        self,
        plan: MissionPlan,
        fence: list[tuple[float, float]] | None,
        connector: Connector,
        rec: Recorder,
        state: MissionState,
        crew: Crew,
        flight: Flight,
        show: Callable[[], None] | None = None,
    ):
        self.plan, self.fence, self.connector = plan, fence, connector
        self.rec, self.state, self.crew, self.flight, self.show = rec, state, crew, flight, show
        self.takeoff_slots = asyncio.Semaphore(plan.spec.flight.takeoff_at_once)

    async def connect(self, a: Agent) -> None:
        """Connect the agent's vehicle with the driver its autopilot reports (see mavlink/connect.py). A
        vehicle that disagrees with the mission file (AutopilotMismatch, an InputError) stops the mission;
        the others get their end action."""
        spec = a.spec
        try:
            vehicle = await self.connector.connect(
                spec.connection,
                spec.sysid,
                name=spec.name,
                autopilot=spec.autopilot,
                timeout=self.plan.spec.timing.connect_timeout,
            )
        except InputError as exc:
            self.refuse(a, exc)
            return
        a.vehicle = vehicle
        vehicle.add_listener(a.feed.listener(spec.sysid), ("TUNNEL",))  # the detector's reports, where they come

    def refuse(self, a: Agent, exc: InputError) -> None:
        """The vehicle contradicts the mission file (its autopilot) or the mission's safety rules (its GCS
        failsafe is off): it fails, and the mission stops with `exc` (one line, exit 2)."""
        a.error = str(exc)
        self.crew.enter(a, State.FAILED, error=a.error)
        self.state.fail(exc)

    async def start(self, a: Agent) -> None:
        """Connect, preflight, (fence,) take off and fly to the first cell; then the agent searches."""
        timing = self.plan.spec.timing
        try:
            self.crew.enter(a, State.CONNECT)
            await self.state.until_stopped(self.connect(a))
            if self.state.stopping:
                return
            self.crew.enter(a, State.PREFLIGHT)
            try:
                await self.state.until_stopped(
                    failsafes.check(
                        a,
                        self.fence is not None,
                        self.plan.spec.mission.allow_no_failsafe,
                        lambda text: self.note(a, text),
                    )
                )
            except InputError as exc:  # its GCS failsafe is off: the mission stops before anything takes off
                self.refuse(a, exc)
                return
            if self.state.stopping:
                return
            await self.state.until_stopped(self.preflight(a))
            if self.state.stopping:
                return
            battery = a.battery()
            needed = self.plan.spec.battery.takeoff_min
            if battery is not None and battery < needed:
                raise MavlinkError(f"{a.name}: battery {battery} % is below the {needed} % needed to start")
            home = a.vehicle.home
            if home is None:
                raise MavlinkError(f"{a.name}: no home position")
            first = self.plan.grid.latlon_to_cell(home.lat, home.lon)
            if not self.plan.grid.in_grid(*first):
                raise MavlinkError(f"{a.name}: home {home.lat:.6f},{home.lon:.6f} is outside the grid")
            if self.fence is not None:
                await self.upload_fence(a, home)
            await self.state.until_stopped(
                failsafes.all_checked(self.crew, self.state)
            )  # a refusal stops the mission before any take-off
            async with self.takeoff_slots:
                if self.state.stopping:
                    return
                self.crew.enter(a, State.TAKEOFF)
                altitude = self.plan.altitude
                wait = timeouts.takeoff(timing.takeoff_timeout, a.vehicle, altitude)
                await self.state.until_stopped(a.vehicle.arm_and_takeoff(altitude, wait))
                if self.state.stopping:
                    return
                # the first cell: the home cell, or the nearest free one nobody holds yet
                cell = self.flight.nearest_free(first, exclude=a)
                await self.flight.fly(a, cell, timing.takeoff_timeout)
            a.cell = cell
            await self.flight.sense_and_share(a, moved=True, since=0.0)
            self.crew.enter(a, State.SEARCH)
        except (TimeoutError, MavlinkError) as exc:
            a.error = str(exc)
            self.crew.enter(a, State.FAILED, error=str(exc))
        except InputError:
            raise  # bad input: the mission stops with it (run() raises it, one line, exit 2)
        except Exception as exc:  # a driver's bug, or a reply it did not expect: this vehicle fails, not the mission
            a.error = f"unexpected {type(exc).__name__} while starting: {exc}"
            log.error("%s: %s", a.name, a.error)
            log.debug("%s: the unexpected error", a.name, exc_info=True)
            self.crew.enter(a, State.FAILED, error=a.error)

    async def preflight(self, a: Agent) -> None:
        """Wait until the vehicle can arm in the mode it is flown in, its reports shown as they come
        (NotReady after ready_timeout names the last one); then read its speed parameters and record
        them with the timeouts they give (event "limits": a step of one cell, and the end action from
        the far corner of the grid)."""
        timing, m = self.plan.spec.timing, self.plan.spec.mission
        await a.vehicle.wait_ready(timing.ready_timeout, report=lambda text: self.note(a, text))
        limits = await a.vehicle.read_limits()
        across = math.hypot(self.plan.grid.width, self.plan.grid.height) * self.plan.grid.cell
        if timing.end_timeout is not None:
            end = timing.end_timeout
        elif m.end_action == "land":
            end = limits.land_timeout(self.plan.altitude)
        else:
            end = limits.rtl_timeout(across, self.plan.altitude)
        self.rec.event(
            "limits",
            vehicle=a.name,
            sysid=a.spec.sysid,
            read=list(limits.read),
            speed=round(limits.speed, 3),
            climb=round(limits.climb, 3),
            descent=round(limits.descent, 3),
            land_speed=round(limits.land_speed, 3),
            takeoff_timeout=round(timeouts.takeoff(timing.takeoff_timeout, a.vehicle, self.plan.altitude), 1),
            step_timeout=round(
                limits.move_timeout(self.plan.grid.cell) if timing.step_timeout is None else timing.step_timeout, 1
            ),
            end_timeout=round(end, 1),
        )

    def note(self, a: Agent, text: str) -> None:
        """What the vehicle says (or still lacks) while it gets ready: recorded (event "preflight"), logged
        and shown in the live view; the same text within NOTE_REPEAT_S is shown once."""
        now = time.monotonic()
        if now - a.notes.get(text, -math.inf) < NOTE_REPEAT_S:
            return
        a.notes[text] = now
        a.status = text
        self.rec.event("preflight", vehicle=a.name, sysid=a.spec.sysid, text=text)
        log.info("%s: %s", a.name, text)
        if self.show is not None:
            self.show()

    async def upload_fence(self, a: Agent, home: Any) -> None:
        """The mission's fence to the vehicle, before it takes off (preflight, and again before a vehicle on
        the ground rejoins). A vehicle whose home is outside the fence, or that does not take the fence,
        does not fly (the others do)."""
        fence = self.fence
        assert fence is not None
        if not fence_contains(fence, home.lat, home.lon):
            why = (
                f"{a.name}: home {home.lat:.6f},{home.lon:.6f} is outside the fence (the search area's "
                "boundary); launch it inside the area, or fly without fence"
            )
            self.rec.event("fence", vehicle=a.name, sysid=a.spec.sysid, uploaded=False, error=why)
            raise MavlinkError(why)
        try:
            await self.state.until_stopped(a.vehicle.upload_fence(fence))
        except (TimeoutError, MavlinkError) as exc:
            self.rec.event("fence", vehicle=a.name, sysid=a.spec.sysid, uploaded=False, error=str(exc))
            raise MavlinkError(f"{exc}; without its fence {a.name} does not take off") from None
        if not self.state.stopping:
            self.rec.event("fence", vehicle=a.name, sysid=a.spec.sysid, uploaded=True, vertices=len(fence))

    async def fresh_position(self, a: Agent, timeout: float = FRESH_REPORT_S) -> Position | None:
        """The vehicle's next position report (its heartbeat, with its arming, comes as often), or the
        last one after `timeout` s."""
        old = a.vehicle.position
        deadline = time.monotonic() + timeout
        while a.vehicle.position is old and time.monotonic() < deadline and not self.state.stopping:
            await asyncio.sleep(FRESH_POLL_S)
        return a.vehicle.position

    async def rejoin(self, a: Agent) -> None:
        """A vehicle back after a link loss, or home on low battery with a fresh one (Agent.fresh_battery):
        take it back from its failsafe in the air (or take off again from the ground, after its fence), fly
        to the nearest free cell, and search again."""
        timing = self.plan.spec.timing
        try:
            # what the vehicle reported before its link went is stale: decide on a report from after it
            pos = await self.fresh_position(a)
            await self.state.while_held()  # the operator's pause: it rejoins on resume
            if a.vehicle.armed and pos is not None and pos.rel_alt > RESUME_ABOVE_M:
                # still in the air, perhaps returning or landing on its failsafe: take it back there
                await a.vehicle.resume()
            else:
                # on the ground: ready to arm in the mode it is flown in first (its failsafe left it in RTL
                # or LAND, a reboot in its boot mode), and the fence again (a rebooted ArduPilot keeps its
                # fence but has it off)
                await self.state.until_stopped(
                    a.vehicle.wait_ready(timing.ready_timeout, report=lambda t: self.note(a, t))
                )
                if self.fence is not None:
                    if a.vehicle.home is None:
                        raise MavlinkError(f"{a.name}: no home position")
                    await self.upload_fence(a, a.vehicle.home)
                altitude = self.plan.altitude
                async with self.takeoff_slots:
                    await a.vehicle.arm_and_takeoff(
                        altitude, timeouts.takeoff(timing.takeoff_timeout, a.vehicle, altitude)
                    )
            await self.state.while_held()  # paused while it took off: it holds there until resume
            pos = a.vehicle.position
            here = self.plan.grid.latlon_to_cell(pos.lat, pos.lon) if pos is not None else a.cell
            if here is None or not self.plan.grid.in_grid(*here):
                here = a.cell or (0, 0)
            a.cell = None
            cell = self.flight.nearest_free(here, exclude=a)
            a.cell = cell
            since = time.monotonic()
            await self.flight.fly(a, cell, None if timing.step_timeout is None else timing.step_timeout * 3)
            await self.flight.sense_and_share(a, moved=True, since=since)
            self.crew.enter(a, State.SEARCH, rejoined=True)
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # noqa: BLE001 - a task that dies silently would leave the vehicle in REJOIN
            if not isinstance(exc, (MavlinkError, asyncio.TimeoutError)):
                log.exception("%s: rejoining failed", a.name)
            a.error = str(exc) or type(exc).__name__
            self.crew.enter(a, State.FAILED, error=a.error)
        finally:
            a.rejoin_task = None
