"""Hand-built scenarios for the tests."""

import numpy as np

from swarmctl.world import SearchEnv, WorldConfig
from swarmctl.world.scenario import Scenario


def make_scenario(size, targets, starts, obstacles=()):
    """A scenario on a size x size map; obstacles is a list of (x, y) cells."""
    grid = np.zeros((size, size), dtype=bool)
    for x, y in obstacles:
        grid[x, y] = True
    return Scenario(
        targets=np.array(targets, dtype=np.int64),
        obstacles=grid,
        starts=np.array(starts, dtype=np.int64),
        obstacle_rects=[],
    )


def make_env(size, targets, starts, obstacles=(), stop_at_success=True, **cfg):
    """A batch-of-one env reset to a hand-built scenario."""
    cfg.setdefault("map_size", size)
    cfg.setdefault("uavs", len(starts))
    cfg.setdefault("targets", len(starts))  # generation parameter only; reset_to uses the given targets
    env = SearchEnv(WorldConfig(**cfg), batch=1, stop_at_success=stop_at_success)
    env.reset_to([make_scenario(size, targets, starts, obstacles)])
    return env
