"""LA(n), the paper's look-ahead baseline.

Each vehicle, assuming the others stay still, scores every sequence of n moves (5^n) by the sum over
the sequence of phi_hat(cell) / xi(cell), xi = 1 + the others it believes are in the cell; a move off
the map or into a known obstacle makes the sequence -inf. It plays the first move of the best
sequence, ties broken at random. Once on a target it hovers (unless a lower-numbered vehicle is
already there), and a target another vehicle sits on is removed from its value map: explored cells
whose value that target explains read the value of the nearest remaining known target instead. The
cells of vehicles known to hover on a target are blocked like obstacles: they stay there, and the
controller's guard refuses every move into them.

Speed: the scores only need the (2n+1)^2 patch around each vehicle, so all vehicles of all episodes
are scored with one gather of shape (vehicles, 5^n, n) from precomputed patch indices.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from swarmctl.policy.draws import LOOKAHEAD, Draws
from swarmctl.policy.hover import FIRST, parks
from swarmctl.world.beliefs import Beliefs
from swarmctl.world.moves import MOVES, STAY


class LookAhead:
    hover = FIRST  # the hover rule (swarmctl.policy.hover)
    hold: int | None = None  # targets the mission holds, when fewer than its vehicles (hover.park_allowed)

    def __init__(self, depth: int = 4):
        self.depth = depth
        self.name = f"la:{depth}"
        seqs = np.array(list(itertools.product(range(len(MOVES)), repeat=depth)), dtype=np.int64)
        offsets = MOVES[seqs].cumsum(axis=1)  # (S, n, 2)
        self.side = 2 * depth + 1
        self.patch_index = (offsets[..., 0] + depth) * self.side + (offsets[..., 1] + depth)  # (S, n)
        self.first_move = seqs[:, 0]
        self.seed = 0

    def reset(self, beliefs: Beliefs, seed: int) -> None:
        self.seed = int(seed)

    @staticmethod
    def value_maps(beliefs: Beliefs) -> np.ndarray:
        """phi_hat / xi per decider with taken targets removed; -inf where the decider must not go."""
        value = beliefs.phi_without_taken() / (1.0 + beliefs.others_count)
        value[beliefs.explored & beliefs.blocked] = -np.inf
        return value

    def act(self, beliefs: Beliefs) -> np.ndarray:
        b, u, w, h = beliefs.batch, beliefs.deciders, beliefs.width, beliefs.height
        n_veh, d = b * u, self.depth
        value = self.value_maps(beliefs).reshape(n_veh, w, h)
        padded = np.full((n_veh, w + 2 * d, h + 2 * d), -np.inf, dtype=np.float32)
        padded[:, d : d + w, d : d + h] = value
        pos = beliefs.pos.reshape(n_veh, 2)
        views = sliding_window_view(padded, (self.side, self.side), axis=(1, 2))
        patches = views[np.arange(n_veh), pos[:, 0], pos[:, 1]].reshape(n_veh, -1)
        scores = patches[:, self.patch_index].sum(axis=-1)  # (N, S)
        if self.hover != FIRST:  # on a target it may not park on: staying there is not a choice
            moving_on = (beliefs.hovering_self & ~parks(beliefs, self.hover, self.hold)).reshape(-1)
            scores[np.ix_(moving_on, self.first_move == STAY)] = -np.inf
        best = scores.max(axis=1, keepdims=True)
        ties = scores >= best - 1e-6
        draws = Draws(self.seed, beliefs).deciders(LOOKAHEAD, len(self.first_move)).reshape(n_veh, -1)
        choice = np.argmax(ties * (draws + 1.0), axis=1)
        actions = self.first_move[choice].reshape(b, u)
        return np.where(parks(beliefs, self.hover, self.hold), STAY, actions)
