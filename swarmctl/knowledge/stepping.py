"""One decision step of many agents at once: the agents of a ground-mode process, whose knowledge are
rows of one stack on an ideal stacked bus (swarmctl.knowledge.bus, swarmctl.knowledge.stack).

    step_all(exchanges, step, cells, on_target, sensed)   # ex.step(step, cell, on, *sensed) for each, in order
    poll_all(exchanges)                                   # ex.poll(0.0) for each

KnowledgeExchange.step does, per agent: set the own position, sense the footprint's cells, note the
cells it has learnt (push rule), take the delta of the cells it sensed and publish it (and, on its
digest steps, the digest). The array work of all that touches only the agent's own row of the stack,
and publishing on an ideal stacked bus merges nothing before the next poll, so doing the array work of
every agent first, in a few operations over all rows, and then each agent's sends in the agents' order
gives the same knowledge, the same frames on each link in the same order, the same bus deliveries and
the same counters as calling `step` agent by agent (pinned by tests/test_knowledge_stepping.py). What
stays per agent is what must: encoding the delta, writing its frames on the agent's link and
publishing them on the bus (each message through the trust checks), the digests.

Polling: on such a bus the first poll of a round merges what every member was sent (the bus's batch)
and the others only take their counts; `poll_all` does that once for all instead of one call each.

A lossy bus draws each frame's loss from the receiver's position when the frame is published, so there
the order of the agents' position updates and sends matters: such exchanges (and UDP ones, and any
whose knowledge is not a row of its bus's stack) take the per-agent path, `KnowledgeExchange.step`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from swarmctl.knowledge.arrays import STEP_SHIFT
from swarmctl.knowledge.exchange import KnowledgeExchange
from swarmctl.knowledge.model import Delta, quantise_phi
from swarmctl.knowledge.stack import position_key, split_key

Sensed = tuple[np.ndarray, np.ndarray, np.ndarray] | None  # cells (N, 2), phi (N,), obstacle (N,); None: nothing


def batchable(exchanges: Sequence[KnowledgeExchange]) -> bool:
    """Whether the exchanges can be stepped at once: all on one ideal bus whose stack holds their
    knowledge (see the module docstring)."""
    if not exchanges:
        return False
    bus = exchanges[0].bus
    if bus is None or not bus.ideal or bus.stack is None or bus._batch is None or not bus._batch.stacked:
        return False
    return all(ex.bus is bus and ex.knowledge._stack is bus.stack for ex in exchanges)


def poll_all(exchanges: Sequence[KnowledgeExchange]) -> int:
    """`ex.poll(0.0)` for each exchange (what arrived merged, digests and requests answered); returns
    how many messages they handled in all."""
    if not batchable(exchanges):
        return sum(ex.poll(0.0) for ex in exchanges)
    bus = exchanges[0].bus
    assert bus is not None and bus._batch is not None  # batchable
    batch = bus._batch
    batch.flush()
    handled = 0
    for ex in exchanges:
        handled += ex.poll(0.0) if ex._inbox else batch.handled.pop(ex, 0)
    return handled


def step_all(
    exchanges: Sequence[KnowledgeExchange],
    step: int,
    cells: Sequence[tuple[int, int]],
    on_target: Sequence[bool],
    sensed: Sequence[Sensed],
    then: Callable[[int], None] | None = None,
) -> None:
    """`exchanges[i].step(step, cells[i], on_target[i], *sensed[i])` for each i in order, followed each
    time by `then(i)` (e.g. the agent's detections); batched when `batchable`, else one by one."""
    if not batchable(exchanges):
        for i, ex in enumerate(exchanges):
            s = sensed[i]
            c, p, o = s if s is not None else (None, None, None)
            ex.step(step, cells[i], on_target[i], c, p, o)
            if then is not None:
                then(i)
        return
    deltas = _step_arrays(exchanges, int(step), cells, on_target, sensed)
    for i, ex in enumerate(exchanges):
        ex._publish(step, deltas[i])
        if then is not None:
            then(i)


def _step_arrays(
    exchanges: Sequence[KnowledgeExchange],
    step: int,
    cells: Sequence[tuple[int, int]],
    on_target: Sequence[bool],
    sensed: Sequence[Sensed],
) -> list[Delta]:
    """Positions, sensing, the push rule's notes and the deltas of every exchange, on their stack."""
    stack = exchanges[0].knowledge._stack
    w, h = stack.width, stack.height
    rows = np.array([ex.knowledge._row for ex in exchanges], dtype=np.int64)
    vids = np.array([ex.vehicle_id for ex in exchanges], dtype=np.int64)
    xy = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
    if ((xy < 0) | (xy >= (w, h))).any():
        raise ValueError(f"cells outside the {w} x {h} grid")
    # the own positions (Knowledge.set_position: the same step or newer replaces the stored one)
    position_key(step, (0, 0), False)  # checks the step's range
    keys = (step << STEP_SHIFT) | (xy[:, 0] << 13) | (xy[:, 1] << 1) | np.asarray(on_target, dtype=np.int64)
    old = stack.position[rows, vids]
    newer = (old < 0) | (step >= old >> STEP_SHIFT)
    stack.position[rows[newer], vids[newer]] = keys[newer]
    # what each senses (Knowledge.sense), all rows in one go
    parts = [(i, s) for i, s in enumerate(sensed) if s is not None and len(s[0])]
    if parts:
        c = np.concatenate([np.asarray(s[0], dtype=np.int64).reshape(-1, 2) for _, s in parts])
        if ((c < 0) | (c >= (w, h))).any():
            raise ValueError(f"cells outside the {w} x {h} grid")
        r = np.repeat(rows[[i for i, _ in parts]], [len(s[0]) for _, s in parts])
        q = quantise_phi(np.concatenate([np.asarray(s[1], dtype=np.float64).reshape(-1) for _, s in parts]))
        obs = np.concatenate([np.asarray(s[2], dtype=bool).reshape(-1) for _, s in parts])
        x, y = c[:, 0], c[:, 1]
        new = ~stack.explored[r, x, y]
        stack.explored[r, x, y] = True
        np.maximum.at(stack.phi_q, (r, x, y), q)
        np.logical_or.at(stack.obstacle, (r, x, y), obs)
        stack.pending[r[new], x[new], y[new]] = True
    # the push rule's notes (KnowledgeExchange._note_learned)
    whole = len(rows) == stack.rows and bool((rows == np.arange(stack.rows)).all())  # views, not copies
    at = slice(None) if whole else rows
    k, x, y = _nonzero(stack.explored[at] > stack.noted[at])
    stack.learned_at[rows[k], x, y] = step
    stack.noted[rows[k], x, y] = True
    # the deltas (Knowledge.take_delta): each row's pending cells in x, y order, with its position
    k, x, y = _nonzero(stack.pending[at])
    stack.pending[at] = False
    kr = rows[k]
    found = np.stack([x, y], axis=1)
    phi, obstacle = stack.phi_q[kr, x, y], stack.obstacle[kr, x, y]
    bounds = np.searchsorted(k, np.arange(len(rows) + 1)).tolist()
    own = stack.position[rows, vids].tolist()
    deltas = []
    for i, ex in enumerate(exchanges):
        pos: tuple[int, tuple[int, int] | None, bool] = split_key(own[i]) if own[i] >= 0 else (0, None, False)
        a, b = bounds[i], bounds[i + 1]
        deltas.append(Delta(ex.vehicle_id, *pos, found[a:b], phi[a:b], obstacle[a:b]))
    return deltas


def _nonzero(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """np.nonzero of a 3-d mask, in the same order, through flatnonzero (several times faster)."""
    _, w, h = mask.shape
    k, rest = np.divmod(np.flatnonzero(mask), w * h)
    x, y = np.divmod(rest, h)
    return k, x, y
