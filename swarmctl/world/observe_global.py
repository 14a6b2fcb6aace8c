"""The global-local observation: the paper's local window plus the whole map, pooled, around the vehicle.

After Theile et al., "UAV Path Planning using Global and Local Map Information with Deep Reinforcement
Learning" (ICAR 2021). The paper's F x F window (swarmctl.world.observe) sees nothing beyond it, so on
a map wider than F a vehicle far from anything its window shows has nothing to go on (the paper's
straggler). This variant adds four channels that see the whole area at any size:

    3 unexplored   fraction of cells not yet explored        (beyond the map: 0)
    4 value        mean of phi_hat - rho * omega_hat          (beyond the map: -rho)
    5 blocked      fraction of cells known blocked            (beyond the map: 1)
    6 others       other vehicles known per cell              (beyond the map: 0)

each averaged over an F x F grid of bins of the (2W - 1) x (2H - 1) area centred on the vehicle (so the
vehicle is always in the middle and every cell of the map is in view), with adaptive-pooling bins:
bin i covers [floor(i S / F), ceil((i + 1) S / F)) of a side of S cells. Channels 0-2 are the paper's.
One (7, F, F) tensor per vehicle, so the replay memory and the batching stay as they are; a network
of this variant (swarmctl.policy.qnet.GlobalLocalQNetwork) splits the channels.
"""

from __future__ import annotations

import numpy as np

from swarmctl.world.beliefs import GLOBAL_LOCAL_VARIANT, Beliefs
from swarmctl.world.observe import build_observations

GLOBAL_LOCAL = GLOBAL_LOCAL_VARIANT
GLOBAL_CHANNELS = ("unexplored", "value", "blocked", "others")
CHANNELS = 3 + len(GLOBAL_CHANNELS)


def bin_edges(cells: int, bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Adaptive-pooling bins of a side of `cells` cells: (starts, ends), each bin at least one cell."""
    i = np.arange(bins)
    return (i * cells) // bins, -((-(i + 1) * cells) // bins)


def pooled_around(maps: np.ndarray, pos: np.ndarray, side: int, fill: np.ndarray) -> np.ndarray:
    """Each map averaged over side x side bins of the (2W - 1) x (2H - 1) area centred on `pos`.

    maps (N, C, W, H) float32; pos (N, 2) cells; fill (C,): what a cell beyond the map counts as.
    Returns (N, C, side, side) float32. One summed-area table per map, four gathers per bin corner."""
    n, c, w, h = maps.shape
    sat = np.zeros((n, c, w + 1, h + 1), dtype=np.float64)
    sat[:, :, 1:, 1:] = maps.cumsum(2, dtype=np.float64).cumsum(3)
    sx, ex = bin_edges(2 * w - 1, side)
    sy, ey = bin_edges(2 * h - 1, side)
    x0 = pos[:, 0, None] - (w - 1) + sx[None]  # (N, side) map rows of each bin
    x1 = pos[:, 0, None] - (w - 1) + ex[None]
    y0 = pos[:, 1, None] - (h - 1) + sy[None]
    y1 = pos[:, 1, None] - (h - 1) + ey[None]
    cx0, cx1 = np.clip(x0, 0, w), np.clip(x1, 0, w)
    cy0, cy1 = np.clip(y0, 0, h), np.clip(y1, 0, h)
    ni = np.arange(n)[:, None, None]

    def corner(xs: np.ndarray, ys: np.ndarray) -> np.ndarray:  # (N, side, side, C)
        return sat[ni, :, xs[:, :, None], ys[:, None, :]]

    inside = corner(cx1, cy1) - corner(cx0, cy1) - corner(cx1, cy0) + corner(cx0, cy0)
    area = ((x1 - x0)[:, :, None] * (y1 - y0)[:, None, :]).astype(np.float64)
    area_in = ((cx1 - cx0)[:, :, None] * (cy1 - cy0)[:, None, :]).astype(np.float64)
    total = inside + (area - area_in)[..., None] * fill[None, None, None, :]
    result: np.ndarray = (total / area[..., None]).astype(np.float32).transpose(0, 3, 1, 2)
    return result


def observe_global_local(beliefs: Beliefs, remove_taken: bool = False) -> np.ndarray:
    """(B, U, 7, F, F) float32: the paper's three channels, then the four pooled whole-map channels."""
    s = beliefs.settings
    b, u, w, h = beliefs.explored.shape
    f = s.window
    value = beliefs.value_channel(remove_taken)
    local = build_observations(value, beliefs.pos, beliefs.positions, beliefs.others, f, s.rho)
    maps = np.stack(
        [
            (~beliefs.explored).astype(np.float32),
            value,
            beliefs.blocked.astype(np.float32),
            beliefs.others_count.astype(np.float32),
        ],
        axis=2,
    ).reshape(b * u, len(GLOBAL_CHANNELS), w, h)
    fill = np.array([0.0, -s.rho, 1.0, 0.0])
    pooled = pooled_around(maps, beliefs.pos.reshape(b * u, 2), f, fill).reshape(b, u, -1, f, f)
    return np.concatenate([local, pooled], axis=2)
