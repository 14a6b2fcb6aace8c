"""Flying one agent's vehicle to a cell, and sensing and sharing what it sees there.

Used by the launch (the first cell), the rounds (every move) and a rejoin. Every setpoint is a
guarded cell's centre at the mission altitude (the guard's `setpoint_altitude`). Sensing is from
the vehicle's position (swarmctl.mission.sensing): the footprint round each cell reached is explored,
and a detector's reports add targets.
"""

from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from swarmctl.knowledge.stepping import step_all
from swarmctl.mavlink.errors import MavlinkError
from swarmctl.mavlink.vehicle import Waker
from swarmctl.mission import timeouts
from swarmctl.mission.agent import Agent, State
from swarmctl.mission.sensing import Sensed, footprints, sense
from swarmctl.mission.state import cancel

if TYPE_CHECKING:
    from swarmctl.geo.grid import GeoGrid
    from swarmctl.mission.crew import Crew
    from swarmctl.mission.finish import FinishLine
    from swarmctl.mission.recorder import Recorder
    from swarmctl.mission.spec import FlightTable, TimingTable
    from swarmctl.mission.state import MissionState
    from swarmctl.mission.watch import Watch
    from swarmctl.world.guard import SafetyGuard

log = logging.getLogger(__name__)

_FAR = np.iinfo(np.int64).max


POLL_S = 0.05  # how often the waiting flights' timers are looked at (timeout, the driver's resends)
COURSE_S = 0.1  # how often a flight in progress is checked against its course (swarmctl.mission.watch)


@dataclass
class _Flight:
    agent: Agent
    cell: tuple[int, int]
    limit: float  # seconds it may take, from when its position target has gone out
    deadline: float | None = None  # None: its driver is still sending the position target
    reached: bool | None = None  # the outcome, once known


class Flight:
    """Flies the crew's vehicles to cells and senses there: the grid and the guard (every setpoint's
    cell and altitude), the sensor footprint (`fov`, cells), the `[flight]` and `[timing]` limits,
    the watch (a flight off course ends its wait), and the finish line (the finds)."""

    def __init__(
        self,
        grid: GeoGrid,
        guard: SafetyGuard,
        fov: float,
        limits: FlightTable,
        timing: TimingTable,
        rec: Recorder,
        state: MissionState,
        crew: Crew,
        watch: Watch,
        finish: FinishLine,
    ):
        self.grid, self.guard, self.fov, self.limits, self.timing = grid, guard, fov, limits, timing
        self.rec, self.state, self.crew, self.watch, self.finish = rec, state, crew, watch, finish

    def nearest_free(self, start: tuple[int, int], exclude: Agent | None = None) -> tuple[int, int]:
        """The free cell (not blocked, nobody holds it) nearest to `start`."""
        taken = self.crew.held(exclude)
        w, h = self.grid.width, self.grid.height
        xs, ys = np.meshgrid(np.arange(w), np.arange(h), indexing="ij")
        d = (xs - start[0]) ** 2 + (ys - start[1]) ** 2
        d = np.where(self.grid.blocked, _FAR, d).astype(np.int64)
        for cell in taken:
            d[cell] = _FAR
        flat = int(np.argmin(d))
        if d.flat[flat] == _FAR:
            raise MavlinkError("no free cell left to fly to")
        return (flat // h, flat % h)

    async def fly(self, a: Agent, cell: tuple[int, int], timeout: float | None) -> bool:
        """One vehicle's flight to a cell (see fly_all)."""
        return (await self.fly_all([(a, cell)], timeout))[0]

    async def fly_all(self, moves: list[tuple[Agent, tuple[int, int]]], timeout: float | None) -> list[bool]:
        """Send each vehicle the position target for its cell's centre at the mission altitude and wait until
        each has reached it, for `timeout` seconds (None: derived from the vehicle's speeds and the distance
        to the cell, timeouts.move) from when its target went out. Per move, False only when that time ran
        out: a wait cut short because the link was lost, the mission stopped or the vehicle went off course
        (swarmctl.mission.watch flags it at the next round) gives True at once (it is not a step timeout).

        One waiter for all of them (not a task per vehicle): it looks for arrivals whenever a flying vehicle
        reports its position (at most once a drain of the links: `Vehicle.fix_waker`), and at the timers
        (timeout, the driver's resends) every POLL_S. A driver that sends at once (`Vehicle.goto_nowait`) is
        not given a task at all, one that must wait for an answer (PX4) gets one for its `goto` only."""
        for a, cell in moves:
            if self.grid.blocked[cell]:  # the guard never lets this happen; defence in depth
                raise MavlinkError(f"{a.name}: refusing a setpoint in blocked cell {cell}")
        alt = self.guard.setpoint_altitude()
        flights: list[_Flight] = []
        sending: list[asyncio.Task] = []
        for a, cell in moves:
            lat, lon = self.grid.cell_to_latlon(*cell)
            f = _Flight(a, cell, timeouts.move(timeout, a.vehicle, lat, lon, alt))
            flights.append(f)
            if a.vehicle.goto_nowait(lat, lon, alt):
                f.deadline = time.monotonic() + f.limit
            else:
                sending.append(asyncio.ensure_future(self._send(f, lat, lon, alt)))
        try:
            await self._wait(flights, sending)
        finally:
            for t in sending:
                if not t.done():
                    await cancel(t)
        return [bool(f.reached) for f in flights]

    @staticmethod
    async def _send(f: _Flight, lat: float, lon: float, alt: float) -> None:
        await f.agent.vehicle.goto(lat, lon, alt)
        f.deadline = time.monotonic() + f.limit

    async def _wait(self, flights: list[_Flight], sending: list[asyncio.Task]) -> None:
        waker = Waker()
        vehicles = [f.agent.vehicle for f in flights]
        for v in vehicles:
            v.fix_waker = waker
        try:
            await self._wait_woken(flights, sending, waker)
        finally:
            for v in vehicles:
                if v.fix_waker is waker:
                    v.fix_waker = None

    async def _wait_woken(self, flights: list[_Flight], sending: list[asyncio.Task], waker: Waker) -> None:
        """Until every flight has its outcome: arrivals looked at when woken (a position report), the
        timers and the driver's resends every POLL_S, the course every COURSE_S."""
        tolerance = self.limits.reach_tolerance
        poll_at = course_at = 0.0
        while True:
            for t in sending:
                if t.done() and (exc := t.exception()) is not None:
                    raise exc
            now = time.monotonic()
            poll = now >= poll_at
            if poll:
                poll_at = now + POLL_S
            course = now >= course_at
            if course:
                course_at = now + COURSE_S
            waiting = False
            for f in flights:
                if f.reached is not None:
                    continue
                if f.deadline is None:
                    waiting = True
                    continue
                v = f.agent.vehicle
                if (
                    v.reached(tolerance)
                    or v.lost
                    or self.state.stopping
                    or (course and self.watch.off_course(f.agent, f.cell))
                ):
                    f.reached = True
                elif not poll:
                    waiting = True  # woken by a position report: its timers wait for the poll
                elif now > f.deadline:
                    f.reached = False
                else:
                    try:
                        await v.keep_going()
                        waiting = True
                    except MavlinkError:  # as wait_reached would have ended: not reached in time
                        f.reached = False
            if not waiting:
                return
            await waker.wait(poll_at - time.monotonic())

    async def sense_and_share(self, a: Agent, moved: bool, since: float) -> list[tuple[int, int]]:
        """Sense (the footprint round the cell reached, when the vehicle arrived somewhere new and is not off
        course; with a detector, after waiting for its report there) and publish; returns the targets it saw."""
        if a.cell is None:
            return []
        on_target = a.state is State.HOVER
        moved = self._arrived(a, moved)
        if moved and a.detector is not None:
            reports = await self._wait_reports(a, since)
        else:
            reports = self._take_reports(a)
        sensed = sense(self.grid, self.fov, a.cell if moved else None, reports, a.visited)
        found, fresh = self._found(a, sensed)
        a.exchange.step(self.state.step, a.cell, on_target, sensed.cells, sensed.phi, sensed.obstacle)
        self._report(a, sensed, found, fresh)
        return found

    async def sense_and_share_all(self, agents: list[Agent], moved: set[int], since: float) -> None:
        """`sense_and_share` for each agent (those in `moved` arrived at a new cell), the detectors' reports
        awaited together, then the knowledge step of all of them at once (swarmctl.knowledge.stepping: in
        ground mode a few array operations for every agent, then each one's frames in the agents' order)."""
        agents = [a for a in agents if a.cell is not None]
        on_target = [a.state is State.HOVER for a in agents]
        arrived = [self._arrived(a, a.index in moved) for a in agents]
        reports: list[list] = [[] for _ in agents]
        waiting = [i for i, a in enumerate(agents) if arrived[i] and a.detector is not None]
        for i, a in enumerate(agents):
            if not (arrived[i] and a.detector is not None):
                reports[i] = self._take_reports(a)
        if waiting:
            got = await asyncio.gather(*(self._wait_reports(agents[i], since) for i in waiting))
            for i, r in zip(waiting, got):
                reports[i] = r
        plain = [i for i, a in enumerate(agents) if arrived[i] and not reports[i]]  # the footprint alone
        prints = footprints(self.grid, self.fov, [agents[i].here for i in plain])
        sensed = [Sensed() for _ in agents]
        for i, p in zip(plain, prints):
            sensed[i] = p
        for i, a in enumerate(agents):
            if reports[i]:
                sensed[i] = sense(self.grid, self.fov, a.cell if arrived[i] else None, reports[i], a.visited)
        finds = [self._found(a, s) for a, s in zip(agents, sensed)]

        def then(i: int) -> None:
            self._report(agents[i], sensed[i], *finds[i])

        step_all(
            [a.exchange for a in agents],
            self.state.step,
            [a.here for a in agents],
            on_target,
            [(s.cells, s.phi, s.obstacle) for s in sensed],
            then,
        )

    def _arrived(self, a: Agent, moved: bool) -> bool:
        """Whether the agent senses at its cell this round (it moved there and is not off course); notes
        the visit and its pass."""
        if moved and self.watch.off_course(a, a.here):
            moved = False  # steered away before it got there: nothing sensed there (swarmctl.mission.watch)
        if moved:
            a.visited[a.here] = self.state.step
            self.finish.probability.look(a.here, a.name)  # passes (swarmctl.mission.probability)
        return moved

    async def _wait_reports(self, a: Agent, since: float) -> list:
        """Wait for the detector's report for the agent's cell (an event when none comes), then every
        report received."""
        report = await a.feed.wait_report(
            a.here, since, self.timing.sense_timeout, abort=lambda: a.vehicle.lost or self.state.stopping
        )
        if report is None:
            self.rec.event("no_report", vehicle=a.name, cell=a.cell, step=self.state.step)
        return self._take_reports(a)

    @staticmethod
    def _take_reports(a: Agent) -> list:
        """The detector reports received since the last call (a warning, once, when the mission gives the
        agent no detector)."""
        reports = a.feed.take_new()
        if reports and a.detector is None and not a.unexpected_reports:
            a.unexpected_reports = True
            log.warning(
                "%s: detector reports arrive on its link although the mission gives it no detector; they are used, "
                'but the controller does not wait for them: add detector = "mavlink" to its [[vehicles]] table',
                a.name,
            )
        return reports

    @staticmethod
    def _found(a: Agent, sensed: Sensed) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
        """The targets sensed, and those of them the agent did not know yet."""
        found = [(int(x), int(y)) for x, y in sensed.targets]
        return found, [t for t in found if t not in a.knowledge.targets]

    def _report(self, a: Agent, sensed: Sensed, found: list[tuple[int, int]], fresh: list[tuple[int, int]]) -> None:
        """After the agent's step: its dropped report entries and the new targets, reported (DETECTIONs with
        the step and cell they were seen from, which the others check) and recorded."""
        if sensed.dropped:
            a.sensor_dropped += sensed.dropped
            self.rec.event("report_dropped", vehicle=a.name, step=self.state.step, dropped=sensed.dropped)
        if not fresh:
            return
        seen: dict[tuple[int, int], list[tuple[int, int]]] = {}
        for t, origin in zip(found, sensed.seen_from.tolist()):
            if t in fresh:
                seen.setdefault((int(origin[0]), int(origin[1])), []).append(t)
        for origin, targets in seen.items():
            a.exchange.report_targets(
                np.array(targets, dtype=np.int64), a.visited.get(origin, self.state.step), seen_from=origin
            )
        latlon = [self.grid.cell_to_latlon(*t) for t in fresh]
        self.rec.event("targets", vehicle=a.name, cells=fresh, step=self.state.step, latlon=latlon)
        self.finish.found(a, fresh)  # the swarm's first sight of each: a find (swarmctl.mission.finish)
