"""The per-vehicle observation: 3 x F x F, one builder for the simulator and the controller.

Channels: 0 own position (one-hot), 1 other vehicles (count per cell, as known to the vehicle),
2 value: phi_hat - rho * omega_hat (unexplored cells read 1, explored cells phi - rho * obstacle).
The window's lower corner is clip(x - F//2, 0, W - F) per axis; along an axis shorter than F the
window starts at 0 and the cells beyond the map are padded as obstacles (value -rho).

`observe(beliefs)` is what every caller uses: the simulator's SearchEnv.observe and the field's
policies build Beliefs first (swarmctl.world.beliefs), so both see the same tensor.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from swarmctl.world.beliefs import PAPER_VARIANT, Beliefs


def window_corners(pos: np.ndarray, width: int, height: int, window: int) -> np.ndarray:
    """Lower corner of each vehicle's window; `pos` is (..., 2)."""
    half = window // 2
    cx = np.clip(pos[..., 0] - half, 0, max(width - window, 0))
    cy = np.clip(pos[..., 1] - half, 0, max(height - window, 0))
    return np.stack([cx, cy], axis=-1)


def observe(beliefs: Beliefs, remove_taken: bool = False) -> np.ndarray:
    """(B, U, C, F, F) float32 observations of every decider (F = beliefs.settings.window; C = 3 for the
    paper's variant, 7 for the global-local one: swarmctl.world.observe_global); with remove_taken the
    targets others sit on leave the value channel (swarmctl.world.taken)."""
    s = beliefs.settings
    if s.variant != PAPER_VARIANT:
        from swarmctl.world.observe_global import observe_global_local

        return observe_global_local(beliefs, remove_taken)
    return build_observations(
        beliefs.value_channel(remove_taken), beliefs.pos, beliefs.positions, beliefs.others, s.window, s.rho
    )


def build_observations(
    value: np.ndarray, pos: np.ndarray, positions: np.ndarray, others: np.ndarray, window: int, rho: float
) -> np.ndarray:
    """Observations from the arrays behind them.

    value: (B, U, W, H) float32 value channels; pos: (B, U, 2) own cells; positions (B, U, N, 2): where
    each decider believes each vehicle is; others (B, U, N) bool: which of them enter the vehicle
    channel (the other vehicles whose position is known). Returns (B, U, 3, F, F) float32."""
    b, u, w, h = value.shape
    f = window
    n = b * u
    obs = np.zeros((n, 3, f, f), dtype=np.float32)
    idx = np.arange(n)
    if w <= f and h <= f:  # one window covers the map: every corner is (0, 0)
        corner = None
        if w == f and h == f:
            obs[:, 2] = value.reshape(n, w, h)
        else:
            obs[:, 2] = -rho
            obs[:, 2, :w, :h] = value.reshape(n, w, h)
    else:
        corner = window_corners(pos, w, h, f).reshape(n, 2)
        pw, ph = max(w, f), max(h, f)
        if (pw, ph) != (w, h):
            padded = np.full((n, pw, ph), -rho, dtype=np.float32)
            padded[:, :w, :h] = value.reshape(n, w, h)
        else:
            padded = value.reshape(n, w, h)
        views = sliding_window_view(padded, (f, f), axis=(1, 2))
        obs[:, 2] = views[idx, corner[:, 0], corner[:, 1]]

    own = pos.reshape(n, 2) if corner is None else pos.reshape(n, 2) - corner
    obs[idx, 0, own[:, 0], own[:, 1]] = 1.0

    if corner is None:  # every known position lies in the window
        rel, visible = positions.reshape(n, -1, 2), others.reshape(n, -1)
    else:
        rel = positions.reshape(n, -1, 2) - corner[:, None, :]
        visible = others.reshape(n, -1) & (rel >= 0).all(-1) & (rel < f).all(-1)
    rows, who = np.nonzero(visible)
    if len(rows):  # one count per vehicle on its cell of channel 1
        np.add.at(obs.reshape(-1), ((rows * 3 + 1) * f + rel[rows, who, 0]) * f + rel[rows, who, 1], 1.0)
    return obs.reshape(b, u, 3, f, f)
