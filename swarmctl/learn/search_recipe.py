"""The search recipe: deep Q-learning from demonstrations (DQfD, Hester et al., AAAI 2018) with a team
reward, DAgger labels and a curriculum by competence, read top to bottom.

One Q-network (`make_network(world.variant, world.window)`, the world's observation variant) chooses
every vehicle's move, as in swarmctl.learn.ddql (the paper's trainer, unchanged beside this one). What
differs:

- The reward is the team's (`team_reward`), the same for every vehicle of an episode, computed from
  SearchEnv's arrays before and after a step (SearchEnv's own reward, the paper's, is not read):
  + per target the swarm sees for the first time, + per free cell it sees for the first time (the
  union over vehicles), - a cost per joint step, - per vehicle in a collision, + a bonus on success.
  Success is terminal (no bootstrap); the step limit is a truncation (bootstrap).
- The rules (`search_mask`): moves off the map, into a known obstacle or into a cell another vehicle
  holds are masked; no hover rule: staying on a target is the network's choice. They go into the
  checkpoint (`train["recipe"]`, `flight_rules`) so that `ddql:PATH` flies the model as trained.
- Demonstrations: the coordinated planner's episodes in a store per stage that is never evicted, and
  DAgger rounds: every `dagger_every`-th round the student acts (with exploration) and the planner
  labels every state it visits (`CoordinatedPolicy.act` on the same beliefs); those go to the
  demonstration store's own ring.
- The loss (`dqfd_loss`): n-step double-DQN TD + 1-step TD + the large-margin supervised loss on the
  samples that carry a teacher's label (`margin_loss`: each other move's hinge summed; DQfD's max form
  is an option, see there why it is not the default) + L2 (Adam's weight decay); a batch draws
  `demo_share` of its samples from the demonstrations (annealed), and each part is stratified by stage.
- The curriculum (swarmctl.learn.search_config): the next stage opens when the student's validation
  success reaches `advance_share` of the teacher's on the same episodes; earlier stages stay in the
  replay. Selection on the validation seed, the report on the test seed; both through
  swarmctl.learn.evaluate.run_policy, as `swarmctl eval` measures.

train() runs: prefill (a stage's demonstrations), pre-training on them, then rounds of collect (P
episodes stepped together, learning after each joint step) and, every `eval_every` episodes,
evaluate-and-save. Everything is seeded: the episodes by (seed, episode), the exploration by draws
keyed by (seed, episode, step, vehicle), the replay's sampling by torch generators.
"""

from __future__ import annotations

import copy
import csv
import json
import shutil
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from swarmctl.errors import InputError, ScenarioError
from swarmctl.learn.ddql import (
    LAYOUT,
    PREFILL_EPISODE_OFFSET,
    TRAIN_EPISODE_OFFSET,
    best_path,
    git_commit,
    replay_path,
    resume_snapshot,
    same_options,
)
from swarmctl.learn.evaluate import run_policy
from swarmctl.learn.kernels import fuse_conv_relu, keep_freed_memory, twin_forward
from swarmctl.learn.search_config import SearchConfig, SearchStage, StageWorld, refuse_held_out
from swarmctl.policy.base import allowed_moves, softmax_sample
from swarmctl.policy.checkpoint import save_checkpoint
from swarmctl.policy.coordinated import CoordinatedPolicy
from swarmctl.policy.fused import to_memory_format
from swarmctl.policy.hover import NO
from swarmctl.policy.qnet import QNet, make_network
from swarmctl.world.beliefs import Beliefs
from swarmctl.world.config import WorldConfig
from swarmctl.world.draws import uniform
from swarmctl.world.env import SearchEnv
from swarmctl.world.moves import N_ACTIONS, STAY

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.learn.city_maps import CityMaps  # loaded with the first city world (shapely)

RECIPE = "dqfd-search-v1"  # the checkpoint's train["recipe"]["name"]
EXPLORE_COIN, EXPLORE_PICK = 0x5EA0, 0x5EA1  # streams of the student's exploration draws
STAGE_EPISODES = 10_000_000  # demonstration episode ids: PREFILL_EPISODE_OFFSET + stage, world, episode
CITY_CROPS = 4  # crops a city world's validation and test episodes are spread over


# --- 1. the team reward -------------------------------------------------------------------------------


@dataclass(frozen=True)
class RewardWeights:
    target: float = 1.0
    cell: float = 0.01
    step: float = 0.05
    success: float = 10.0
    collision: float = 1.0

    @classmethod
    def of(cls, cfg: SearchConfig) -> RewardWeights:
        return cls(cfg.reward_target, cfg.reward_cell, cfg.step_cost, cfg.success_bonus, cfg.collision_penalty)


def swarm_explored(env: SearchEnv) -> np.ndarray:
    """(B, W, H) bool: the cells some vehicle of each episode knows (sensed, or received)."""
    return np.asarray(env.explored.any(axis=1))


def team_reward(
    weights: RewardWeights,
    before: np.ndarray,
    after: np.ndarray,
    targets: np.ndarray,
    obstacles: np.ndarray,
    collided: np.ndarray,
    success: np.ndarray,
) -> np.ndarray:
    """(B,) float32: the team's reward for one joint step, from what the swarm knew before (B, W, H) and
    after it, the targets and obstacles (B, W, H), who collided (B, U) and which episodes succeeded (B,)."""
    new = after & ~before
    found = (new & targets).sum(axis=(1, 2))
    cells = (new & ~obstacles).sum(axis=(1, 2))
    reward = (
        weights.target * found
        + weights.cell * cells
        - weights.step
        - weights.collision * collided.sum(axis=1)
        + weights.success * success
    )
    return reward.astype(np.float32)


def step_team(env: SearchEnv, actions: np.ndarray, weights: RewardWeights) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """env.step with the team reward: (observations, team reward (B,), success (B,))."""
    before = swarm_explored(env)
    obs, _, success, info = env.step(actions)
    assert obs is not None  # the trainer's environments observe
    reward = team_reward(weights, before, swarm_explored(env), env.target_mask, env.obstacles, info.collided, success)
    return obs, reward, success


# --- 2. the rules ---------------------------------------------------------------------------------------


def search_mask(beliefs: Beliefs) -> np.ndarray:
    """(B, U, 5) bool: the moves the recipe allows: none off the map, into a known obstacle or into a cell
    another vehicle holds; no hover rule (staying on a target, or leaving it, is the network's choice)."""
    return allowed_moves(beliefs, hover=NO, mask=True)


def flight_rules(world: WorldConfig) -> dict[str, str]:
    """The checkpoint's train["recipe"]: the decision rules and observation of training, in the names of
    `ddql:` options (swarmctl.policy.ddql), so that the model flies as it was trained."""
    return {"name": RECIPE, "hover": NO, "mask": "yes", "taken": "remove" if world.remove_taken else "keep"}


def policy_spec(path: Path, rules: dict[str, str]) -> str:
    """The `ddql:` spec that flies a checkpoint under its recipe's rules, each option written out."""
    return f"ddql:{path}:hover={rules['hover']}:mask={rules['mask']}:taken={rules['taken']}"


# --- 3. episodes: demonstrations, the student's, DAgger ---------------------------------------------------


@dataclass
class Rollout:
    """T joint steps of B episodes x U vehicles (T: the longest episode; an episode stops at success)."""

    obs: np.ndarray  # (T + 1, B, U, C, F, F) float16
    allowed: np.ndarray  # (T + 1, B, U, 5) bool, search_mask at each observation
    actions: np.ndarray  # (T, B, U) the moves made
    expert: np.ndarray  # (T, B, U) the teacher's moves in those states, -1 where not labelled
    rewards: np.ndarray  # (T, B) float32 team reward
    live: np.ndarray  # (T, B) bool, the episode was running before step t
    success: np.ndarray  # (B,) bool, it succeeded (its last step is terminal)


# A label in the stores: the teacher's move + LABEL_BASE x the bits of the other moves as good as it (none:
# the move alone, as every run before teacher_ties); -1: no label
LABEL_BASE = 8


def encode_label(moves: np.ndarray, ties: np.ndarray) -> np.ndarray:
    """(...) int64 labels of the teacher's moves (...) and the moves as good as them (..., 5) bool."""
    bits = (ties.astype(np.int64) << np.arange(ties.shape[-1])).sum(-1)
    return moves.astype(np.int64) + LABEL_BASE * bits


def labelled_moves(expert: torch.Tensor, n_actions: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The stores' labels (N,) (>= 0) as the teacher's moves (N,) and every labelled move (N, n_actions) bool."""
    move = expert % LABEL_BASE
    bits = (expert // LABEL_BASE)[:, None] >> torch.arange(n_actions, device=expert.device)
    return move, F.one_hot(move, n_actions).bool() | (bits & 1).bool()


# (env, observations (B, U, C, F, F) float32, allowed moves (B, U, 5)) -> moves (B, U)
Actor = Callable[[SearchEnv, np.ndarray, np.ndarray], np.ndarray]


def rollout(
    env: SearchEnv,
    obs: np.ndarray,
    steps: int,
    weights: RewardWeights,
    act: Actor | None = None,
    teacher: CoordinatedPolicy | None = None,
    after_step: Callable[[], None] | None = None,
    ties: bool = False,
) -> Rollout:
    """Run the episodes `env` was reset to (stop_at_success: each stops at success) for up to `steps` joint
    steps. `act` moves (None: the teacher moves, and labels its own moves); `teacher` labels every state
    (DAgger) with the step limit as its horizon, with `ties` every move as good as its own too (encode_label);
    `after_step` is called after every joint step."""
    if act is None and teacher is None:
        raise ValueError("rollout needs an actor or a teacher")
    if teacher is not None:
        teacher.horizon = steps
        teacher.reset(env.beliefs(), env.seed)
    b, u = env.batch, env.uavs
    beliefs = env.beliefs()
    seen, masks = [obs.astype(np.float16)], [search_mask(beliefs)]
    actions, expert, rewards, live = [], [], [], []
    success = np.zeros(b, dtype=bool)
    for _ in range(steps):
        running = ~env.done
        if not running.any():
            break
        if teacher is None:
            label = np.full((b, u), -1, dtype=np.int64)
        elif ties:
            label = encode_label(*teacher.labels(beliefs))
        else:
            label = teacher.act(beliefs)
        moves = label % LABEL_BASE if act is None else act(env, obs, masks[-1])
        moves = np.where(running[:, None], moves, STAY)
        obs, reward, succeeded = step_team(env, moves, weights)
        success |= succeeded & running
        beliefs = env.beliefs()
        seen.append(obs.astype(np.float16))
        masks.append(search_mask(beliefs))
        actions.append(moves)
        expert.append(label)
        rewards.append(reward)
        live.append(running)
        if after_step is not None:
            after_step()
    return Rollout(
        np.stack(seen),
        np.stack(masks),
        np.stack(actions).astype(np.int64),
        np.stack(expert).astype(np.int64),
        np.stack(rewards).astype(np.float32),
        np.stack(live),
        success,
    )


# --- 4. n-step returns and the trajectories the stores hold -------------------------------------------------


def nstep_returns(
    rewards: np.ndarray, terminal: bool, n: int, gamma: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For one trajectory's L rewards: each step's n-step return sum_{i<k} gamma^i r_{t+i}, the discount of
    its bootstrap (gamma^k, 0 where those k steps reach a terminal end) and k = min(n, L - t), the steps
    ahead of its bootstrap observation. A trajectory that was cut by the step limit (not terminal)
    bootstraps from its last observation."""
    length = len(rewards)
    t = np.arange(length)
    ahead = np.minimum(n, length - t)
    ret = np.zeros(length, dtype=np.float64)
    for i in range(min(n, length)):
        ok = i < ahead
        ret[ok] += gamma**i * rewards[t[ok] + i]
    disc = np.power(gamma, ahead.astype(np.float64))
    if terminal:
        disc[t + ahead == length] = 0.0
    return ret.astype(np.float32), disc.astype(np.float32), ahead.astype(np.int64)


@dataclass
class Trajectories:
    """Whole trajectories, one per (episode, vehicle), as consecutive rows: each of its L transitions,
    then its last observation (a row that is no sample). A row's bootstrap observations are the rows 1
    and `ahead` after it."""

    obs: np.ndarray  # (S, C, F, F) float16
    allowed: np.ndarray  # (S, 5) bool
    action: np.ndarray  # (S,) int64
    expert: np.ndarray  # (S,) int64, -1: no label
    reward: np.ndarray  # (S,) float32, the 1-step team reward
    disc1: np.ndarray  # (S,) float32, gamma or 0 (terminal)
    ret_n: np.ndarray  # (S,) float32
    disc_n: np.ndarray  # (S,) float32
    ahead: np.ndarray  # (S,) int64, rows to the n-step bootstrap observation
    sample: np.ndarray  # (S,) bool, the row starts a transition
    lengths: np.ndarray  # (P,) rows per trajectory

    @property
    def samples(self) -> int:
        return int(self.sample.sum())


def trajectories(r: Rollout, n: int, gamma: float) -> Trajectories:
    """The rollout's trajectories with their 1-step and n-step targets' parts."""
    steps, b, u = r.actions.shape
    lengths = r.live.sum(axis=0)
    parts: dict[str, list[np.ndarray]] = {f.name: [] for f in fields(Trajectories) if f.name != "lengths"}
    rows = []
    for e in range(b):
        length = int(lengths[e])
        if length == 0:
            continue
        terminal = bool(r.success[e])
        ret_n, disc_n, ahead = nstep_returns(r.rewards[:length, e], terminal, n, gamma)
        ret_1, disc_1, _ = nstep_returns(r.rewards[:length, e], terminal, 1, gamma)
        pad = np.zeros(1, dtype=np.float32)
        for v in range(u):
            parts["obs"].append(r.obs[: length + 1, e, v])
            parts["allowed"].append(r.allowed[: length + 1, e, v])
            parts["action"].append(np.append(r.actions[:length, e, v], STAY))
            parts["expert"].append(np.append(r.expert[:length, e, v], -1))
            parts["reward"].append(np.concatenate([ret_1, pad]))
            parts["disc1"].append(np.concatenate([disc_1, pad]))
            parts["ret_n"].append(np.concatenate([ret_n, pad]))
            parts["disc_n"].append(np.concatenate([disc_n, pad]))
            parts["ahead"].append(np.append(ahead, 0))
            parts["sample"].append(np.arange(length + 1) < length)
            rows.append(length + 1)
    if not rows:
        raise ValueError("a rollout without a step")
    return Trajectories(**{k: np.concatenate(v) for k, v in parts.items()}, lengths=np.array(rows, dtype=np.int64))


# --- 5. the stores ----------------------------------------------------------------------------------------------


@dataclass
class Batch:
    """A minibatch on the training device (observations float32 in the trainer's layout)."""

    obs: torch.Tensor
    next1: torch.Tensor
    next_n: torch.Tensor
    action: torch.Tensor
    expert: torch.Tensor
    reward: torch.Tensor
    disc1: torch.Tensor
    ret_n: torch.Tensor
    disc_n: torch.Tensor
    allowed: torch.Tensor
    allowed1: torch.Tensor
    allowed_n: torch.Tensor

    @classmethod
    def cat(cls, parts: Sequence[Batch]) -> Batch:
        return cls(**{f.name: torch.cat([getattr(p, f.name) for p in parts]) for f in fields(cls)})


class TransitionStore:
    """Trajectories in a ring of slots on the training device.

    A slot holds an observation and, where a transition starts, its action, label, rewards, discounts
    and the slots of its 1-step and n-step bootstrap observations: later slots of the same trajectory.
    A trajectory never wraps round the ring's end (the cursor goes back to `keep` first) and slots are
    overwritten in order, so the slots a transition points to are overwritten only after its own: a
    transition is valid while its own slot holds it. Slots below `keep` (`protect`: the demonstrations)
    are never overwritten."""

    ARRAYS = ("obs", "allowed", "action", "expert", "reward", "disc1", "ret_n", "disc_n", "next1", "next_n", "sample")

    def __init__(self, capacity: int, obs_shape: tuple[int, ...], key: Sequence[int], device: torch.device):
        self.capacity, self.device = int(capacity), device
        self.obs = torch.zeros((capacity, *obs_shape), dtype=torch.float16, device=device)
        self.allowed = torch.zeros((capacity, N_ACTIONS), dtype=torch.bool, device=device)
        self.action = torch.zeros(capacity, dtype=torch.int64, device=device)
        self.expert = torch.full((capacity,), -1, dtype=torch.int64, device=device)
        self.reward = torch.zeros(capacity, dtype=torch.float32, device=device)
        self.disc1 = torch.zeros(capacity, dtype=torch.float32, device=device)
        self.ret_n = torch.zeros(capacity, dtype=torch.float32, device=device)
        self.disc_n = torch.zeros(capacity, dtype=torch.float32, device=device)
        self.next1 = torch.zeros(capacity, dtype=torch.int64, device=device)
        self.next_n = torch.zeros(capacity, dtype=torch.int64, device=device)
        self.sample = torch.zeros(capacity, dtype=torch.bool, device=device)
        self.cursor = self.keep = self.filled = 0
        self.generator = torch.Generator(device=device)
        self.generator.manual_seed(int(np.random.SeedSequence([*key, 0x5701E]).generate_state(1)[0]))
        self._valid = torch.zeros(0, dtype=torch.int64, device=device)

    @property
    def size(self) -> int:
        """Valid transitions held."""
        return len(self._valid)

    def add(self, t: Trajectories) -> None:
        """Write whole trajectories, overwriting the oldest unprotected ones when the ring is full."""
        total = int(t.lengths.sum())
        if total > self.capacity - self.keep:
            raise ValueError(f"{total} slots of trajectories do not fit a store of {self.capacity - self.keep}")
        slots = np.empty(total, dtype=np.int64)
        start, cursor = 0, self.cursor
        for length in t.lengths.tolist():
            if cursor + length > self.capacity:
                cursor = self.keep
            slots[start : start + length] = cursor + np.arange(length)
            start, cursor = start + length, cursor + length
            self.filled = max(self.filled, cursor)
        if len(np.unique(slots)) != total:
            raise ValueError(f"{total} slots of trajectories do not fit a store of {self.capacity - self.keep} at once")
        self.cursor = cursor
        dest = torch.from_numpy(slots).to(self.device)
        rows = {
            "obs": t.obs,
            "allowed": t.allowed,
            "action": t.action,
            "expert": t.expert,
            "reward": t.reward,
            "disc1": t.disc1,
            "ret_n": t.ret_n,
            "disc_n": t.disc_n,
            "next1": slots + t.sample,  # a last observation points to itself
            "next_n": slots + t.ahead,
            "sample": t.sample,
        }
        for name, values in rows.items():
            array: torch.Tensor = getattr(self, name)
            array[dest] = torch.from_numpy(np.ascontiguousarray(values)).to(self.device, array.dtype)
        self._refresh()

    def protect(self) -> None:
        """Never overwrite what the store holds now."""
        self.keep = self.cursor

    def _refresh(self) -> None:
        self._valid = torch.nonzero(self.sample[: self.filled]).squeeze(1)

    def draw(self, n: int) -> Batch:
        """n transitions drawn uniformly (with replacement) from the valid ones."""
        pick = torch.randint(0, self.size, (n,), device=self.device, generator=self.generator)
        idx = self._valid[pick]
        one, ahead = self.next1[idx], self.next_n[idx]
        as_f32 = lambda i: self.obs[i].to(dtype=torch.float32, memory_format=LAYOUT)  # noqa: E731
        return Batch(
            as_f32(idx),
            as_f32(one),
            as_f32(ahead),
            self.action[idx],
            self.expert[idx],
            self.reward[idx],
            self.disc1[idx],
            self.ret_n[idx],
            self.disc_n[idx],
            self.allowed[idx],
            self.allowed[one],
            self.allowed[ahead],
        )

    def state(self) -> dict:
        """What the checkpoint keeps of the store (its arrays go to the replay file): the ring's
        counters, the sampling generator and a fingerprint of the contents."""
        return {
            "capacity": self.capacity,
            "shape": list(self.obs.shape[1:]),
            "cursor": self.cursor,
            "keep": self.keep,
            "filled": self.filled,
            "generator": self.generator.get_state(),
            "fingerprint": self._fingerprint(),
        }

    def arrays(self) -> dict[str, torch.Tensor]:
        return {name: getattr(self, name)[: self.filled].cpu() for name in self.ARRAYS}

    def _fingerprint(self) -> float:
        n = self.filled
        return float(self.reward[:n].double().sum() + self.action[:n].double().sum() * 1e-3 + self.sample[:n].sum())

    def load(self, arrays: dict[str, torch.Tensor], state: dict) -> bool:
        """Take back a saved store; False (the store left empty) when it is not the one `state` describes."""
        n = int(state["filled"])
        if int(state["capacity"]) != self.capacity or n > self.capacity:
            return False
        try:
            for name in self.ARRAYS:
                value, array = arrays[name], getattr(self, name)
                if tuple(value.shape) != (n, *array.shape[1:]):
                    return False
                array[:n] = value.to(self.device, array.dtype)
        except (KeyError, TypeError, RuntimeError):
            return False
        self.cursor, self.keep, self.filled = int(state["cursor"]), int(state["keep"]), n
        if abs(self._fingerprint() - float(state["fingerprint"])) > 1e-6 * max(1.0, abs(float(state["fingerprint"]))):
            self.cursor = self.keep = self.filled = 0
            self._refresh()
            return False
        self.generator.set_state(state["generator"])
        self._refresh()
        return True


def split_counts(total: int, sizes: Sequence[int], current: int, current_share: float) -> list[int]:
    """How many of `total` samples each stage's store gives: the current stage `current_share`, the
    earlier ones the rest evenly (stores without samples left out; the shares renormalised), by
    largest remainder."""
    weights = np.zeros(len(sizes))
    earlier = [i for i in range(len(sizes)) if i != current and sizes[i] > 0]
    if sizes[current] > 0:
        weights[current] = current_share if earlier else 1.0
    for i in earlier:
        weights[i] = (1.0 - weights[current]) / len(earlier)
    if weights.sum() <= 0:
        return [0] * len(sizes)
    exact = total * weights / weights.sum()
    counts = np.floor(exact).astype(np.int64)
    order = np.argsort(-(exact - counts), kind="stable")
    counts[order[: total - int(counts.sum())]] += 1
    return [int(c) for c in counts]


# --- 6. the loss ------------------------------------------------------------------------------------------------


def margin_loss(
    q: torch.Tensor, expert: torch.Tensor, allowed: torch.Tensor, margin: float, form: str = "sum"
) -> torch.Tensor:
    """Per sample, the large-margin loss of the labelled move a_E over the other allowed moves, 0 once Q(s, a_E)
    exceeds each of their Q by the margin. A label naming several moves as good (encode_label) asks it of the
    best of them, Q(s, a_E) = their highest Q, over the moves it does not name.
    `max` (DQfD's): max_a [Q(s, a) + margin [a != a_E]] - Q(s, a_E);
    `sum`: sum over a != a_E of max(0, Q(s, a) + margin - Q(s, a_E)). With the TD losses, on the coordinated
    planner's 20 x 20 demonstrations, the max form left every move's Q equal: its loss stayed at the margin
    through 2,000 pre-training updates (lr 1e-3), and at lr 2.5e-4 the student took the teacher's move in 36 %
    of its states after 2,700 updates; the sum form, which pushes down every move inside the margin and not
    only the highest, took 60 % after 1,200 (lr 1e-3)."""
    _, labelled = labelled_moves(expert, q.shape[1])
    own = q.masked_fill(~labelled, float("-inf")).max(dim=1, keepdim=True).values
    if form == "max":
        raised = (q + margin * (~labelled).to(q.dtype)).masked_fill(~(allowed | labelled), float("-inf"))
        return raised.max(dim=1).values - own.squeeze(1)
    inside = (q + margin - own).clamp(min=0.0).masked_fill(labelled | ~allowed, 0.0)
    return inside.sum(dim=1)


def dqfd_loss(
    q_net: QNet, target_net: QNet, b: Batch, cfg: SearchConfig
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The DQfD loss of a minibatch (L2 is the optimiser's weight decay) and its parts (detached)."""
    q = q_net(b.obs)
    q_taken = q.gather(1, b.action[:, None]).squeeze(1)
    with torch.no_grad():
        n = len(b.action)
        online, target = twin_forward(q_net, target_net, torch.cat([b.next1, b.next_n]))
        best = online.masked_fill(~torch.cat([b.allowed1, b.allowed_n]), float("-inf")).argmax(dim=1, keepdim=True)
        value = target.gather(1, best).squeeze(1)  # double DQN: the online network picks, the target values
        y1 = b.reward + b.disc1 * value[:n]
        yn = b.ret_n + b.disc_n * value[n:]
    td1 = F.smooth_l1_loss(q_taken, y1, reduction="none", beta=cfg.huber_delta)
    tdn = F.smooth_l1_loss(q_taken, yn, reduction="none", beta=cfg.huber_delta)
    demo = b.expert >= 0
    sup = margin_loss(q, b.expert.clamp(min=0), b.allowed, cfg.margin, cfg.margin_form) * demo
    loss = (td1 + cfg.nstep_weight * tdn + cfg.margin_weight * sup).mean()
    return loss, {"td1": td1.detach().mean(), "tdn": tdn.detach().mean(), "margin": sup.detach().mean()}


# --- 7. worlds ----------------------------------------------------------------------------------------------------


def stage_world_config(base: WorldConfig, w: StageWorld) -> WorldConfig:
    """A stage world's WorldConfig: its map, vehicles, targets and obstacles; the observation settings
    (window, fov, rho, variant, taken targets) of `base`."""
    return replace(
        base,
        scenario=w.scenario,
        map_size=w.map_size,
        uavs=w.uavs,
        targets=w.targets,
        clusters=w.clusters,
        obstacles=0.0 if w.city else w.obstacles,
        finish="held",
        explore_reward=0.0,
    )


class CityCrops:
    """Crops of the city footprints for the city worlds, loaded once, never the held-out city."""

    def __init__(self, path: str):
        refuse_held_out(str(Path(path).resolve()) if path else "", "city footprints")
        self.path = path
        self._maps: CityMaps | None = None

    def sample(self, key: Sequence[int], side: int, fraction: float) -> np.ndarray:
        if self._maps is None:
            from swarmctl.learn.city_maps import DEFAULT_CITY, CityMaps

            path = Path(self.path) if self.path else DEFAULT_CITY
            refuse_held_out(str(path.resolve()), "city footprints")
            self._maps = CityMaps.load(path)
        return self._maps.sample(np.random.default_rng(np.random.SeedSequence([*key, 0xC17E])), side, side, fraction)


def world_groups(
    base: WorldConfig, w: StageWorld, key: Sequence[int], episodes: int, city: CityCrops
) -> list[tuple[WorldConfig, np.ndarray | None, int]]:
    """The (config, fixed map, episodes) groups that `episodes` evaluation episodes of a world are run
    in: one, or for a city world a few crops keyed by `key`."""
    cfg = stage_world_config(base, w)
    if not w.city:
        return [(cfg, None, episodes)]
    crops = min(CITY_CROPS, episodes)
    return [
        (cfg, city.sample([*key, k], w.map_size, w.city), episodes // crops + (k < episodes % crops))
        for k in range(crops)
    ]


def reset_world(
    base: WorldConfig, w: StageWorld, seed: int, ids: np.ndarray, key: Sequence[int], city: CityCrops
) -> tuple[SearchEnv, np.ndarray]:
    """A SearchEnv of world `w` (a city world on a crop keyed by `key`) reset to episodes `ids` of `seed`."""
    cfg = stage_world_config(base, w)
    for attempt in range(10):
        blocked = city.sample([*key, attempt], w.map_size, w.city) if w.city else None
        env = SearchEnv(cfg, batch=len(ids), stop_at_success=True)
        try:
            obs = env.reset(seed, ids, blocked)
        except ScenarioError:  # a crop that cannot hold the episodes: the next one
            if blocked is None:
                raise
            continue
        assert obs is not None
        return env, obs
    raise ScenarioError(f"{w.name}: 10 city crops in a row could not hold its episodes")


# --- 8. the trainer --------------------------------------------------------------------------------------------------


@dataclass
class Progress:
    """The trainer's counters: with the networks, optimiser, stores and random states, all a resumed run
    needs to go on where it stopped."""

    episodes_done: int = 0
    rounds: int = 0
    joint_steps: int = 0
    samples: int = 0  # the student's
    demo_samples: int = 0  # the teacher's, and DAgger's
    updates: int = 0
    pretrained: int = 0  # updates on demonstrations only
    update_credit: float = 0.0
    stage: int = 0
    stage_opened: list = field(default_factory=list)  # episodes_done when each stage opened
    teacher: dict = field(default_factory=dict)  # world name -> the teacher's validation success
    next_eval: int = 0
    evals: list = field(default_factory=list)
    train_seconds: float = 0.0
    wall_seconds: float = 0.0  # of the earlier sessions of a resumed run
    changes: list = field(default_factory=list)  # schedule options changed on --resume: episode, option, from, to


METRICS = [
    "episodes",
    "rounds",
    "stage",
    "joint_steps",
    "samples",
    "demo_samples",
    "updates",
    "loss",
    "td1",
    "tdn",
    "margin",
    "epsilon",
    "demo_share",
    "train_success",
    "val_success",
    "val_stage_success",
    "teacher_stage_success",
    "samples_per_s",
    "wall_s",
]
# may change on --resume; the schedule's changes are kept in the checkpoint (Progress.changes) for its card
SCHEDULE_FREE = ("demo_share_start", "demo_share_end")
RESUME_FREE = ("episodes", "threads", "eval_every", "test_episodes", "keep_resume", *SCHEDULE_FREE)


def tensorboard_writer(folder: Path | None):  # -> torch.utils.tensorboard.SummaryWriter | None
    """A TensorBoard writer to `folder` (None: none); InputError when TensorBoard is not installed."""
    if folder is None:
        return None
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        raise InputError(
            f"--tensorboard {folder}: TensorBoard is not installed (torch.utils.tensorboard needs the "
            "tensorboard package): pip install tensorboard, or leave --tensorboard out (the metrics are in the CSV)"
        ) from None
    return SummaryWriter(str(folder))


class SearchTrainer:
    """One run of the recipe (train() drives it): its networks, stores, counters and outputs."""

    def __init__(self, world: WorldConfig, cfg: SearchConfig, out: Path, device: str = "cpu"):
        self.world, self.cfg, self.out = world, cfg, out
        self.dev = torch.device(device)
        self.stages: tuple[SearchStage, ...] = cfg.curriculum_stages()
        self.weights = RewardWeights.of(cfg)
        self.rules = flight_rules(world)
        self.ties = cfg.teacher_ties == "all"
        self.city = CityCrops(cfg.city_footprints)
        torch.manual_seed(cfg.seed)
        torch.set_num_threads(cfg.threads)
        q_net = make_network(world.variant, world.window)
        # channels-last and each convolution with its ReLU as one oneDNN primitive (learn.kernels)
        self.q_net = fuse_conv_relu(to_memory_format(q_net, LAYOUT, self.dev))
        keep_freed_memory()
        self.target_net = to_memory_format(copy.deepcopy(self.q_net), LAYOUT, self.dev)
        self.optimizer = torch.optim.Adam(self.q_net.parameters(), lr=cfg.lr, weight_decay=cfg.l2)
        self.state = Progress(next_eval=cfg.eval_every)
        self.demos: list[TransitionStore] = []
        self.agents: list[TransitionStore] = []
        self.obs_shape: tuple[int, ...] = ()
        self.losses: list[torch.Tensor] = []
        self.recent_success: list[bool] = []
        self.start = time.time()

    # --- prefill: a stage's demonstrations ---------------------------------------------------------------
    def open_stage(self, index: int) -> None:
        """Open stage `index`: record the teacher's demonstrations there (never evicted), make the stage's
        student store, and measure the teacher's validation success there (the stage's bar)."""
        demos = self.record_demonstrations(index)
        self.make_stores(index, len(demos.sample))
        self.demos[index].add(demos)
        self.demos[index].protect()
        self.state.demo_samples += demos.samples
        self.state.stage = index
        self.state.stage_opened.append(self.state.episodes_done)
        for w, row in self.evaluate_stage(index, "coordinated", self.cfg.val_seed, self.cfg.val_episodes).items():
            self.state.teacher[w] = row["success_rate"]

    def record_demonstrations(self, index: int) -> Trajectories:
        """The coordinated teacher's `demo_episodes` episodes on each world of stage `index`."""
        cfg, parts = self.cfg, []
        for j, w in enumerate(self.stages[index].worlds):
            first = PREFILL_EPISODE_OFFSET + index * STAGE_EPISODES + j * (STAGE_EPISODES // 10)
            for start in range(0, cfg.demo_episodes, cfg.parallel_envs):
                ids = first + np.arange(start, min(start + cfg.parallel_envs, cfg.demo_episodes))
                env, obs = reset_world(self.world, w, cfg.seed, ids, [cfg.seed, index, j, start, 1], self.city)
                run = rollout(env, obs, w.steps, self.weights, teacher=CoordinatedPolicy(), ties=self.ties)
                parts.append(trajectories(run, cfg.n_step, cfg.gamma))
        demos = _concat(parts)
        self.obs_shape = tuple(demos.obs.shape[1:])
        return demos

    def make_stores(self, index: int, demo_slots: int) -> None:
        """Stage `index`'s empty stores: the demonstrations' (`demo_slots`, then the DAgger ring) and the
        student's."""
        cfg, stage = self.cfg, self.stages[index]
        longest = max(self._round_slots(w) for w in stage.worlds)
        if cfg.replay_capacity < longest:
            raise InputError(f"--replay {cfg.replay_capacity}: a round of {stage.name} takes up to {longest} samples")
        dagger = cfg.dagger_capacity if cfg.dagger_every and cfg.dagger_capacity >= longest else 0
        store = TransitionStore(demo_slots + dagger, self.obs_shape, [cfg.seed, index, 0xDE], self.dev)
        self.demos[index:] = [store]
        student = TransitionStore(cfg.replay_capacity, self.obs_shape, [cfg.seed, index, 0xA6], self.dev)
        self.agents[index:] = [student]

    def _round_slots(self, w: StageWorld) -> int:
        return self.cfg.parallel_envs * w.uavs * (w.steps + 1)

    # --- collect: the student's episodes (DAgger-labelled every dagger_every-th round) --------------------
    def collect(self) -> Rollout:
        """One round: P episodes of a world of the current stage (round robin), the student acting with
        exploration, a gradient step after every joint step; its samples into the stores."""
        cfg, state = self.cfg, self.state
        stage = self.stages[state.stage]
        w = stage.worlds[state.rounds % len(stage.worlds)]
        p = min(cfg.parallel_envs, cfg.episodes - state.episodes_done)
        ids = TRAIN_EPISODE_OFFSET + state.episodes_done + np.arange(p)
        env, obs = reset_world(self.world, w, cfg.seed, ids, [cfg.seed, state.rounds, 2], self.city)
        labelled = cfg.dagger_every > 0 and self.demos[state.stage].keep < self.demos[state.stage].capacity
        labelled = labelled and state.rounds % cfg.dagger_every == cfg.dagger_every - 1
        epsilon = cfg.epsilon(state.episodes_done / cfg.episodes)

        def after_step() -> None:
            state.joint_steps += 1
            if sum(s.size for s in self.agents) + sum(s.size for s in self.demos) >= cfg.batch_size:
                state.update_credit += cfg.updates_per_step
            while state.update_credit >= 1.0:
                state.update_credit -= 1.0
                self.learn()

        run = rollout(
            env,
            obs,
            w.steps,
            self.weights,
            act=self.student(epsilon),
            teacher=CoordinatedPolicy() if labelled else None,
            after_step=after_step,
            ties=self.ties,
        )
        t = trajectories(run, cfg.n_step, cfg.gamma)
        state.samples += t.samples
        if labelled:
            self.demos[state.stage].add(t)
            state.demo_samples += t.samples
        else:
            self.agents[state.stage].add(t)
        state.rounds += 1
        state.episodes_done += p
        self.recent_success = (self.recent_success + run.success.tolist())[-200:]
        return run

    def student(self, epsilon: float) -> Actor:
        """The student: greedy on Q among the allowed moves, a uniform allowed move with probability
        epsilon, its draws keyed by (seed, episode, step, vehicle)."""

        def act(env: SearchEnv, obs: np.ndarray, allowed: np.ndarray) -> np.ndarray:
            b, u = obs.shape[:2]
            with torch.inference_mode():
                x = torch.from_numpy(obs.reshape(b * u, *obs.shape[2:])).to(self.dev)
                q = self.q_net(x).cpu().numpy().reshape(b, u, -1)
            greedy = np.where(allowed, q, -np.inf).argmax(axis=-1)
            vehicles = np.broadcast_to(np.arange(u), (b, u))
            coin = uniform(self.cfg.seed, env.episodes, env.t, vehicles, EXPLORE_COIN)
            pick = uniform(self.cfg.seed, env.episodes, env.t, vehicles, EXPLORE_PICK)
            any_allowed = softmax_sample(np.where(allowed, 0.0, -np.inf).reshape(b * u, -1), 1.0, pick.reshape(-1))
            moves: np.ndarray = np.where(coin < epsilon, any_allowed.reshape(b, u), greedy)
            return moves

        return act

    # --- learn: one gradient step -----------------------------------------------------------------------------
    def learn(self, demos_only: bool = False) -> None:
        cfg, state = self.cfg, self.state
        batch = self.draw(cfg.batch_size, 1.0 if demos_only else cfg.demo_share(state.episodes_done / cfg.episodes))
        loss, parts = dqfd_loss(self.q_net, self.target_net, batch, cfg)
        self.optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(self.q_net.parameters(), cfg.max_grad_norm)
        self.optimizer.step()
        state.updates += 1
        if state.updates % cfg.target_update_every == 0:
            self.target_net.load_state_dict(self.q_net.state_dict())
        self.losses.append(torch.stack([loss.detach(), parts["td1"], parts["tdn"], parts["margin"]]))

    def draw(self, n: int, demo_share: float) -> Batch:
        """n samples: `demo_share` of them from the demonstration stores (all while the student's are
        empty), each part stratified over the stages (split_counts)."""
        agent_sizes = [s.size for s in self.agents]
        n_demo = n if sum(agent_sizes) == 0 else int(round(n * demo_share))
        parts = []
        for stores, sizes, k in (
            (self.demos, [s.size for s in self.demos], n_demo),
            (self.agents, agent_sizes, n - n_demo),
        ):
            counts = split_counts(k, sizes, self.state.stage, self.cfg.current_share)
            parts += [store.draw(c) for store, c in zip(stores, counts) if c]
        return Batch.cat(parts)

    # --- evaluate and save --------------------------------------------------------------------------------------
    def evaluate_stage(self, index: int, spec: str, seed: int, episodes: int) -> dict[str, dict]:
        """{world name: run_policy's success_rate and mean_steps} over a stage's worlds, as `swarmctl eval`
        measures them (city worlds: over a few crops keyed by the seed)."""
        rows = {}
        for j, w in enumerate(self.stages[index].worlds):
            runs = [
                (n, run_policy(cfg, spec, n, seed, w.steps, progress=False, blocked=blocked))
                for cfg, blocked, n in world_groups(self.world, w, [seed, index, j], episodes, self.city)
            ]
            total = sum(n for n, _ in runs)
            rows[w.name] = {
                "success_rate": sum(n * r["success_rate"] for n, r in runs) / total,
                "mean_steps": sum(n * r["mean_steps"] for n, r in runs) / total,
            }
        return rows

    def evaluate(self, path: Path, seed: int, episodes: int, spec: str | None = None) -> dict[str, dict]:
        """Every opened stage's worlds; the student of checkpoint `path` under its rules, or `spec`."""
        spec = spec or policy_spec(path, self.rules)
        rows: dict[str, dict] = {}
        for index in range(self.state.stage + 1):
            rows.update(self.evaluate_stage(index, spec, seed, episodes))
        return rows

    def evaluate_and_save(self, final: bool = False) -> dict:
        """Validation of the current network on every opened stage; opens the next stage when the current
        one's success reaches its bar; writes the checkpoint (with what --resume needs unless final) and
        keeps the best (by stage, then validation success) as NAME.best.pt."""
        cfg, state = self.cfg, self.state
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "eval.pt"
            self.write(path, resume=False)
            worlds = self.evaluate(path, cfg.val_seed, cfg.val_episodes)
        current = [w.name for w in self.stages[state.stage].worlds]
        stage_success = float(np.mean([worlds[w]["success_rate"] for w in current]))
        teacher_success = float(np.mean([state.teacher[w] for w in current]))
        row = {
            "episodes": state.episodes_done,
            "stage": state.stage,
            "success_rate": float(np.mean([r["success_rate"] for r in worlds.values()])),
            "mean_steps": float(np.mean([r["mean_steps"] for r in worlds.values()])),
            "stage_success": stage_success,
            "teacher_stage_success": teacher_success,
            "worlds": worlds,
        }
        state.evals.append(row)
        best = max(state.evals, key=lambda e: (e["stage"], e["success_rate"], -e["mean_steps"])) is row
        if not final and stage_success >= cfg.advance_share * teacher_success and state.stage + 1 < len(self.stages):
            self.open_stage(state.stage + 1)
        self.write(self.out, resume=cfg.keep_resume and not final)
        if best:
            shutil.copyfile(self.out, best_path(self.out))
        return row

    def metadata(self) -> dict:
        state = self.state
        wall = state.wall_seconds + time.time() - self.start
        return {
            "recipe": RECIPE,
            "scenario": f"search curriculum {self.cfg.curriculum}",
            "stages": [s.name for s in self.stages],
            "stage_reached": state.stage,
            "episodes": state.episodes_done,
            "episodes_planned": self.cfg.episodes,
            "seed": self.cfg.seed,
            "git_commit": git_commit(),
            "wall_time_s": round(wall, 1),
            "samples": state.samples,
            "demo_samples": state.demo_samples,
            "updates": state.updates,
            "train_samples_per_s": round(state.samples / max(state.train_seconds, 1e-9), 1),
            "teacher_val_success": state.teacher,
            "evals": state.evals,
            "changes": state.changes,
            "final_eval": state.evals[-1] if state.evals else None,
            "torch": str(torch.__version__),
            "device": str(self.dev),
        }

    def write(self, path: Path, resume: bool) -> None:
        """The checkpoint (format v2, swarmctl.policy.checkpoint) with the recipe's rules in
        train["recipe"]; with `resume`, the state --resume needs and the stores in replay_path(path)."""
        snapshot = None
        if resume:
            self.state.wall_seconds += time.time() - self.start
            self.start = time.time()
            snapshot = {
                "progress": asdict(self.state),
                "target": {k: v.detach().cpu() for k, v in self.target_net.state_dict().items()},
                "optimizer": self.optimizer.state_dict(),
                "torch_rng": torch.get_rng_state(),
                "stores": {key: store.state() for key, store in self._stores().items()},
            }
            tmp = replay_path(path).with_suffix(".tmp")
            torch.save({key: store.arrays() for key, store in self._stores().items()}, tmp)
            tmp.replace(replay_path(path))
        saved = to_memory_format(copy.deepcopy(self.q_net).cpu(), torch.contiguous_format)
        train = {**asdict(self.cfg), "recipe": self.rules}
        save_checkpoint(path, saved, self.world.as_dict(), train, self.metadata(), resume=snapshot)

    def _stores(self) -> dict[str, TransitionStore]:
        return {
            **{f"demo{i}": s for i, s in enumerate(self.demos)},
            **{f"agent{i}": s for i, s in enumerate(self.agents)},
        }

    def resume(self) -> None:
        """Load a stopped run's state from its checkpoint (`out`) and stores (replay_path(out)); stores
        that are lost are rebuilt: the demonstrations recorded again, the student's empty."""
        net, info, snapshot = resume_snapshot(self.out)
        saved = {"teacher_ties": "one", **(info.get("train") or {})}  # a run from before the option: "one"
        same_options(self.out, saved, {k: v for k, v in asdict(self.cfg).items() if k not in RESUME_FREE})
        # a checkpoint saved before a world field existed holds its default (WorldConfig fills it in)
        if saved.get("recipe") != self.rules or WorldConfig(**info["world"]).as_dict() != self.world.as_dict():
            raise InputError(f"{self.out}: was trained on another world or rules; resume with the run's own options")
        self.q_net.load_state_dict(net.state_dict())
        self.target_net.load_state_dict(snapshot["target"])
        self.optimizer.load_state_dict(snapshot["optimizer"])
        torch.set_rng_state(snapshot["torch_rng"])
        self.state = Progress(**snapshot["progress"])
        for key in SCHEDULE_FREE:
            before, now = saved.get(key), getattr(self.cfg, key)
            if before is not None and before != now:
                change = {"episode": self.state.episodes_done, "option": key, "from": before, "to": now}
                self.state.changes.append(change)
                print(f"train-search: {key} {before} -> {now} from episode {change['episode']}", flush=True)
        try:
            arrays = torch.load(replay_path(self.out), map_location="cpu", weights_only=True)
        except (OSError, RuntimeError, EOFError, ValueError):
            arrays = {}
        lost = []
        for index in range(self.state.stage + 1):
            demo, student = snapshot["stores"][f"demo{index}"], snapshot["stores"][f"agent{index}"]
            self.obs_shape = tuple(demo["shape"])
            self.make_stores(index, demo["keep"])
            if not self.demos[index].load(arrays.get(f"demo{index}", {}), demo):
                lost.append(f"demo{index}")
                self.demos[index].add(self.record_demonstrations(index))  # the same episodes again
                self.demos[index].protect()
            if not self.agents[index].load(arrays.get(f"agent{index}", {}), student):
                lost.append(f"agent{index}")
        if lost:
            print(
                f"train-search: {replay_path(self.out)} is missing or does not match the run ({', '.join(lost)}); "
                "the demonstrations were recorded again and the student's samples start empty",
                flush=True,
            )


def _concat(parts: list[Trajectories]) -> Trajectories:
    return Trajectories(**{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Trajectories)})


def train(
    world: WorldConfig,
    cfg: SearchConfig,
    out: Path,
    device: str = "cpu",
    progress: bool = True,
    metrics_path: Path | None = None,
    resume: bool = False,
    stop: Callable[[], bool] | None = None,
    tensorboard: Path | None = None,
) -> dict:
    """Train with the search recipe; writes the checkpoint to `out` (the best on the validation seed to
    NAME.best.pt, metrics to NAME.csv, the test report of the best to NAME.test.json) and returns its
    metadata. resume: go on with the stopped run whose checkpoint is `out`. stop: polled after every
    round; when it returns True the run saves what --resume needs and returns ("stopped": True)."""
    writer = tensorboard_writer(tensorboard)
    run = SearchTrainer(world, cfg, out, device)
    state = run.state
    if resume:
        run.resume()
        state = run.state
    else:
        run.open_stage(0)  # 1. prefill: the first stage's demonstrations

    # 2. pre-train on the demonstrations alone
    while state.pretrained < cfg.pretrain_updates:
        run.learn(demos_only=True)
        state.pretrained += 1

    metrics_path = metrics_path or out.with_suffix(".csv")
    metrics_path.parent.mkdir(parents=True, exist_ok=True)
    metrics_file = open(metrics_path, "a" if resume and metrics_path.exists() else "w", newline="")
    csv_writer = csv.writer(metrics_file)
    if metrics_file.tell() == 0:
        csv_writer.writerow(METRICS)
    bar = tqdm(total=cfg.episodes, initial=state.episodes_done, unit="ep", disable=not progress, desc="train-search")
    result: dict = {}
    try:
        while state.episodes_done < cfg.episodes:
            # 3. collect and learn
            started, before = time.perf_counter(), state.episodes_done
            run.collect()
            state.train_seconds += time.perf_counter() - started
            losses = torch.stack(run.losses).mean(0).cpu().tolist() if run.losses else [float("nan")] * 4
            run.losses = []
            # 4. evaluate and save
            row: dict = {}
            if state.episodes_done >= state.next_eval or state.episodes_done >= cfg.episodes:
                row = run.evaluate_and_save(final=state.episodes_done >= cfg.episodes)
                while state.next_eval <= state.episodes_done:
                    state.next_eval += cfg.eval_every
            progress_now = state.episodes_done / cfg.episodes
            values = {
                "episodes": state.episodes_done,
                "rounds": state.rounds,
                "stage": state.stage,
                "joint_steps": state.joint_steps,
                "samples": state.samples,
                "demo_samples": state.demo_samples,
                "updates": state.updates,
                "loss": losses[0],
                "td1": losses[1],
                "tdn": losses[2],
                "margin": losses[3],
                "epsilon": cfg.epsilon(progress_now),
                "demo_share": cfg.demo_share(progress_now),
                "train_success": float(np.mean(run.recent_success)),
                "val_success": row.get("success_rate", ""),
                "val_stage_success": row.get("stage_success", ""),
                "teacher_stage_success": row.get("teacher_stage_success", ""),
                "samples_per_s": state.samples / max(state.train_seconds, 1e-9),
                "wall_s": state.wall_seconds + time.time() - run.start,
            }
            csv_writer.writerow([_cell(values[k]) for k in METRICS])
            metrics_file.flush()
            if writer is not None:
                for key, value in values.items():
                    if key != "episodes" and value != "":
                        writer.add_scalar(f"search/{key}", value, state.episodes_done)
            bar.update(state.episodes_done - before)
            bar.set_postfix(
                stage=state.stage,
                samples_s=f"{values['samples_per_s']:.0f}",
                success=f"{values['train_success']:.2f}",
                loss=f"{losses[0]:.3f}",
                val=f"{state.evals[-1]['stage_success']:.2f}" if state.evals else "-",
            )
            if stop is not None and stop() and state.episodes_done < cfg.episodes:
                run.write(out, resume=True)
                return {**run.metadata(), "stopped": True}
        result = run.metadata()
        if cfg.test_episodes:  # 5. the report: the selected checkpoint on the test seed, and the teacher
            selected = best_path(out)
            test = {
                "checkpoint": selected.name,
                "seed": cfg.test_seed,
                "episodes_per_world": cfg.test_episodes,
                "student": run.evaluate(selected, cfg.test_seed, cfg.test_episodes),
                "teacher": run.evaluate(selected, cfg.test_seed, cfg.test_episodes, spec="coordinated"),
            }
            out.with_suffix(".test.json").write_text(json.dumps(test, indent=1))
            result["test"] = test
    finally:
        bar.close()
        metrics_file.close()
        if writer is not None:
            writer.close()
    return result


def _cell(value: object) -> object:
    return f"{value:.5g}" if isinstance(value, float) else value
