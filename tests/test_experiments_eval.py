"""Eval's per-episode records: who ended on which target, who was still searching, the straggler's
distance to the nearest free target; consistent with the aggregate figures."""

import numpy as np
import pytest

from swarmctl.learn.evaluate import episode_records, evaluate
from swarmctl.world import WorldConfig
from swarmctl.world.env import SearchEnv
from swarmctl.world.scenario import Scenario


def hand_built(starts, obstacles=None) -> SearchEnv:
    """6 x 6, targets at (0, 0) and (5, 5), the given starts."""
    blocked = np.zeros((6, 6), dtype=bool) if obstacles is None else obstacles
    env = SearchEnv(WorldConfig(map_size=6, uavs=2, targets=2, window=8), batch=1, observations=False)
    env.reset_to([Scenario(np.array([[0, 0], [5, 5]]), blocked, np.array(starts), [])], episodes=[7])
    return env


def test_a_lone_straggler_gets_its_bfs_distance_to_the_free_target():
    env = hand_built([[0, 0], [2, 0]])
    (rec,) = episode_records(env, np.array([40]), np.array([False]))
    assert rec["episode"] == 7 and rec["steps"] == 40 and rec["success"] is False
    assert rec["on_target"] == [0, None] and rec["searching"] == [1]
    assert rec["straggler_distance"] == 3 + 5  # open map: Manhattan steps to (5, 5)


def test_the_straggler_distance_goes_round_obstacles():
    wall = np.zeros((6, 6), dtype=bool)
    wall[3, 0:5] = True  # a wall at x = 3 with its gap at the top row
    env = hand_built([[0, 0], [2, 0]], wall)
    (rec,) = episode_records(env, np.array([40]), np.array([False]))
    assert rec["straggler_distance"] == 5 + 3 + 0  # up to y = 5, across to x = 5


def test_two_vehicles_on_one_target_leave_the_second_searching():
    env = hand_built([[0, 0], [0, 0]])
    (rec,) = episode_records(env, np.array([40]), np.array([False]))
    assert rec["on_target"] == [0, 0] and rec["searching"] == [1]
    assert rec["straggler_distance"] == 10


def test_nobody_on_a_target_has_no_straggler():
    env = hand_built([[2, 2], [3, 3]])
    (rec,) = episode_records(env, np.array([40]), np.array([False]))
    assert rec["on_target"] == [None, None] and rec["searching"] == [0, 1]
    assert rec["straggler_distance"] is None


@pytest.mark.parametrize("policy", ["frontier", "random", "oracle"])
def test_per_episode_records_add_up_to_the_aggregates(policy):
    world = WorldConfig(map_size=8, uavs=3, targets=4, obstacles=0.1, window=8)
    (r,) = evaluate(world, [policy], episodes=30, seed=3, steps=25, chunk=7, progress=False)
    per = r["per_episode"]
    assert [e["episode"] for e in per] == list(range(30))
    assert np.mean([e["success"] for e in per]) == pytest.approx(r["success_rate"])
    assert np.mean([e["steps"] for e in per]) == pytest.approx(r["mean_steps"])
    if policy == "oracle":
        return
    assert sum(e["collisions"] for e in per) / 30 == pytest.approx(r["collisions_per_episode"])
    for e in per:
        held = [k for k in e["on_target"] if k is not None]
        if e["success"]:
            assert e["searching"] == [] and len(set(held)) == 3 == len(held)
        else:
            assert e["searching"] and e["steps"] == 25
        assert (e["straggler_distance"] is not None) <= (len(e["searching"]) == 1)


def test_per_episode_records_do_not_depend_on_the_batch():
    world = WorldConfig(map_size=8, uavs=2, targets=3, window=8)
    a = evaluate(world, ["la:2"], episodes=12, seed=1, steps=20, chunk=12, progress=False)[0]["per_episode"]
    b = evaluate(world, ["la:2"], episodes=12, seed=1, steps=20, chunk=5, progress=False)[0]["per_episode"]
    assert a == b
