"""Noticing what was not commanded: each round, every searching or hovering vehicle's reported position
against the setpoint it was given.

A real vehicle without MAVLink signing obeys a position target from any sender (docs/security.md); the
controller cannot stop that, but it knows where it sent each vehicle. At the start of every round (no
step is in flight then) a vehicle is off course when

- it is more than `[flight] off_course_m` metres (horizontally) from the path of its last step: the
  segment to the centre of the cell it was sent to from the centre of the cell it held at the last
  check, or from where it was at the last check it passed, whichever is nearer (a vehicle still on its
  way after a step timeout turns towards its new cell from there; a vehicle held away does not move
  the start: only a position on course does). Not checked the first round a vehicle searches, after
  its launch or a rejoin, whose path is not a step; or
- it is more than `[flight] below_altitude_m` metres below the mission altitude (once it has been at
  that altitude since it was first seen commanded: a vehicle taken back from its failsafe climbs first).

A step in flight is checked the same way while it flies (`off_course`): a vehicle steered away ends
its wait at once, so that it does not hold the round for the step timeout.

Then: an `off_course` event, an alarm in the live table (`Agent.alarm`), and the setpoint sent again.
A vehicle off course for more than `[flight] off_course_rounds` rounds in a row is treated as taken
over: the agent's OVERRIDE transition with `reason = "not commanded"` (the controller stops commanding
it, as for a pilot's mode) and the others carry on. A vehicle back on course clears its alarm.
"""

from __future__ import annotations

import asyncio
import math
from typing import TYPE_CHECKING

from swarmctl.mavlink.codec import ne_m
from swarmctl.mission.agent import State
from swarmctl.mission.state import quietly

if TYPE_CHECKING:
    from swarmctl.geo.grid import GeoGrid
    from swarmctl.mission.agent import Agent
    from swarmctl.mission.crew import Crew
    from swarmctl.mission.recorder import Recorder
    from swarmctl.mission.spec import FlightTable
    from swarmctl.mission.state import MissionState
    from swarmctl.world.guard import SafetyGuard

NOT_COMMANDED = "not commanded"  # the OVERRIDE reason


def off_path_m(point: tuple[float, float], start: tuple[float, float]) -> float:
    """Distance (metres) of `point` from the segment from `start` to the origin (north, east metres)."""
    (pn, pe), (sn, se) = point, start
    length2 = sn * sn + se * se
    t = 0.0 if length2 == 0.0 else min(1.0, max(0.0, (pn * sn + pe * se) / length2))
    return math.hypot(pn - t * sn, pe - t * se)


Cell = tuple[int, int]


def deviation(grid: GeoGrid, altitude: float, a: Agent, start: Cell | None, cell: Cell) -> tuple[float, float] | None:
    """(metres from the path to the centre of `cell`, metres below `altitude`) of the vehicle now; None
    without a position report. The path starts at the centre of cell `start` or where the vehicle was
    at the last check it passed (`Agent.watch_pos`: a vehicle still on its way after a step timeout
    turns from there), whichever is nearer; 0 m off it when `start` is None (no path known)."""
    pos = a.vehicle.position
    if pos is None:
        return None
    below = altitude - pos.rel_alt
    if start is None:
        return 0.0, below
    # the path's ends in metres from the centre of `cell`, kept per agent (a flight is checked every
    # COURSE_S against the same path) and converted again only when an end moves
    path = getattr(a, "watch_path", None)
    if path is None or path[0] != start or path[1] != cell or path[2] is not grid:
        lat, lon = grid.cell_to_latlon(*cell)
        start_m = ne_m(lat, lon, *grid.cell_to_latlon(*start))
        # then: watch_pos, its metres, the position last measured, its metres off the path
        path = a.watch_path = [start, cell, grid, lat, lon, start_m, None, None, None, 0.0]
    watch_pos = a.watch_pos
    if path[6] != watch_pos or (watch_pos is not None and path[7] is None):
        path[6], path[7], path[8] = watch_pos, None if watch_pos is None else ne_m(path[3], path[4], *watch_pos), None
    if path[8] is not pos:  # a new position report: how far it is off the path
        here = ne_m(path[3], path[4], pos.lat, pos.lon)
        off = off_path_m(here, path[5])
        path[8], path[9] = pos, off if path[7] is None else min(off, off_path_m(here, path[7]))
    return path[9], below


class Watch:
    """The check of the module docstring, for the crew's agents: the grid, the guard (the altitude of
    every setpoint), the limits (`[flight]`), and where off-course events are recorded."""

    def __init__(
        self, grid: GeoGrid, guard: SafetyGuard, limits: FlightTable, rec: Recorder, state: MissionState, crew: Crew
    ):
        self.grid, self.guard, self.limits = grid, guard, limits
        self.rec, self.state, self.crew = rec, state, crew

    def problems(self, a: Agent, start: Cell | None, cell: Cell) -> tuple[list[str], dict]:
        """What is off (texts) for a vehicle sent from `start` to `cell`, and the figures. The altitude
        counts only once the vehicle has been at the mission altitude since it was first seen commanded
        (`Agent.climbed`): a vehicle taken back from its failsafe low down climbs first."""
        d = deviation(self.grid, self.guard.setpoint_altitude(), a, start, cell)
        if d is None:
            return [], {}
        off, below = d
        limits = self.limits
        if below <= limits.below_altitude_m:
            a.climbed = True
        out = []
        if off > limits.off_course_m:
            out.append(f"{off:.0f} m off course")
        if a.climbed and below > limits.below_altitude_m:
            out.append(f"{below:.0f} m below the mission altitude")
        return out, dict(off_m=round(off, 1), below_m=round(below, 1))

    def off_course(self, a: Agent, cell: Cell) -> bool:
        """A step in flight from the agent's cell to `cell` has gone off course (checked while it flies,
        so that a vehicle steered away does not hold the round for the step timeout). Only for vehicles
        the watch has seen commanded (not the launch's first cell, not a rejoin)."""
        if a.watch_from is None or a.cell is None:
            return False
        return bool(self.problems(a, a.cell, cell)[0])

    async def check(self) -> None:
        """The check for every agent of this process; resends the setpoints of the vehicles off course
        (all at once)."""
        resend: list[Agent] = []
        for a in self.crew.agents:
            if a.state not in (State.SEARCH, State.HOVER) or a.cell is None or a.vehicle.lost:
                a.watch_from, a.watch_pos, a.off_course, a.alarm, a.climbed = None, None, 0, None, False
                continue
            found, detail = self.problems(a, a.watch_from, a.cell)
            a.watch_from = a.cell
            if not found:
                pos = a.vehicle.position
                a.watch_pos = None if pos is None else (pos.lat, pos.lon)  # only a position on course
                if a.alarm is not None:
                    self._record(a, cleared=True)
                a.off_course, a.alarm = 0, None
                continue
            a.off_course += 1
            a.alarm = f"{NOT_COMMANDED}: " + ", ".join(found)
            detail["rounds"] = a.off_course
            if a.off_course > self.limits.off_course_rounds:
                self.crew.enter(a, State.OVERRIDE, reason=NOT_COMMANDED, **detail)
                a.override_reason = NOT_COMMANDED
                a.cell = None  # treated as taken over: stop commanding it
                continue
            self._record(a, **detail)
            resend.append(a)
        if resend:
            alt = self.guard.setpoint_altitude()
            await asyncio.gather(
                *(
                    quietly(a.vehicle.goto(*self.grid.cell_to_latlon(*a.cell), alt))
                    for a in resend
                    if a.cell is not None
                )
            )

    def _record(self, a: Agent, **detail: object) -> None:
        self.rec.event("off_course", vehicle=a.name, sysid=a.spec.sysid, step=self.state.step, cell=a.cell, **detail)
