"""Shortest 4-connected grid distances, batched: many maps and sources in one call."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

UNREACHABLE = np.iinfo(np.int32).max // 2


def grid_distances(passable: np.ndarray, sources: np.ndarray, limit: int | None = None) -> np.ndarray:
    """BFS distance from the nearest source cell over passable cells, for a stack of maps.

    passable, sources: (N, W, H) bool. Returns (N, W, H) int32, UNREACHABLE where no path exists
    (and, with `limit`, beyond `limit` steps: the search stops there). Source cells count as
    passable. Runs one vectorised relaxation per distance layer.
    """
    dist = np.where(sources, 0, UNREACHABLE).astype(np.int32)
    frontier = sources.copy()
    open_ = passable & ~sources
    d = 0
    while frontier.any() and (limit is None or d < limit):
        d += 1
        grown = np.zeros_like(frontier)
        grown[:, 1:, :] |= frontier[:, :-1, :]
        grown[:, :-1, :] |= frontier[:, 1:, :]
        grown[:, :, 1:] |= frontier[:, :, :-1]
        grown[:, :, :-1] |= frontier[:, :, 1:]
        frontier = grown & open_
        open_ &= ~frontier
        dist[frontier] = d
    return dist


def step_towards(dist_to_goal: np.ndarray, pos: np.ndarray, ties: np.ndarray) -> np.ndarray:
    """The move (0..4) that lowers the distance to the goal most, ties broken by `ties`.

    dist_to_goal: (N, W, H) distances from each goal; pos: (N, 2); ties: (N, 5) uniforms in [0, 1) (the
    highest among the equally good moves wins). A vehicle at its goal, or with no path, stays.
    """
    from swarmctl.world.moves import MOVES

    n, w, h = dist_to_goal.shape
    cand = pos[:, None, :] + MOVES[None, :, :]  # (N, 5, 2)
    inside = (cand[..., 0] >= 0) & (cand[..., 0] < w) & (cand[..., 1] >= 0) & (cand[..., 1] < h)
    cx = np.clip(cand[..., 0], 0, w - 1)
    cy = np.clip(cand[..., 1], 0, h - 1)
    d = dist_to_goal[np.arange(n)[:, None], cx, cy].astype(np.float64)
    d[~inside] = np.inf
    d[d >= UNREACHABLE] = np.inf
    best = d.min(1, keepdims=True)
    choice = (d == best) & np.isfinite(d)
    choice[~np.isfinite(best[:, 0]), 0] = True  # no path: stay
    result: np.ndarray = np.argmax(choice * (ties + 1.0), axis=1)
    return result


def largest_free_region(blocked: np.ndarray) -> np.ndarray:
    """Bool mask [x, y] of the largest 4-connected region of cells not `blocked` (all False if none)."""
    labels, n = ndimage.label(~blocked)
    if n == 0:
        return np.zeros_like(blocked, dtype=bool)
    sizes = np.bincount(labels.ravel())[1:]
    result: np.ndarray = labels == (1 + int(np.argmax(sizes)))
    return result


def reachable_from(passable: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(N, W, H) bool: the passable cells 4-connected over passable cells to one of `cells` (N, S, 2) [x, y]
    of their map (a cell of `cells` that is not passable reaches nothing); one labelling for the stack."""
    structure = np.zeros((3, 3, 3), dtype=bool)
    structure[1] = ndimage.generate_binary_structure(2, 1)  # 4-connected within a map, never across maps
    labels, _ = ndimage.label(passable, structure)
    seeds = labels[np.arange(len(labels))[:, None], cells[..., 0], cells[..., 1]]
    return np.isin(labels, seeds[seeds > 0])
