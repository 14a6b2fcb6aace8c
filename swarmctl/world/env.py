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
  covered: every free cell 4-connected to a start cell has been sensed by step t (`covered_fraction`).
With `stop_at_success` (test episodes) a successful episode freezes; training episodes run on.

Each vehicle has its own knowledge (explored mask, where it believes the others are and whether they
hover on a target). After every move each vehicle senses the disc of radius zeta around itself and
broadcasts what it sensed, its position and whether it hovers; the channel decides which receivers
get it (ideal: all, none: nobody, model/fixed: each message lost independently, by a draw keyed by
(seed, episode, step, sender, receiver), so the batch never changes which messages are lost). Policies
see only `beliefs()` (swarmctl.world.beliefs), never the hidden targets; `observe()` is the paper's
observation built from them. With `cfg.guard` the safety guard (swarmctl.world.guard) turns refused moves into
"stay" before they are applied, as the controller does.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from swarmctl.errors import ScenarioError
from swarmctl.world.beliefs import PAPER_VARIANT, Beliefs, ObservationSettings
from swarmctl.world.channel import Channel
from swarmctl.world.config import WorldConfig
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

    def __init__(self, cfg: WorldConfig, batch: int = 1, stop_at_success: bool = True, observations: bool = True):
        if batch < 1:
            raise ScenarioError(f"batch {batch} must be >= 1")
        self.cfg = cfg
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
        self, seed: int = 0, episodes: Iterable[int] | None = None, blocked: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Start B episodes; episode indices default to 0..B-1. Returns observations (or None).
        `blocked` (W, H) bool: every episode on this fixed map (a real area's grid), targets and
        starts drawn on it (scenario.generate_scenario)."""
        ids = list(range(self.batch) if episodes is None else episodes)
        if len(ids) != self.batch:
            raise ScenarioError(f"reset got {len(ids)} episode indices for a batch of {self.batch}")
        scenarios = [generate_scenario(self.cfg, seed, int(i), blocked) for i in ids]
        return self.reset_to(scenarios, seed=seed, episodes=ids)

    def reset_to(
        self, scenarios: list[Scenario], seed: int = 0, episodes: Iterable[int] | None = None
    ) -> np.ndarray | None:
        """Start from given scenarios (hand-built cases, real maps). All share one grid size.
        `seed`: the episode seed (as given to reset); `episodes`: their ids (default 0..B-1). The ids key
        the policies' random draws; seed and ids key the channel's message losses (Channel.lost)."""
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
        self._sense_and_share()
        self._record_sensing()
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
        self._sense_and_share()
        if cfg.finish == "held":
            success = on_target.all(1) & ~any_collision
        else:  # found / covered read what the discs sensed on arrival
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
        new = (self.found_step < 0) & self._sensed[self._bi, self._target_cells]
        self.found_step[new] = self.t

    def _finished(self) -> np.ndarray:
        """(B,) bool: the finish line `found` or `covered` is reached."""
        if self.cfg.finish == "found":
            found = np.asarray((self.found_step >= 0).all(1))  # (an array: numpy's stubs allow a scalar)
            return found
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

    # ----- knowledge ------------------------------------------------------------------------
    def _sense_and_share(self) -> None:
        """Each vehicle senses its disc and broadcasts it with its position through the channel."""
        b, u, w, h = self.batch, self.uavs, self.width, self.height
        disc = self._disc_table[self._cell]  # (B, U, D) flat cells
        explored = self.explored.reshape(b, u, w * h)
        kind = self.channel.kind
        if kind == "ideal":  # every vehicle gets every disc, positions and hover flags
            explored[self._bi[:, :, None], np.arange(u)[None, :, None], disc.reshape(b, 1, -1)] = True
            # new arrays, as below: beliefs handed out earlier keep what they were given
            self.known_pos = np.repeat(self.pos[:, None, :, :], u, axis=1)
            self.known_hover = np.repeat(self._hover[:, None, :], u, axis=1)
            return
        if kind == "none":
            explored[self._bi[:, :, None], np.arange(u)[None, :, None], disc] = True
        delivered = self._deliveries()  # (B, receiver, sender)
        if kind != "none":
            sensed = np.zeros((b, u, w * h), dtype=bool)
            sensed[self._bi[:, :, None], np.arange(u)[None, :, None], disc] = True
            explored |= (delivered.astype(np.float32) @ sensed.astype(np.float32)) > 0
        self.known_pos = np.where(delivered[..., None], self.pos[:, None, :, :], self.known_pos)
        self.known_hover = np.where(delivered, self._hover[:, None, :], self.known_hover)

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
        return Beliefs(
            explored,
            lambda: masked(phi),
            known_obstacles,
            lambda: explored & targets[:, None],
            self.known_pos[rows],
            self.known_hover[rows],
            self._decider_ids[rows],
            self.episodes[rows],
            self.t,
            self.settings,
            value=lambda: masked(seen),
        )

    def observe(self, remove_taken: bool | None = None) -> np.ndarray:
        """(B, U, 3, F, F) float32 observations for every vehicle (remove_taken: default the world's).

        Without taken-target removal this is observe(self.beliefs()) built straight from the arrays
        behind the beliefs (the same builder, observe.build_observations, on the same values:
        tests/test_fast_paths.py holds them equal), which saves a third of a step at batch 1."""
        taken = self.cfg.remove_taken if remove_taken is None else remove_taken
        if taken or self.settings.variant != PAPER_VARIANT:
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
