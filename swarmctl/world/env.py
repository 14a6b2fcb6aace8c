"""The batched search world: B episodes x U vehicles stepped at once in numpy arrays.

    env = SearchEnv(WorldConfig(), batch=256)
    obs = env.reset(seed=0)                       # (B, U, 3, F, F)
    obs, reward, success, info = env.step(actions)  # actions (B, U) in 0..4

Semantics (PAPER.md, CONTRACTS.md): a move outside the map or into an obstacle leaves the vehicle
where it is (nu = 0, penalty theta); vehicles whose post-move cells coincide collide (penalty psi,
no target reward); a swap is not a collision; a vehicle on a target cell without collision earns
+1. Success at step t: after the t-th joint move every vehicle is on a target and no two share a
cell. With `stop_at_success` (test episodes) a successful episode freezes; training episodes run on.

Each vehicle has its own knowledge (explored mask and where it believes the others are). After every
move each vehicle senses the disc of radius zeta around itself and broadcasts what it sensed and its
position; the channel decides which receivers get it (ideal: all, none: nobody, model/fixed: each
message lost independently). A batch of one is what the controller uses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarmctl.errors import ScenarioError
from swarmctl.world.channel import Channel
from swarmctl.world.config import WorldConfig
from swarmctl.world.moves import MOVES, STAY
from swarmctl.world.observe import build_observations
from swarmctl.world.scenario import Scenario, fov_offsets, generate_scenario, value_map
from swarmctl.world.taken import remove_taken_targets


@dataclass
class StepInfo:
    """Per-step details: moves that were valid (nu), collisions (chi), and guard refusals."""

    valid: np.ndarray  # (B, U) bool
    collided: np.ndarray  # (B, U) bool
    on_target: np.ndarray  # (B, U) bool
    refused: np.ndarray  # (B, U) bool, moves the guard turned into "stay"


class SearchEnv:
    """B parallel episodes of the paper's search world."""

    phi_tolerance = 1e-6  # phi is exact here (the controller's Knowledge carries it quantised)

    def __init__(self, cfg: WorldConfig, batch: int = 1, stop_at_success: bool = True, observations: bool = True):
        if batch < 1:
            raise ScenarioError(f"batch {batch} must be >= 1")
        self.cfg = cfg
        self.batch = batch
        self.stop_at_success = stop_at_success
        self.observations = observations
        self.channel = Channel(cfg.channel, cfg.cell_size, cfg.loss)
        self._offsets = fov_offsets(cfg.fov)
        self._disc_table: np.ndarray | None = None
        self.width = self.height = cfg.map_size
        self.scenarios: list[Scenario] = []
        self.last_observations: np.ndarray | None = None

    # ----- episode set-up -------------------------------------------------------------------
    def reset(
        self, seed: int = 0, episodes: np.ndarray | range | None = None, blocked: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Start B episodes; episode indices default to 0..B-1. Returns observations (or None).
        `blocked` (W, H) bool: every episode on this fixed map (a real area's grid), targets and
        starts drawn on it (scenario.generate_scenario)."""
        if episodes is None:
            episodes = range(self.batch)
        episodes = list(episodes)
        if len(episodes) != self.batch:
            raise ScenarioError(f"reset got {len(episodes)} episode indices for a batch of {self.batch}")
        scenarios = [generate_scenario(self.cfg, seed, int(i), blocked) for i in episodes]
        return self.reset_to(scenarios, seed=seed + 7_919 * (episodes[0] + 1))

    def reset_to(self, scenarios: list[Scenario], seed: int = 0) -> np.ndarray | None:
        """Start from given scenarios (hand-built cases, real maps). All share one grid size."""
        if len(scenarios) != self.batch:
            raise ScenarioError(f"reset_to got {len(scenarios)} scenarios for a batch of {self.batch}")
        self.scenarios = scenarios
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
        self._seen_value = (self.phi - self.cfg.rho * self.obstacles).astype(np.float32)
        self._disc_table = _disc_table(self.width, self.height, self._offsets)
        self.explored = np.zeros((b, self.uavs, self.width, self.height), dtype=bool)
        self.known_pos = np.full((b, self.uavs, self.uavs, 2), -1, dtype=np.int64)
        self.t = 0
        self.done = np.zeros(b, dtype=bool)
        self.duration = np.zeros(b, dtype=np.int64)  # step of success, 0 while running
        self.collisions = np.zeros(b, dtype=np.int64)
        self.rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xC4A7]))
        self._sense_and_share()
        self.last_observations = self.observe() if self.observations else None
        return self.last_observations

    # ----- one joint move -------------------------------------------------------------------
    def step(self, actions: np.ndarray):
        """Apply a joint move. Returns (obs or None, reward (B, U), success (B,), StepInfo)."""
        cfg = self.cfg
        actions = np.asarray(actions, dtype=np.int64)
        if actions.shape != (self.batch, self.uavs) or actions.min() < 0 or actions.max() >= len(MOVES):
            raise ValueError(f"actions must be ints in 0..4 of shape {(self.batch, self.uavs)}")
        if self.stop_at_success:
            actions = np.where(self.done[:, None], STAY, actions)
        prop = self.pos + MOVES[actions]
        inside = (prop[..., 0] >= 0) & (prop[..., 0] < self.width) & (prop[..., 1] >= 0) & (prop[..., 1] < self.height)
        px = np.clip(prop[..., 0], 0, self.width - 1)
        py = np.clip(prop[..., 1], 0, self.height - 1)
        bi = np.arange(self.batch)[:, None]
        valid = inside & ~self.obstacles[bi, px, py]
        dest = np.where(valid[..., None], prop, self.pos)
        refused = np.zeros_like(valid)
        if cfg.guard:
            refused = guard_refusals(self.pos, dest)
            dest = np.where(refused[..., None], self.pos, dest)
        self.pos = dest

        same = (dest[:, :, None, :] == dest[:, None, :, :]).all(-1)  # (B, U, U)
        collided = same.sum(-1) > 1
        on_target = self.target_mask[bi, dest[..., 0], dest[..., 1]]
        reward = (-cfg.theta * (~valid) - cfg.psi * collided + (~collided & on_target)).astype(np.float32)
        success = on_target.all(1) & ~collided.any(1)

        self.t += 1
        running = ~self.done
        self.collisions += (collided.any(1) & running).astype(np.int64)
        newly = success & running
        self.duration[newly] = self.t
        if self.stop_at_success:
            self.done |= success
        self._sense_and_share()
        obs = self.last_observations = self.observe() if self.observations else None
        return obs, reward, success, StepInfo(valid=valid, collided=collided, on_target=on_target, refused=refused)

    # ----- knowledge ------------------------------------------------------------------------
    def _sense_and_share(self) -> None:
        """Each vehicle senses its disc and broadcasts it with its position through the channel."""
        b, u, w, h = self.batch, self.uavs, self.width, self.height
        disc = self._disc_table[self.pos[..., 0] * h + self.pos[..., 1]]  # (B, U, D) flat cells
        sensed = np.zeros((b, u, w * h), dtype=bool)
        sensed[np.arange(b)[:, None, None], np.arange(u)[None, :, None], disc] = True
        explored = self.explored.reshape(b, u, w * h)
        delivered = self._deliveries()  # (B, receiver, sender)
        if self.channel.kind == "ideal":
            explored |= sensed.any(1, keepdims=True)
        elif self.channel.kind == "none":
            explored |= sensed
        else:
            explored |= (delivered.astype(np.float32) @ sensed.astype(np.float32)) > 0
        self.known_pos = np.where(delivered[..., None], self.pos[:, None, :, :], self.known_pos)

    def _deliveries(self) -> np.ndarray:
        b, u = self.batch, self.uavs
        eye = np.broadcast_to(np.eye(u, dtype=bool), (b, u, u))
        if self.channel.kind == "ideal":
            return np.ones((b, u, u), dtype=bool)
        if self.channel.kind == "none":
            return eye.copy()
        dist = np.sqrt(((self.pos[:, :, None, :] - self.pos[:, None, :, :]) ** 2).sum(-1))
        lost = self.rng.random((b, u, u)) < self.channel.loss_probability(dist)
        return eye | ~lost

    def known_value(self) -> np.ndarray:
        """phi_hat per vehicle (B, U, W, H): true phi where explored, 1 elsewhere."""
        return np.where(self.explored, self.phi[:, None], np.float32(1.0))

    def known_obstacles(self) -> np.ndarray:
        """omega_hat per vehicle (B, U, W, H): obstacles the vehicle has explored."""
        return self.explored & self.obstacles[:, None]

    def others_count(self) -> np.ndarray:
        """(B, U, W, H) int: how many other vehicles each vehicle believes are on each cell."""
        b, u, w, h = self.batch, self.uavs, self.width, self.height
        kp = self.known_pos  # (B, V, U, 2)
        valid = (kp[..., 0] >= 0) & ~np.eye(u, dtype=bool)[None]
        bi, vi, _ = np.nonzero(valid)
        flat = ((bi * u + vi) * w + kp[..., 0][valid]) * h + kp[..., 1][valid]
        return np.bincount(flat, minlength=b * u * w * h).reshape(b, u, w, h)

    def taken_targets(self) -> np.ndarray:
        """(B, U, W, H) bool: explored target cells on which the vehicle believes another vehicle is."""
        return (self.others_count() > 0) & self.explored & self.target_mask[:, None]

    def value_channel(self, remove_taken: bool | None = None) -> np.ndarray:
        """phi_hat - rho * omega_hat per vehicle (B, U, W, H) float32; with remove_taken (default:
        the world's setting) the targets others sit on are removed from phi_hat (world.taken)."""
        out = np.ones(self.explored.shape, dtype=np.float32)
        if remove_taken is None:
            remove_taken = self.cfg.remove_taken
        taken = self.taken_targets() if remove_taken else None
        if taken is not None and taken.any():
            phi = remove_taken_targets(self.known_value(), self.explored, taken, self.cfg.sigma2, self.cfg.phi_cutoff)
            seen = phi - np.float32(self.cfg.rho) * self.obstacles[:, None]
            np.copyto(out, seen, where=self.explored)
        else:
            np.copyto(out, self._seen_value[:, None], where=self.explored)
        return out

    def observe(self, remove_taken: bool | None = None) -> np.ndarray:
        """(B, U, 3, F, F) float32 observations for every vehicle."""
        return build_observations(
            self.value_channel(remove_taken), self.pos, self.known_pos, self.cfg.window, self.cfg.rho
        )


def _disc_table(width: int, height: int, offsets: np.ndarray) -> np.ndarray:
    """(W*H, D) flat indices of the sensing disc around every cell; cells off the map repeat the
    centre (setting a cell twice is harmless), so sensing is one gather with no masks."""
    xs, ys = np.meshgrid(np.arange(width), np.arange(height), indexing="ij")
    cx = xs.ravel()[:, None] + offsets[:, 0]
    cy = ys.ravel()[:, None] + offsets[:, 1]
    inside = (cx >= 0) & (cx < width) & (cy >= 0) & (cy < height)
    centre = (xs.ravel() * height + ys.ravel())[:, None]
    return np.where(inside, cx * height + cy, centre)


def guard_refusals(pos: np.ndarray, dest: np.ndarray) -> np.ndarray:
    """The controller's guard, vectorised: a move is refused when its destination is a cell another
    vehicle holds or is moving to. pos, dest (B, U, 2) -> refused (B, U) bool (stays are never refused)."""
    u = pos.shape[1]
    moving = (dest != pos).any(-1)
    other = ~np.eye(u, dtype=bool)
    holds = ((dest[:, :, None, :] == pos[:, None, :, :]).all(-1) & other).any(-1)
    enters = ((dest[:, :, None, :] == dest[:, None, :, :]).all(-1) & other).any(-1)
    return moving & (holds | enters)
