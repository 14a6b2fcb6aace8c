"""The coordinated planner (`coordinated`): the swarm searches as one team.

Each step, every belief holder plans the whole swarm as it knows it, and each decider plays its own
part of that plan (as frontier does; with shared beliefs the plan is made once per episode):

1. **Defer the hover** (the hover rule, swarmctl.policy.hover): no vehicle parks on a target while
   the swarm knows fewer targets than it has vehicles, so nobody is left to search a big map alone;
   with a step limit (`horizon`), the swarm also parks when the steps left are only just enough to
   reach the known targets.
2. **Targets by optimal assignment**: once parking is allowed, the vehicles on targets park there and
   the free known targets go to the searching vehicles by shortest-path distance over the known
   passable cells, minimising the longest trip and then the sum (scipy's linear_sum_assignment).
3. **Exploration goals, fanned out** (Burgard et al., "Coordinated multi-robot exploration", IEEE T-RO
   2005): the others, in mission order, take the cell whose sensing disc holds the most probability
   left (`Beliefs.density`: the unexplored cells under a uniform prior and a detector that never
   misses) less `beta` per step of path; the cells round an assigned goal then count less for the
   vehicles after it. In the cluster scenario unexplored cells near a known target weigh more
   (targets come in clusters: the paper's value map phi says the same). With `use_prior` off
   (`coordinated:prior=no`) the planner weighs what a uniform prior would leave after the same passes
   (`Beliefs.uniform_density`): the same search, blind to where the person is likely to be.
4. **Moves without conflicts**: each vehicle steps along a shortest path to its goal, in mission order,
   never into a cell another vehicle holds now or an earlier vehicle moves to (the guard's rule), so
   the plan never collides and the guard never refuses it.

A vehicle's move is a function of the beliefs it holds, the episode's seed (tie-breaks) and the step
limit: no state is kept between steps, so any state another policy visits can be labelled (DAgger).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.optimize import linear_sum_assignment

from swarmctl.policy.draws import CLAIMS, NAVIGATE, uniform
from swarmctl.policy.hover import DEFER, NO, swarm_parking
from swarmctl.policy.planners import CHUNK_CELLS, deciders_part, distances_from, target_lists
from swarmctl.world.beliefs import Beliefs
from swarmctl.world.moves import MOVES, STAY
from swarmctl.world.paths import UNREACHABLE, grid_distances
from swarmctl.world.scenario import fov_offsets

_FAR = 1e9  # the cost of an unreachable target in the assignment


@dataclass(frozen=True)
class CoordinatedSettings:
    """The planner's constants (chosen on synthetic maps and the Chicago Loop grid; docs/RESULTS.md)."""

    beta: float = 3.0  # unexplored cells a step of path must be worth
    # beta times (the largest weight left) ** beta_gain: where the probability is dense a step of path is worth
    # more of it, so the team sweeps a hotspot through instead of hopping between its best discs (tuned on
    # seed 45046 among 0, 0.5 and 1; docs/RESULTS.md, "Searching with a prior")
    beta_gain: float = 0.5
    spread: float = 2.0  # the cells within spread x fov of an assigned goal count less for later vehicles
    discount: float = 1.0  # how much less (1: not at all)
    cluster_gain: float = 0.0  # extra weight of unexplored cells near a known target
    margin: int = 2  # steps of slack when the step limit decides to park


def bottleneck_assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of an assignment of min(R, C) pairs that minimises the largest cost, then the
    sum (costs >= _FAR are never used: such rows are left out)."""
    if cost.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    levels = np.unique(cost[cost < _FAR])
    rows, cols = linear_sum_assignment(cost)
    ok = cost[rows, cols] < _FAR
    rows, cols = rows[ok], cols[ok]
    if len(rows) == 0 or len(levels) <= 1:
        return rows, cols
    need = len(rows)  # pairs the sum-optimal assignment makes: no threshold may make fewer
    lo, hi = 0, int(np.searchsorted(levels, cost[rows, cols].max()))
    while lo < hi:  # the smallest level that still allows `need` pairs
        mid = (lo + hi) // 2
        capped = np.where(cost <= levels[mid], cost, _FAR)
        r, c = linear_sum_assignment(capped)
        if int((capped[r, c] < _FAR).sum()) >= need:
            hi = mid
        else:
            lo = mid + 1
    capped = np.where(cost <= levels[lo], cost, _FAR)
    r, c = linear_sum_assignment(capped)
    keep = capped[r, c] < _FAR
    return r[keep], c[keep]


class CoordinatedPolicy:
    """The coordinated planner (module docstring); `hover` is the hover rule (defer, first or no)."""

    def __init__(
        self,
        hover: str = DEFER,
        settings: CoordinatedSettings | None = None,
        name: str | None = None,
        use_prior: bool = True,
    ):
        self.hover = hover
        self.settings = settings or CoordinatedSettings()
        self.name = name or "coordinated"
        self.use_prior = use_prior  # weigh the beliefs' density (the prior's), or a uniform prior's
        self.horizon: int | None = None  # the episode's step limit, when the caller knows it
        self.hold: int | None = None  # targets the mission holds, when fewer than its vehicles
        self.seed = 0

    def reset(self, beliefs: Beliefs, seed: int) -> None:
        self.seed = int(seed)

    # --- the plan ----------------------------------------------------------------------------------
    def plan(self, beliefs: Beliefs, hb: np.ndarray, hu: np.ndarray) -> np.ndarray:
        """Every vehicle's move (M, N) in the swarm plan of the holders (hb, hu)."""
        return self.plan_with_ties(beliefs, hb, hu)[..., 0]

    def plan_with_ties(self, beliefs: Beliefs, hb: np.ndarray, hu: np.ndarray) -> np.ndarray:
        """(M, N, 1 + 5) int64: every vehicle's move, then which of the 5 moves are as good as it (1: the
        same path distance to its goal, into a cell it may enter; the tie-break chose among those)."""
        m, n = len(hb), beliefs.vehicles
        w, h = beliefs.width, beliefs.height
        positions = beliefs.positions[hb, hu]  # (M, N, 2)
        known = positions[..., 0] >= 0
        on_target = beliefs.hovering[hb, hu] & known
        targets = beliefs.targets[hb, hu]
        obstacles = beliefs.obstacles[hb, hu]
        park = swarm_parking(beliefs, self.hover, self.hold, (hb, hu))  # (M,) the hover rule
        parked = on_target & park[:, None]
        searching = known & ~parked
        parked_cells = np.zeros((m, w, h), dtype=bool)
        pi, pn = np.nonzero(parked)
        parked_cells[pi, positions[pi, pn, 0], positions[pi, pn, 1]] = True
        passable = ~(obstacles | parked_cells)
        dist = distances_from(positions, passable, searching)  # (M, N, W, H)

        goals = positions.copy()
        has_goal = np.zeros((m, n), dtype=bool)
        cells, valid = target_lists(targets & ~parked_cells)
        if self.hover != NO and valid.any():
            assigned = self._assign_targets(dist, searching, cells, valid, park, beliefs.step)
            has_goal |= assigned >= 0
            goals = np.where(
                has_goal[..., None], np.take_along_axis(cells, np.maximum(assigned, 0)[..., None], 1), goals
            )
        pending = searching & ~has_goal
        if pending.any():
            self._explore(beliefs, hb, hu, dist, targets, pending, goals, has_goal)
        moves, ties = self._navigate(beliefs, hb, positions, known, passable, dist, goals, has_goal & searching)
        moves = np.where(parked, STAY, moves)
        ties[parked] = np.arange(len(MOVES)) == STAY
        return np.concatenate([moves[..., None], ties.astype(np.int64)], axis=-1)

    def _assign_targets(
        self,
        dist: np.ndarray,
        searching: np.ndarray,
        cells: np.ndarray,
        valid: np.ndarray,
        park: np.ndarray,
        step: int,
    ) -> np.ndarray:
        """(M, N) the target slot of each searching vehicle or -1: the free targets, optimally, where
        parking is allowed or the step limit leaves just the time to reach them."""
        m, n = searching.shape
        mi, ni = np.arange(m)[:, None, None], np.arange(n)[None, :, None]
        d = dist[mi, ni, cells[:, None, :, 0], cells[:, None, :, 1]].astype(np.float64)  # (M, N, K)
        d[~(searching[..., None] & valid[:, None, :]) | (d >= UNREACHABLE)] = _FAR
        slot = np.full((m, n), -1, dtype=np.int64)
        left = None if self.horizon is None else self.horizon - step
        for i in np.flatnonzero(valid.any(1) & searching.any(1)):
            columns = np.flatnonzero(valid[i])  # this map's targets only: the batch's padding never breaks a tie
            r, c = bottleneck_assignment(d[i][:, columns])
            if len(r) == 0:
                continue
            if not park[i] and (left is None or left > d[i][r, columns[c]].max() + self.settings.margin):
                continue  # deferred: explore on
            slot[i, r] = columns[c]
        return slot

    def _explore(
        self,
        beliefs: Beliefs,
        hb: np.ndarray,
        hu: np.ndarray,
        dist: np.ndarray,
        targets: np.ndarray,
        pending: np.ndarray,
        goals: np.ndarray,
        has_goal: np.ndarray,
    ) -> None:
        """Exploration goals for the pending vehicles, in mission order (goals/has_goal updated)."""
        s = self.settings
        m, n, w, h = dist.shape
        fov = beliefs.settings.fov
        kernel = _disc_kernel(fov)
        weight = (beliefs.density if self.use_prior else beliefs.uniform_density)[hb, hu]  # a copy: changed below
        beta = np.float32(s.beta)
        if s.beta_gain:  # (the paper's unexplored map: its largest weight is 1, beta stays)
            beta = beta * weight.max((1, 2), initial=0.0)[:, None, None] ** np.float32(s.beta_gain)
        if s.cluster_gain > 0 and targets.any():
            weight *= 1.0 + np.float32(s.cluster_gain) / (1.0 + _distance_to_targets(targets))
        reach = max(s.spread * fov, 0.5)
        xs, ys = np.meshgrid(np.arange(w), np.arange(h), indexing="ij")
        episodes = beliefs.episodes[hb]
        rows = np.arange(m)
        utility = None
        for j in range(n):
            todo = pending[:, j]
            if not todo.any():
                continue
            if utility is None:
                utility = ndimage.correlate(weight, kernel[None], mode="constant")
            dj = dist[:, j]
            ties = uniform(self.seed, episodes, 0, np.full((m, 1), j), CLAIMS, (w, h))[:, 0]
            score = utility - beta * np.minimum(dj, UNREACHABLE).astype(np.float32) + 1e-3 * ties
            # the vehicle's own cell is no goal: staying makes no pass (with pod 1 its disc is explored anyway)
            score[(dj >= UNREACHABLE) | (dj == 0) | (utility <= 0)] = -np.inf
            if beliefs.pod < 1.0:
                # a detector that misses never clears a cell: a disc worth less than one step of path is no
                # goal while a better one is left anywhere, or the team dithers over what it has searched
                worth = np.where(utility >= beta, score, -np.inf)
                score = np.where(np.isfinite(worth).any((1, 2), keepdims=True), worth, score)
            flat = score.reshape(m, -1).argmax(1)
            ok = todo & np.isfinite(score.reshape(m, -1)[rows, flat])
            if not ok.any():
                continue
            gx, gy = np.divmod(flat, h)
            goals[rows[ok], j] = np.stack([gx[ok], gy[ok]], axis=1)
            has_goal[rows[ok], j] = True
            near = ((xs[None] - gx[:, None, None]) ** 2 + (ys[None] - gy[:, None, None]) ** 2 <= reach**2) & ok[
                :, None, None
            ]
            weight[near] *= np.float32(1.0 - s.discount)
            utility = None

    def _navigate(
        self,
        beliefs: Beliefs,
        hb: np.ndarray,
        positions: np.ndarray,
        known: np.ndarray,
        passable: np.ndarray,
        dist: np.ndarray,
        goals: np.ndarray,
        has_goal: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(M, N) moves one step towards each goal, in mission order, never into a cell another vehicle
        holds or an earlier one enters; a vehicle without a goal stays. And (M, N, 5) bool: the moves as
        good as each one (the tie-break's choices)."""
        m, n = known.shape
        w, h = passable.shape[1:]
        moves = np.full((m, n), STAY, dtype=np.int64)
        ties = np.zeros((m, n, len(MOVES)), dtype=bool)
        ties[..., STAY] = True
        if not has_goal.any():
            return moves, ties
        mi, ni = np.nonzero(has_goal)
        # the search from a goal only needs to reach the cells next to its vehicle (same map, so the
        # vehicle's distance to its goal bounds it)
        trip = dist[mi, ni, goals[mi, ni, 0], goals[mi, ni, 1]].astype(np.int64)
        src = np.zeros((len(mi), w, h), dtype=bool)
        src[np.arange(len(mi)), goals[mi, ni, 0], goals[mi, ni, 1]] = True
        pas = passable[mi]
        to_goal = np.full((m, n, w, h), UNREACHABLE, dtype=np.int32)
        per = max(1, CHUNK_CELLS // max(1, w * h))
        for i in range(0, len(mi), per):
            part = slice(i, i + per)
            reach = trip[part][trip[part] < UNREACHABLE]
            limit = int(reach.max()) + 1 if len(reach) else 1
            to_goal[mi[part], ni[part]] = grid_distances(pas[part], src[part], limit)
        occupied = np.zeros((m, w, h), dtype=bool)
        ki, kn = np.nonzero(known)
        occupied[ki, positions[ki, kn, 0], positions[ki, kn, 1]] = True
        reserved = np.zeros((m, w, h), dtype=bool)
        rows = np.arange(m)
        episodes = beliefs.episodes[hb]
        vehicles = np.broadcast_to(np.arange(n), (m, n))
        ties = uniform(self.seed, episodes, beliefs.step, vehicles, NAVIGATE, (len(MOVES),))
        for j in range(n):
            act = has_goal[:, j]
            if not act.any():
                continue
            cand = positions[:, j, None, :] + MOVES[None]  # (M, 5, 2)
            inside = (cand[..., 0] >= 0) & (cand[..., 0] < w) & (cand[..., 1] >= 0) & (cand[..., 1] < h)
            cx, cy = np.clip(cand[..., 0], 0, w - 1), np.clip(cand[..., 1], 0, h - 1)
            d = to_goal[rows[:, None], j, cx, cy].astype(np.float64)
            free = inside & ~occupied[rows[:, None], cx, cy] & ~reserved[rows[:, None], cx, cy]
            free[:, STAY] = True
            d[~free | (d >= UNREACHABLE)] = np.inf
            d[:, STAY] = np.minimum(d[:, STAY], UNREACHABLE)  # staying is always possible
            best = d.min(1, keepdims=True)
            choice = np.argmax((d == best) * (ties[:, j] + 1.0), axis=1)
            choice = np.where(act, choice, STAY)
            moves[:, j] = choice
            ties[act, j] = (d == best)[act]
            dest = positions[:, j] + MOVES[choice]
            known_j = known[:, j]
            reserved[rows[known_j], dest[known_j, 0], dest[known_j, 1]] = True
        return moves, ties

    # --- the decider's part ------------------------------------------------------------------------
    def act(self, beliefs: Beliefs) -> np.ndarray:
        return deciders_part(beliefs, self.plan)

    def labels(self, beliefs: Beliefs) -> tuple[np.ndarray, np.ndarray]:
        """What `act` gives (B, U), and (B, U, 5) bool: every move as good as it, by the planner's own
        measure (a teacher's label without its tie-break: swarmctl.learn.search_recipe)."""
        both = deciders_part(beliefs, self.plan_with_ties)
        return both[..., 0], both[..., 1:].astype(bool)


def _disc_kernel(fov: float) -> np.ndarray:
    offsets = fov_offsets(fov)
    r = int(np.abs(offsets).max()) if len(offsets) else 0
    k = np.zeros((2 * r + 1, 2 * r + 1), dtype=np.float32)
    k[offsets[:, 0] + r, offsets[:, 1] + r] = 1.0
    return k


def _distance_to_targets(targets: np.ndarray) -> np.ndarray:
    """(M, W, H) float32 Euclidean distance to the nearest known target of each map (inf: none)."""
    out = np.full(targets.shape, np.inf, dtype=np.float32)
    for i in np.flatnonzero(targets.any((1, 2))):
        out[i] = ndimage.distance_transform_edt(~targets[i])
    return out
