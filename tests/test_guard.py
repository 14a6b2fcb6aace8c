"""The safety guard: one implementation (swarmctl.world.guard) for the simulator's --guard and the
controller; hand-built refusals, the contested-cell rule on both paths, and property tests."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.world.guard import ACCEPTED, BLOCKED, CONTESTED, HELD, OUTSIDE, TOO_FAR, SafetyGuard, guard_moves
from swarmctl.world.moves import EAST, MOVES, STAY, WEST
from tests.helpers import make_env


def test_each_refusal_by_hand():
    blocked = np.zeros((5, 5), dtype=bool)
    blocked[2, 2] = True
    pos = np.array([[[0, 0], [2, 1], [0, 4], [4, 3], [3, 3]]])
    proposed = np.array([[[-1, 0], [2, 2], [2, 4], [3, 3], [3, 3]]])  # off, building, two cells, held, stay
    dest, refused = guard_moves(pos, proposed, blocked)
    assert refused[0].tolist() == [OUTSIDE, BLOCKED, TOO_FAR, HELD, ACCEPTED]
    assert (dest == pos).all()
    g = SafetyGuard(blocked, 40.0)
    reasons = [d.refused for d in g.guard_moves(pos[0], proposed[0])]
    assert reasons == ["outside the grid", "blocked cell", "more than one move", "held by another vehicle", None]
    assert g.setpoint_altitude() == 40.0


def test_a_contested_cell_goes_to_the_lower_index_in_the_controller_and_in_the_simulator():
    # (1, 1) and (3, 1) both move to (2, 1): vehicle 0 goes, vehicle 1 stays
    g = SafetyGuard(np.zeros((5, 5), dtype=bool), 40.0)
    d = g.guard_moves(np.array([[1, 1], [3, 1]]), np.array([[2, 1], [2, 1]]))
    assert d[0].cell == (2, 1) and d[0].refused is None
    assert d[1].cell == (3, 1) and d[1].refused == "another vehicle is moving there"
    env = make_env(5, targets=[(0, 4), (4, 4)], starts=[(1, 1), (3, 1)], guard=True, stop_at_success=False)
    _, _, _, info = env.step(np.array([[EAST, WEST]]))
    assert env.pos[0].tolist() == [[2, 1], [3, 1]]
    assert info.refused[0].tolist() == [False, True] and not info.collided.any()
    # the lower index wins even when it comes second in the proposals' order of arrival: swap roles
    env = make_env(5, targets=[(0, 4), (4, 4)], starts=[(3, 1), (1, 1)], guard=True, stop_at_success=False)
    env.step(np.array([[WEST, EAST]]))
    assert env.pos[0].tolist() == [[2, 1], [1, 1]]


def test_a_lower_index_refused_for_another_reason_leaves_the_cell_to_the_next():
    blocked = np.zeros((5, 5), dtype=bool)
    pos = np.array([[[0, 1], [3, 1]]])
    dest, refused = guard_moves(pos, np.array([[[2, 1], [2, 1]]]), blocked)  # vehicle 0 jumps two cells
    assert refused[0].tolist() == [TOO_FAR, ACCEPTED] and dest[0, 1].tolist() == [2, 1]
    dest, refused = guard_moves(np.array([[[2, 2], [1, 1], [3, 1]]]), np.array([[[2, 2], [2, 1], [2, 1]]]), blocked)
    assert refused[0].tolist() == [ACCEPTED, ACCEPTED, CONTESTED]


@settings(max_examples=300, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.integers(1, 12),
    st.integers(1, 12),
    st.integers(1, 8),
    st.booleans(),
    st.integers(1, 3),
)
def test_random_policies_never_break_the_rules(seed, w, h, uavs, wild, batch):
    rng = np.random.default_rng(seed)
    blocked = rng.random((batch, w, h)) < 0.25
    pos = []
    for b in range(batch):
        free = np.argwhere(~blocked[b])
        if len(free) < uavs:
            return
        pos.append(free[rng.choice(len(free), uavs, replace=False)])
    pos = np.stack(pos)
    for _ in range(20):
        if wild:  # any cell at all, even far away or off the grid
            proposed = rng.integers(-2, max(w, h) + 2, size=(batch, uavs, 2))
        else:  # the five grid moves
            proposed = pos + MOVES[rng.integers(0, 5, (batch, uavs))]
        new, refused = guard_moves(pos, proposed, blocked)
        assert ((new >= 0) & (new < [w, h])).all()
        bi = np.arange(batch)[:, None]
        assert not blocked[bi, new[..., 0], new[..., 1]].any()
        assert (np.abs(new - pos).sum(-1) <= 1).all()
        assert ((refused == ACCEPTED) == (new == proposed).all(-1)).all() or ((new == pos).all(-1)).all()
        for b in range(batch):
            assert len({tuple(c) for c in new[b]}) == uavs  # no two vehicles end in one cell
            for u in range(uavs):  # nobody moves into a cell another vehicle held
                moved = tuple(new[b, u]) != tuple(pos[b, u])
                assert not (moved and any(tuple(new[b, u]) == tuple(pos[b, j]) for j in range(uavs) if j != u))
        pos = new


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 6))
def test_the_controller_guard_is_the_batched_rule_for_one_batch(seed, uavs):
    rng = np.random.default_rng(seed)
    blocked = rng.random((8, 8)) < 0.2
    free = np.argwhere(~blocked)
    pos = free[rng.choice(len(free), uavs, replace=False)]
    proposed = pos + MOVES[rng.integers(0, 5, uavs)]
    dest, _ = guard_moves(pos[None], proposed[None], blocked)
    assert [d.cell for d in SafetyGuard(blocked, 40.0).guard_moves(pos, proposed)] == [tuple(c) for c in dest[0]]


def test_staying_is_never_refused():
    dest, refused = guard_moves(np.array([[[0, 0], [1, 0]]]), np.array([[[0, 0], [1, 0]]]), np.ones((2, 1), bool))
    assert (refused == ACCEPTED).all() and STAY == 0
