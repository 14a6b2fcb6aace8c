"""The controller's safety guard: hand-built refusals and a property test with random policies."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.mission.guard import SafetyGuard
from swarmctl.world.moves import MOVES


def test_each_refusal_by_hand():
    blocked = np.zeros((5, 5), dtype=bool)
    blocked[2, 2] = True
    g = SafetyGuard(blocked, 40.0)
    assert g.check((0, 0), (-1, 0), set(), set()).refused == "outside the grid"
    assert g.check((2, 1), (2, 2), set(), set()).refused == "blocked cell"
    assert g.check((0, 0), (2, 0), set(), set()).refused == "more than one move"
    assert g.check((0, 0), (1, 0), {(1, 0)}, set()).refused == "held by another vehicle"
    assert g.check((0, 0), (1, 0), set(), {(1, 0)}).refused == "another vehicle is moving there"
    ok = g.check((0, 0), (1, 0), set(), set())
    assert ok.refused is None and ok.cell == (1, 0)
    assert g.setpoint_altitude() == 40.0


def test_two_vehicles_heading_for_one_cell_first_wins():
    g = SafetyGuard(np.zeros((5, 5), dtype=bool), 40.0)
    d = g.guard_moves(np.array([[1, 1], [3, 1]]), np.array([[2, 1], [2, 1]]))
    assert d[0].cell == (2, 1) and d[0].refused is None
    assert d[1].cell == (3, 1) and d[1].refused == "another vehicle is moving there"


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 12), st.integers(1, 12), st.integers(1, 8), st.booleans())
def test_random_policies_never_break_the_rules(seed, w, h, uavs, wild):
    rng = np.random.default_rng(seed)
    blocked = rng.random((w, h)) < 0.25
    free = np.argwhere(~blocked)
    if len(free) < uavs:
        return
    pos = free[rng.choice(len(free), uavs, replace=False)]
    g = SafetyGuard(blocked, 40.0)
    for _ in range(20):
        if wild:  # any cell at all, even far away or off the grid
            proposed = rng.integers(-2, max(w, h) + 2, size=(uavs, 2))
        else:  # the five grid moves
            proposed = pos + MOVES[rng.integers(0, 5, uavs)]
        new = np.array([d.cell for d in g.guard_moves(pos, proposed)])
        assert ((new >= 0) & (new < [w, h])).all()
        assert not blocked[new[:, 0], new[:, 1]].any()
        assert (np.abs(new - pos).sum(1) <= 1).all()
        assert len({tuple(c) for c in new}) == uavs  # no two vehicles end in one cell
        for u in range(uavs):  # nobody moves into a cell another vehicle held
            moved = tuple(new[u]) != tuple(pos[u])
            assert not (moved and any(tuple(new[u]) == tuple(pos[j]) for j in range(uavs) if j != u))
        pos = new
