"""One knowledge step and one poll for all agents of a stacked ideal bus (swarmctl.knowledge.stepping)
against the per-agent path (KnowledgeExchange.step and poll agent by agent): same frames on each link,
in the same order, same knowledge and bookkeeping, same counters, same bus deliveries."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from swarmctl.knowledge.bus import KnowledgeBus
from swarmctl.knowledge.exchange import KnowledgeExchange
from swarmctl.knowledge.model import disc_cells
from swarmctl.knowledge.stack import KnowledgeStack
from swarmctl.knowledge.stepping import batchable, poll_all, step_all
from swarmctl.mission.sensing import footprints, sense
from swarmctl.world.channel import Channel

W, H = 13, 9


def make(n: int, digest_every: int, channel: Channel | None = None):
    stack = KnowledgeStack(n, W, H)
    bus = KnowledgeBus(channel, seed=3, stack=stack)
    links: list[list[bytes]] = [[] for _ in range(n)]
    members = {v: v + 1 for v in range(n)}
    exchanges = [
        KnowledgeExchange(
            stack.knowledge(v),
            7,
            bus=bus,
            outlet=lambda f, link=links[v]: link.append(f) or True,
            digest_every=digest_every,
            members=members,
            fov=2.0,
        )
        for v in range(n)
    ]
    return bus, exchanges, links


def state(bus, exchanges, links):
    st_ = bus.stack
    arrays = {
        name: getattr(st_, name).copy()
        for name in ("explored", "phi_q", "obstacle", "position", "target_step", "pending", "learned_at", "noted")
    }
    return arrays, [ex.counters() for ex in exchanges], [list(link) for link in links], bus.counters()


rounds_strategy = st.lists(
    st.lists(
        st.tuples(
            st.integers(0, W - 1),
            st.integers(0, H - 1),
            st.booleans(),  # on target
            st.integers(0, 2),  # 0: nothing sensed, 1: the footprint, 2: random cells
            st.integers(0, 2**31),  # seed of the random cells, phi and obstacles
            st.booleans(),  # reports a target
        ),
        min_size=1,
        max_size=5,
    ),
    min_size=1,
    max_size=6,
)


def _sensed(cell, kind, seed):
    if kind == 0:
        return None
    rng = np.random.default_rng(seed)
    cells = disc_cells(cell, W, H, 2.0) if kind == 1 else rng.integers(0, (W, H), size=(int(rng.integers(0, 12)), 2))
    return cells, rng.random(len(cells)), rng.random(len(cells)) < 0.3


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rounds_strategy, st.integers(1, 4))
def test_a_batched_round_is_the_per_agent_round(rounds, digest_every):
    n = max(len(r) for r in rounds)
    ref, got = make(n, digest_every), make(n, digest_every)
    assert batchable(got[1])
    for step, plan in enumerate(rounds, start=1):
        live = list(range(len(plan)))
        args = [(p[0], p[1]) for p in plan], [p[2] for p in plan], [_sensed((p[0], p[1]), p[3], p[4]) for p in plan]

        def targets(bus_exchanges, i, step=step, plan=plan):
            if plan[i][5]:
                cell = (plan[i][0], plan[i][1])
                bus_exchanges[i].report_targets(np.array([cell]), step, seen_from=cell)

        for i in live:  # the reference: the per-agent path
            ex = ref[1][i]
            s = args[2][i]
            ex.step(step, args[0][i], args[1][i], *(s if s is not None else (None, None, None)))
            targets(ref[1], i)
        step_all([got[1][i] for i in live], step, *args, then=lambda i: targets(got[1], i))
        assert sum(ex.poll(0.0) for ex in ref[0].members) == poll_all(got[0].members)
        a, b = state(*ref), state(*got)
        for name in a[0]:
            assert np.array_equal(a[0][name], b[0][name]), name
        assert a[1:] == b[1:]


def test_a_lossy_bus_takes_the_per_agent_path():
    bus, exchanges, _links = make(3, 5, Channel("model", cell_size=10.0))
    assert not batchable(exchanges)
    step_all(exchanges, 1, [(0, 0), (1, 1), (2, 2)], [False] * 3, [None] * 3)
    assert [ex.stats["deltas"] for ex in exchanges] == [1, 1, 1]


def test_a_position_off_the_grid_is_refused():
    _bus, exchanges, _links = make(2, 5)
    with pytest.raises(ValueError, match="outside"):
        step_all(exchanges, 1, [(0, 0), (W, 0)], [False, False], [None, None])


class _Grid:
    def __init__(self, seed: int):
        self.width, self.height = W, H
        self.blocked = np.random.default_rng(seed).random((W, H)) < 0.3


@given(st.lists(st.tuples(st.integers(0, W - 1), st.integers(0, H - 1)), max_size=8), st.floats(0.5, 4.0))
def test_the_footprints_at_once_are_what_sense_gives_each(cells, fov):
    grid = _Grid(len(cells))
    for cell, got in zip(cells, footprints(grid, fov, cells), strict=True):
        want = sense(grid, fov, cell, [], {cell})
        for name in ("cells", "phi", "obstacle", "targets", "seen_from"):
            assert np.array_equal(getattr(want, name), getattr(got, name)), name
            assert getattr(want, name).dtype == getattr(got, name).dtype, name
        assert got.dropped == 0
