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

from collections.abc import Sequence
from functools import lru_cache
from typing import Protocol

import numpy as np

from swarmctl.policy.hover import FIRST, NO, parks
from swarmctl.world.beliefs import Beliefs, Crew
from swarmctl.world.moves import MOVES, N_ACTIONS, STAY, block_starts, move_table


class Policy(Protocol):
    name: str

    def reset(self, beliefs: Beliefs, seed: int) -> None: ...

    def act(self, beliefs: Beliefs) -> np.ndarray: ...


_STAY_ONLY = np.arange(len(MOVES)) == STAY
_STAY_ONLY.setflags(write=False)

# The rules and the draw below call numpy's ufuncs and their reduce/accumulate methods directly: at
# batch 1 a decision is a few dozen tiny array operations, and the wrappers (np.clip, ndarray.any,
# .max, .sum, .cumsum) cost more than the arithmetic. The results are the same bits.
_any, _all = np.logical_or.reduce, np.logical_and.reduce


def allowed_moves(beliefs: Beliefs, hover: bool | str = True, mask: bool = True, hold: int | None = None) -> np.ndarray:
    """(B, U, 5) bool: the moves the decision rules allow.

    hover (a rule of swarmctl.policy.hover; True is `first`, False `no`): a decider that parks on a
    target may only stay, and any other may not stay. mask: no move off the map or into a cell the
    decider knows to be blocked (an obstacle, or a vehicle hovering on a target). A decider left with
    no move at all may stay. hold: targets to hold when fewer than the vehicles (hover.park_allowed)."""
    rule = hover if isinstance(hover, str) else (FIRST if hover else NO)
    parked = None if rule == NO else (beliefs.hovering_self if rule == FIRST else parks(beliefs, rule, hold))
    crews = beliefs.crews
    if crews is not None:
        return _allowed_few(beliefs, crews, parked, mask)
    return _allowed_batched(beliefs, parked, mask)


def _allowed_batched(beliefs: Beliefs, parked: np.ndarray | None, mask: bool) -> np.ndarray:
    """allowed_moves in numpy calls whose number does not grow with the batch (the reference
    _allowed_few is tested against)."""
    b, u = beliefs.batch, beliefs.deciders
    if mask:
        w, h = beliefs.width, beliefs.height
        pos = beliefs.pos
        dest = move_table(w, h).reshape(w, h, -1)[pos[..., 0], pos[..., 1]]  # (B, U, 5) flat cells, -1 off the map
        allowed: np.ndarray = dest >= 0
        if beliefs.any_obstacle:  # a move off the map reads some other cell here: it is refused already
            rows = block_starts(b * u, w * h).reshape(b, u, 1)
            allowed &= ~beliefs.obstacles.reshape(-1)[rows + dest]
        held = beliefs.others & beliefs.hovering  # (B, U, N): the cells they hover on are blocked
        if _any(held, axis=None):
            cells = np.where(held, beliefs.positions[..., 0] * h + beliefs.positions[..., 1], -2)
            allowed &= ~_any(dest[..., None] == cells[:, :, None, :], axis=-1)
    else:
        allowed = np.ones((b, u, len(MOVES)), dtype=bool)
    if parked is not None:
        here = parked
        allowed[..., STAY] = here
        if _any(here, axis=None):
            allowed[here] = _STAY_ONLY
    some = _any(allowed, axis=-1)
    if not _all(some, axis=None):
        allowed[..., STAY] |= ~some
    return allowed


@lru_cache(maxsize=16)
def _destinations(width: int, height: int) -> list[list[int]]:
    """move_table as Python lists: per flat cell, the flat cell of each move, -1 off the map."""
    result: list[list[int]] = move_table(width, height).tolist()
    return result


def _allowed_few(beliefs: Beliefs, crews: Sequence[Crew], parked: np.ndarray | None, mask: bool) -> np.ndarray:
    """allowed_moves for a few deciders, from Beliefs.crews (Python ints): the same rules."""
    hover = parked is not None
    parks_here = parked.reshape(-1).tolist() if parked is not None else None
    h = beliefs.height
    size = beliefs.width * h
    table = _destinations(beliefs.width, h)
    obstacles = beliefs.obstacles.reshape(-1) if mask and beliefs.any_obstacle else None
    rows = []
    for i, ((x, y), _, known) in enumerate(crews):
        if parks_here is not None and parks_here[i]:
            rows.append(_STAY_ONLY_ROW)
            continue
        if mask:
            row = [c >= 0 for c in table[x * h + y]]
            held = [hx * h + hy for hx, hy, hovers in known if hovers]
            if held or obstacles is not None:
                for a, c in enumerate(table[x * h + y]):
                    if row[a] and (c in held or (obstacles is not None and obstacles[i * size + c])):
                        row[a] = False
        else:
            row = [True] * N_ACTIONS
        if hover:
            row[STAY] = False
        if not any(row):
            row[STAY] = True
        rows.append(row)
    return np.array(rows, dtype=bool).reshape(beliefs.batch, beliefs.deciders, N_ACTIONS)


_STAY_ONLY_ROW = _STAY_ONLY.tolist()


def softmax_sample(q: np.ndarray, tau: float, u: np.ndarray) -> np.ndarray:
    """One action per row from softmax(q / tau); q is (N, A), u (N,) uniforms in [0, 1)."""
    z = (q - np.maximum.reduce(q, axis=1, keepdims=True)) / tau
    p = np.exp(z, out=z)
    p /= np.add.reduce(p, axis=1, keepdims=True)
    below = np.add.accumulate(p, axis=1) < np.asarray(u).reshape(-1, 1)
    result: np.ndarray = np.minimum(np.add.reduce(below, axis=1), q.shape[1] - 1)
    return result


def choose(q: np.ndarray, allowed: np.ndarray, tau: float | None, u: np.ndarray) -> np.ndarray:
    """Moves (B, U) from Q-values (B, U, 5) among the allowed moves: softmax(Q / tau) sampled with the
    uniforms u (B, U), or argmax when tau is None."""
    b, n, a = q.shape
    q = np.where(allowed, q, -np.inf)
    if tau is None:
        result: np.ndarray = q.argmax(axis=-1)
        return result
    return softmax_sample(q.reshape(b * n, a), tau, np.asarray(u).reshape(-1)).reshape(b, n)
