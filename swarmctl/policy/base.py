"""The interface every policy shares, learned or not, and the decision rules they apply.

A policy acts for every decider of a batch of beliefs at once (swarmctl.world.beliefs):

    policy.reset(beliefs, seed)      # at the start of a batch of episodes (or of a mission)
    moves = policy.act(beliefs)      # (B, U) ints in 0..4, one per decider

Beliefs hold only what the vehicles know (explored cells, known values, obstacles and targets,
where they believe the others are); the simulator (SearchEnv.beliefs) and the controller
(swarmctl.knowledge.model.beliefs_from_knowledge) build them the same way. The oracle is not a
policy: it is a bound computed from the truth (swarmctl.policy.oracle). Random draws come from
swarmctl.policy.draws, keyed by (seed, episode, step, vehicle), so a batch's size never changes them.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from swarmctl.world.beliefs import Beliefs
from swarmctl.world.moves import MOVES, STAY, move_table


class Policy(Protocol):
    name: str

    def reset(self, beliefs: Beliefs, seed: int) -> None: ...

    def act(self, beliefs: Beliefs) -> np.ndarray: ...


def allowed_moves(beliefs: Beliefs, hover: bool = True, mask: bool = True) -> np.ndarray:
    """(B, U, 5) bool: the moves the decision rules allow.

    hover: a decider that hovers on a target may only stay, and any other may not stay. mask: no move
    off the map or into a cell the decider knows to be blocked (an obstacle, or a vehicle hovering on
    a target). A decider left with no move at all may stay."""
    b, u = beliefs.batch, beliefs.deciders
    if mask:
        w, h = beliefs.width, beliefs.height
        pos = beliefs.pos
        dest = move_table(w, h)[pos[..., 0] * h + pos[..., 1]]  # (B, U, 5) flat cells, -1 off the map
        allowed = dest >= 0
        known = beliefs.obstacles
        if known.any():
            flat = known.reshape(b, u, w * h)
            allowed &= ~flat[np.arange(b)[:, None, None], np.arange(u)[None, :, None], dest]
        held = beliefs.others & beliefs.hovering  # (B, U, N): the cells they hover on are blocked
        if held.any():
            cells = np.where(held, beliefs.positions[..., 0] * h + beliefs.positions[..., 1], -2)
            allowed &= ~(dest[..., None] == cells[:, :, None, :]).any(-1)
    else:
        allowed = np.ones((b, u, len(MOVES)), dtype=bool)
    if hover:
        here = beliefs.hovering_self
        allowed[..., STAY] = here
        allowed[here] = np.arange(len(MOVES)) == STAY
    allowed[~allowed.any(-1), STAY] = True
    return allowed


def softmax_sample(q: np.ndarray, tau: float, u: np.ndarray) -> np.ndarray:
    """One action per row from softmax(q / tau); q is (N, A), u (N,) uniforms in [0, 1)."""
    z = (q - q.max(axis=1, keepdims=True)) / tau
    p = np.exp(z)
    p /= p.sum(axis=1, keepdims=True)
    return np.minimum((p.cumsum(axis=1) < np.asarray(u).reshape(-1, 1)).sum(axis=1), q.shape[1] - 1)


def choose(q: np.ndarray, allowed: np.ndarray, tau: float | None, u: np.ndarray) -> np.ndarray:
    """Moves (B, U) from Q-values (B, U, 5) among the allowed moves: softmax(Q / tau) sampled with the
    uniforms u (B, U), or argmax when tau is None."""
    b, n, a = q.shape
    q = np.where(allowed, q, -np.inf)
    if tau is None:
        return q.argmax(axis=-1)
    return softmax_sample(q.reshape(b * n, a), tau, np.asarray(u).reshape(-1)).reshape(b, n)
