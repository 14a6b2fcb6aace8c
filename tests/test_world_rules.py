"""The paper's step semantics on hand-built cases: moves, rewards, collisions, success, sensing."""

import numpy as np
import pytest

from swarmctl.world import SearchEnv, WorldConfig
from swarmctl.world.moves import EAST, NORTH, SOUTH, STAY, WEST
from tests.helpers import make_env

THETA, PSI = 1.0, 0.8


def step(env, *moves):
    return env.step(np.array([moves]))


def test_move_off_the_map_is_invalid_and_penalised():
    env = make_env(6, [[5, 5]], [[0, 0]])
    _, r, _, info = step(env, SOUTH)
    assert tuple(env.pos[0, 0]) == (0, 0)
    assert not info.valid[0, 0]
    assert r[0, 0] == pytest.approx(-THETA)


def test_move_into_obstacle_is_invalid():
    env = make_env(6, [[5, 5]], [[2, 2]], obstacles=[(3, 2)])
    _, r, _, info = step(env, EAST)
    assert tuple(env.pos[0, 0]) == (2, 2) and r[0, 0] == pytest.approx(-THETA)
    _, r, _, _ = step(env, NORTH)
    assert tuple(env.pos[0, 0]) == (2, 3) and r[0, 0] == 0.0


def test_axes_north_is_plus_y_east_is_plus_x():
    env = make_env(6, [[5, 5]], [[2, 2]])
    step(env, NORTH)
    assert tuple(env.pos[0, 0]) == (2, 3)
    step(env, EAST)
    assert tuple(env.pos[0, 0]) == (3, 3)
    step(env, WEST)
    step(env, SOUTH)
    assert tuple(env.pos[0, 0]) == (2, 2)


def test_reaching_a_target_earns_one():
    env = make_env(6, [[3, 2], [0, 5]], [[2, 2], [0, 0]])
    _, r, success, info = step(env, EAST, STAY)
    assert r[0, 0] == 1.0 and r[0, 1] == 0.0
    assert info.on_target[0, 0] and not success[0]


def test_collision_on_a_target_gives_both_minus_psi_and_no_reward():
    env = make_env(6, [[3, 2], [0, 5]], [[2, 2], [4, 2]])
    _, r, success, info = step(env, EAST, WEST)
    assert info.collided[0].all()
    assert r[0, 0] == pytest.approx(-PSI) and r[0, 1] == pytest.approx(-PSI)
    assert not success[0]
    assert (env.pos[0] == [3, 2]).all()  # both stay where their moves took them


def test_invalid_move_and_collision_penalties_add():
    env = make_env(6, [[5, 5]], [[0, 0], [1, 0]])
    _, r, _, _ = step(env, WEST, WEST)  # vehicle 0 bumps the border, vehicle 1 moves onto it
    assert r[0, 0] == pytest.approx(-THETA - PSI)
    assert r[0, 1] == pytest.approx(-PSI)


def test_swap_is_not_a_collision():
    env = make_env(6, [[5, 5]], [[2, 2], [3, 2]])
    _, r, _, info = step(env, EAST, WEST)
    assert not info.collided.any()
    assert (r == 0).all()


def test_success_needs_every_vehicle_on_a_distinct_target_and_freezes_the_episode():
    env = make_env(6, [[3, 2], [3, 4]], [[2, 2], [3, 5]])
    _, _, success, _ = step(env, EAST, SOUTH)
    assert success[0] and env.done[0] and env.duration[0] == 1
    _, r, _, _ = step(env, WEST, WEST)  # frozen: actions ignored
    assert (env.pos[0] == [[3, 2], [3, 4]]).all()


def test_training_episodes_run_on_after_success():
    env = make_env(6, [[3, 2], [3, 4]], [[2, 2], [3, 5]], stop_at_success=False)
    step(env, EAST, SOUTH)
    step(env, WEST, STAY)
    assert tuple(env.pos[0, 0]) == (2, 2)


def test_sensing_is_a_disc_of_radius_zeta_and_ideal_sharing_unites_knowledge():
    env = make_env(20, [[19, 19]], [[5, 5], [15, 15]])
    assert env.explored[0, 0].sum() == 29 * 2  # both vehicles' discs, shared
    assert (env.explored[0, 0] == env.explored[0, 1]).all()
    assert env.explored[0, 0, 5, 8] and not env.explored[0, 0, 5, 9] and not env.explored[0, 0, 8, 8]


def test_no_channel_keeps_knowledge_private_and_others_unknown():
    env = make_env(20, [[19, 19]], [[5, 5], [15, 15]], channel="none")
    assert env.explored[0, 0].sum() == 29 and env.explored[0, 1].sum() == 29
    assert (env.known_pos[0, 0, 1] == -1).all()
    assert (env.known_pos[0, 0, 0] == [5, 5]).all()


def test_lossy_channel_delivers_about_one_minus_p():
    cfg = WorldConfig(channel="fixed", loss=0.3)
    env = SearchEnv(cfg, batch=2000, stop_at_success=False, observations=False)
    env.reset(seed=1)
    got = (env.known_pos[:, 0, 1, 0] >= 0).mean()
    assert got == pytest.approx(0.7, abs=0.04)


def test_observation_channels_on_a_hand_built_case():
    env = make_env(20, [[10, 10]], [[10, 7], [12, 7]])
    obs = env.observe()[0, 0]  # vehicle 0, window covers the whole 20 x 20 map
    assert obs.shape == (3, 20, 20)
    assert obs[0, 10, 7] == 1.0 and obs[0].sum() == 1.0
    assert obs[1, 12, 7] == 1.0 and obs[1].sum() == 1.0
    assert obs[2, 10, 10] == pytest.approx(1.0)  # target seen: phi = 1
    assert obs[2, 10, 5] == pytest.approx(0.0)  # explored, phi 0 (distance 5)
    assert obs[2, 0, 0] == 1.0  # unexplored reads 1


def test_observation_window_is_clamped_on_big_maps_and_padded_on_small_ones():
    env = make_env(30, [[29, 29]], [[2, 28], [27, 1]], obstacles=[(4, 28)])
    obs = env.observe()[0]
    # vehicle 0 at (2, 28): corner clip(2-10, 0, 10) = 0, clip(28-10, 0, 10) = 10
    assert obs[0, 0, 2, 18] == 1.0
    assert obs[0, 2, 4, 18] == pytest.approx(-0.2)  # explored obstacle: phi - rho = -0.2
    # vehicle 1 at (27, 1): corner (10, 0); it sees vehicle 0? (2, 28) is outside its window
    assert obs[1, 0, 17, 1] == 1.0 and obs[1, 1].sum() == 0.0
    small = make_env(6, [[5, 5]], [[0, 0]])
    o = small.observe()[0, 0]
    assert o.shape == (3, 20, 20)
    assert o[0, 0, 0] == 1.0
    assert np.allclose(o[2, 6:, :], -0.2) and np.allclose(o[2, :, 6:], -0.2)


def test_guarded_world_never_has_collisions():
    env = SearchEnv(WorldConfig(uavs=6, targets=6, guard=True), batch=64, stop_at_success=False, observations=False)
    env.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(100):
        _, _, _, info = env.step(rng.integers(0, 5, (64, 6)))
        assert not info.collided.any()


def test_batched_step_matches_batch_of_one():
    cfg = WorldConfig(obstacles=0.1, uavs=3)
    big = SearchEnv(cfg, batch=8, stop_at_success=False)
    big.reset(seed=5)
    rng = np.random.default_rng(1)
    acts = rng.integers(0, 5, (10, 8, 3))
    singles = []
    for i in range(8):
        e = SearchEnv(cfg, batch=1, stop_at_success=False)
        e.reset(seed=5, episodes=[i])
        singles.append(e)
    for a in acts:
        ob, r, _, _ = big.step(a)
        for i, e in enumerate(singles):
            o1, r1, _, _ = e.step(a[i : i + 1])
            assert (r1[0] == r[i]).all() and (o1[0] == ob[i]).all()
