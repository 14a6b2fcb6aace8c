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


def others_count(env: SearchEnv) -> np.ndarray:
    """(B, U, W, H) int: how many other vehicles each vehicle believes are on each cell."""
    b, u, w, h = env.batch, env.uavs, env.width, env.height
    kp = env.known_pos  # (B, V, U, 2)
    valid = (kp[..., 0] >= 0) & ~np.eye(u, dtype=bool)[None]
    bi, vi, _ = np.nonzero(valid)
    flat = ((bi * u + vi) * w + kp[..., 0][valid]) * h + kp[..., 1][valid]
    return np.bincount(flat, minlength=b * u * w * h).reshape(b, u, w, h)
