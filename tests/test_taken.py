"""Taken targets: a target another vehicle sits on leaves the value map (LA(n), and DDQL when asked)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.errors import InputError
from swarmctl.knowledge.model import Knowledge, Position
from swarmctl.policy.ddql import make_ddql_policy
from swarmctl.world.scenario import value_map
from swarmctl.world.taken import remove_taken_targets
from tests.helpers import make_env

SIGMA2, CUTOFF = 1.0, 0.01


def test_a_taken_target_loses_its_bump_and_its_neighbours_read_the_free_one():
    targets = np.array([[[3, 3], [6, 3]]])
    phi = value_map(targets, 10, 10, SIGMA2, CUTOFF)[0]
    explored = np.ones((10, 10), dtype=bool)
    taken = np.zeros((10, 10), dtype=bool)
    taken[3, 3] = True
    out = remove_taken_targets(phi, explored, taken, SIGMA2, CUTOFF)
    assert out[3, 3] == pytest.approx(np.exp(-9 / 2))  # now worth what the free target 3 cells away gives it
    assert out[2, 3] == 0.0  # 4 cells from the free target: below the cut-off
    assert out[6, 3] == 1.0 and out[5, 3] == phi[5, 3]  # the free target's bump is untouched
    # alone, the taken target leaves nothing behind
    alone = value_map(np.array([[[3, 3]]]), 10, 10, SIGMA2, CUTOFF)[0]
    assert remove_taken_targets(alone, explored, taken, SIGMA2, CUTOFF).max() == 0.0


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_removing_never_adds_value_and_leaves_unexplored_cells_alone(seed):
    rng = np.random.default_rng(seed)
    b, w, h = 3, 9, 7
    targets = np.stack([rng.choice(w * h, 3, replace=False) for _ in range(b)])
    cells = np.stack([targets // h, targets % h], axis=-1)
    phi = value_map(cells, w, h, SIGMA2, CUTOFF)
    explored = rng.random((b, w, h)) < 0.6
    phi_hat = np.where(explored, phi, np.float32(1.0))
    taken = explored & (phi >= 1.0) & (rng.random((b, w, h)) < 0.5)
    out = remove_taken_targets(phi_hat, explored, taken, SIGMA2, CUTOFF)
    assert (out <= phi_hat + 1e-6).all()
    assert np.array_equal(out[~explored], phi_hat[~explored])
    assert (out[taken] < 1.0).all()
    for i in range(b):  # maps of a batch are independent
        alone = remove_taken_targets(phi_hat[i], explored[i], taken[i], SIGMA2, CUTOFF)
        assert np.allclose(alone, out[i])
    nothing = np.zeros_like(taken)
    assert np.array_equal(remove_taken_targets(phi_hat, explored, nothing, SIGMA2, CUTOFF), phi_hat)


def _two_on_targets(remove_taken):
    """Vehicle 0 has stepped onto the target at (2, 2); vehicle 1, next to it, sees it there."""
    env = make_env(10, targets=[(2, 2), (8, 8)], starts=[(2, 1), (3, 2)], remove_taken=remove_taken)
    env.step(np.array([[1, 0]]))  # vehicle 0 north onto (2, 2), vehicle 1 stays
    assert tuple(env.pos[0, 0]) == (2, 2)
    return env


def test_the_world_removes_a_target_from_the_others_observations_only_when_asked():
    kept = _two_on_targets(remove_taken=False)
    removed = _two_on_targets(remove_taken=True)
    assert kept.beliefs().value_channel(remove_taken=False)[0, 1, 2, 2] == 1.0
    removed_value = removed.beliefs().value_channel(remove_taken=True)
    assert removed_value[0, 1, 2, 2] == 0.0  # the other target is unexplored: nothing left
    assert removed_value[0, 0, 2, 2] == 1.0  # the vehicle on it still sees its own target
    assert np.array_equal(kept.observe(remove_taken=True), removed.observe())


def test_the_controllers_knowledge_removes_it_the_same_way():
    env = _two_on_targets(remove_taken=True)
    k = Knowledge(10, 10, vehicle_id=1)
    x, y = np.nonzero(env.explored[0, 1])
    k.sense(np.stack([x, y], 1), env.phi[0, x, y], env.obstacles[0, x, y])
    k.merge_position(1, Position(1, (3, 2)))
    k.merge_position(0, Position(1, (2, 2), on_target=True))
    sim = env.observe()[0, 1]
    obs = k.observation(window=env.cfg.window, rho=env.cfg.rho, remove_taken=True)
    assert np.array_equal(obs[:2], sim[:2])
    assert np.abs(obs[2] - sim[2]).max() <= 0.5 / 255 + 1e-6
    assert k.observation(window=env.cfg.window, rho=env.cfg.rho)[2][2, 2] == 1.0


@pytest.mark.parametrize(
    "spec, needle",
    [("ddql:x.pt:taken=drop", "taken must be remove or keep"), ("ddql:x.pt:hover=maybe", "hover must be yes or no")],
)
def test_bad_ddql_options_are_named(spec, needle):
    with pytest.raises(InputError, match=needle):
        make_ddql_policy(spec)


def test_la_in_the_field_sees_what_la_in_the_simulator_sees():
    from swarmctl.knowledge.model import beliefs_from_knowledge
    from swarmctl.policy.lookahead import LookAhead

    env = _two_on_targets(remove_taken=False)
    env.step(np.array([[0, 1]]))  # vehicle 1 north to (3, 3), next to the taken target
    k = Knowledge(10, 10, vehicle_id=1)
    x, y = np.nonzero(env.explored[0, 1])
    k.sense(np.stack([x, y], 1), env.phi[0, x, y], env.obstacles[0, x, y])
    k.merge_position(1, Position(2, (3, 3)))
    k.merge_position(0, Position(2, (2, 2), on_target=True))
    sim = LookAhead.value_maps(env.beliefs())[0, 1]
    field = LookAhead.value_maps(beliefs_from_knowledge([k], vehicles=2))[0, 0]
    assert sim[2, 2] == field[2, 2] == -np.inf  # the cell vehicle 0 hovers on is blocked for vehicle 1
    assert sim[1, 2] == 0.0  # and the target's bump is gone
    assert np.array_equal(np.isinf(sim), np.isinf(field))
    finite = np.isfinite(sim)
    assert np.abs(sim[finite] - field[finite]).max() <= 0.5 / 255 + 1e-6


def _beliefs(pos, blocked, hovering):
    """Hand-built beliefs: deciders at `pos` (B, U, 2), each knowing `blocked` (B, U, W, H) and only itself."""
    from swarmctl.world.beliefs import Beliefs

    b, u = pos.shape[:2]
    positions = np.full((b, u, u, 2), -1)
    positions[:, np.arange(u), np.arange(u)] = pos
    hover = np.zeros((b, u, u), dtype=bool)
    hover[:, np.arange(u), np.arange(u)] = hovering
    explored = np.ones(blocked.shape, dtype=bool)
    return Beliefs(
        explored,
        np.zeros(blocked.shape, np.float32),
        blocked,
        np.zeros_like(blocked),
        positions,
        hover,
        np.broadcast_to(np.arange(u), (b, u)),
        np.zeros(b, dtype=np.int64),
    )


def test_allowed_moves_keep_a_vehicle_on_the_map_out_of_known_obstacles_and_still_only_on_a_target():
    from swarmctl.policy.base import allowed_moves

    pos = np.array([[[0, 0], [5, 5], [5, 6], [2, 2]]])  # (B=1, U=4, 2)
    blocked = np.zeros((1, 4, 8, 8), dtype=bool)
    blocked[0, 0, 1, 0] = True  # vehicle 0 knows an obstacle east of it
    blocked[0, 3, [1, 3, 2, 2], [2, 2, 1, 3]] = True  # vehicle 3 is boxed in
    hovering = np.array([[False, False, True, False]])
    allowed = allowed_moves(_beliefs(pos, blocked, hovering))
    # moves: stay, north (0, +1), east (+1, 0), south (0, -1), west (-1, 0)
    assert allowed[0, 0].tolist() == [False, True, False, False, False]
    assert allowed[0, 1].tolist() == [False, True, True, True, True]
    assert allowed[0, 2].tolist() == [True, False, False, False, False]
    assert allowed[0, 3].tolist() == [True, False, False, False, False]  # no move at all: it may stay
    assert allowed_moves(_beliefs(pos, blocked, hovering), hover=False, mask=False).all()


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([None, 0.1, 1.0]))
def test_choose_never_takes_a_move_that_is_not_allowed(seed, tau):
    from swarmctl.policy.base import choose

    rng = np.random.default_rng(seed)
    q = rng.normal(size=(4, 3, 5)).astype(np.float32) * 10
    allowed = rng.random((4, 3, 5)) < 0.5
    allowed[..., 0] |= ~allowed.any(-1)
    moves = choose(q, allowed, tau, rng.random((4, 3)))
    assert allowed[np.arange(4)[:, None], np.arange(3)[None], moves].all()
