"""The PettingZoo ParallelEnv over the simulator: PettingZoo's own API test, and the episodes it plays."""

import numpy as np
import pytest

pytest.importorskip("pettingzoo")

from pettingzoo.test import parallel_api_test  # noqa: E402

from swarmctl.learn.parallel_env import SearchParallelEnv  # noqa: E402
from swarmctl.world import SearchEnv, WorldConfig  # noqa: E402
from swarmctl.world.moves import STAY  # noqa: E402


@pytest.mark.parametrize(
    "world",
    [
        WorldConfig(),
        WorldConfig(scenario="sparse", uavs=3, targets=3, obstacles=0.1),
        WorldConfig(variant="global-local-v1"),
    ],
)
def test_pettingzoos_parallel_api_test_passes(world):
    parallel_api_test(SearchParallelEnv(world, steps=30), num_cycles=60)


def test_it_plays_evals_episodes_and_ends_them_as_the_world_does():
    world = WorldConfig(scenario="cluster", uavs=2, targets=4)
    env = SearchParallelEnv(world, steps=5)
    obs, infos = env.reset(seed=7)
    reference = SearchEnv(world, batch=1, observations=True)
    expected = reference.reset(7, [0])[0]
    assert np.array_equal(obs["uav_0"], expected[0]) and np.array_equal(obs["uav_1"], expected[1])
    assert infos["uav_0"]["action_mask"].dtype == np.int8 and infos["uav_0"]["action_mask"][STAY] == 1
    for _ in range(5):
        assert env.agents == ["uav_0", "uav_1"]
        obs, rewards, terminated, truncated, infos = env.step({"uav_0": STAY, "uav_1": STAY})
    assert env.agents == [] and all(truncated.values()) and not any(terminated.values())
    env.reset()  # the next episode of the same seed
    second = SearchEnv(world, batch=1, observations=False)
    second.reset(7, [1])
    assert np.array_equal(env._env.targets, second.targets)
    with pytest.raises(ValueError, match="action"):
        env.step({"uav_0": 9})
