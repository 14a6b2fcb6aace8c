"""The search: lock-step decision rounds until the mission ends.

Each round, for the agents of this process that are searching:
1. merge what arrived on the knowledge channel, track the distance flown;
2. state updates: each agent's own transitions (link, pilot, battery: Agent.next_state), and an
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
from swarmctl.mission.agent import Agent, State
from swarmctl.mission.flight import fly_all, held, sense_and_share_all
from swarmctl.mission.launch import rejoin
from swarmctl.mission.watch import watch
from swarmctl.world.moves import MOVE_NAMES, MOVES

if TYPE_CHECKING:
    from swarmctl.mission.controller import Controller


async def search(c: Controller) -> None:
    """Decision rounds until the search ends; sets c.outcome."""
    timing = c.plan.spec.timing
    c.search_started = time.monotonic()
    while True:
        t0, cpu0, all0 = time.monotonic(), time.thread_time(), time.process_time()
        poll_all([a.exchange for a in c.agents])
        for a in c.agents:
            a.track()
        update_states(c)
        await watch(c)  # what was not commanded (swarmctl.mission.watch)
        outcome = ended(c)
        if outcome is not None:
            c.outcome = outcome
            return
        moved = await decision_round(c)
        c.round_times.append(time.monotonic() - t0)
        c.cpu_times.append(time.thread_time() - cpu0)
        c.process_cpu_times.append(time.process_time() - all0)
        if c.view is not None:
            c.view(c)
        # nobody moved (all staying or waiting): do not spin faster than 10 rounds a second
        wait = max(timing.step_period, 0.0 if moved else 0.1) - (time.monotonic() - t0)
        if wait > 0:
            await c.pause(wait)
        elif not any(a.live for a in c.agents):
            await asyncio.sleep(0.2)  # everyone is lost: wait for them without spinning


def ended(c: Controller) -> str | None:
    """The search's outcome if it is over, else None."""
    if c.stopping:
        return "interrupted"
    live = [a for a in c.agents if a.live]
    if not live and not any(a.state is State.LOST for a in c.agents):
        return "failed"
    if not c.finish.classic:  # the mission file's finish line (swarmctl.mission.finish)
        outcome = c.finish.check(c)
        if outcome is not None:
            return outcome
    elif live and all(a.state is State.HOVER for a in live) and others_hovering(c):
        cells = [a.cell for a in live]
        if len(set(cells)) == len(cells):
            # complete when every vehicle is hovering on a target; partial when some dropped out
            return "complete" if len(live) == len(c.agents) else "partial"
    assert c.search_started is not None  # the rounds run once the search has started
    if time.monotonic() - c.search_started > c.plan.spec.timing.time_limit:
        return "time limit"
    return None


def others_hovering(c: Controller) -> bool:
    """Onboard mode: every vehicle of the mission flown by another process is known (through the
    knowledge channel) to hover on a target of its own. Always true in ground mode."""
    mine = {a.cell for a in c.agents if a.state is State.HOVER}
    for v in range(len(c.plan.spec.vehicles)):
        if c.ours(v):
            continue
        known = [p for p in (a.knowledge.positions.get(v) for a in c.agents) if p is not None]
        if not known:
            return False
        newest = max(known, key=lambda p: p.order())
        if not newest.on_target or newest.cell in mine:
            return False
    return True


def update_states(c: Controller) -> None:
    """Each agent's own transitions, with their side effects, then the hover rule."""
    for a in c.agents:
        change = a.next_state(c.plan.spec.battery.return_below)
        if change is not None:
            state, extra = change
            if state is State.LOST and a.rejoin_task is not None:
                a.rejoin_task.cancel()
                a.rejoin_task = None
            c.enter(a, state, **extra)
            if state is State.REJOIN:
                a.rejoin_task = c.spawn(rejoin(c, a), f"rejoin {a.name}")
            elif state is State.OVERRIDE:
                a.cell = None  # the pilot took over: stop commanding it
            elif state is State.LOW_BATTERY:
                a.end_action = "rtl"
                c.spawn(c.quietly(a.vehicle.rtl()), f"rtl {a.name}")
                a.cell = None
            continue
        # on_find = "mark": a find is reported and searched past, never hovered on (swarmctl.mission.finish)
        if c.finish.marks:
            continue
        if (
            a.state is State.SEARCH
            and a.cell is not None
            and a.cell in a.knowledge.targets
            and c.policy.parks(len(a.knowledge.targets), len(c.plan.spec.vehicles))  # the hover rule
        ):
            hovering = {b.cell for b in c.agents if b is not a and b.state is State.HOVER}
            hovering |= {p.cell for v, p in a.knowledge.peers.items() if p.on_target and not c.ours(v)}
            if a.cell not in hovering:
                c.enter(a, State.HOVER)
                a.exchange.step(c.step, a.cell, True)  # tell the others this target is taken


async def decision_round(c: Controller) -> bool:
    """One decision round; True when some vehicle moved."""
    timing = c.plan.spec.timing
    searching = [a for a in c.agents if a.state is State.SEARCH]
    t = time.monotonic()
    n = len(c.plan.spec.vehicles)
    knowledges = [a.knowledge for a in searching]
    beliefs = c.policy.beliefs(knowledges, c.step, n, targets_done=c.finish.marks) if searching else None
    choices = c.policy.decide(beliefs) if beliefs is not None else []
    c.decide_times.append(time.monotonic() - t)
    proposed = {
        a.index: (a.here[0] + int(MOVES[ch.move][0]), a.here[1] + int(MOVES[ch.move][1]))
        for a, ch in zip(searching, choices)
    }
    # guard every vehicle this process knows of, in mission order; vehicles not searching stay
    order = [a for a in c.agents if a.cell is not None and a.state is not State.FAILED]
    current = [a.cell for a in order]
    wanted = [proposed.get(a.index, a.cell) for a in order]
    outside = sorted(held(c) - set(current))  # other processes' vehicles: they stay
    decisions = c.guard.guard_moves(
        np.array(current + outside, dtype=np.int64).reshape(-1, 2),
        np.array(wanted + outside, dtype=np.int64).reshape(-1, 2),
    )
    guarded = {a.index: d for a, d in zip(order, decisions)}
    c.step += 1
    if beliefs is not None:  # what --verify decides again: the beliefs, and the guard's other vehicles
        held_cells = [(a.index, a.here) for a in order if a.index not in proposed] + [(-1, x) for x in outside]
        c.rec.inputs(c.step, [a.name for a in searching], beliefs, held_cells)
    moves: list[tuple[Agent, tuple[int, int]]] = []
    records, refusals = [], []
    for a, ch in zip(searching, choices):
        d = guarded[a.index]
        if d.refused:
            a.refused += 1
            refused = dict(vehicle=a.name, step=c.step, cell=a.cell, proposed=proposed[a.index], reason=d.refused)
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
    c.rec.events_at_once(refusals)  # before the vehicles fly: one write for the step's refusals
    since = time.monotonic()
    reached = await fly_all(c, moves, timing.step_timeout)
    waited = time.monotonic() - since
    for (a, cell), ok in zip(moves, reached):
        if not ok:
            a.timeouts += 1
            c.rec.event("step_timeout", vehicle=a.name, step=c.step, cell=cell)
        a.cell = cell  # the cell is claimed either way; the vehicle keeps flying there
    moved = {a.index for a, _ in moves}
    live = [a for a in c.agents if a.state in (State.SEARCH, State.HOVER)]
    t = time.monotonic()
    await sense_and_share_all(c, live, moved, since)
    c.wait_times.append(waited + time.monotonic() - t)
    others = [
        dict(vehicle=a.name, sysid=a.spec.sysid, state=a.state, cell=a.cell, received=a.received_since())
        for a in c.agents
        if a not in searching
    ]
    c.rec.plain_event(
        "step", step=c.step, vehicles=records, others=others, decide_ms=round(c.decide_times[-1] * 1000, 3)
    )
    c.rec.knowledge(c.step, [(a.name, a.knowledge) for a in c.agents])
    return bool(moves)


def move_index(cur: tuple[int, int], new: tuple[int, int]) -> int:
    """The move (0..4) from `cur` to the neighbouring (or same) cell `new`."""
    d = (new[0] - cur[0], new[1] - cur[1])
    for i, m in enumerate(MOVES):
        if (int(m[0]), int(m[1])) == d:
            return i
    return 0
