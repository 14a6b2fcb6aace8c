"""The oracle: a computed lower bound on episode duration, not a simulated policy.

With full knowledge of the targets, vehicles are assigned to distinct targets so that the time until
the last one arrives (BFS steps around obstacles) is as small as possible: a bottleneck assignment,
found by binary search over thresholds with a perfect-matching test (scipy's linear_sum_assignment).
Collisions on the way are ignored, so no policy can finish sooner.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from swarmctl.world.env import SearchEnv
from swarmctl.world.paths import UNREACHABLE, grid_distances


def vehicle_target_distances(env: SearchEnv) -> np.ndarray:
    """(B, U, K) BFS steps from each vehicle's cell to each target over the true free cells."""
    b, w, h = env.batch, env.width, env.height
    k = env.targets.shape[1]
    src = np.zeros((b, k, w, h), dtype=bool)
    src[np.arange(b)[:, None], np.arange(k)[None, :], env.targets[..., 0], env.targets[..., 1]] = True
    passable = np.repeat(~env.obstacles[:, None], k, axis=1)
    dist = grid_distances(passable.reshape(b * k, w, h), src.reshape(b * k, w, h)).reshape(b, k, w, h)
    bi = np.arange(b)[:, None, None]
    ki = np.arange(k)[None, None, :]
    return dist[bi, ki, env.pos[..., 0][..., None], env.pos[..., 1][..., None]]


def bottleneck(cost: np.ndarray) -> float:
    """Smallest t such that every row can take a distinct column with cost <= t (inf if none)."""
    u, k = cost.shape
    if u > k:
        return np.inf
    values = np.unique(cost[cost < UNREACHABLE])
    lo, hi = 0, len(values) - 1
    best = np.inf
    while lo <= hi:
        mid = (lo + hi) // 2
        over = (cost > values[mid]).astype(np.float64)
        rows, cols = linear_sum_assignment(over)
        if over[rows, cols].sum() == 0:
            best, hi = float(values[mid]), mid - 1
        else:
            lo = mid + 1
    return best


class OracleBound:
    """Lower bound on episode duration for each episode of a freshly reset env."""

    name = "oracle"

    def durations(self, env: SearchEnv) -> np.ndarray:
        d = vehicle_target_distances(env)
        return np.array([max(bottleneck(d[i]), 1.0) for i in range(env.batch)])
