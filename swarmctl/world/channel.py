"""Packet-error probability between two vehicles as a function of distance.

Model: air-to-air log-distance path loss with log-normal shadowing, after
Liu et al. (IEEE Access 7:98832, 2019), Rayleigh small-scale fading, and an outage threshold for a
rate-2/3 code:

    PL(d)  = PL0 + 10 n log10(d / 1 m) + X,      X ~ N(0, sigma^2) dB
    SNR    = P_tx - PL(d) - N0 + 10 log10(|h|^2), |h|^2 ~ Exp(1)          (Rayleigh)
    error  <=> log2(1 + SNR) < R  <=>  SNR < 2^R - 1
    PER(d) = E_X[ 1 - exp(-(2^R - 1) / mean_snr(d, X)) ]

P_tx = 20 dBm, N0 = -76 dBm and R = 2/3 are the paper's. The paper does not give the exponent or the
shadowing: we assume n = 2.2 and sigma = 3 dB (typical of Liu et al.'s low-altitude air-to-air
measurements) and fit the reference loss PL0 so that PER(110 m) = 0.5, the paper's calibration point.
The expectation over X uses 40-point Gauss-Hermite quadrature. Distances below 1 m are taken as 1 m.

Each message is lost independently, by a draw keyed by (seed, episode, step, sender, receiver) on the
world's LOSSES stream (swarmctl.world.draws), so an episode loses the same messages whatever batch or
chunk it runs in.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.optimize import brentq

from swarmctl.world.draws import LOSSES, uniform

P_TX_DBM = 20.0
NOISE_DBM = -76.0
CODE_RATE = 2.0 / 3.0
PATH_LOSS_EXPONENT = 2.2
SHADOWING_DB = 3.0
HALF_LOSS_DISTANCE_M = 110.0

_SNR_THRESHOLD = 2.0**CODE_RATE - 1.0
_GH_X, _GH_W = np.polynomial.hermite.hermgauss(40)
_SHADOW_DB = np.sqrt(2.0) * SHADOWING_DB * _GH_X  # quadrature nodes for X ~ N(0, sigma^2)
_SHADOW_W = _GH_W / np.sqrt(np.pi)


def _per(distance_m: np.ndarray, pl0_db: float) -> np.ndarray:
    d = np.maximum(np.asarray(distance_m, dtype=np.float64), 1.0)
    mean_snr_db = P_TX_DBM - NOISE_DBM - pl0_db - 10.0 * PATH_LOSS_EXPONENT * np.log10(d)
    snr = 10.0 ** ((mean_snr_db[..., None] - _SHADOW_DB) / 10.0)
    result: np.ndarray = (1.0 - np.exp(-_SNR_THRESHOLD / snr)) @ _SHADOW_W
    return result


@lru_cache(maxsize=1)
def reference_path_loss_db() -> float:
    """PL0 (dB at 1 m) fitted so that the packet-error probability is 0.5 at 110 m."""
    return float(brentq(lambda pl0: _per(np.array(HALF_LOSS_DISTANCE_M), pl0) - 0.5, 0.0, 150.0))


def packet_error_probability(distance_m: np.ndarray | float) -> np.ndarray:
    """Probability that one packet is lost between two vehicles `distance_m` metres apart."""
    return _per(np.asarray(distance_m, dtype=np.float64), reference_path_loss_db())


class Channel:
    """Per-message loss between vehicles: 'ideal' (never lost), 'none' (always lost),
    'model' (distance-dependent, above) or 'fixed' (constant probability `loss`)."""

    def __init__(self, kind: str = "ideal", cell_size: float = 10.0, loss: float = 0.0):
        self.kind, self.cell_size, self.loss = kind, float(cell_size), float(loss)

    def loss_probability(self, distance_cells: np.ndarray) -> np.ndarray:
        """Loss probability for messages between vehicles `distance_cells` apart (any shape)."""
        d = np.asarray(distance_cells, dtype=np.float64)
        if self.kind == "ideal":
            return np.zeros_like(d)
        if self.kind == "none":
            return np.ones_like(d)
        if self.kind == "fixed":
            return np.full_like(d, self.loss)
        return packet_error_probability(d * self.cell_size)

    def lost(self, distance_cells: np.ndarray, seed: int, episodes: np.ndarray, step: int) -> np.ndarray:
        """(B, receiver, sender) bool: which of the messages sent at `step` are lost, for vehicles
        `distance_cells` (B, U, U) apart in episodes `episodes` (B,) ids of the world seeded `seed`. Each
        loss is its own draw keyed by (seed, episode, step, sender, receiver), so it does not depend on
        the other episodes of the batch. The diagonal (a vehicle's own message) is drawn like the rest:
        the caller keeps it."""
        d = np.asarray(distance_cells, dtype=np.float64)
        b, u = d.shape[0], d.shape[1]
        if self.kind == "ideal":
            return np.zeros(d.shape, dtype=bool)
        if self.kind == "none":
            return np.ones(d.shape, dtype=bool)
        senders = np.broadcast_to(np.arange(u), (b, u))
        draws = uniform(seed, episodes, step, senders, LOSSES, (u,))  # [b, sender, receiver]
        return draws.transpose(0, 2, 1) < self.loss_probability(d)
