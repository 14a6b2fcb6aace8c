"""Scenario generation: targets (sparse, cluster, multi-cluster), rectangular obstacles, start cells.

Episode i of a run depends only on (seed, i): `episode_rng(seed, i)` is its generator. A failed draw
(no room for the next target, no room for an obstacle) is retried from scratch up to
`MAX_ATTEMPTS` times, then stops with a ScenarioError that names the parameter to change.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from swarmctl.errors import ScenarioError
from swarmctl.world.config import WorldConfig
from swarmctl.world.paths import largest_free_region
from swarmctl.world.prior import draw_cells

MAX_ATTEMPTS = 100
MAX_OBSTACLE_FAILURES = 50


class _DrawFailed(Exception):
    """One draw of an episode hit a dead end; the caller retries."""


@dataclass
class Scenario:
    """One episode's ground truth. Arrays are indexed [x, y]."""

    targets: np.ndarray  # (K, 2) int cells
    obstacles: np.ndarray  # (M, M) bool
    starts: np.ndarray  # (U, 2) int cells, distinct, free, not on a target
    obstacle_rects: list[tuple[int, int, int, int]]  # (x0, y0, w, h) in placement order


def episode_rng(seed: int, episode: int) -> np.random.Generator:
    """The generator for episode `episode` of a run with `seed`."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(episode), 0x5CE7]))


def _cell_coords(width: int, height: int) -> np.ndarray:
    xs, ys = np.meshgrid(np.arange(width), np.arange(height), indexing="ij")
    return np.stack([xs.ravel(), ys.ravel()], axis=1)


def _draw(rng: np.random.Generator, weights: np.ndarray) -> int:
    total = weights.sum()
    if total <= 0:
        raise _DrawFailed
    return int(rng.choice(weights.size, p=weights / total))


def place_targets(
    cfg: WorldConfig, rng: np.random.Generator, allowed: np.ndarray | None = None, prior: np.ndarray | None = None
) -> np.ndarray:
    """Targets by the paper's sequential rules; returns (K, 2) cells. `allowed` (W, H) bool, for a
    fixed map: targets only there (its shape is the map's); None: anywhere on the M x M map. The
    scenario `prior` draws the K targets from `prior` (W, H) without replacement (uniform when None),
    within `allowed`, with no spacing rule."""
    k = cfg.targets
    width, height = allowed.shape if allowed is not None else (cfg.map_size, cfg.map_size)
    if cfg.scenario == "prior":
        weights = np.ones((width, height)) if prior is None else np.asarray(prior, dtype=np.float64)
        if allowed is not None:
            weights = np.where(allowed, weights, 0.0)
        return draw_cells(weights, k, rng)
    cells = _cell_coords(width, height).astype(np.float64)
    n = cells.shape[0]
    where = allowed.ravel().astype(np.float64) if allowed is not None else 1.0
    min_d2 = np.full(n, np.inf)  # squared distance from each cell to the nearest placed target
    chosen: list[int] = []

    def add(index: int) -> None:
        chosen.append(index)
        np.minimum(min_d2, ((cells - cells[index]) ** 2).sum(axis=1), out=min_d2)

    if cfg.scenario == "sparse":
        add(int(rng.integers(n)) if isinstance(where, float) else _draw(rng, where))  # a float: allowed is None
        dist0 = np.sqrt(((cells - cells[chosen[0]]) ** 2).sum(axis=1))
        for _ in range(1, k):
            add(_draw(rng, np.where(min_d2 > cfg.d_sparse**2, dist0, 0.0) * where))
    else:
        # cluster and multi-cluster: K split as evenly as possible over C clusters
        sizes = [k // cfg.clusters + (1 if c < k % cfg.clusters else 0) for c in range(cfg.clusters)]
        for size in sizes:
            seed_weights = np.where(min_d2 > 1.0, 1.0, 0.0) * where
            seed_cell = _draw(rng, seed_weights)
            add(seed_cell)
            inv = 1.0 / (1.0 + np.sqrt(((cells - cells[seed_cell]) ** 2).sum(axis=1)))
            for _ in range(1, size):
                add(_draw(rng, np.where(min_d2 > 1.0, inv, 0.0) * where))
    return cells[chosen].astype(np.int64)


def _box_sums(mask: np.ndarray, w: int, h: int) -> np.ndarray:
    """Sum of `mask` over every w x h box; result[x0, y0] covers mask[x0:x0+w, y0:y0+h]."""
    sat = np.zeros((mask.shape[0] + 1, mask.shape[1] + 1), dtype=np.int64)
    sat[1:, 1:] = mask.astype(np.int64).cumsum(0).cumsum(1)
    return sat[w:, h:] - sat[:-w, h:] - sat[w:, :-h] + sat[:-w, :-h]


def _dilate(mask: np.ndarray, offsets: list[tuple[int, int]]) -> np.ndarray:
    out = np.zeros_like(mask)
    m, n = mask.shape
    for dx, dy in offsets:
        xs, xd = (slice(0, m - dx), slice(dx, m)) if dx >= 0 else (slice(-dx, m), slice(0, m + dx))
        ys, yd = (slice(0, n - dy), slice(dy, n)) if dy >= 0 else (slice(-dy, n), slice(0, n + dy))
        out[xd, yd] |= mask[xs, ys]
    return out


# cells at distance <= 1 (target spacing) and < 2 (obstacle spacing) from a cell
_WITHIN_1 = [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)]
_WITHIN_LT2 = [(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)]


def place_obstacles(
    cfg: WorldConfig, targets: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, list[tuple[int, int, int, int]]]:
    """Rectangles placed one by one until the covered fraction reaches eta (overshoot allowed).

    Lower-left corner uniform among positions where the rectangle is inside the map, every cell is
    more than 1 from every target, and it is at distance >= 2 from every earlier rectangle.
    """
    m = cfg.map_size
    obstacles = np.zeros((m, m), dtype=bool)
    rects: list[tuple[int, int, int, int]] = []
    if cfg.obstacles <= 0:
        return obstacles, rects
    target_mask = np.zeros((m, m), dtype=bool)
    target_mask[targets[:, 0], targets[:, 1]] = True
    near_targets = _dilate(target_mask, _WITHIN_1)
    goal = cfg.obstacles * m * m
    failures = 0
    while obstacles.sum() < goal:
        w = int(rng.integers(cfg.obstacle_min, cfg.obstacle_max + 1))
        h = int(rng.integers(cfg.obstacle_min, cfg.obstacle_max + 1))
        forbidden = near_targets | _dilate(obstacles, _WITHIN_LT2)
        if w > m or h > m:
            ok = np.zeros((0, 0), dtype=bool)
        else:
            ok = _box_sums(forbidden, w, h) == 0
        candidates = np.flatnonzero(ok)
        if candidates.size == 0:
            failures += 1
            if failures > MAX_OBSTACLE_FAILURES:
                raise _DrawFailed
            continue
        x0, y0 = np.unravel_index(int(rng.choice(candidates)), ok.shape)
        obstacles[x0 : x0 + w, y0 : y0 + h] = True
        rects.append((int(x0), int(y0), w, h))
    return obstacles, rects


def place_starts(cfg: WorldConfig, obstacles: np.ndarray, targets: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """U distinct start cells, uniform among free cells that are not targets."""
    free = ~obstacles
    free[targets[:, 0], targets[:, 1]] = False
    candidates = np.flatnonzero(free)
    if candidates.size < cfg.uavs:
        raise _DrawFailed
    picked = rng.choice(candidates, size=cfg.uavs, replace=False)
    return np.stack(np.unravel_index(picked, free.shape), axis=1).astype(np.int64)


def generate_scenario(
    cfg: WorldConfig, seed: int, episode: int, blocked: np.ndarray | None = None, prior: np.ndarray | None = None
) -> Scenario:
    """Episode `episode` of the run with `seed`: targets, then obstacles, then start cells.

    `blocked` (W, H) bool is a fixed map (a real area's grid): its blocked cells are the obstacles
    (cfg.map_size and cfg.obstacles do not apply), and targets and starts are drawn by the same
    rules among the cells of its largest connected free region, so every target can be reached.
    `prior` (W, H) weights: where the scenario `prior` draws the targets (uniform when None)."""
    rng = episode_rng(seed, episode)
    region = largest_free_region(blocked) if blocked is not None else None
    for _ in range(MAX_ATTEMPTS):
        try:
            if region is not None and blocked is not None:  # (one is None only with the other)
                targets = place_targets(cfg, rng, allowed=region, prior=prior)
                starts = place_starts(cfg, ~region, targets, rng)
                return Scenario(targets=targets, obstacles=blocked.copy(), starts=starts, obstacle_rects=[])
            targets = place_targets(cfg, rng, prior=prior)
            obstacles, rects = place_obstacles(cfg, targets, rng)
            starts = place_starts(cfg, obstacles, targets, rng)
            return Scenario(targets=targets, obstacles=obstacles, starts=starts, obstacle_rects=rects)
        except _DrawFailed:
            continue
    if region is not None:
        raise ScenarioError(
            f"no valid {cfg.scenario} scenario after {MAX_ATTEMPTS} draws on the grid: its largest free region "
            f"({int(region.sum())} cells) cannot hold K={cfg.targets} targets by the scenario's spacing and "
            f"U={cfg.uavs} starts; lower --targets or --uavs"
        )
    what = "--targets" if cfg.scenario == "sparse" else "--obstacles"
    raise ScenarioError(
        f"no valid {cfg.scenario} scenario after {MAX_ATTEMPTS} draws (M={cfg.map_size}, K={cfg.targets}, "
        f"eta={cfg.obstacles}, U={cfg.uavs}): lower {what} or enlarge --map"
    )


def value_map(targets: np.ndarray, width: int, height: int, sigma2: float = 1.0, cutoff: float = 0.01) -> np.ndarray:
    """phi(m) = max_k exp(-||m - z_k||^2 / (2 sigma^2)), with phi < cutoff set to 0.

    `targets` is (..., K, 2); returns (..., width, height) float32 (all 0 when K is 0: nothing to find).
    """
    targets = np.asarray(targets)
    if targets.shape[-2] == 0:
        return np.zeros((*targets.shape[:-2], width, height), dtype=np.float32)
    xs = np.arange(width, dtype=np.float32)
    ys = np.arange(height, dtype=np.float32)
    tx = targets[..., 0].astype(np.float32)[..., None, None]
    ty = targets[..., 1].astype(np.float32)[..., None, None]
    d2 = (xs[:, None] - tx) ** 2 + (ys[None, :] - ty) ** 2  # (..., K, W, H)
    phi: np.ndarray = np.exp(-d2.min(axis=-3) / (2.0 * sigma2)).astype(np.float32)
    phi[phi < cutoff] = 0.0
    return phi


@functools.lru_cache(maxsize=16)
def fov_offsets(radius: float) -> np.ndarray:
    """Cell offsets of the Euclidean sensing disc ||d|| <= radius (29 cells for radius 3); read-only,
    made once per radius (every agent senses its disc every step)."""
    offsets = _disc_offsets(float(radius))
    offsets.flags.writeable = False
    return offsets


def _disc_offsets(radius: float) -> np.ndarray:
    r = int(np.floor(radius))
    d = np.arange(-r, r + 1)
    dx, dy = np.meshgrid(d, d, indexing="ij")
    keep = dx**2 + dy**2 <= radius**2 + 1e-9
    return np.stack([dx[keep], dy[keep]], axis=1).astype(np.int64)
