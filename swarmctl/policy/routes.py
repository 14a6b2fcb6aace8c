"""Routes of cells flown as a policy (`pattern:NAME`): each vehicle follows its own list of cells.

A mission flying a search pattern (`[mission] policy = "pattern:parallel"` with `lkp`) hands every
vehicle its share of the pattern as cells (swarmctl.mission.plan turns the pattern's routes into them);
the policy flies those cells through the same beliefs, guard and knowledge sharing as every other:

- a cell of a vehicle's route is done once the vehicle reaches it or the cell is explored already (by
  this vehicle's footprint or by what the others shared), or when no path over the cells the decider
  knows to be passable reaches it; the vehicle steps along a shortest path over those cells (round
  known obstacles and vehicles hovering on targets) to the first cell of its route not done;
- it never steps into a cell another vehicle holds now, nor into one an earlier decider of the batch
  moves to this step, so the guard has nothing to refuse;
- once the hover rule lets the swarm park on the targets it knows and one of them is free, or once its
  route is done, a vehicle takes the coordinated planner's move (swarmctl.policy.coordinated): the
  known targets are reached first, and a vehicle whose route is done never idles: it searches on for
  what the pattern left unexplored.

Each vehicle's place on its route is the policy's state, per episode, kept from step to step.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from swarmctl.policy.coordinated import CoordinatedPolicy
from swarmctl.policy.draws import NAVIGATE, Draws
from swarmctl.policy.hover import DEFER, parks, swarm_parking
from swarmctl.world.beliefs import Beliefs
from swarmctl.world.moves import MOVES, STAY
from swarmctl.world.paths import UNREACHABLE, grid_distances

ROUTE_PATTERNS = ("expanding-square", "sector", "parallel")  # the IAMSAR patterns swarmctl.geo.patterns plans
ROUTE_PREFIX = "pattern"  # a route policy's spec: pattern:NAME


class RoutePolicy:
    """Each vehicle flies its own route of cells, then the coordinated planner's moves (module docstring).

    routes[v] is vehicle v's route, (L, 2) cells in order (v: its index in the swarm); a vehicle with
    no route, or an empty one, takes the coordinated planner's moves from the start."""

    def __init__(self, routes: Sequence[npt.ArrayLike] = (), name: str = "routes", hover: str = DEFER):
        self.name = name
        self.hover = hover  # the hover rule (swarmctl.policy.hover), the fallback's too
        self.hold: int | None = None  # targets the mission holds, when fewer than its vehicles
        self.fallback = CoordinatedPolicy(hover=hover)
        self.seed = 0
        self.set_routes(routes)

    def set_routes(self, routes: Sequence[npt.ArrayLike]) -> None:
        """The vehicles' routes (routes[v]: (L, 2) cells); every vehicle starts at its route's first cell."""
        self.routes = [np.asarray(r, dtype=np.int64).reshape(-1, 2) for r in routes]
        self._index: dict[int, np.ndarray] = {}

    def reset(self, beliefs: Beliefs, seed: int) -> None:
        self.seed = int(seed)
        self.fallback.reset(beliefs, seed)
        self._index = {int(e): np.zeros(beliefs.vehicles, dtype=np.int64) for e in beliefs.episodes}

    def _progress(self, episode: int, vehicles: int) -> np.ndarray:
        """Each vehicle's next route cell in `episode` (an episode the reset did not see starts at 0)."""
        if episode not in self._index:
            self._index[episode] = np.zeros(vehicles, dtype=np.int64)
        return self._index[episode]

    def goals(self, beliefs: Beliefs, passable: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each decider's next route cell (B, U, 2) and whether it has one (B, U), after moving every
        decider's place past the cells done (reached, explored, or out of reach over `passable`)."""
        b, u = beliefs.batch, beliefs.deciders
        pos = beliefs.pos
        reach = grid_distances(passable, _sources(pos.reshape(b * u, 2), passable.shape)).reshape(
            b, u, beliefs.width, beliefs.height
        )
        goals = pos.copy()
        following = np.zeros((b, u), dtype=bool)
        explored = beliefs.explored
        for bi in range(b):
            index = self._progress(int(beliefs.episodes[bi]), beliefs.vehicles)
            for ui in range(u):
                v = int(beliefs.me[bi, ui])
                route = self.routes[v] if v < len(self.routes) else np.zeros((0, 2), dtype=np.int64)
                i = int(index[v])
                while i < len(route):
                    x, y = int(route[i, 0]), int(route[i, 1])
                    inside = 0 <= x < beliefs.width and 0 <= y < beliefs.height
                    here = x == pos[bi, ui, 0] and y == pos[bi, ui, 1]
                    if inside and not here and not explored[bi, ui, x, y] and reach[bi, ui, x, y] < UNREACHABLE:
                        break
                    i += 1
                index[v] = i
                if i < len(route):
                    goals[bi, ui] = route[i]
                    following[bi, ui] = True
        return goals, following

    def act(self, beliefs: Beliefs) -> np.ndarray:
        b, u = beliefs.batch, beliefs.deciders
        w, h = beliefs.width, beliefs.height
        passable = ~beliefs.blocked.reshape(b * u, w, h)
        goals, following = self.goals(beliefs, passable)
        targets = beliefs.targets
        free_targets = (targets & ~beliefs.hover_cells).any((2, 3))
        to_targets = swarm_parking(beliefs, self.hover, self.hold) & free_targets
        following &= ~to_targets
        parked = parks(beliefs, self.hover, self.hold)
        following &= ~parked
        moves = np.full((b, u), STAY, dtype=np.int64)
        pos = beliefs.pos
        reserved = np.zeros((b, w, h), dtype=bool)
        others = ~following & ~parked
        if others.any():
            self.fallback.hover, self.fallback.hold = self.hover, self.hold
            planned = self.fallback.act(beliefs)
            moves = np.where(others, planned, moves)
            bi, ui = np.nonzero(others)
            dest = pos[bi, ui] + MOVES[moves[bi, ui]]
            reserved[bi, dest[:, 0], dest[:, 1]] = True
        if not following.any():
            return moves
        fi, fu = np.nonzero(following)
        rows = fi * u + fu
        to_goal = grid_distances(passable[rows], _sources(goals[fi, fu], (len(rows), w, h)))
        ties = Draws(self.seed, beliefs).deciders(NAVIGATE, len(MOVES))
        held = _held_by_others(beliefs)
        order = np.lexsort((beliefs.me[fi, fu], fi))  # mission order within each batch
        for k in order:
            bk, uk = int(fi[k]), int(fu[k])
            cand = pos[bk, uk] + MOVES  # (5, 2)
            inside = (cand[:, 0] >= 0) & (cand[:, 0] < w) & (cand[:, 1] >= 0) & (cand[:, 1] < h)
            cx, cy = np.clip(cand[:, 0], 0, w - 1), np.clip(cand[:, 1], 0, h - 1)
            d = to_goal[k, cx, cy].astype(np.float64)
            free = inside & ~held[bk, uk, cx, cy] & ~reserved[bk, cx, cy]
            free[STAY] = True
            d[~free | (d >= UNREACHABLE)] = np.inf
            d[STAY] = min(d[STAY], float(UNREACHABLE))  # staying is always possible
            choice = int(np.argmax((d == d.min()) * (ties[bk, uk] + 1.0)))
            moves[bk, uk] = choice
            reserved[bk, cx[choice], cy[choice]] = True
        return moves


def _sources(cells: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """(N, W, H) bool: cell i of `cells` (N, 2) set in map i."""
    src = np.zeros(shape, dtype=bool)
    src[np.arange(len(cells)), cells[:, 0], cells[:, 1]] = True
    return src


def _held_by_others(beliefs: Beliefs) -> np.ndarray:
    """(B, U, W, H) bool: the cells the other vehicles hold now, as each decider knows them."""
    b, u = beliefs.batch, beliefs.deciders
    held = np.zeros((b, u, beliefs.width, beliefs.height), dtype=bool)
    bi, ui, ni = np.nonzero(beliefs.others)
    cells = beliefs.positions[bi, ui, ni]
    held[bi, ui, cells[:, 0], cells[:, 1]] = True
    return held
