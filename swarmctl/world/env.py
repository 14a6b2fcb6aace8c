"""The batched search world: B episodes x U vehicles stepped at once in numpy arrays.

    env = SearchEnv(WorldConfig(), batch=256)
    obs = env.reset(seed=0)                       # (B, U, 3, F, F)
    obs, reward, success, info = env.step(actions)  # actions (B, U) in 0..4

Semantics (the paper's): a move outside the map or into an obstacle leaves the vehicle
where it is (nu = 0, penalty theta); vehicles whose post-move cells coincide collide (penalty psi,
no target reward); a swap is not a collision; a vehicle on a target cell without collision earns
+1. Success at step t >= 1 depends on the finish line `cfg.finish` (the reward never does):
  held (the paper's): after the t-th joint move every vehicle is on a target and no two share a cell;
  found: every target has been inside some vehicle's sensing disc by step t (`found_step`, kept under
    found and covered, holds the step each target was first sensed, 0 for the starts' discs, -1 not yet);
  covered: every free cell 4-connected to a start cell has been sensed by step t (`covered_fraction`);
  pos: the team's probability of success (`team_pos()`, against the episode's prior) has reached `cfg.pos_goal`.
With `stop_at_success` (test episodes) a successful episode freezes; training episodes run on.

Prior and detector (swarmctl.world.prior): `reset(..., prior=...)` gives every episode a prior over its
free cells (uniform when none). A pass over a cell is its entry into a vehicle's disc (the starts' discs,
then the cells of the disc at the cell a vehicle reaches that the disc it left did not hold; staying adds
none); the world counts the team's passes per cell (`passes`, what was truly flown), and each vehicle the
passes it knows of (its own and those in the messages it received, as `explored` is shared). With
`cfg.pod` < 1 a target entering a vehicle's disc is detected with
probability pod, one draw per (episode, step, vehicle, target) from the world's DETECTIONS stream; an
undetected target stays unknown (not among the known targets, not found, no hovering on it), and the
value map a vehicle sees is made from the targets it knows. `team_pos()` is 1 - the prior's residual after
the team's passes; `pos_trace` holds it after every step, `pos_step` the step it first reached pos_goal.

Each vehicle has its own knowledge (explored mask, where it believes the others are and whether they
hover on a target, and the step it last heard each of them: `heard`). After every move each vehicle
senses the disc of radius zeta around itself and broadcasts what it sensed, its position and whether
it hovers; the channel decides which receivers get it (ideal: all, none: nobody, model/fixed: each
message lost independently, by a draw keyed by (seed, episode, step, sender, receiver), so the batch
never changes which messages are lost). Policies
see only `beliefs()` (swarmctl.world.beliefs), never the hidden targets; `observe()` is the paper's
observation built from them. With `cfg.guard` the safety guard (swarmctl.world.guard) turns refused moves into
"stay" before they are applied, as the controller does.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from swarmctl.errors import ScenarioError
from swarmctl.world import prior as prior_model
from swarmctl.world.beliefs import PAPER_VARIANT, Beliefs, ObservationSettings
from swarmctl.world.channel import Channel
from swarmctl.world.config import WorldConfig
from swarmctl.world.draws import DETECTIONS, uniform
from swarmctl.world.guard import guard_moves
from swarmctl.world.moves import MOVES, STAY, cell_table, move_table
from swarmctl.world.observe import build_observations, observe
from swarmctl.world.paths import reachable_from
from swarmctl.world.scenario import Scenario, fov_offsets, generate_scenario, value_map


@dataclass
class StepInfo:
    """Per-step details: moves that were valid (nu), collisions (chi), and guard refusals."""

    valid: np.ndarray  # (B, U) bool
    collided: np.ndarray  # (B, U) bool
    on_target: np.ndarray  # (B, U) bool
    refused: np.ndarray  # (B, U) bool, moves the guard turned into "stay"


class SearchEnv:
    """B parallel episodes of the paper's search world."""

    _disc_table: np.ndarray  # (W * H, D) the flat cells of each cell's sensing disc (reset_to)

    def __init__(
        self,
        cfg: WorldConfig,
        batch: int = 1,
        stop_at_success: bool = True,
        observations: bool = True,
        track_pos: bool | None = None,
    ):
        if batch < 1:
            raise ScenarioError(f"batch {batch} must be >= 1")
        self.cfg = cfg
        # the team's passes and POS cost a step about as much as the rest of it: kept when asked, or when the
        # episode needs them (pod < 1, a prior, the pos finish line), never for the paper's training
        self.track_pos = track_pos
        self.batch = batch
        self.stop_at_success = stop_at_success
        self.observations = observations
        self.channel = Channel(cfg.channel, cfg.cell_size, cfg.loss)
        self.settings = ObservationSettings.from_world(cfg)  # phi is exact here (the field's is quantised)
        self._offsets = fov_offsets(cfg.fov)
        self.width = self.height = cfg.map_size
        self.scenarios: list[Scenario] = []
        self.last_observations: np.ndarray | None = None

    # ----- episode set-up -------------------------------------------------------------------
    def reset(
        self,
        seed: int = 0,
        episodes: Iterable[int] | None = None,
        blocked: np.ndarray | None = None,
        prior: np.ndarray | None = None,
    ) -> np.ndarray | None:
        """Start B episodes; episode indices default to 0..B-1. Returns observations (or None).
        `blocked` (W, H) bool: every episode on this fixed map (a real area's grid), targets and
        starts drawn on it (scenario.generate_scenario). `prior` (W, H) non-negative weights: where the
        person is likely to be, normalised over each episode's free cells (None: uniform); the scenario
        `prior` draws the targets from it."""
        ids = list(range(self.batch) if episodes is None else episodes)
        if len(ids) != self.batch:
            raise ScenarioError(f"reset got {len(ids)} episode indices for a batch of {self.batch}")
        if prior is not None:
            shape = blocked.shape if blocked is not None else (self.cfg.map_size, self.cfg.map_size)
            if np.shape(prior) != shape:
                raise ScenarioError(f"prior: shape {np.shape(prior)} is not the map's {shape}")
        scenarios = [generate_scenario(self.cfg, seed, int(i), blocked, prior) for i in ids]
        return self.reset_to(scenarios, seed=seed, episodes=ids, prior=prior)

    def reset_to(
        self,
        scenarios: list[Scenario],
        seed: int = 0,
        episodes: Iterable[int] | None = None,
        prior: np.ndarray | None = None,
    ) -> np.ndarray | None:
        """Start from given scenarios (hand-built cases, real maps). All share one grid size.
        `seed`: the episode seed (as given to reset); `episodes`: their ids (default 0..B-1). The ids key
        the policies' random draws; seed and ids key the channel's message losses (Channel.lost).
        `prior`: (W, H) or (B, W, H) weights, normalised over each episode's free cells (None: uniform)."""
        if len(scenarios) != self.batch:
            raise ScenarioError(f"reset_to got {len(scenarios)} scenarios for a batch of {self.batch}")
        self.scenarios = scenarios
        self.episodes = np.arange(self.batch) if episodes is None else np.asarray(list(episodes), dtype=np.int64)
        self.width, self.height = scenarios[0].obstacles.shape
        b = self.batch
        self.targets = np.stack([s.targets for s in scenarios])  # (B, K, 2)
        self.obstacles = np.stack([s.obstacles for s in scenarios])  # (B, W, H)
        self.pos = np.stack([s.starts for s in scenarios]).astype(np.int64)  # (B, U, 2)
        self.uavs = self.pos.shape[1]
        self.target_mask = np.zeros_like(self.obstacles)
        bi = np.repeat(np.arange(b), self.targets.shape[1])
        self.target_mask[bi, self.targets[..., 0].ravel(), self.targets[..., 1].ravel()] = True
        self.phi = value_map(self.targets, self.width, self.height, self.cfg.sigma2, self.cfg.phi_cutoff)
        self._seen_value = (self.phi - np.float32(self.cfg.rho) * self.obstacles).astype(np.float32)  # explored cells
        self._disc_table = _disc_table(self.width, self.height, self._offsets)
        # flat cells (x * H + y) for the move rules: one gather per rule instead of per-axis arithmetic
        self._moves = move_table(self.width, self.height)
        self._cells = cell_table(self.width, self.height)
        self._cell = self.pos[..., 0] * self.height + self.pos[..., 1]  # (B, U)
        self._obstacle_flat = self.obstacles.reshape(b, -1)
        self._target_flat = self.target_mask.reshape(b, -1)
        self._bi = np.arange(b)[:, None]
        self.explored = np.zeros((b, self.uavs, self.width, self.height), dtype=bool)
        self.known_pos = np.full((b, self.uavs, self.uavs, 2), -1, dtype=np.int64)
        self.known_hover = np.zeros((b, self.uavs, self.uavs), dtype=bool)  # [b, v, u]: v believes u hovers
        self.heard = np.full((b, self.uavs, self.uavs), -1, dtype=np.int64)  # [b, v, u]: the step v last heard u
        self._lower = np.tri(self.uavs, k=-1, dtype=bool)[None]  # [u, v]: v < u
        self._hover = self._hovering()
        self._decider_ids = np.broadcast_to(np.arange(self.uavs), (b, self.uavs))
        self._not_me = ~np.eye(self.uavs, dtype=bool)[None]  # [u, n]: n is another vehicle than u
        self._obstacle_free = not self.obstacles.any()
        self.t = 0
        self.done = np.zeros(b, dtype=bool)
        self.duration = np.zeros(b, dtype=np.int64)  # step of success, 0 while running
        self.collisions = np.zeros(b, dtype=np.int64)
        self.seed = int(seed)  # with the episode ids, keys the channel's losses
        finish = self.cfg.finish
        # found / covered: the union over vehicles of the cells their own discs sensed, kept as it grows (a
        # few cells per vehicle and step). It equals the union of `explored` under every channel (a received
        # cell was sensed by its sender), which would cost a pass over B x U x W x H per step.
        self._sensed = None if finish == "held" else np.zeros((b, self.width * self.height), dtype=bool)
        self._target_cells = self.targets[..., 0] * self.height + self.targets[..., 1]  # (B, K) flat
        self.found_step = np.full(self.targets.shape[:2], -1, dtype=np.int64)  # found: step first sensed
        self._reachable = (
            reachable_from(~self.obstacles, self.pos).reshape(b, -1) if finish == "covered" else None
        )  # covered: free cells 4-connected to a start
        self._reset_search(prior)
        self._came_from: np.ndarray | None = None  # (B, U) the cells the vehicles looked from before this step
        self._sense_and_share(np.ones((b, self.uavs), dtype=bool))
        self._record_sensing()
        self._record_pos()
        self.last_observations = self.observe() if self.observations else None
        return self.last_observations

    # ----- one joint move -------------------------------------------------------------------
    def step(self, actions: np.ndarray) -> tuple[np.ndarray | None, np.ndarray, np.ndarray, StepInfo]:
        """Apply a joint move. Returns (obs or None, reward (B, U), success (B,), StepInfo)."""
        cfg = self.cfg
        actions = np.asarray(actions, dtype=np.int64)
        # as unsigned, a negative action is huge: one reduction checks both ends
        if actions.shape != (self.batch, self.uavs) or actions.view(np.uint64).max() >= len(MOVES):
            raise ValueError(f"actions must be ints in 0..4 of shape {(self.batch, self.uavs)}")
        if self.stop_at_success and self.done.any():
            actions = np.where(self.done[:, None], STAY, actions)
        bi = self._bi
        target = self._moves[self._cell, actions]  # (B, U) flat cell, -1 off the map
        # -1 reads the last cell, which does not matter: off the map is invalid anyway
        valid = target >= 0
        if not self._obstacle_free:
            valid &= ~self._obstacle_flat[bi, target]
        refused = np.zeros_like(valid)
        if cfg.guard:
            prop, code = guard_moves(self.pos, self.pos + MOVES[actions], self.obstacles)
            refused = code != 0
            target = prop[..., 0] * self.height + prop[..., 1]
        dest = np.where(valid, target, self._cell)
        moved = dest != self._cell  # a pass: the vehicle has just reached its cell
        self._came_from = self._cell
        self._cell = dest
        self.pos = self._cells[dest]

        same = dest[:, :, None] == dest[:, None, :]  # (B, U, U)
        collided = same.sum(-1) > 1
        on_target = self._target_flat[bi, dest]
        self._hover = on_target & ~(same & self._lower).any(-1)
        reward = (-cfg.theta * (~valid) - cfg.psi * collided + (~collided & on_target)).astype(np.float32)
        any_collision = collided.any(1)

        self.t += 1
        fresh = self._fresh_cells() if cfg.explore_reward else None
        self._sense_and_share(moved)
        self._record_pos()
        if cfg.finish == "held":
            success = on_target.all(1) & ~any_collision
        else:  # found / covered / pos read what the discs sensed on arrival
            self._record_sensing()
            success = self._finished()
        running = ~self.done
        self.collisions += any_collision & running
        newly = success & running
        self.duration[newly] = self.t
        if self.stop_at_success:
            self.done |= success
        if fresh is not None:  # the exploration reward: cells this vehicle's disc newly showed it, in discs
            reward += np.float32(cfg.explore_reward) * fresh / np.float32(len(self._offsets))
        obs = self.last_observations = self.observe() if self.observations else None
        return obs, reward, success, StepInfo(valid=valid, collided=collided, on_target=on_target, refused=refused)

    def _fresh_cells(self) -> np.ndarray:
        """(B, U) float32: cells of each vehicle's sensing disc at its new cell that it had not explored."""
        b, u, w, h = self.batch, self.uavs, self.width, self.height
        disc = self._disc_table[self._cell]  # (B, U, D); off-map entries repeat the centre
        seen = self.explored.reshape(b, u, w * h)[self._bi[:, :, None], np.arange(u)[None, :, None], disc]
        order = np.argsort(disc, axis=-1)
        cells = np.take_along_axis(disc, order, axis=-1)
        first = np.ones(disc.shape, dtype=bool)  # each cell counted once (off-map entries repeat the centre)
        first[..., 1:] = cells[..., 1:] != cells[..., :-1]
        result: np.ndarray = (~np.take_along_axis(seen, order, axis=-1) & first).sum(-1).astype(np.float32)
        return result

    # ----- finish lines found / covered ------------------------------------------------------
    def _record_sensing(self) -> None:
        """Add the vehicles' current discs to the sensed union; date the targets first sensed now."""
        if self._sensed is None:
            return
        self._sensed[self._bi, self._disc_table[self._cell].reshape(self.batch, -1)] = True
        if self.detected is None:  # pod 1: a target in a disc is found
            new = (self.found_step < 0) & self._sensed[self._bi, self._target_cells]
        else:
            new = (self.found_step < 0) & self.detected
        self.found_step[new] = self.t

    def _finished(self) -> np.ndarray:
        """(B,) bool: the finish line `found`, `covered` or `pos` is reached."""
        if self.cfg.finish == "found":
            found = np.asarray((self.found_step >= 0).all(1))  # (an array: numpy's stubs allow a scalar)
            return found
        if self.cfg.finish == "pos":
            reached: np.ndarray = self.pos_step >= 0
            return reached
        assert self._reachable is not None and self._sensed is not None  # finish "covered"
        covered: np.ndarray = ~(self._reachable & ~self._sensed).any(1)
        return covered

    def covered_fraction(self) -> np.ndarray:
        """(B,) float: the share of the free cells 4-connected to a start that have been sensed (finish
        `covered` only; 1.0 when there are none)."""
        if self._reachable is None:
            raise ValueError("covered_fraction needs a world with finish 'covered'")
        assert self._sensed is not None  # kept for finish "covered"
        reachable = self._reachable.sum(1)
        sensed = (self._reachable & self._sensed).sum(1)
        return np.where(reachable > 0, sensed / np.maximum(reachable, 1), 1.0)

    # ----- prior, passes and detections ------------------------------------------------------
    def _reset_search(self, prior: np.ndarray | None) -> None:
        """The episode's prior, pass counts, detections and POS record, before the starts' passes."""
        b, u, k = self.batch, self.uavs, self.targets.shape[1]
        free = ~self.obstacles
        weights = np.ones(free.shape) if prior is None else np.broadcast_to(np.asarray(prior, np.float64), free.shape)
        self.uniform_prior = prior is None
        self.prior = prior_model.normalise_prior(weights, free)  # (B, W, H)
        self._free_cells = free
        self.passes = np.zeros((b, self.width * self.height), dtype=np.uint8)  # the team's: what was flown
        # POS kept as it changes (a few cells a step): the prior's total and the residual left on the map
        self._prior_flat = self.prior.reshape(b, -1)
        self._prior_total = self._prior_flat.sum(1)
        self._left = self._prior_total.copy()
        self._miss = prior_model.miss_table(self.cfg.pod)
        self._disc_inside = _disc_inside(self.width, self.height, self._offsets)
        certain = self.cfg.pod >= 1.0
        # pod < 1: what each vehicle knows (passes, targets detected); pod 1 reads them off `explored`
        self.believed_passes = None if certain else np.zeros((b, u, self.width * self.height), dtype=np.uint8)
        self.known_targets = None if certain else np.zeros((b, u, k), dtype=bool)
        self.detected = None if certain else np.zeros((b, k), dtype=bool)  # the team's detections
        self.pos_trace: list[np.ndarray] = []  # (B,) POS after the starts' passes, then after every step
        self.pos_step = np.full(b, -1, dtype=np.int64)  # the step POS first reached cfg.pos_goal
        wanted = self.cfg.pod < 1.0 or self.cfg.finish == "pos" or prior is not None
        self._tracking = wanted if self.track_pos is None else (self.track_pos or wanted)

    def _count_passes(self, moved: np.ndarray) -> np.ndarray | None:
        """Add the passes of the vehicles that `moved` (B, U) to the team's counts; returns each vehicle's
        own looks (B, U, W*H) bool when vehicles keep their own counts (pod < 1), else None."""
        if not self._tracking:  # (pod < 1 always tracks)
            return None
        b, wh = self.batch, self.width * self.height
        bi, ui = np.nonzero(moved)
        cells = self._cell[bi, ui]
        table = self._disc_table[cells]  # (P, D)
        entering = self._disc_inside[cells]  # (P, D): each disc cell once
        if self._came_from is not None:  # a cell still in the footprint it left is the same look, no new pass
            before = self._disc_table[self._came_from[bi, ui]]
            entering = entering & ~(table[:, :, None] == before[:, None, :]).any(-1)
        flat = (bi[:, None] * wh + table)[entering]
        if flat.size:
            where, looks = np.unique(flat, return_counts=True)
            counts = self.passes.reshape(-1)
            old = counts[where]
            new = np.minimum(old + looks, prior_model.MAX_PASSES).astype(np.uint8)
            counts[where] = new
            lost = self._prior_flat.reshape(-1)[where] * (self._miss[old] - self._miss[new])
            self._left = self._left - np.bincount(where // wh, weights=lost, minlength=b)
        if self.believed_passes is None:
            return None
        own = np.zeros((b, self.uavs, wh), dtype=bool)
        pi, di = np.nonzero(entering)
        own[bi[pi], ui[pi], table[pi, di]] = True
        return own

    def _detect(self, moved: np.ndarray) -> np.ndarray:
        """(B, U, K) bool: the targets each passing vehicle detects now (pod < 1), one draw each target that
        has just entered its footprint (one still in the footprint it left is the same look)."""
        radius2 = self.cfg.fov**2 + 1e-9
        d2 = ((self.pos[:, :, None, :] - self.targets[:, None, :, :]) ** 2).sum(-1)
        in_disc = (d2 <= radius2) & moved[..., None]
        if self._came_from is not None:
            before = self._cells[self._came_from]  # (B, U, 2)
            d2_before = ((before[:, :, None, :] - self.targets[:, None, :, :]) ** 2).sum(-1)
            in_disc &= d2_before > radius2
        draws = uniform(self.seed, self.episodes, self.t, self._decider_ids, DETECTIONS, (self.targets.shape[1],))
        result: np.ndarray = in_disc & (draws < self.cfg.pod)
        return result

    def _record_pos(self) -> None:
        """Append the team's POS now; date the episodes reaching pos_goal."""
        if not self._tracking:
            return
        now = self.team_pos()
        self.pos_trace.append(now)
        self.pos_step[(self.pos_step < 0) & (now >= self.cfg.pos_goal - 1e-9)] = self.t

    def team_pos(self) -> np.ndarray:
        """(B,) the team's probability of success so far: 1 - the residual of the episode's prior after the
        passes flown (uniform prior when none was given; the explored share of the free cells at pod 1)."""
        if not self._tracking:
            raise RuntimeError("the team's POS is not tracked: make the SearchEnv with track_pos=True")
        result: np.ndarray = np.clip(self._prior_total - self._left, 0.0, 1.0)
        return result

    def density(self, passes: np.ndarray, rows: slice | np.ndarray = slice(None)) -> np.ndarray:
        """(B', U, W, H) float32 the residual density (prior.density) of the episodes `rows` after `passes`
        (B', U, W, H): pass counts, or explored masks at pod 1."""
        free = self._free_cells[rows]
        return prior_model.density(self.prior[rows][:, None], passes, self.cfg.pod, free[:, None])

    # ----- knowledge ------------------------------------------------------------------------
    def _sense_and_share(self, moved: np.ndarray) -> None:
        """Each vehicle senses its disc and broadcasts it with its position through the channel; the
        vehicles that `moved` (B, U) make a pass (passes counted, targets detected)."""
        b, u, w, h = self.batch, self.uavs, self.width, self.height
        disc = self._disc_table[self._cell]  # (B, U, D) flat cells
        explored = self.explored.reshape(b, u, w * h)
        kind = self.channel.kind
        own = self._count_passes(moved)
        delivered = None if kind == "ideal" else self._deliveries()  # (B, receiver, sender)
        if own is not None and self.detected is not None:  # pod < 1
            found = self._detect(moved)
            self.detected = self.detected | found.any(1)
            known = self._share_search(own, found, delivered)
            on = (self.pos[:, :, None, :] == self.targets[:, None, :, :]).all(-1)  # (B, U, K)
            self._hover = self._hover & (on & known).any(-1)  # a vehicle hovers on a target it knows of only
        if kind == "ideal":  # every vehicle gets every disc, positions and hover flags
            explored[self._bi[:, :, None], np.arange(u)[None, :, None], disc.reshape(b, 1, -1)] = True
            # new arrays, as below: beliefs handed out earlier keep what they were given
            self.known_pos = np.repeat(self.pos[:, None, :, :], u, axis=1)
            self.known_hover = np.repeat(self._hover[:, None, :], u, axis=1)
            self.heard.fill(self.t)
            return
        if kind == "none":
            explored[self._bi[:, :, None], np.arange(u)[None, :, None], disc] = True
        assert delivered is not None  # (made above for every channel but ideal)
        if kind != "none":
            sensed = np.zeros((b, u, w * h), dtype=bool)
            sensed[self._bi[:, :, None], np.arange(u)[None, :, None], disc] = True
            explored |= (delivered.astype(np.float32) @ sensed.astype(np.float32)) > 0
        self.known_pos = np.where(delivered[..., None], self.pos[:, None, :, :], self.known_pos)
        self.known_hover = np.where(delivered, self._hover[:, None, :], self.known_hover)
        self.heard = np.where(delivered, self.t, self.heard)

    def _share_search(self, own: np.ndarray, found: np.ndarray, delivered: np.ndarray | None) -> np.ndarray:
        """pod < 1: each vehicle's passes and detections now (own (B, U, W*H), found (B, U, K)) reach the
        vehicles the channel delivers them to (None: ideal, every vehicle), as explored cells do; returns
        the targets each vehicle knows of (B, U, K)."""
        assert self.believed_passes is not None and self.known_targets is not None
        if delivered is None:
            looks = np.broadcast_to(own.sum(1, dtype=np.int64)[:, None], own.shape)
            heard = np.broadcast_to(np.asarray(found.any(1))[:, None], found.shape)
        else:
            links = delivered.astype(np.float32)
            looks = np.rint(links @ own.astype(np.float32)).astype(np.int64)
            heard = np.asarray(links @ found.astype(np.float32)) > 0
        self.believed_passes = prior_model.add_passes(self.believed_passes, looks)
        known: np.ndarray = self.known_targets | heard
        self.known_targets = known
        return known

    def hovering_now(self) -> np.ndarray:
        """(B, U) bool: the vehicle is on a target and no lower-numbered vehicle is on the same cell: it
        hovers there (the controller's HOVER state) and says so with its position."""
        return self._hover.copy()

    def _hovering(self) -> np.ndarray:
        bi = np.arange(self.batch)[:, None]
        on_target = self.target_mask[bi, self.pos[..., 0], self.pos[..., 1]]
        same = (self.pos[:, :, None, :] == self.pos[:, None, :, :]).all(-1)
        result: np.ndarray = on_target & ~(same & self._lower).any(-1)
        return result

    def _deliveries(self) -> np.ndarray:
        b, u = self.batch, self.uavs
        eye = np.broadcast_to(np.eye(u, dtype=bool), (b, u, u))
        if self.channel.kind == "ideal":
            return np.ones((b, u, u), dtype=bool)
        if self.channel.kind == "none":
            return eye.copy()
        dist = np.sqrt(((self.pos[:, :, None, :] - self.pos[:, None, :, :]) ** 2).sum(-1))
        lost = self.channel.lost(dist, self.seed, self.episodes, self.t)  # [b, receiver, sender]
        result: np.ndarray = eye | ~lost
        return result

    def beliefs(self, batches: np.ndarray | None = None) -> Beliefs:
        """What each vehicle knows, as every policy reads it (B batches of U deciders, N = U vehicles);
        `batches` (bool mask or indices) keeps some episodes only."""
        rows = (
            slice(None)
            if batches is None
            else (np.flatnonzero(batches) if np.asarray(batches).dtype == bool else np.asarray(batches))
        )
        explored = self.explored[rows]
        phi, obstacles, seen = self.phi[rows], self.obstacles[rows], self._seen_value[rows]

        def masked(source: np.ndarray) -> np.ndarray:  # truth where explored, 1 elsewhere
            out = np.ones(explored.shape, dtype=np.float32)
            np.copyto(out, source[:, None], where=explored)
            return out

        def known_obstacles() -> np.ndarray:
            return _no_obstacles(explored.shape) if self._obstacle_free else explored & obstacles[:, None]

        targets = self.target_mask[rows]
        known_targets = lambda: explored & targets[:, None]  # noqa: E731
        value = lambda: masked(seen)  # noqa: E731
        phi_hat = lambda: masked(phi)  # noqa: E731
        density: Callable[[], np.ndarray] | None = None
        passes: Callable[[], np.ndarray] | None = None
        shape = explored.shape
        if self.believed_passes is not None and self.known_targets is not None:  # pod < 1
            counts = self.believed_passes[rows].reshape(shape)
            passes = lambda: counts  # noqa: E731
            density = lambda: self.density(counts, rows)  # noqa: E731
            known = self.known_targets[rows]
            cells = self.targets[rows]
            known_targets, phi_hat, value = self._known_maps(known, cells, explored, obstacles)
        elif not self.uniform_prior:  # pod 1: a cell explored once is cleared
            density = lambda: self.density(explored, rows)  # noqa: E731
        return Beliefs(
            explored,
            phi_hat,
            known_obstacles,
            known_targets,
            self.known_pos[rows],
            self.known_hover[rows],
            self._decider_ids[rows],
            self.episodes[rows],
            self.t,
            self.settings,
            value=value,
            density=density,
            passes=passes,
            pod=self.cfg.pod,
            heard=self.heard[rows],
        )

    def _known_maps(
        self, known: np.ndarray, cells: np.ndarray, explored: np.ndarray, obstacles: np.ndarray
    ) -> tuple[Callable[[], np.ndarray], Callable[[], np.ndarray], Callable[[], np.ndarray]]:
        """pod < 1: the known targets (B, U, W, H), phi_hat and the value channel made from the targets each
        vehicle knows of (`known` (B, U, K) of the targets `cells` (B, K, 2)): an undetected target
        shows nowhere."""
        b, u, w, h = explored.shape
        where = np.where(known[..., None], cells[:, None], -(10 * (w + h)))  # unknown targets: far off the map
        rho = np.float32(self.cfg.rho)

        def targets() -> np.ndarray:
            out = np.zeros(explored.shape, dtype=bool)
            bi, ui, ki = np.nonzero(known)
            out[bi, ui, cells[bi, ki, 0], cells[bi, ki, 1]] = True
            return out

        def phi_known() -> np.ndarray:
            phi = value_map(where, w, h, self.cfg.sigma2, self.cfg.phi_cutoff)
            return np.where(explored, phi, np.float32(1.0)).astype(np.float32)

        def value() -> np.ndarray:
            phi = value_map(where, w, h, self.cfg.sigma2, self.cfg.phi_cutoff) - rho * obstacles[:, None]
            return np.where(explored, phi, np.float32(1.0)).astype(np.float32)

        return targets, phi_known, value

    def observe(self, remove_taken: bool | None = None) -> np.ndarray:
        """(B, U, 3, F, F) float32 observations for every vehicle (remove_taken: default the world's).

        Without taken-target removal this is observe(self.beliefs()) built straight from the arrays
        behind the beliefs (the same builder, observe.build_observations, on the same values:
        tests/test_fast_paths.py holds them equal), which saves a third of a step at batch 1."""
        taken = self.cfg.remove_taken if remove_taken is None else remove_taken
        if taken or self.settings.variant != PAPER_VARIANT or self.known_targets is not None:
            return observe(self.beliefs(), taken)
        value = np.ones(self.explored.shape, dtype=np.float32)
        np.copyto(value, self._seen_value[:, None], where=self.explored)
        others = (self.known_pos[..., 0] >= 0) & self._not_me
        s = self.settings
        return build_observations(value, self.pos, self.known_pos, others, s.window, s.rho)


@lru_cache(maxsize=16)
def _no_obstacles(shape: tuple[int, ...]) -> np.ndarray:
    """An all-False, read-only view of `shape`: the known obstacles of an obstacle-free world."""
    return np.broadcast_to(False, shape)


def _disc_inside(width: int, height: int, offsets: np.ndarray) -> np.ndarray:
    """(W*H, D) bool: which entries of _disc_table are cells of the disc (the others repeat the centre),
    so that each cell of a disc is counted once."""
    xs, ys = np.meshgrid(np.arange(width), np.arange(height), indexing="ij")
    cx = xs.ravel()[:, None] + offsets[:, 0]
    cy = ys.ravel()[:, None] + offsets[:, 1]
    result: np.ndarray = (cx >= 0) & (cx < width) & (cy >= 0) & (cy < height)
    return result


def _disc_table(width: int, height: int, offsets: np.ndarray) -> np.ndarray:
    """(W*H, D) flat indices of the sensing disc around every cell; cells off the map repeat the
    centre (setting a cell twice is harmless), so sensing is one gather with no masks."""
    xs, ys = np.meshgrid(np.arange(width), np.arange(height), indexing="ij")
    cx = xs.ravel()[:, None] + offsets[:, 0]
    cy = ys.ravel()[:, None] + offsets[:, 1]
    inside = (cx >= 0) & (cx < width) & (cy >= 0) & (cy < height)
    centre = (xs.ravel() * height + ys.ravel())[:, None]
    return np.where(inside, cx * height + cy, centre)


# Peak bytes of a SearchEnv and a policy stepping it, measured with tracemalloc (numpy arrays) and
# rounded up: the disc table is built through about four int64 temporaries per disc cell; per episode
# and cell, each vehicle's knowledge and the policies' maps took at most 95 B (LA(4); frontier 45 B).
DISC_BYTES_PER_CELL_OFFSET = 32
EPISODE_BYTES_PER_CELL = 32
VEHICLE_BYTES_PER_CELL = 128
OBSERVATION_COPIES = 3  # an observation batch, the next one and the network's input


def planned_bytes(cfg: WorldConfig, batch: int, cells: int | None = None) -> int:
    """About how much memory B = `batch` episodes of `cfg` take while a policy steps them, observations
    included (`cells`: the map's cell count when it is not M x M, e.g. a real grid)."""
    cells = cfg.map_size**2 if cells is None else int(cells)
    disc = DISC_BYTES_PER_CELL_OFFSET * len(fov_offsets(cfg.fov)) * cells
    per_episode = cells * (EPISODE_BYTES_PER_CELL + VEHICLE_BYTES_PER_CELL * cfg.uavs)
    per_episode += OBSERVATION_COPIES * cfg.uavs * 3 * cfg.window**2 * 4 + 16 * cfg.uavs**2
    return disc + batch * per_episode
