"""Distributed deep Q-learning (DDQL), read top to bottom.

One Q-network shared by every vehicle, one replay memory fed by every vehicle of P parallel episodes,
double Q-learning with a target network copied every `target_update_every` gradient steps, RAdam,
a replay prefilled with random-policy episodes, training episodes alternating 50 and 150 steps, and
softmax (temperature) or epsilon-greedy exploration annealed over training. The end of a training
episode is a truncation: targets always bootstrap. Every hyperparameter is a TrainConfig field.
"""

from __future__ import annotations

import copy
import csv
import shutil
import subprocess
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from swarmctl.learn.replay import ReplayMemory
from swarmctl.policy.base import allowed_moves, softmax_sample
from swarmctl.policy.checkpoint import load_checkpoint, model_reference, save_checkpoint
from swarmctl.policy.qnet import QNetwork
from swarmctl.world.config import WorldConfig
from swarmctl.world.env import SearchEnv

TRAIN_EPISODE_OFFSET = 1_000_000_000  # training episodes never overlap evaluation episodes
PREFILL_EPISODE_OFFSET = 2_000_000_000
LAYOUT = torch.channels_last  # the training networks' memory format


@dataclass
class TrainConfig:
    episodes: int = 3000  # N_e training episodes (the paper's longest run)
    parallel_envs: int = 16  # episodes stepped together; P * U samples per joint step
    episode_lengths: tuple[int, int] = (50, 150)  # alternating training-episode lengths (paper)
    prefill_episodes: int = 1000  # random-policy episodes in the replay before training (paper)
    replay_capacity: int = 100_000  # samples (vehicle transitions)
    batch_size: int = 64
    updates_per_step: float = 1.0  # gradient steps per joint step of the P parallel episodes
    lr: float = 5e-4  # RAdam learning rate
    gamma: float = 0.9  # discount (paper)
    target_update_every: int = 500  # n_q, gradient steps between target-network copies
    double: bool = True  # double DQN target; False = plain target-network target
    huber: bool = True  # Huber (smooth L1) loss; False = MSE
    max_grad_norm: float = 10.0
    exploration: str = "softmax"  # softmax | egreedy
    rules: bool = False  # act under the deployment rules (hover on a free target, no move off the map or into a
    #                      known obstacle) while exploring and in the held-out evaluation; False = the paper
    temperature_start: float = 1.0  # softmax temperature, annealed linearly ...
    temperature_end: float = 0.1  # ... to the test-time tau
    epsilon_start: float = 1.0  # epsilon-greedy, annealed linearly ...
    epsilon_end: float = 0.0  # ... to 0 by the end (paper)
    eval_every: int = 250  # episodes between held-out evaluations
    eval_episodes: int = 200
    eval_seed: int = 2026  # held-out evaluation episodes (the README tables use seed 0)
    eval_steps: int = 40
    eval_tau: float = 0.1
    snapshots: tuple[int, ...] = ()  # episode counts at which a copy is kept as NAME.epN.pt (learning curves)
    threads: int = 2  # torch CPU threads
    extra: dict = field(default_factory=dict)

    def exploration_value(self, progress: float) -> float:
        """Temperature (softmax) or epsilon (egreedy) at training progress in [0, 1]."""
        if self.exploration == "softmax":
            return self.temperature_start + (self.temperature_end - self.temperature_start) * progress
        return self.epsilon_start + (self.epsilon_end - self.epsilon_start) * progress


def explore(
    q: np.ndarray, cfg: TrainConfig, value: float, rng: np.random.Generator, allowed: np.ndarray | None = None
) -> np.ndarray:
    """Exploratory actions for Q-values q (N, 5), among the `allowed` (N, 5) moves when given."""
    if allowed is not None:
        q = np.where(allowed, q, -np.inf)
    if cfg.exploration == "softmax":
        return softmax_sample(q, value, rng.random(q.shape[0]))
    greedy = q.argmax(axis=1)
    if allowed is None:
        random = rng.integers(0, q.shape[1], size=q.shape[0])
    else:  # uniform among the allowed moves
        random = softmax_sample(np.where(allowed, 0.0, -np.inf), 1.0, rng.random(q.shape[0]))
    return np.where(rng.random(q.shape[0]) < value, random, greedy)


def rule_mask(env: SearchEnv) -> np.ndarray:
    """(B * U, 5) bool: the moves the deployment rules allow (policy.base.allowed_moves: hover and mask)."""
    return allowed_moves(env.beliefs()).reshape(-1, 5)


def git_commit() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(__file__).parent,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def best_path(out: Path) -> Path:
    """Where train() keeps the checkpoint of its best held-out evaluation: NAME.best.pt beside NAME.pt."""
    return out.with_name(out.stem + ".best" + out.suffix)


def snapshot_path(out: Path, episodes: int) -> Path:
    """Where train() keeps the checkpoint as it stood after `episodes` episodes (TrainConfig.snapshots)."""
    return out.with_name(f"{out.stem}.ep{episodes}{out.suffix}")


def _eval_rank(row: dict) -> tuple:
    return (row["success_rate"], -row["mean_steps"])


def greedy_eval(net: QNetwork, world: WorldConfig, cfg: TrainConfig, device: torch.device) -> dict:
    """Success rate and mean duration on the fixed held-out episodes, softmax tau = eval_tau (under the
    deployment rules when cfg.rules)."""
    env = SearchEnv(world, batch=cfg.eval_episodes, stop_at_success=True)
    obs = env.reset(seed=cfg.eval_seed)
    rng = np.random.default_rng(cfg.eval_seed)
    for _ in range(cfg.eval_steps):
        if env.done.all():
            break
        with torch.inference_mode():
            q = net(torch.from_numpy(obs.reshape(-1, *obs.shape[2:])).to(device)).cpu().numpy()
        if cfg.rules:
            q = np.where(rule_mask(env), q, -np.inf)
        actions = softmax_sample(q, cfg.eval_tau, rng.random(q.shape[0])).reshape(env.batch, env.uavs)
        obs, _, _, _ = env.step(actions)
    duration = np.where(env.done, env.duration, cfg.eval_steps)
    return {"success_rate": float(env.done.mean()), "mean_steps": float(duration.mean())}


def gradient_step(
    q_net: QNetwork, target_net: QNetwork, optimizer: torch.optim.Optimizer, batch: tuple, cfg: TrainConfig
) -> torch.Tensor:
    """One double-DQN gradient step on a minibatch (o, a, r, o'); returns the loss (a tensor on the
    device, not read here).

    Fusing the forwards was measured and not taken: the online network on o and o' in one call of
    2 x 64 rows costs 1.6x the separate calls (the backward then runs over the o' rows too), and the
    online and target networks on o' in one vmapped call gained nothing over two calls."""
    o, a, r, o2 = batch
    with torch.no_grad():
        if cfg.double:
            next_a = q_net(o2).argmax(dim=1, keepdim=True)
            next_q = target_net(o2).gather(1, next_a).squeeze(1)
        else:
            next_q = target_net(o2).max(dim=1).values
        td_target = r + cfg.gamma * next_q  # truncation, never terminal: always bootstrap
    q_taken = q_net(o).gather(1, a[:, None]).squeeze(1)
    loss = F.smooth_l1_loss(q_taken, td_target) if cfg.huber else F.mse_loss(q_taken, td_target)
    optimizer.zero_grad()
    loss.backward()
    torch.nn.utils.clip_grad_norm_(q_net.parameters(), cfg.max_grad_norm)
    optimizer.step()
    return loss.detach()


def train(
    world: WorldConfig,
    cfg: TrainConfig,
    seed: int,
    out: Path,
    init: Path | None = None,
    device: str = "cpu",
    progress: bool = True,
    metrics_path: Path | None = None,
) -> dict:
    """Train the shared Q-network; writes the checkpoint to `out` (and the one of the best held-out
    evaluation to best_path(out)) and returns its metadata."""
    start_time = time.time()
    unreachable = [n for n in cfg.snapshots if n != cfg.episodes and (n % cfg.parallel_envs or n > cfg.episodes)]
    if unreachable:
        raise ValueError(
            f"snapshots {unreachable}: a snapshot is taken between rounds of {cfg.parallel_envs} "
            f"parallel episodes, so it must be a multiple of that, at most {cfg.episodes}"
        )
    torch.manual_seed(seed)
    torch.set_num_threads(cfg.threads)
    dev = torch.device(device)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xD0]))

    # networks, optimiser, replay
    if init is not None:
        q_net, init_info = load_checkpoint(init, window=world.window)
        q_net.train()
    else:
        q_net, init_info = QNetwork(world.window), None
    # channels-last activations: oneDNN's convolutions run a gradient step 1.4x faster in that layout
    q_net.to(dev, memory_format=LAYOUT)
    target_net = copy.deepcopy(q_net).to(dev, memory_format=LAYOUT)
    optimizer = torch.optim.RAdam(q_net.parameters(), lr=cfg.lr)
    obs_shape = (3, world.window, world.window)
    replay = ReplayMemory(cfg.replay_capacity, obs_shape, seed=seed, device=dev)

    # 1. prefill the replay with random-policy episodes
    prefill_batch = max(1, min(cfg.prefill_episodes, 100))
    done_prefill, round_index = 0, 0
    while done_prefill < cfg.prefill_episodes:
        n = min(prefill_batch, cfg.prefill_episodes - done_prefill)
        env = SearchEnv(world, batch=n, stop_at_success=False)
        obs = env.reset(seed, range(PREFILL_EPISODE_OFFSET + done_prefill, PREFILL_EPISODE_OFFSET + done_prefill + n))
        for _ in range(cfg.episode_lengths[round_index % 2]):
            actions = rng.integers(0, 5, size=(n, env.uavs))
            next_obs, reward, _, _ = env.step(actions)
            replay.add(obs.reshape(-1, *obs_shape), actions.ravel(), reward.ravel(), next_obs.reshape(-1, *obs_shape))
            obs = next_obs
        done_prefill += n
        round_index += 1

    # 2. train
    metrics_path = metrics_path or out.with_suffix(".csv")
    metrics_path.parent.mkdir(parents=True, exist_ok=True)
    metrics_file = open(metrics_path, "w", newline="")
    writer = csv.writer(metrics_file)
    writer.writerow(
        [
            "episodes",
            "joint_steps",
            "samples",
            "updates",
            "loss",
            "exploration",
            "train_success",
            "eval_success",
            "eval_mean_steps",
            "wall_s",
        ]
    )
    evals: list[dict] = []
    episodes_done, joint_steps, samples, updates, update_credit = 0, 0, 0, 0, 0.0
    train_seconds = 0.0

    def save() -> dict:
        """Write the checkpoint as it stands (at every evaluation and at the end)."""
        wall = time.time() - start_time
        metadata = {
            "scenario": world.scenario,
            "episodes": episodes_done,
            "episodes_planned": cfg.episodes,
            "seed": seed,
            "git_commit": git_commit(),
            "wall_time_s": round(wall, 1),
            "samples": samples,
            "joint_steps": joint_steps,
            "updates": updates,
            "samples_per_s": round(samples / max(wall, 1e-9), 1),
            # in the training loop only: acting, stepping, replay and gradient steps (no prefill, evaluation, saving)
            "train_samples_per_s": round(samples / max(train_seconds, 1e-9), 1),
            "evals": evals,
            "final_eval": evals[-1] if evals else None,
            "init": model_reference(init, init_info) if init else None,
            "init_metadata": init_info["metadata"] if init_info else None,
            "torch": str(torch.__version__),
            "device": str(dev),
        }
        saved = copy.deepcopy(q_net).cpu().to(memory_format=torch.contiguous_format)
        save_checkpoint(out, saved, world.as_dict(), asdict(cfg), metadata)
        return metadata

    recent_loss, recent_success = [], []
    next_eval = cfg.eval_every
    bar = tqdm(total=cfg.episodes, unit="ep", disable=not progress, desc="train")
    rounds = 0
    while episodes_done < cfg.episodes:
        round_start = time.perf_counter()
        p = min(cfg.parallel_envs, cfg.episodes - episodes_done)
        env = SearchEnv(world, batch=p, stop_at_success=False)
        obs = env.reset(seed, range(TRAIN_EPISODE_OFFSET + episodes_done, TRAIN_EPISODE_OFFSET + episodes_done + p))
        obs_t = torch.from_numpy(obs.reshape(-1, *obs_shape)).to(dev)  # each observation crosses to the device once
        succeeded = np.zeros(p, dtype=bool)
        losses = []  # on the device: read once a round, not once a gradient step
        for _ in range(cfg.episode_lengths[rounds % 2]):
            explore_value = cfg.exploration_value(episodes_done / cfg.episodes)
            with torch.inference_mode():
                q = q_net(obs_t).cpu().numpy()
            actions = explore(q, cfg, explore_value, rng, rule_mask(env) if cfg.rules else None).reshape(p, env.uavs)
            next_obs, reward, success, _ = env.step(actions)
            succeeded |= success
            next_t = torch.from_numpy(next_obs.reshape(-1, *obs_shape)).to(dev)
            replay.add(obs_t, actions.ravel(), reward.ravel(), next_t)
            obs_t = next_t
            joint_steps += 1
            samples += p * env.uavs

            if replay.size >= cfg.batch_size:  # without prefill, learning waits for one batch of samples
                update_credit += cfg.updates_per_step
            while update_credit >= 1.0:
                update_credit -= 1.0
                losses.append(gradient_step(q_net, target_net, optimizer, replay.sample(cfg.batch_size, LAYOUT), cfg))
                updates += 1
                if updates % cfg.target_update_every == 0:
                    target_net.load_state_dict(q_net.state_dict())
        if losses:
            recent_loss.extend(torch.stack(losses).cpu().tolist())
        train_seconds += time.perf_counter() - round_start
        rounds += 1
        episodes_done += p
        recent_success.extend(succeeded.tolist())
        recent_loss, recent_success = recent_loss[-200:], recent_success[-200:]
        wall = time.time() - start_time
        eval_row = {}
        snapshot_due = episodes_done in cfg.snapshots
        if episodes_done >= next_eval or episodes_done >= cfg.episodes or snapshot_due:
            q_net.eval()
            eval_row = greedy_eval(q_net, world, cfg, dev)
            q_net.train()
            evals.append({"episodes": episodes_done, **eval_row})
            if episodes_done >= next_eval:
                next_eval += cfg.eval_every
            metadata = save()
            if snapshot_due:
                shutil.copyfile(out, snapshot_path(out, episodes_done))
            if max(evals, key=_eval_rank) is evals[-1]:  # the best so far on the held-out episodes
                shutil.copyfile(out, best_path(out))
        mean_loss = float(np.mean(recent_loss)) if recent_loss else float("nan")
        writer.writerow(
            [
                episodes_done,
                joint_steps,
                samples,
                updates,
                f"{mean_loss:.5f}",
                f"{explore_value:.4f}",
                f"{np.mean(recent_success):.3f}",
                eval_row.get("success_rate", ""),
                eval_row.get("mean_steps", ""),
                f"{wall:.1f}",
            ]
        )
        metrics_file.flush()
        bar.update(p)
        bar.set_postfix(
            samples_s=f"{samples / max(wall, 1e-9):.0f}",
            success=f"{np.mean(recent_success):.2f}",
            loss=f"{mean_loss:.4f}",
            eval=f"{evals[-1]['success_rate']:.2f}" if evals else "-",
        )
    bar.close()
    metrics_file.close()

    return metadata  # the evaluation after the last round saved the final checkpoint
