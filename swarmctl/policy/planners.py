"""Non-learned planners on beliefs: random, frontier exploration and lawnmower (boustrophedon).

Frontier and lawnmower plan the whole swarm as each deciding vehicle knows it, and the decider plays
its own part of that plan: the vehicles it knows of and that do not hover on a target are taken in
mission order; known targets nobody hovers on go to them nearest pair first (greedy assignment, one
vehicle per target); the others go to the nearest unexplored cell (frontier) or along their sweep
(lawnmower), each unexplored goal claiming a disc that later vehicles avoid when they can. Paths are
BFS shortest paths over the cells the decider does not know to be blocked (obstacles, and the cells
of vehicles hovering on a target: they stay, and the guard refuses every move into them). A decider
that hovers stays.

When every decider of a batch holds the same beliefs (ideal sharing), the plan is made once for the
batch; ties are broken with draws keyed by the vehicle being planned (swarmctl.policy.draws), so the
plan is the same whoever makes it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from swarmctl.policy.draws import CLAIMS, NAVIGATE, RANDOM, Draws, uniform
from swarmctl.policy.hover import FIRST, NO, parks, swarm_parking
from swarmctl.world.beliefs import Beliefs
from swarmctl.world.moves import MOVES, STAY
from swarmctl.world.paths import UNREACHABLE, grid_distances, step_towards

CHUNK_CELLS = 8_000_000  # distance-map cells computed at once (bounds memory on big maps and swarms)


class RandomPolicy:
    """Uniform over the five moves (the paper's replay-prefill policy); with a hover rule other than
    `no` (its default), a vehicle that parks on a target stays."""

    name = "random"
    hover = NO
    hold: int | None = None  # targets the mission holds, when fewer than its vehicles (hover.park_allowed)

    def reset(self, beliefs: Beliefs, seed: int) -> None:
        self.seed = int(seed)

    def act(self, beliefs: Beliefs) -> np.ndarray:
        u = Draws(self.seed, beliefs).deciders(RANDOM)
        moves = np.minimum((u * len(MOVES)).astype(np.int64), len(MOVES) - 1)
        return moves if self.hover == NO else np.where(parks(beliefs, self.hover, self.hold), STAY, moves)


# --- the swarm plan, as one belief holder sees it ------------------------------------------------------


def distances_from(cells: np.ndarray, passable: np.ndarray, use: np.ndarray | None = None) -> np.ndarray:
    """BFS steps from each of N cells per map: cells (M, N, 2), passable (M, W, H) -> (M, N, W, H) int32.
    Rows where `use` (M, N) is False are left UNREACHABLE (no source)."""
    m, n = cells.shape[:2]
    w, h = passable.shape[1:]
    src = np.zeros((m, n, w, h), dtype=bool)
    ok = (cells[..., 0] >= 0) if use is None else use & (cells[..., 0] >= 0)
    mi, ni = np.nonzero(ok)
    src[mi, ni, cells[mi, ni, 0], cells[mi, ni, 1]] = True
    pas = np.broadcast_to(passable[:, None], (m, n, w, h)).reshape(m * n, w, h)
    return grid_distances(pas, src.reshape(m * n, w, h)).reshape(m, n, w, h)


def target_lists(targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Known target masks (M, W, H) as padded lists: cells (M, K, 2) and valid (M, K)."""
    mi, x, y = np.nonzero(targets)
    m = targets.shape[0]
    counts = np.bincount(mi, minlength=m)
    k = max(int(counts.max()) if m else 0, 1)
    slot = np.arange(len(mi)) - np.repeat(np.cumsum(counts) - counts, counts)
    cells = np.zeros((m, k, 2), dtype=np.int64)
    valid = np.zeros((m, k), dtype=bool)
    cells[mi, slot] = np.stack([x, y], axis=1)
    valid[mi, slot] = True
    return cells, valid


def assign_targets(dist: np.ndarray, active: np.ndarray, cells: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Greedy assignment of known targets to vehicles, nearest pair first, one vehicle per target.

    dist (M, N, W, H) from each vehicle; active (M, N); cells (M, K, 2) with valid (M, K). Returns
    (M, N) target slot or -1."""
    m, n = active.shape
    k = cells.shape[1]
    mi, ni = np.arange(m)[:, None, None], np.arange(n)[None, :, None]
    d = dist[mi, ni, cells[:, None, :, 0], cells[:, None, :, 1]].astype(np.float64)  # (M, N, K)
    d[~(active[..., None] & valid[:, None, :]) | (d >= UNREACHABLE)] = np.inf
    goal = np.full((m, n), -1, dtype=np.int64)
    rows = np.arange(m)
    for _ in range(min(n, k)):
        flat = d.reshape(m, -1).argmin(1)
        vi, ti = np.divmod(flat, k)
        ok = np.isfinite(d[rows, vi, ti])
        if not ok.any():
            break
        goal[rows[ok], vi[ok]] = ti[ok]
        d[rows[ok], vi[ok], :] = np.inf
        d[rows[ok], :, ti[ok]] = np.inf
    return goal


def nearest_unexplored(
    dist: np.ndarray,
    explored: np.ndarray,
    pending: np.ndarray,
    noise: Callable[[int], np.ndarray],
    spread: float,
    goals: np.ndarray,
) -> np.ndarray:
    """Goals for the `pending` (M, N) vehicles, in index order: the nearest reachable unexplored cell,
    avoiding the discs (radius `spread`) claimed by the vehicles before them when it can.

    dist (M, N, W, H); explored (M, W, H); noise(j) -> (M, W, H) tie-break uniforms for vehicle j;
    goals (M, N, 2) is updated in place for the pending vehicles that have one, and returned."""
    m, n, w, h = dist.shape
    xs, ys = np.meshgrid(np.arange(w), np.arange(h), indexing="ij")
    claimed = np.zeros((m, w, h), dtype=bool)
    rows = np.arange(m)
    for j in range(n):
        if not pending[:, j].any():
            continue
        d = dist[:, j].astype(np.float64) + noise(j) * 0.5
        open_ = ~explored & (dist[:, j] < UNREACHABLE)
        preferred = np.where(open_ & ~claimed, d, np.inf).reshape(m, -1)
        fallback = np.where(open_, d, np.inf).reshape(m, -1)
        use = np.isfinite(preferred.min(1))
        flat = np.where(use, preferred.argmin(1), fallback.argmin(1))
        ok = np.isfinite(fallback.min(1)) & pending[:, j]
        gx, gy = np.divmod(flat, h)
        goals[rows[ok], j] = np.stack([gx[ok], gy[ok]], axis=1)
        near = (xs[None] - gx[:, None, None]) ** 2 + (ys[None] - gy[:, None, None]) ** 2 <= spread**2
        claimed |= near & ok[:, None, None]
    return goals


def navigate(pos: np.ndarray, goals: np.ndarray, passable: np.ndarray, ties: np.ndarray) -> np.ndarray:
    """Moves (D,) one step along a shortest path from pos (D, 2) to goals (D, 2) over passable (D, W, H);
    ties (D, 5) uniforms break equal choices. No path, or at the goal: stay."""
    d = pos.shape[0]
    src = np.zeros(passable.shape, dtype=bool)
    src[np.arange(d), goals[:, 0], goals[:, 1]] = True
    return step_towards(grid_distances(passable, src), pos, ties)


def deciders_part(beliefs: Beliefs, plan: Callable[[Beliefs, np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
    """(B, U, ...): each decider's own entry of the swarm plan its beliefs make, where
    plan(beliefs, hb, hu) gives (M, N, ...) for every vehicle as the holders (hb, hu) see the swarm.
    With shared beliefs the plan is made once per batch; holders go in chunks that bound memory."""
    b, u, n = beliefs.batch, beliefs.deciders, beliefs.vehicles
    holder = np.where(beliefs.shared()[:, None], 0, np.arange(u)[None, :])  # whose plan each decider plays
    hb_all, hu_all = np.nonzero(holder == np.arange(u)[None, :])
    row = np.full((b, u), -1, dtype=np.int64)
    row[hb_all, hu_all] = np.arange(len(hb_all))
    per = max(1, CHUNK_CELLS // max(1, n * beliefs.width * beliefs.height))
    chunks = range(0, len(hb_all), per)
    plans = np.concatenate([plan(beliefs, hb_all[i : i + per], hu_all[i : i + per]) for i in chunks])
    return plans[row[np.arange(b)[:, None], holder], beliefs.me]


class _SwarmPlanner:
    """What frontier and lawnmower share: the swarm plan per belief holder, the decider's part of it."""

    name = "planner"
    hover = FIRST  # the hover rule (swarmctl.policy.hover)
    hold: int | None = None  # targets the mission holds, when fewer than its vehicles (hover.park_allowed)

    def reset(self, beliefs: Beliefs, seed: int) -> None:
        self.seed = int(seed)

    def fixed_goals(self, beliefs: Beliefs, hb: np.ndarray, hu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Goals (M, N, 2) the planner sets itself for holders (hb, hu), and which vehicles (M, N) have
        one; the others explore (nearest unexplored with claims). Frontier: none."""
        m, n = len(hb), beliefs.vehicles
        return np.zeros((m, n, 2), dtype=np.int64), np.zeros((m, n), dtype=bool)

    def plan(self, beliefs: Beliefs, hb: np.ndarray, hu: np.ndarray) -> np.ndarray:
        """Every vehicle's goal (M, N, 2) as the deciders (hb, hu) see the swarm."""
        draws = Draws(self.seed, beliefs)
        positions = beliefs.positions[hb, hu]
        park = swarm_parking(beliefs, self.hover, self.hold, (hb, hu))  # (M,)
        parked = beliefs.hovering[hb, hu] & park[:, None]
        active = beliefs.others[hb, hu] & ~parked
        active[np.arange(len(hb)), beliefs.me[hb, hu]] = ~(beliefs.hovering_self[hb, hu] & park)
        if park.all():
            hover_cells = beliefs.hover_cells[hb, hu]
        else:  # the cells of the vehicles that park
            hover_cells = beliefs.hover_cells[hb, hu] & park[:, None, None]
        passable = ~(beliefs.obstacles[hb, hu] | hover_cells)
        dist = distances_from(positions, passable, active)
        cells, valid = target_lists(beliefs.targets[hb, hu] & ~hover_cells)
        slot = assign_targets(dist, active, cells, valid & park[:, None])
        has_target = slot >= 0
        goals = np.where(has_target[..., None], np.take_along_axis(cells, np.maximum(slot, 0)[..., None], 1), positions)
        fixed, has_fixed = self.fixed_goals(beliefs, hb, hu)
        goals = np.where((has_fixed & ~has_target)[..., None], fixed, goals)
        pending = active & ~has_target & ~has_fixed
        spread = 2 * beliefs.settings.fov
        episodes = draws.episodes[hb]

        def noise(j: int) -> np.ndarray:
            return uniform(
                self.seed, episodes, beliefs.step, np.full((len(hb), 1), j), CLAIMS, (beliefs.width, beliefs.height)
            )[:, 0]

        return nearest_unexplored(dist, beliefs.explored[hb, hu], pending, noise, spread, goals)

    def goals(self, beliefs: Beliefs) -> np.ndarray:
        """(B, U, 2): each decider's own goal in the swarm plan it makes (once per batch when shared)."""
        return deciders_part(beliefs, self.plan)

    def act(self, beliefs: Beliefs) -> np.ndarray:
        b, u = beliefs.batch, beliefs.deciders
        goals = self.goals(beliefs).reshape(b * u, 2)
        ties = Draws(self.seed, beliefs).deciders(NAVIGATE, len(MOVES)).reshape(b * u, -1)
        passable = ~beliefs.blocked.reshape(b * u, beliefs.width, beliefs.height)
        moves = navigate(beliefs.pos.reshape(b * u, 2), goals, passable, ties).reshape(b, u)
        return np.where(parks(beliefs, self.hover, self.hold), STAY, moves)


class FrontierPolicy(_SwarmPlanner):
    """Nearest unexplored cell per vehicle, spread apart by claims; known targets first."""

    name = "frontier"


def sweep_waypoints(width: int, height: int, uavs: int, fov: float) -> list[np.ndarray]:
    """Boustrophedon lanes per vehicle: the map split into U vertical strips, lanes 2*zeta+1 apart
    (a vehicle flying a lane senses zeta cells either side). Returns U arrays of (L_u, 2) waypoints."""
    reach = max(int(np.floor(fov)), 0)
    spacing = 2 * reach + 1
    bounds = np.linspace(0, width, uavs + 1).round().astype(int)
    lo_y, hi_y = 0, height - 1  # lanes run edge to edge, or the disc misses the corners
    out = []
    for v in range(uavs):
        x_lo, x_hi = bounds[v], max(bounds[v + 1] - 1, bounds[v])
        lanes = list(range(min(x_lo + reach, x_hi), x_hi + 1, spacing))
        if lanes[-1] + reach < x_hi:
            lanes.append(x_hi - reach if x_hi - reach > lanes[-1] else x_hi)
        pts = []
        for i, x in enumerate(lanes):
            ends = (lo_y, hi_y) if i % 2 == 0 else (hi_y, lo_y)
            pts += [(x, ends[0]), (x, ends[1])]
        out.append(np.array(pts, dtype=np.int64))
    return out


class LawnmowerPolicy(_SwarmPlanner):
    """Boustrophedon sweep split between the swarm's vehicles (lanes planned from the first beliefs and
    kept as the policy's state), then known targets (or any unexplored cell)."""

    name = "lawnmower"

    def reset(self, beliefs: Beliefs, seed: int) -> None:
        super().reset(beliefs, seed)
        n = beliefs.vehicles
        paths = sweep_waypoints(beliefs.width, beliefs.height, n, beliefs.settings.fov)
        length = max(len(p) for p in paths)
        self.waypoints = np.zeros((n, length, 2), dtype=np.int64)
        self.lengths = np.array([len(p) for p in paths])
        for v, p in enumerate(paths):
            self.waypoints[v, : len(p)] = p
            self.waypoints[v, len(p) :] = p[-1]
        self.index = np.zeros((beliefs.batch, n), dtype=np.int64)  # each vehicle's next waypoint, per episode
        self._row = {int(e): i for i, e in enumerate(beliefs.episodes)}

    def _rows(self, beliefs: Beliefs) -> np.ndarray:
        """Rows of self.index for the beliefs' episodes (a subset of the reset ones, in any order)."""
        return np.array([self._row[int(e)] for e in beliefs.episodes], dtype=np.int64)

    def _advance(self, beliefs: Beliefs) -> None:
        """Each decider moves its own waypoint on while it stands on it or cannot reach it."""
        b, u = beliefs.batch, beliefs.deciders
        bi = self._rows(beliefs)[:, None]
        me = beliefs.me
        passable = ~beliefs.blocked.reshape(b * u, beliefs.width, beliefs.height)
        dist = distances_from(beliefs.pos.reshape(b * u, 1, 2), passable)[:, 0].reshape(b, u, *passable.shape[1:])
        ui = np.arange(u)[None, :]
        for _ in range(self.waypoints.shape[1]):
            idx = self.index[bi, me]
            active = idx < self.lengths[me]
            wp = self.waypoints[me, np.minimum(idx, self.waypoints.shape[1] - 1)]
            reached = (beliefs.pos == wp).all(-1)
            at = (np.arange(b)[:, None], ui, wp[..., 0], wp[..., 1])
            unusable = beliefs.blocked[at] | (dist[at] >= UNREACHABLE)
            step = active & (reached | unusable)
            if not step.any():
                break
            np.add.at(self.index, (np.broadcast_to(bi, me.shape)[step], me[step]), 1)

    def fixed_goals(self, beliefs: Beliefs, hb: np.ndarray, hu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        idx = self.index[self._rows(beliefs)[hb]]  # (M, N)
        sweeping = idx < self.lengths[None, :]
        wp = self.waypoints[np.arange(beliefs.vehicles)[None, :], np.minimum(idx, self.waypoints.shape[1] - 1)]
        return wp, sweeping

    def act(self, beliefs: Beliefs) -> np.ndarray:
        self._advance(beliefs)
        return super().act(beliefs)
