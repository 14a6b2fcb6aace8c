"""The interface every policy shares, learned or not.

A policy acts for all vehicles of all episodes of a SearchEnv at once:

    policy.reset(env, rng)      # at the start of a batch of episodes
    actions = policy.act(env)   # (B, U) ints in 0..4, read from the vehicles' own knowledge

Planners read only what the vehicles know (explored cells, known obstacles, where they believe the
others are), never the hidden targets. The oracle is the exception: it is a computed bound.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from swarmctl.world.env import SearchEnv


class Policy(Protocol):
    name: str

    def reset(self, env: SearchEnv, rng: np.random.Generator) -> None: ...

    def act(self, env: SearchEnv) -> np.ndarray: ...


def known_target_indices(env: SearchEnv) -> np.ndarray:
    """(B, U, K) bool: vehicle u has explored target k (it reads phi = 1 there)."""
    bi = np.arange(env.batch)[:, None, None]
    ui = np.arange(env.uavs)[None, :, None]
    return env.explored[bi, ui, env.targets[:, None, :, 0], env.targets[:, None, :, 1]]


def hovering(env: SearchEnv) -> np.ndarray:
    """(B, U) bool: the vehicle is on a target and no lower-numbered vehicle is on the same cell; such a
    vehicle stays (LA(n) in the paper; the controller's HOVER state)."""
    bi = np.arange(env.batch)[:, None]
    on_target = env.target_mask[bi, env.pos[..., 0], env.pos[..., 1]]
    same = (env.pos[:, :, None, :] == env.pos[:, None, :, :]).all(-1)
    lower_there = (same & np.tri(env.uavs, k=-1, dtype=bool)[None]).any(-1)
    return on_target & ~lower_there
