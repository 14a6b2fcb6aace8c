"""The finish line: when a search is complete, as the mission file's `[mission]` finish,
expected_targets and on_find say (docs/mission.md, "The finish line"), and the finds on the way.

- `held` (the default): complete when N distinct targets are held (hovered on) by live vehicles; N
  left out is the vehicle count, the paper's criterion, decided exactly as before this module
  (swarmctl.mission.rounds.Rounds.ended: "complete", or "partial" when vehicles dropped out).
- `found`: complete when N targets are found: known to the swarm, in the union of the agents'
  knowledge of target cells. N left out (unknown): complete when the area is covered.
- `pos >= X`: complete when the search's probability of success (POS, swarmctl.mission.probability:
  against the mission's prior, uniform without one, with `[sensing] pod`) reaches X.
- `covered`: complete when every reachable cell is explored in the union of the agents' knowledge.
  Reachable: the free cells of the grid (not blocked: what the safety guard lets a vehicle enter)
  4-connected to a cell a vehicle of the mission held (its launch cell, and any cell it flew to or
  rejoined at): the region the swarm can fly over.

With `confirm_finds = true` held and found count only the finds the operator confirmed on the live
page (MissionState.confirmed), and a search that would end partial waits while a find it holds or
knows has no word yet; a rejected find (MissionState.rejected) is no target for the line either way.

A find is the first time a target cell enters the swarm's knowledge: a `find` event (the vehicle, the
cell, its lat/lon, the seconds since the search started and the step), and the summary's `finds`. With
`on_find = "mark"` the finding vehicle does not hover on it (Rounds.update_states), the policy treats
known targets as done (swarmctl.mission.decide), and the find is reported to the ground station as a
STATUSTEXT (MAV_SEVERITY_NOTICE) from the vehicle's system id and the agent's component (191, as its
knowledge frames): written on the vehicle's own link (a ground station behind its routing sees it, the
tlog keeps it) and to the mission's `gcs` when it has one.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.knowledge.model import stacked_field
from swarmctl.knowledge.stack import NEVER
from swarmctl.mission.agent import State
from swarmctl.mission.probability import POS_DECIMALS, SearchProbability
from swarmctl.mission.spec import pos_goal

if TYPE_CHECKING:
    from swarmctl.mavlink.gcs import GcsForwarder
    from swarmctl.mission.agent import Agent
    from swarmctl.mission.crew import Crew
    from swarmctl.mission.plan import MissionPlan
    from swarmctl.mission.recorder import Recorder
    from swarmctl.mission.spec import MissionSpec
    from swarmctl.mission.state import MissionState

log = logging.getLogger(__name__)

STATUSTEXT_CHARS = 50  # MAVLink's STATUSTEXT text field
NOTICE = mavlink2.MAV_SEVERITY_NOTICE


@dataclass
class Find:
    """A target cell's first entry into the swarm's knowledge."""

    cell: tuple[int, int]
    lat: float
    lon: float
    step: int  # the decision round it was found in (0: during the launch, before the first)
    time_s: float  # seconds since the search started (0.0: during the launch)
    vehicle: str | None  # the vehicle whose detector saw it; None: learnt from another process's vehicle

    def record(self) -> dict:
        return dict(
            cell=list(self.cell),
            lat=self.lat,
            lon=self.lon,
            vehicle=self.vehicle,
            step=self.step,
            time_s=round(self.time_s, 2),
        )


def find_text(lat: float, lon: float, name: str) -> str:
    """The STATUSTEXT of a find, at most STATUSTEXT_CHARS: "swarmctl: target found at LAT,LON by NAME"
    (5 decimals, about a metre), shortened as the name asks: "swarmctl: target at ...", "target at ...",
    then the name cut."""
    at = f"{lat:.5f},{lon:.5f}"
    for head in ("swarmctl: target found at ", "swarmctl: target at ", "target at "):
        text = f"{head}{at} by {name}"
        if len(text) <= STATUSTEXT_CHARS:
            return text
    return text[:STATUSTEXT_CHARS]


def describe(spec: MissionSpec) -> str:
    """The finish line in a line, for the plan's description."""
    m = spec.mission
    n = m.expected_targets
    if m.finish == "held":
        count = n if n is not None else len(spec.vehicles)
        what = f"complete when {count} distinct target{'s are' if count != 1 else ' is'} hovered on by live vehicles"
    elif m.finish == "found" and n is not None:
        what = f"complete when {n} target{'s are' if n != 1 else ' is'} found"
    elif (goal := pos_goal(m.finish)) is not None:
        source = "a uniform prior" if m.prior is None else f"the prior {m.prior.name}"
        what = f"complete when the probability of success reaches {goal:g} ({source}, pod {spec.sensing.pod:g})"
    else:
        what = "complete when every cell the vehicles can reach is explored"
        if m.finish == "found":
            what += " (the number of targets is unknown)"
    if m.on_find == "mark":
        then = "a vehicle that finds a target reports it (event, STATUSTEXT) and searches on"
    else:
        then = "a vehicle hovers on the first target it finds that nobody holds"
    if m.confirm_finds and m.finish != "covered":
        what += " (counting the finds an operator confirms on the live page, --web)"
    return f"finish {m.finish}: {what}; {then}"


class FinishLine:
    """The mission's finish rule, the finds and the coverage of the crew's knowledge; finds are recorded
    (`rec`) and, with on_find = "mark", announced on the finding vehicle's link and to the `gcs`."""

    def __init__(
        self,
        plan: MissionPlan,
        crew: Crew,
        state: MissionState,
        rec: Recorder,
        gcs: GcsForwarder | None = None,
    ):
        m = plan.spec.mission
        self.goal: float | None = pos_goal(m.finish)  # finish = "pos >= X": X
        self.rule: str = "pos" if self.goal is not None else m.finish
        # POS against the plan's prior (uniform without one) with the detector's pod, whatever the rule
        source = m.prior.name if m.prior is not None else "uniform"
        self.probability = SearchProbability(plan.prior, ~plan.grid.blocked, plan.spec.sensing.pod, plan.fov, source)
        self.on_find: str = m.on_find
        self.confirm: bool = m.confirm_finds  # held and found count the finds the operator confirmed
        self.given: int | None = m.expected_targets
        self.vehicles = vehicles = len(plan.spec.vehicles)
        # N: for held, the vehicle count when left out; for found and covered, None when left out (unknown)
        self.expected: int | None = self.given if self.given is not None or self.rule != "held" else vehicles
        self.grid = plan.grid
        self._regions, _ = plan.grid.free_regions()  # 4-connected free regions, labelled 1.. (0: blocked)
        self.reachable = np.zeros(self._regions.shape, dtype=bool)
        self._seeds: set[tuple[int, int]] = set()
        self.finds: dict[tuple[int, int], Find] = {}
        self.met: bool | None = None  # whether the finish line was met when the search ended (None: running)
        self.crew, self.state, self.rec, self.gcs = crew, state, rec, gcs

    # --- what the rule needs ----------------------------------------------------------------------------
    @property
    def to_hold(self) -> int | None:
        """Targets to hold when fewer than the vehicles (held, or hover on finds, with expected_targets
        below the vehicle count); None: one a vehicle."""
        if self.marks or self.given is None or self.given >= self.vehicles:
            return None
        return self.given

    @property
    def marks(self) -> bool:
        """on_find = "mark": finds are reported and searched past, never hovered on."""
        return self.on_find == "mark"

    @property
    def classic(self) -> bool:
        """The default (held, N left out): the paper's rule, decided in Rounds.ended as it always was."""
        return self.rule == "held" and self.given is None and not self.confirm

    def awaiting(self, cells: set[tuple[int, int]]) -> bool:
        """With confirm_finds: some of these target cells still wait for the operator's word."""
        return self.confirm and not cells <= self.state.confirmed | self.state.rejected

    def counted(self, cells: set[tuple[int, int]] | list[tuple[int, int]]) -> int:
        """How many of these target cells the line counts: all, or with confirm_finds those confirmed."""
        return len(set(cells) & self.state.confirmed) if self.confirm else len(set(cells))

    # --- the swarm's knowledge --------------------------------------------------------------------------
    def hold_cells(self) -> None:
        """Note the cells the vehicles hold now (this process's, and other processes' as known): the
        reachable region grows by the free region of any cell not in it yet."""
        cells = {a.cell for a in self.crew.agents if a.cell is not None}
        if self.crew.onboard:
            for a in self.crew.agents:
                cells.update(
                    p.cell for v, p in a.knowledge.peers.items() if not self.crew.ours(v) and p.cell is not None
                )
        new = [x for x in cells - self._seeds if self.grid.in_grid(*x)]
        if not new:
            return
        self._seeds.update(new)
        regions = {int(self._regions[x]) for x in new if not self.reachable[x]} - {0}
        if regions:
            self.reachable |= np.isin(self._regions, sorted(regions))

    def explored(self) -> np.ndarray:
        """(W, H) bool: the cells explored in the union of the agents' knowledge."""
        if not self.crew.agents:
            return np.zeros(self._regions.shape, dtype=bool)
        return np.logical_or.reduce(stacked_field([a.knowledge for a in self.crew.agents], "explored"), axis=0)

    def known_targets(self) -> list[tuple[int, int]]:
        """The target cells in the union of the agents' knowledge (sorted)."""
        if not self.crew.agents:
            return []
        known = np.logical_and.reduce(
            stacked_field([a.knowledge for a in self.crew.agents], "target_step") == NEVER, axis=0
        )
        cells = [(int(x), int(y)) for x, y in np.argwhere(~known)]
        rejected = self.state.rejected  # the finds the operator rejected (MissionState.judge)
        return [c for c in cells if c not in rejected] if rejected else cells

    def coverage(self) -> tuple[int, int]:
        """(reachable cells explored, reachable cells)."""
        self.hold_cells()
        total = int(np.count_nonzero(self.reachable))
        return int(np.count_nonzero(self.explored() & self.reachable)), total

    def pos(self) -> float:
        """The search's probability of success now (onboard, with the cells the agents know other processes'
        vehicles explored counted as one pass)."""
        if self.crew.onboard:
            self.probability.note_explored(self.explored())
        return self.probability.pos()

    def standing(self) -> str:
        """How the search stands, in a line: POS (and its goal), the probability left, the coverage."""
        pos = self.pos()
        goal = f" (goal {self.goal:g})" if self.goal is not None else ""
        return f"POS {pos:.3f}{goal}  probability left {1.0 - pos:.3f}  coverage {100 * self.covered_fraction():.1f} %"

    def recorded_pos(self) -> float:
        """POS as the step records and the summary keep it (4 decimals)."""
        return round(self.pos(), POS_DECIMALS)

    def covered_fraction(self) -> float:
        done, total = self.coverage()
        return round(done / total, 4) if total else 0.0

    # --- finds ------------------------------------------------------------------------------------------
    def found(self, a: Agent | None, cells: list[tuple[int, int]]) -> None:
        """Target cells the agent's detector reported (those it did not know yet), or (a None) that the
        swarm learnt from another process: the ones new to the swarm become finds, recorded and, with
        on_find = "mark" and a finding vehicle of this process, reported to the ground station."""
        for cell in cells:
            cell = (int(cell[0]), int(cell[1]))
            if cell in self.finds:
                continue
            lat, lon = self.grid.cell_to_latlon(*cell)
            since = self.state.search_seconds()
            find = Find(cell, lat, lon, self.state.step, since, a.name if a is not None else None)
            self.finds[cell] = find
            self.rec.event("find", **find.record())
            if a is not None and self.marks:
                announce(a, find_text(lat, lon, a.name), self.gcs)

    def sweep(self) -> None:
        """Targets the agents know that are no find yet (learnt over the knowledge channel from another
        process's vehicle, whose own process reports it): recorded as finds without a vehicle."""
        missing = [t for t in self.known_targets() if t not in self.finds]
        if missing:
            self.found(None, missing)

    # --- the rule ---------------------------------------------------------------------------------------
    def check(self) -> str | None:
        """The outcome when the rule (other than the classic one) ends the search now: "complete" when
        its line is met, "partial" when the search cannot go on (no live vehicle searches: they all hold
        targets; or, for found with N, the area covered with fewer found); None: carry on."""
        if self.crew.onboard:
            self.sweep()
        if self.is_met():
            return "complete"
        live = [a for a in self.crew.agents if a.live]
        if live and all(a.state is State.HOVER for a in live) and self.crew.others_hovering():
            if self.awaiting(self.crew.held_targets()):
                return None  # the operator has yet to confirm or reject what they hold
            return "partial"  # everyone parked on a target: nobody left to search
        if self.rule == "found" and self.expected is not None:
            done, total = self.coverage()
            if total and done == total and not self.awaiting(set(self.known_targets())):
                return "partial"  # nothing left to find, fewer than expected found
        return None

    def is_met(self) -> bool:
        """Whether the finish line holds now (held with N given, found, covered; the classic rule is
        Rounds.ended's)."""
        if self.rule == "held":
            return self.counted(self.crew.held_targets()) >= (self.expected or 0)
        if self.goal is not None:
            return self.pos() >= self.goal
        if self.rule == "found" and self.expected is not None:
            return self.counted(self.known_targets()) >= self.expected
        done, total = self.coverage()
        return total > 0 and done == total

    def summary(self, outcome: str | None, targets_found: list[dict]) -> dict:
        """What summary.json adds: the rule and whether it was met, the finds in order, the coverage;
        each entry of `targets_found` gains the time and the vehicle of its find."""
        if self.crew.onboard or len(self.finds) < len(self.known_targets()):
            self.sweep()
        for t in targets_found:
            f = self.finds.get(tuple(t["cell"]))
            t["time_s"] = None if f is None else round(f.time_s, 2)
            t["vehicle"] = None if f is None else f.vehicle
        met = self.met
        if met is None:  # still running: as it stands now
            met = outcome == "complete" if self.classic else self.is_met()
        out = dict(
            finish=dict(rule=self.rule, expected_targets=self.expected, on_find=self.on_find, met=bool(met)),
            finds=[f.record() for f in sorted(self.finds.values(), key=lambda f: (f.time_s, f.step, f.cell))],
            covered_fraction=self.covered_fraction(),
            pos=self.recorded_pos(),
            passes=self.probability.team_passes().tolist(),
        )
        if self.goal is not None:
            out["pos_goal"] = self.goal
        return out

    def close(self, outcome: str | None) -> None:
        """At the end of the search (before the end actions): whether the line was met then."""
        self.met = outcome == "complete" if self.classic else self.is_met()


def announce(a: Agent, text: str, gcs: GcsForwarder | None) -> bool:
    """A STATUSTEXT (NOTICE) from the vehicle's agent: on its own link (ArduPilot; MAVSDK's link carries
    no STATUSTEXT from us) and to the mission's ground station; True when it went out somewhere."""
    try:
        frame = a.exchange.codec.statustext(NOTICE, text)
    except Exception as exc:  # a report must never stop the search
        log.warning("%s: the STATUSTEXT of a find could not be made: %s", a.name, exc)
        return False
    sent = False
    write = getattr(a.vehicle, "write_frame", None)
    if write is not None:
        try:
            sent = bool(write(frame))
        except Exception as exc:
            log.warning("%s: the STATUSTEXT of a find could not be sent on its link: %s", a.name, exc)
    if gcs is not None:
        try:
            gcs.sock.sendto(frame, gcs.address)
            sent = True
        except OSError as exc:
            log.warning("the STATUSTEXT of a find could not be sent to the ground station: %s", exc)
    return sent
