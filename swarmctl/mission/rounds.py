"""The search: lock-step decision rounds until the mission ends.

Each round, for the agents of this process that are searching:
1. merge what arrived on the knowledge channel, track the distance flown;
2. state updates: each agent's own transitions (link, pilot, battery: Agent.next_state; home on the
   energy its return takes, swarmctl.mission.energy; back with a fresh battery), and an
   agent on a known target cell that no other vehicle hovers over starts hovering there when the
   hover rule lets it park (FieldPolicy.parks: by default once the swarm knows as many targets as it
   has vehicles); then every
   commanded vehicle's position against its setpoint (off course: flagged, re-commanded, and taken
   over when it persists: swarmctl.mission.watch);
3. the policy chooses a move for every searching agent at once (one batch), and the recording keeps
   the beliefs it chose on (inputs.jsonl, for `swarmctl replay --verify`);
4. the safety guard checks the moves against the grid, the blocked cells and the cells every other
   vehicle holds or moves to (refused moves become "stay" and are logged);
5. each moving vehicle gets the position target for its cell centre at the mission altitude, and the
   round waits until they arrive or the step timeout passes;
6. each vehicle that arrived somewhere new senses (its detector's report for that cell) and every
   live agent shares (a delta of new cells and its position; digests and repairs).

The operator's orders from the live page (swarmctl.mission.web) are taken between rounds: a vehicle
sent home leaves the search; while the search is paused no round runs and no setpoint goes out (the
clock and the time limit pause too); a rejected find is no target for the policy or the hover rule,
and a vehicle hovering on it searches again.

The search ends when every live vehicle hovers on a distinct target ("complete", or "partial" when
some vehicles dropped out), or at the mission's own finish line (`[mission] finish`, expected_targets:
swarmctl.mission.finish), when the time limit passes ("time limit"), when no vehicle is left
("failed") or when the mission is stopped ("interrupted").
"""

from __future__ import annotations

import asyncio
import time
from typing import TYPE_CHECKING

import numpy as np

from swarmctl.knowledge.stepping import poll_all
from swarmctl.mission.agent import IN_TOUCH, Agent, State
from swarmctl.mission.decide import without_targets
from swarmctl.mission.state import quietly
from swarmctl.policy.hover import NO, OUT_OF_TOUCH_STEPS
from swarmctl.world.moves import MOVE_NAMES, MOVES

if TYPE_CHECKING:
    from collections.abc import Callable

    from swarmctl.mission.crew import Crew
    from swarmctl.mission.decide import FieldPolicy
    from swarmctl.mission.finish import FinishLine
    from swarmctl.mission.flight import Flight
    from swarmctl.mission.launch import Launch
    from swarmctl.mission.recorder import Recorder
    from swarmctl.mission.spec import BatteryTable, TimingTable
    from swarmctl.mission.state import MissionState
    from swarmctl.mission.watch import Watch
    from swarmctl.world.guard import SafetyGuard


HELD_POLL_S = 0.1  # while paused, the rounds look for a resume, a stop or a lost link this often


class Rounds:
    """The search's decision rounds for the crew: the `[timing]` and `[battery]` settings, the policy,
    the guard, the watch, how vehicles fly (Flight) and rejoin (Launch), the finish line, and `show`,
    called after each round for the live view."""

    def __init__(
        self,
        timing: TimingTable,
        battery: BatteryTable,
        policy: FieldPolicy,
        guard: SafetyGuard,
        rec: Recorder,
        state: MissionState,
        crew: Crew,
        watch: Watch,
        flight: Flight,
        launch: Launch,
        finish: FinishLine,
        show: Callable[[], None] | None = None,
    ):
        self.timing, self.battery, self.policy, self.guard = timing, battery, policy, guard
        self.rec, self.state, self.crew, self.watch = rec, state, crew, watch
        self.flight, self.launch, self.finish, self.show = flight, launch, finish, show

    async def search(self) -> None:
        """Decision rounds until the search ends; sets self.state.outcome."""
        timing = self.timing
        self.state.search_started = time.monotonic()
        while True:
            t0, cpu0, all0 = time.monotonic(), time.thread_time(), time.process_time()
            poll_all([a.exchange for a in self.crew.agents])
            for a in self.crew.agents:
                a.track()
            self.obey()
            self.update_states()
            self.state.holding = self.state.held
            if self.state.held:  # paused by the operator: no setpoint goes out, not even a re-command
                outcome = self.ended()
                if outcome is not None:
                    self.state.outcome = outcome
                    return
                if self.show is not None:
                    self.show()
                await self.state.pause(HELD_POLL_S)
                continue
            await self.watch.check()  # what was not commanded (swarmctl.mission.watch)
            outcome = self.ended()
            if outcome is not None:
                self.state.outcome = outcome
                return
            if self.state.held:  # paused while the watch looked: not one move more
                continue
            moved = await self.decision_round()
            self.state.times.round.append(time.monotonic() - t0)
            self.state.times.cpu.append(time.thread_time() - cpu0)
            self.state.times.process_cpu.append(time.process_time() - all0)
            if self.show is not None:
                self.show()
            # nobody moved (all staying or waiting): do not spin faster than 10 rounds a second
            wait = max(timing.step_period, 0.0 if moved else 0.1) - (time.monotonic() - t0)
            if wait > 0:
                await self.state.pause(wait)
            elif not any(a.live for a in self.crew.agents):
                await asyncio.sleep(0.2)  # everyone is lost: wait for them without spinning

    def ended(self) -> str | None:
        """The search's outcome if it is over, else None."""
        if self.state.stopping:
            return "interrupted"
        live = [a for a in self.crew.agents if a.live]
        # a lost vehicle may come back, and with `[battery] relaunch` one home on low battery too
        coming = (State.LOST, State.LOW_BATTERY) if self.battery.relaunch else (State.LOST,)
        if not live and not any(a.state in coming for a in self.crew.agents):
            return "failed"
        if not self.finish.classic:  # the mission file's finish line (swarmctl.mission.finish)
            outcome = self.finish.check()
            if outcome is not None:
                return outcome
        elif live and all(a.state is State.HOVER for a in live) and self.crew.others_hovering():
            cells = [a.cell for a in live]
            if len(set(cells)) == len(cells):
                # complete when every vehicle is hovering on a target; partial when some dropped out
                return "complete" if len(live) == len(self.crew.agents) else "partial"
        assert self.state.search_started is not None  # the rounds run once the search has started
        if self.state.search_seconds() > self.timing.time_limit:  # the operator's pauses left out
            return "time limit"
        return None

    def obey(self) -> None:
        """The operator's orders since the last round (MissionState.orders), taken between rounds so that
        no round sees an agent change under it: "home" sends a searching or hovering vehicle home (its
        search is over; its end action stays rtl)."""
        orders, self.state.orders = self.state.orders, []
        for action, name in orders:
            a = self.crew.named(name)
            if action != "home" or a is None or a.state not in (State.SEARCH, State.HOVER):
                continue
            a.sent_home, a.end_action = True, "rtl"
            self.crew.enter(a, State.ENDED, end_state="returning home (operator)")
            a.cell = None  # no longer commanded; the guard no longer keeps its cell
            self.state.spawn(quietly(a.vehicle.rtl()), f"rtl {a.name}")

    def update_states(self) -> None:
        """Each agent's own transitions, with their side effects, then the hover rule."""
        battery = self.battery
        relaunch_at = battery.takeoff_min if battery.relaunch else None
        for a in self.crew.agents:
            change = a.next_state(battery.return_below, reserve=battery.reserve, relaunch_at=relaunch_at)
            if change is not None:
                state, extra = change
                if state is State.LOST and a.rejoin_task is not None:
                    a.rejoin_task.cancel()
                    a.rejoin_task = None
                self.crew.enter(a, state, **extra)
                if state is State.REJOIN:
                    a.end_action = None  # back from low battery: its end action is the mission's again
                    a.rejoin_task = self.state.spawn(self.launch.rejoin(a), f"rejoin {a.name}")
                elif state is State.OVERRIDE:
                    a.cell = None  # the pilot took over: stop commanding it
                elif state is State.LOW_BATTERY:
                    a.end_action = "rtl"
                    self.state.spawn(quietly(a.vehicle.rtl()), f"rtl {a.name}")
                    a.cell = None
                continue
            rejected = self.state.rejected
            if a.state is State.HOVER and a.cell in rejected:  # the operator rejected the find it holds
                self.crew.enter(a, State.SEARCH)
                a.exchange.step(self.state.step, a.here, False)  # tell the others the cell is free again
                continue
            # on_find = "mark": a find is reported and searched past, never hovered on (swarmctl.mission.finish)
            if self.finish.marks:
                continue
            known = len(a.knowledge.targets) - (len(rejected & a.knowledge.targets.keys()) if rejected else 0)
            if (
                a.state is State.SEARCH
                and a.cell is not None
                and a.cell in a.knowledge.targets
                and a.cell not in rejected
                and self.policy.parks(known, self.crew.vehicles, self.out_of_touch(a))  # the hover rule
            ):
                hovering = {b.cell for b in self.crew.agents if b is not a and b.state is State.HOVER}
                hovering |= {p.cell for v, p in a.knowledge.peers.items() if p.on_target and not self.crew.ours(v)}
                if a.cell not in hovering:
                    self.crew.enter(a, State.HOVER)
                    a.exchange.step(self.state.step, a.cell, True)  # tell the others this target is taken
        if self.policy.hover == NO and self.finish.classic and not self.finish.marks:
            self.hold_once_all_on_targets()

    def in_touch(self) -> set[int]:
        """This process's vehicles on their way to the search or in it: heard on their own links, whatever
        their last knowledge report (one taking off has sent none)."""
        return {a.index for a in self.crew.agents if a.state in IN_TOUCH}

    def out_of_touch(self, a: Agent) -> int:
        """The teammates `a` has had no report from in the hover rule's last OUT_OF_TOUCH_STEPS rounds
        (as the policy's beliefs count them: swarmctl.policy.hover)."""
        return a.knowledge.out_of_touch(self.state.step, self.crew.vehicles, OUT_OF_TOUCH_STEPS, self.in_touch())

    def hold_once_all_on_targets(self) -> None:
        """Under the hover rule `no` nobody parks on the way: staying on a target is the policy's own
        choice, as for the networks trained under that rule. The search is held, as the simulator's
        `held` finish says, once every live vehicle sits on a known target of its own (and, onboard, every
        other process's vehicle is last known on one): then each holds its target (HOVER)."""
        live = [a for a in self.crew.agents if a.live]
        cells = [a.cell for a in live]
        if not live or any(a.state is State.REJOIN or a.cell is None for a in live) or len(set(cells)) < len(cells):
            return
        rejected = self.state.rejected
        if any(a.cell not in a.knowledge.targets or a.cell in rejected for a in live):
            return
        known = set().union(*(a.knowledge.targets.keys() for a in live))
        others = [p.cell if p is not None else None for p in self.crew.newest_of_others().values()]
        if any(c is None or c in cells or c not in known for c in others) or len(set(others)) < len(others):
            return
        for a in live:
            if a.state is State.SEARCH and a.cell is not None:
                self.crew.enter(a, State.HOVER)
                a.exchange.step(self.state.step, a.cell, True)  # tell the others this target is taken

    async def decision_round(self) -> bool:
        """One decision round; True when some vehicle moved."""
        timing = self.timing
        searching = [a for a in self.crew.agents if a.state is State.SEARCH]
        t = time.monotonic()
        n = self.crew.vehicles
        knowledges = [a.knowledge for a in searching]
        beliefs = (
            self.policy.beliefs(knowledges, self.state.step, n, self.finish.marks, self.in_touch())
            if searching
            else None
        )
        if beliefs is not None and self.state.rejected:  # the finds the operator rejected are no targets
            beliefs = without_targets(beliefs, self.state.rejected)
        choices = self.policy.decide(beliefs) if beliefs is not None else []
        self.state.times.decide.append(time.monotonic() - t)
        proposed = {
            a.index: (a.here[0] + int(MOVES[ch.move][0]), a.here[1] + int(MOVES[ch.move][1]))
            for a, ch in zip(searching, choices)
        }
        # guard every vehicle this process knows of, in mission order; vehicles not searching stay
        order = [a for a in self.crew.agents if a.cell is not None and a.state is not State.FAILED]
        current = [a.cell for a in order]
        wanted = [proposed.get(a.index, a.cell) for a in order]
        outside = sorted(self.crew.held() - set(current))  # other processes' vehicles: they stay
        decisions = self.guard.guard_moves(
            np.array(current + outside, dtype=np.int64).reshape(-1, 2),
            np.array(wanted + outside, dtype=np.int64).reshape(-1, 2),
        )
        guarded = {a.index: d for a, d in zip(order, decisions)}
        self.state.step += 1
        if beliefs is not None:  # what --verify decides again: the beliefs, and the guard's other vehicles
            held_cells = [(a.index, a.here) for a in order if a.index not in proposed] + [(-1, x) for x in outside]
            self.rec.inputs(self.state.step, [a.name for a in searching], beliefs, held_cells)
        moves: list[tuple[Agent, tuple[int, int]]] = []
        records, refusals = [], []
        for a, ch in zip(searching, choices):
            d = guarded[a.index]
            if d.refused:
                a.refused += 1
                refused = dict(
                    vehicle=a.name, step=self.state.step, cell=a.cell, proposed=proposed[a.index], reason=d.refused
                )
                refusals.append(("refused", refused))
            if d.cell != a.cell:
                moves.append((a, d.cell))
            a.steps += 1
            record = dict(
                vehicle=a.name,
                sysid=a.spec.sysid,
                cell=a.cell,
                obs=ch.obs_digest,
                q=ch.q,
                move=MOVE_NAMES[ch.move],
                guarded=MOVE_NAMES[move_index(a.here, d.cell)],
                refused=d.refused,
                received=a.received_since(),
            )
            if ch.by:  # the move came from a planner, not from the Q-values recorded
                record["by"] = ch.by
            records.append(record)
        self.rec.events_at_once(refusals)  # before the vehicles fly: one write for the step's refusals
        since = time.monotonic()
        reached = await self.flight.fly_all(moves, timing.step_timeout)
        waited = time.monotonic() - since
        for (a, cell), ok in zip(moves, reached):
            if not ok:
                a.timeouts += 1
                self.rec.event("step_timeout", vehicle=a.name, step=self.state.step, cell=cell)
            a.cell = cell  # the cell is claimed either way; the vehicle keeps flying there
        moved = {a.index for a, _ in moves}
        live = [a for a in self.crew.agents if a.state in (State.SEARCH, State.HOVER)]
        t = time.monotonic()
        await self.flight.sense_and_share_all(live, moved, since)
        self.state.times.wait.append(waited + time.monotonic() - t)
        others = [
            dict(vehicle=a.name, sysid=a.spec.sysid, state=a.state, cell=a.cell, received=a.received_since())
            for a in self.crew.agents
            if a not in searching
        ]
        self.rec.plain_event(
            "step",
            step=self.state.step,
            vehicles=records,
            others=others,
            decide_ms=round(self.state.times.decide[-1] * 1000, 3),
            pos=self.finish.recorded_pos(),  # the search's probability of success (swarmctl.mission.probability)
        )
        self.rec.knowledge(self.state.step, [(a.name, a.knowledge) for a in self.crew.agents])
        return bool(moves)


def move_index(cur: tuple[int, int], new: tuple[int, int]) -> int:
    """The move (0..4) from `cur` to the neighbouring (or same) cell `new`."""
    d = (new[0] - cur[0], new[1] - cur[1])
    for i, m in enumerate(MOVES):
        if (int(m[0]), int(m[1])) == d:
            return i
    return 0
