"""The per-vehicle observation: 3 x F x F, one builder for simulator, planners and controller.

Channels: 0 own position (one-hot), 1 other vehicles (count per cell, as known to the vehicle),
2 value: phi_hat - rho * omega_hat (unexplored cells read 1, explored cells phi - rho * obstacle).
The window's lower corner is clip(x - F//2, 0, W - F) per axis; along an axis shorter than F the
window starts at 0 and the cells beyond the map are padded as obstacles (value -rho).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view


def window_corners(pos: np.ndarray, width: int, height: int, window: int) -> np.ndarray:
    """Lower corner of each vehicle's window; `pos` is (..., 2)."""
    half = window // 2
    cx = np.clip(pos[..., 0] - half, 0, max(width - window, 0))
    cy = np.clip(pos[..., 1] - half, 0, max(height - window, 0))
    return np.stack([cx, cy], axis=-1)


def build_observations(
    value: np.ndarray, pos: np.ndarray, known_pos: np.ndarray, window: int, rho: float
) -> np.ndarray:
    """Observations for every vehicle.

    value: (B, U, W, H) float32, each vehicle's value channel (phi_hat - rho * omega_hat).
    pos: (B, U, 2) own cells. known_pos: (B, U, U, 2), known_pos[b, v, u] is where vehicle v
    believes vehicle u is (-1 when unknown); the diagonal is ignored.
    Returns (B, U, 3, F, F) float32.
    """
    b, u, w, h = value.shape
    f = window
    n = b * u
    obs = np.zeros((n, 3, f, f), dtype=np.float32)
    corner = window_corners(pos, w, h, f).reshape(n, 2)
    idx = np.arange(n)
    if w == f and h == f:
        obs[:, 2] = value.reshape(n, w, h)
    else:
        pw, ph = max(w, f), max(h, f)
        if (pw, ph) != (w, h):
            padded = np.full((n, pw, ph), -rho, dtype=np.float32)
            padded[:, :w, :h] = value.reshape(n, w, h)
        else:
            padded = value.reshape(n, w, h)
        views = sliding_window_view(padded, (f, f), axis=(1, 2))
        obs[:, 2] = views[idx, corner[:, 0], corner[:, 1]]

    own = pos.reshape(n, 2) - corner
    obs[idx, 0, own[:, 0], own[:, 1]] = 1.0

    # others: known_pos[b, v, j] for j != v, relative to v's window
    known = known_pos.reshape(n, u, 2)
    others = known - corner[:, None, :]
    not_self = ~np.eye(u, dtype=bool)[np.tile(np.arange(u), b)]  # (n, u)
    visible = (
        not_self
        & (known[..., 0] >= 0)
        & (others[..., 0] >= 0)
        & (others[..., 0] < f)
        & (others[..., 1] >= 0)
        & (others[..., 1] < f)
    )
    rows = np.broadcast_to(idx[:, None], (n, u))[visible]
    np.add.at(obs[:, 1], (rows, others[..., 0][visible], others[..., 1][visible]), 1.0)
    return obs.reshape(b, u, 3, f, f)
