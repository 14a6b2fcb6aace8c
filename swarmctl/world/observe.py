"""The per-vehicle observation: 3 x F x F, one builder for the simulator and the controller.

Channels: 0 own position (one-hot), 1 other vehicles (count per cell, as known to the vehicle),
2 value: phi_hat - rho * omega_hat (unexplored cells read 1, explored cells phi - rho * obstacle).
The window's lower corner is clip(x - F//2, 0, W - F) per axis; along an axis shorter than F the
window starts at 0 and the cells beyond the map are padded as obstacles (value -rho).

`observe(beliefs)` is what every caller uses: the simulator's SearchEnv.observe and the field's
policies build Beliefs first (swarmctl.world.beliefs), so both see the same tensor.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from swarmctl.world.beliefs import PAPER_VARIANT, SCALES_VARIANT, SMALL, Beliefs, Crew
from swarmctl.world.moves import block_starts

FEW = 16  # windows up to which the crop is one flat gather; beyond, a gather of whole rows is faster
DENSE = 64  # a vehicle channel counted cell by cell (bincount) once its vehicles x DENSE reach its cells:
#             np.add.at costs ~55 ns a vehicle, bincount ~0.5 ns a cell (45 windows of 20 x 20 with
#             1,026 vehicles in them: 57 -> 9 us; 512 windows with 512: 30 us by add.at, 83 by bincount)


def observe(beliefs: Beliefs, remove_taken: bool = False) -> np.ndarray:
    """(B, U, C, F, F) float32 observations of every decider (F = beliefs.settings.window; C = 3 for the
    paper's variant, 7 for the global-local one: swarmctl.world.observe_global, 24 for the scales one:
    swarmctl.world.observe_scales); with remove_taken the targets others sit on leave the value channel
    (swarmctl.world.taken; the scales variant has none)."""
    s = beliefs.settings
    if s.variant == SCALES_VARIANT:
        from swarmctl.world.observe_scales import observe_scales

        return observe_scales(beliefs)
    if s.variant != PAPER_VARIANT:
        from swarmctl.world.observe_global import observe_global_local

        return observe_global_local(beliefs, remove_taken)
    value = beliefs.value_channel(remove_taken)
    crews = beliefs.crews
    if crews is not None:
        return _build_few(value, crews, s.window, s.rho)
    return _build_batched(value, beliefs.pos, beliefs.positions, beliefs.others, s.window, s.rho)


def build_observations(
    value: np.ndarray, pos: np.ndarray, positions: np.ndarray, others: np.ndarray, window: int, rho: float
) -> np.ndarray:
    """Observations from the arrays behind them.

    value: (B, U, W, H) float32 value channels; pos: (B, U, 2) own cells; positions (B, U, N, 2): where
    each decider believes each vehicle is; others (B, U, N) bool: which of them enter the vehicle
    channel (the other vehicles whose position is known). Returns (B, U, 3, F, F) float32.

    For up to SMALL deciders x vehicles the vehicle channels are set from Python ints (_build_few);
    beyond, the vehicle counts are scattered with flat indices (counted cell by cell where the windows
    hold many vehicles: DENSE), and so is the window for up to FEW of them: a fixed handful of numpy
    calls whatever the batch (at batch 1 the number of calls is the cost)."""
    if positions.size <= 2 * SMALL:
        n = pos.shape[0] * pos.shape[1]
        own, rows = pos.reshape(n, 2).tolist(), positions.reshape(n, -1, 2).tolist()  # (x, y) lists
        known = others.reshape(n, -1).tolist()
        crews = [(xy, False, [(*c, False) for c, k in zip(row, m) if k]) for xy, row, m in zip(own, rows, known)]
        return _build_few(value, crews, window, rho)
    return _build_batched(value, pos, positions, others, window, rho)


def _padded(value: np.ndarray, window: int, rho: float) -> np.ndarray:
    """(B * U, max(W, F), max(H, F)) value channels, the cells beyond a map shorter than F read -rho."""
    b, u, w, h = value.shape
    pw, ph = max(w, window), max(h, window)
    if (pw, ph) == (w, h):
        return value.reshape(b * u, w, h)
    padded = np.full((b * u, pw, ph), -rho, dtype=np.float32)
    padded[:, :w, :h] = value.reshape(b * u, w, h)
    return padded


def _build_few(value: np.ndarray, crews: Sequence[Crew], window: int, rho: float) -> np.ndarray:
    """build_observations for a few deciders: `crews` holds, flat over (B, U), each decider's own cell,
    a flag unused here, and the (x, y, flag) of the other vehicles it knows, as Python ints (the form of
    Beliefs.crews). Corners, the own cell and the
    vehicle counts are Python arithmetic, each written as a scalar; the window is a slice per decider."""
    b, u, w, h = value.shape
    f, n = window, b * u
    ff = f * f
    obs = np.zeros((n, 3, f, f), dtype=np.float32)
    covers = w <= f and h <= f  # one window covers the map: every corner is (0, 0)
    if w == f and h == f:
        obs[:, 2] = value.reshape(n, w, h)
    elif covers:
        obs[:, 2] = -rho
        obs[:, 2, :w, :h] = value.reshape(n, w, h)
    else:
        padded = _padded(value, f, rho)
    limit_x, limit_y = max(w - f, 0), max(h - f, 0)
    flat = obs.reshape(-1)  # a few cells: one scalar write each is cheaper than one scatter
    for i, ((x, y), _, seen) in enumerate(crews):
        cx, cy = min(max(x - f // 2, 0), limit_x), min(max(y - f // 2, 0), limit_y)
        if not covers:
            obs[i, 2] = padded[i, cx : cx + f, cy : cy + f]
        base = i * 3 * ff
        flat[base + (x - cx) * f + (y - cy)] = 1.0
        for ox, oy, _ in seen:
            rx, ry = ox - cx, oy - cy
            if covers or (0 <= rx < f and 0 <= ry < f):
                flat[base + ff + rx * f + ry] += 1.0
    return obs.reshape(b, u, 3, f, f)


def _build_batched(
    value: np.ndarray, pos: np.ndarray, positions: np.ndarray, others: np.ndarray, window: int, rho: float
) -> np.ndarray:
    """build_observations in numpy calls whose number does not grow with the batch (the reference
    _build_few is tested against)."""
    b, u, w, h = value.shape
    f = window
    n = b * u
    obs = np.zeros((n, 3, f, f), dtype=np.float32)
    pos = pos.reshape(n, 2)
    if w <= f and h <= f:  # one window covers the map: every corner is (0, 0)
        own = pos
        if w == f and h == f:
            obs[:, 2] = value.reshape(n, w, h)
        else:
            obs[:, 2] = -rho
            obs[:, 2, :w, :h] = value.reshape(n, w, h)
        rel, visible = positions.reshape(n, -1, 2), others.reshape(n, -1)
    else:
        corner = np.minimum(np.maximum(pos - f // 2, 0), _corner_limit(w, h, f))  # ufuncs: no np.clip wrapper
        padded = _padded(value, f, rho)
        pw, ph = padded.shape[1:]
        if n <= FEW:  # one flat gather (a few numpy calls)
            start = block_starts(n, pw * ph) + corner[:, 0] * ph + corner[:, 1]
            np.take(padded.reshape(-1), start[:, None, None] + _crop_offsets(f, ph), out=obs[:, 2], mode="clip")
        else:  # whole rows of the window at a time (2.3x faster than the flat gather at 640 windows)
            views = sliding_window_view(padded.reshape(n, pw, ph), (f, f), axis=(1, 2))
            obs[:, 2] = views[block_starts(n, 1), corner[:, 0], corner[:, 1]]
        own = pos - corner
        rel = positions.reshape(n, -1, 2) - corner[:, None, :]
        visible = others.reshape(n, -1) & np.logical_and.reduce((rel >= 0) & (rel < f), axis=-1)
    obs[block_starts(n, 1), 0, own[:, 0], own[:, 1]] = 1.0  # channel 0: the own cell
    seen = np.count_nonzero(visible)
    if seen * DENSE >= n * f * f:  # channel 1 from a count of every cell (small ints: exact as float32)
        cells = block_starts(n, f * f)[:, None] + rel[..., 0] * f + rel[..., 1]
        obs[:, 1] = np.bincount(cells[visible], minlength=n * f * f).reshape(n, f, f)
    elif seen:  # a few vehicles in many windows: one count per vehicle on its cell
        cells = block_starts(n, 3 * f * f)[:, None] + (f * f + rel[..., 0] * f + rel[..., 1])
        np.add.at(obs.reshape(-1), cells[visible], 1.0)
    return obs.reshape(b, u, 3, f, f)


@lru_cache(maxsize=64)
def _crop_offsets(window: int, height: int) -> np.ndarray:
    """(F, F) flat offsets of a window's cells from its lower corner in a map of `height` rows per x."""
    a = np.arange(window)
    offsets = a[:, None] * height + a[None, :]
    offsets.setflags(write=False)
    return offsets


@lru_cache(maxsize=64)
def _corner_limit(width: int, height: int, window: int) -> np.ndarray:
    """The largest window corner per axis (2,): W - F and H - F, 0 along an axis shorter than F."""
    limit = np.array([max(width - window, 0), max(height - window, 0)])
    limit.setflags(write=False)
    return limit
