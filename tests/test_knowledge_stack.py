"""Stacked knowledge (ground mode): every agent's Knowledge a row of one KnowledgeStack, the ideal bus
merging each round's deliveries into all of them at once. The result must be exactly the per-agent
path's (each message merged into each receiver, one by one), which onboard agents keep."""

from __future__ import annotations

import contextlib
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.knowledge.bus import KnowledgeBus
from swarmctl.knowledge.exchange import KnowledgeExchange
from swarmctl.knowledge.model import Delta, Detection, Knowledge, Position, beliefs_from_knowledge
from swarmctl.knowledge.stack import KnowledgeStack
from swarmctl.mission.sensing import footprint, in_footprint
from swarmctl.world.beliefs import ObservationSettings
from swarmctl.world.channel import Channel
from tests.knowledge_helpers import Walkers

SIZE = 20


@contextlib.contextmanager
def agents_on_bus(n: int, stacked: bool, channel: Channel | None = None, seed: int = 0):
    stack = KnowledgeStack(n, SIZE, SIZE) if stacked else None
    bus = KnowledgeBus(channel, seed=seed, stack=stack)
    agents = [
        KnowledgeExchange(
            stack.knowledge(v) if stacked else Knowledge(SIZE, SIZE, v), 7, bus=bus, outlet=lambda f: True
        )
        for v in range(n)
    ]
    try:
        yield bus, agents
    finally:
        for a in agents:
            a.close()


def fly(n: int, stacked: bool, channel: Channel | None, seed: int, rounds: int = 16) -> list:
    """A lock-step search on the bus; per round what every agent polled, knows and counted."""
    walkers = Walkers(n, SIZE, seed=seed)
    rng = np.random.default_rng(seed)
    trace = []
    with agents_on_bus(n, stacked, channel, seed) as (bus, agents):
        for step in range(1, rounds + 1):
            walkers.move()
            for i, a in enumerate(agents):
                cells, phi, obs = walkers.sense(i)
                found = np.array([walkers.cells[i]]) if rng.random() < 0.1 else None
                a.step(step, walkers.cells[i], bool(rng.random() < 0.2), cells, phi, obs, targets=found)
                if rng.random() < 0.1:  # a second report in the same step (the hover rule does this)
                    a.step(step, walkers.cells[i], True)
            polled = [a.poll(0.0) for a in agents]
            trace.append((polled, [a.knowledge.copy() for a in agents], [a.counters() for a in agents], bus.counters()))
    return trace


@pytest.mark.parametrize("channel", [None, Channel("fixed", loss=0.3)], ids=["ideal", "lossy"])
@pytest.mark.parametrize("seed", range(2))
def test_a_stacked_bus_gives_every_agent_exactly_the_per_agent_knowledge_and_counters(channel, seed):
    reference = fly(6, False, channel, seed)
    stacked = fly(6, True, channel, seed)
    for step, (ref, got) in enumerate(zip(reference, stacked), start=1):
        assert got[0] == ref[0], f"step {step}: messages polled"
        for i, (k_ref, k_got) in enumerate(zip(ref[1], got[1])):
            assert k_got == k_ref, f"step {step}, agent {i}: {k_got!r} != {k_ref!r}"
        assert got[2] == ref[2] and got[3] == ref[3], f"step {step}: counters"
    assert reference[-1][3]["delivered"] > 0


cells = st.lists(st.tuples(st.integers(0, 7), st.integers(0, 5)), min_size=0, max_size=12, unique=True)
message = st.tuples(
    st.booleans(),  # a delta (else a detection)
    st.integers(0, 4),  # sender
    st.integers(0, 30),  # step
    st.one_of(st.none(), st.tuples(st.integers(0, 7), st.integers(0, 5))),
    st.booleans(),
    cells,
    st.integers(0, 2**31),
)


def build(spec) -> Delta | Detection:
    is_delta, sender, step, cell, on_target, where, seed = spec
    rng = np.random.default_rng(seed)
    where = np.array(where or [(0, 0)], dtype=np.int64).reshape(-1, 2)
    if is_delta:
        phi = rng.integers(0, 256, len(where)).astype(np.uint8)
        return Delta(sender, step, cell, on_target, where, phi, rng.random(len(where)) < 0.3)
    return Detection(sender, step, cell, on_target, where)


@settings(max_examples=60, deadline=None)
@given(st.lists(message, min_size=1, max_size=10), st.integers(0, 2**31))
def test_a_batch_merge_is_each_message_merged_into_each_receiver(specs, seed):
    rows = 4
    messages = [build(s) for s in specs]
    receivers = np.random.default_rng(seed).random((len(messages), rows)) < 0.7
    stack = KnowledgeStack(rows, 8, 6)
    views = [stack.knowledge(r) for r in range(rows)]
    alone = [Knowledge(8, 6, r) for r in range(rows)]
    for r in range(rows):  # some prior knowledge, own position included
        views[r].set_position(3, (r, r))
        alone[r].set_position(3, (r, r))
        views[r].add_targets([(r, 0)], 9)
        alone[r].add_targets([(r, 0)], 9)
    stack.merge_batch(messages, receivers)
    for m, got in zip(messages, receivers):
        for r in np.flatnonzero(got):
            alone[r].merge(m)
    for r in range(rows):
        assert views[r] == alone[r] and views[r].known_targets().tolist() == alone[r].known_targets().tolist()


def test_positions_and_targets_read_and_write_like_the_dicts_they_were():
    k = Knowledge(10, 10, 2)
    assert dict(k.positions) == {} and k.own_position is None and len(k.targets) == 0
    k.set_position(4, (3, 5), True)
    k.merge(Delta(7, 6, (9, 9), False))
    k.merge(Delta(7, 5, (1, 1), True))  # older: ignored
    assert dict(k.positions) == {2: Position(4, (3, 5), True), 7: Position(6, (9, 9), False)}
    assert k.peers == {7: Position(6, (9, 9), False)} and 7 in k.positions and 3 not in k.positions
    k.add_targets([(1, 2), (4, 4)], 8)
    k.add_targets([(1, 2)], 3)
    assert dict(k.targets) == {(1, 2): 3, (4, 4): 8} and (4, 4) in k.targets and (5, 5) not in k.targets
    assert (11, 0) not in k.targets and "x" not in k.targets
    copy = k.copy()
    copy.add_targets([(0, 0)], 1)
    assert (0, 0) not in k.targets and copy.positions == k.positions
    with pytest.raises(ValueError, match="outside"):
        k.merge_position(300, Position(1, (0, 0)))


def test_beliefs_from_one_stack_equal_beliefs_from_separate_knowledge():
    n = 5
    with agents_on_bus(n, True) as (bus, agents):
        walkers = Walkers(n, SIZE, seed=3)
        for step in range(1, 8):
            walkers.move()
            walkers.step_all(agents, step)
            if step == 3:
                agents[1].report_targets(np.array([walkers.cells[1]]), step)
            bus.settle()
        stacked = [a.knowledge for a in agents]
        alone = [k.copy() for k in stacked]
        s = ObservationSettings(phi_tolerance=0.01)
        a = beliefs_from_knowledge(stacked, n, s, 7, [False, True, False, False, False])
        b = beliefs_from_knowledge(alone, n, s, 7, [False, True, False, False, False])
        for name in ("explored", "phi_hat", "obstacles", "targets", "positions", "hovering", "me"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert a.targets.any() and (a.positions >= 0).all()


@settings(max_examples=80, deadline=None)
@given(
    st.tuples(st.integers(0, 9), st.integers(0, 6)),
    st.lists(st.tuples(st.integers(-3, 12), st.integers(-3, 9)), max_size=30),
    st.sampled_from([1.0, 1.5, 2.0, 3.0, 3.2]),
)
def test_the_footprint_test_agrees_with_the_footprint_cells(cell, cells, fov):
    grid = SimpleNamespace(width=10, height=7)
    cells = np.array(cells, dtype=np.int64).reshape(-1, 2)
    disc = {tuple(c) for c in footprint(cell, grid, fov).tolist()}
    assert in_footprint(cells, cell, grid, fov).tolist() == [tuple(c) in disc for c in cells.tolist()]
