"""Taken targets: a target another vehicle sits on is no longer worth going to.

LA(n) in the paper removes a target a vehicle hovers on from the others' value maps. We do the same
for every policy that wants it (LA(n), and the Q-network's value channel when the world is built
with `remove_taken`): the explored cells whose value the taken target explains (its bump) read the
value of the nearest target that is still free instead, 0 when there is none.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import distance_transform_edt

_FAR = 1.0e4  # sampling along batch axes, so distance transforms never cross maps


def value_bump(dist: np.ndarray, sigma2: float, cutoff: float) -> np.ndarray:
    """phi at distance `dist` from a target: exp(-d^2 / (2 sigma2)), 0 below the cut-off."""
    phi = np.exp(-(dist**2) / (2.0 * sigma2))
    phi[phi < cutoff] = 0.0
    return phi


def remove_taken_targets(
    phi_hat: np.ndarray, explored: np.ndarray, taken: np.ndarray, sigma2: float, cutoff: float, tolerance: float = 1e-6
) -> np.ndarray:
    """phi_hat (..., W, H) with the targets in `taken` removed.

    phi_hat: known phi (1 on unexplored cells); explored: bool, same shape; taken: bool, the target
    cells (explored, phi 1) someone else holds. Leading axes are independent maps. A cell belongs to
    a taken target's bump when its phi is at most that bump's value + `tolerance` (raise it for
    quantised phi). When every map is the same the result is one map, broadcast (read-only)."""
    if not taken.any():
        return phi_hat
    lead = phi_hat.shape[:-2]
    if len(lead) and int(np.prod(lead)) > 1:  # many maps, often equal (agents sharing knowledge): each once
        flat = [a.reshape(-1, *a.shape[-2:]) for a in (phi_hat, explored, taken)]
        if all(_all_equal(a) for a in flat):  # all the same: one map, shared
            p, e, t = (a[:1] for a in flat)
            done = _remove(p, e, t, sigma2, cutoff, tolerance)
            return np.broadcast_to(done, flat[0].shape).reshape(phi_hat.shape)
        first: dict[bytes, int] = {}
        which = np.array(
            [first.setdefault(p.tobytes() + e.tobytes() + t.tobytes(), len(first)) for p, e, t in zip(*flat)]
        )
        if len(first) < which.size:
            keep = np.unique(which, return_index=True)[1]
            p, e, t = (a[keep] for a in flat)
            done = _remove(p, e, t, sigma2, cutoff, tolerance)
            out: np.ndarray = done[which].reshape(phi_hat.shape)
            return out
    return _remove(phi_hat, explored, taken, sigma2, cutoff, tolerance)


def _all_equal(maps: np.ndarray) -> bool:
    """Whether the maps (M, W, H) are all the same (at once when they are one map broadcast)."""
    return maps.strides[0] == 0 or bool(np.logical_and.reduce(maps == maps[:1], axis=None))


def _remove(
    phi_hat: np.ndarray, explored: np.ndarray, taken: np.ndarray, sigma2: float, cutoff: float, tolerance: float
) -> np.ndarray:
    if phi_hat.ndim > 2 and phi_hat.size == phi_hat.shape[-2] * phi_hat.shape[-1]:  # one map: transformed in 2-D
        p, e, t = (a.reshape(a.shape[-2:]) for a in (phi_hat, explored, taken))
        return _remove(p, e, t, sigma2, cutoff, tolerance).reshape(phi_hat.shape)
    sampling = [_FAR] * (phi_hat.ndim - 2) + [1.0, 1.0]
    remaining = explored & (phi_hat >= 1.0) & ~taken
    gone = value_bump(distance_transform_edt(~taken, sampling=sampling), sigma2, cutoff)
    left = (
        value_bump(distance_transform_edt(~remaining, sampling=sampling), sigma2, cutoff)
        if remaining.any()
        else np.zeros_like(gone)
    )
    explained = explored & (gone > 0) & (phi_hat <= gone + tolerance)
    return np.where(explained, left, phi_hat).astype(phi_hat.dtype)
