"""Non-learned planners: random, lawnmower (boustrophedon) and frontier exploration.

Lawnmower and frontier are centralised baselines: each vehicle goes to a known target once one is
assigned to it (greedy nearest-pair assignment, each target to one vehicle), and otherwise follows
its sweep (lawnmower) or the nearest unexplored cell not claimed by another vehicle (frontier).
Paths are BFS shortest paths over the cells not known to be obstacles.
"""

from __future__ import annotations

import numpy as np

from swarmctl.policy.base import known_target_indices
from swarmctl.world.env import SearchEnv
from swarmctl.world.paths import UNREACHABLE, grid_distances, step_towards


class RandomPolicy:
    """Uniform over the five moves (the paper's replay-prefill policy)."""

    name = "random"

    def reset(self, env: SearchEnv, rng: np.random.Generator) -> None:
        self.rng = rng

    def act(self, env: SearchEnv) -> np.ndarray:
        return self.rng.integers(0, 5, size=(env.batch, env.uavs))


def _distances_from_vehicles(env: SearchEnv) -> np.ndarray:
    b, u, w, h = env.batch, env.uavs, env.width, env.height
    passable = ~env.known_obstacles().reshape(b * u, w, h)
    src = np.zeros((b * u, w, h), dtype=bool)
    pos = env.pos.reshape(b * u, 2)
    src[np.arange(b * u), pos[:, 0], pos[:, 1]] = True
    return grid_distances(passable, src).reshape(b, u, w, h)


def assign_known_targets(env: SearchEnv, dist: np.ndarray) -> np.ndarray:
    """Greedy assignment of known targets to vehicles, nearest pair first, one vehicle per target.

    dist: (B, U, W, H) distances from each vehicle. Returns (B, U) target index or -1.
    """
    b, u = env.batch, env.uavs
    k = env.targets.shape[1]
    known = known_target_indices(env)
    bi = np.arange(b)[:, None, None]
    ui = np.arange(u)[None, :, None]
    d = dist[bi, ui, env.targets[:, None, :, 0], env.targets[:, None, :, 1]].astype(np.float64)
    d[~known | (d >= UNREACHABLE)] = np.inf
    goal = np.full((b, u), -1, dtype=np.int64)
    rows = np.arange(b)
    for _ in range(min(u, k)):
        flat = d.reshape(b, -1).argmin(1)
        vu, tk = np.divmod(flat, k)
        ok = np.isfinite(d[rows, vu, tk])
        goal[rows[ok], vu[ok]] = tk[ok]
        d[rows[ok], vu[ok], :] = np.inf
        d[rows[ok], :, tk[ok]] = np.inf
    return goal


def _navigate(env: SearchEnv, goals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Moves that bring each vehicle one step closer to its goal cell (B, U, 2)."""
    b, u, w, h = env.batch, env.uavs, env.width, env.height
    passable = ~env.known_obstacles().reshape(b * u, w, h)
    src = np.zeros((b * u, w, h), dtype=bool)
    g = goals.reshape(b * u, 2)
    src[np.arange(b * u), g[:, 0], g[:, 1]] = True
    dist = grid_distances(passable, src)
    return step_towards(dist, env.pos.reshape(b * u, 2), rng).reshape(b, u)


def _target_goals(env: SearchEnv, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    assigned = assign_known_targets(env, dist)
    has = assigned >= 0
    goals = np.take_along_axis(env.targets, np.maximum(assigned, 0)[..., None], axis=1)
    return goals, has


def _nearest_unexplored(
    env: SearchEnv, dist: np.ndarray, pending: np.ndarray, rng: np.random.Generator, spread: float
) -> tuple[np.ndarray, np.ndarray]:
    """For vehicles in `pending` (B, U): the nearest reachable unexplored cell, vehicles in index
    order, each claiming a disc of radius `spread` that later vehicles avoid when they can."""
    b, u, w, h = env.batch, env.uavs, env.width, env.height
    xs, ys = np.meshgrid(np.arange(w), np.arange(h), indexing="ij")
    claimed = np.zeros((b, w, h), dtype=bool)
    goals = env.pos.copy()
    found = np.zeros((b, u), dtype=bool)
    rows = np.arange(b)
    for v in range(u):
        d = dist[:, v].astype(np.float64) + rng.random((b, w, h)) * 0.5  # random tie-break
        open_ = ~env.explored[:, v] & (dist[:, v] < UNREACHABLE)
        preferred = np.where(open_ & ~claimed, d, np.inf).reshape(b, -1)
        fallback = np.where(open_, d, np.inf).reshape(b, -1)
        use = np.isfinite(preferred.min(1))
        flat = np.where(use, preferred.argmin(1), fallback.argmin(1))
        ok = np.isfinite(fallback.min(1)) & pending[:, v]
        gx, gy = np.divmod(flat, h)
        goals[rows[ok], v] = np.stack([gx[ok], gy[ok]], axis=1)
        found[:, v] = ok
        near = (xs[None] - gx[:, None, None]) ** 2 + (ys[None] - gy[:, None, None]) ** 2 <= spread**2
        claimed |= near & ok[:, None, None]
    return goals, found


class FrontierPolicy:
    """Nearest unexplored cell per vehicle, spread apart by claims; known targets first."""

    name = "frontier"

    def reset(self, env: SearchEnv, rng: np.random.Generator) -> None:
        self.rng = rng

    def act(self, env: SearchEnv) -> np.ndarray:
        dist = _distances_from_vehicles(env)
        goals, has_target = _target_goals(env, dist)
        explore_goals, _ = _nearest_unexplored(env, dist, ~has_target, self.rng, spread=2 * env.cfg.fov)
        goals = np.where(has_target[..., None], goals, explore_goals)
        return _navigate(env, goals, self.rng)


def sweep_waypoints(width: int, height: int, uavs: int, fov: float) -> list[np.ndarray]:
    """Boustrophedon lanes per vehicle: the map split into U vertical strips, lanes 2*zeta+1 apart
    (a vehicle flying a lane senses zeta cells either side). Returns U arrays of (L_u, 2) waypoints."""
    reach = max(int(np.floor(fov)), 0)
    spacing = 2 * reach + 1
    bounds = np.linspace(0, width, uavs + 1).round().astype(int)
    lo_y, hi_y = 0, height - 1  # lanes run edge to edge, or the disc misses the corners
    out = []
    for v in range(uavs):
        x_lo, x_hi = bounds[v], max(bounds[v + 1] - 1, bounds[v])
        lanes = list(range(min(x_lo + reach, x_hi), x_hi + 1, spacing))
        if lanes[-1] + reach < x_hi:
            lanes.append(x_hi - reach if x_hi - reach > lanes[-1] else x_hi)
        pts = []
        for i, x in enumerate(lanes):
            ends = (lo_y, hi_y) if i % 2 == 0 else (hi_y, lo_y)
            pts += [(x, ends[0]), (x, ends[1])]
        out.append(np.array(pts, dtype=np.int64))
    return out


class LawnmowerPolicy:
    """Boustrophedon sweep split between vehicles, then known targets (or any unexplored cell)."""

    name = "lawnmower"

    def reset(self, env: SearchEnv, rng: np.random.Generator) -> None:
        self.rng = rng
        paths = sweep_waypoints(env.width, env.height, env.uavs, env.cfg.fov)
        length = max(len(p) for p in paths)
        self.waypoints = np.zeros((env.uavs, length, 2), dtype=np.int64)
        self.lengths = np.array([len(p) for p in paths])
        for v, p in enumerate(paths):
            self.waypoints[v, : len(p)] = p
            self.waypoints[v, len(p) :] = p[-1]
        self.index = np.zeros((env.batch, env.uavs), dtype=np.int64)

    def act(self, env: SearchEnv) -> np.ndarray:
        b, u = env.batch, env.uavs
        dist = _distances_from_vehicles(env)
        goals, has_target = _target_goals(env, dist)
        bi = np.arange(b)[:, None]
        ui = np.arange(u)[None, :]
        blocked = env.known_obstacles()
        for _ in range(self.waypoints.shape[1]):
            active = self.index < self.lengths[None, :]
            wp = self.waypoints[ui, np.minimum(self.index, self.waypoints.shape[1] - 1)]
            reached = (env.pos == wp).all(-1)
            unusable = blocked[bi, ui, wp[..., 0], wp[..., 1]] | (dist[bi, ui, wp[..., 0], wp[..., 1]] >= UNREACHABLE)
            advance = active & (reached | unusable)
            if not advance.any():
                break
            self.index += advance
        sweeping = self.index < self.lengths[None, :]
        wp = self.waypoints[ui, np.minimum(self.index, self.waypoints.shape[1] - 1)]
        leftover, _ = _nearest_unexplored(env, dist, ~has_target & ~sweeping, self.rng, spread=2 * env.cfg.fov)
        goals = np.where(has_target[..., None], goals, np.where(sweeping[..., None], wp, leftover))
        return _navigate(env, goals, self.rng)
