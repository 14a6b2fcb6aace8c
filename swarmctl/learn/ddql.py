"""Distributed deep Q-learning (DDQL), read top to bottom.

One Q-network shared by every vehicle, one replay memory fed by every vehicle of P parallel episodes,
double Q-learning with a target network copied every `target_update_every` gradient steps, RAdam,
a replay prefilled with random-policy episodes, training episodes alternating 50 and 150 steps, and
softmax (temperature) or epsilon-greedy exploration annealed over training. The end of a training
episode is a truncation: targets always bootstrap. Every hyperparameter is a TrainConfig field
(swarmctl.learn.train_config, where `swarmctl train` reads its options' defaults from).
"""

from __future__ import annotations

import copy
import csv
import shutil
import subprocess
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from swarmctl.errors import InputError, ScenarioError
from swarmctl.learn.curriculum import CURRICULA, Curriculum, held_out_worlds
from swarmctl.learn.kernels import fuse_conv_relu, keep_freed_memory, twin_forward
from swarmctl.learn.replay import ReplayMemory
from swarmctl.learn.train_config import TrainConfig
from swarmctl.policy.base import allowed_moves, softmax_sample
from swarmctl.policy.checkpoint import load_checkpoint, model_reference, save_checkpoint
from swarmctl.policy.fused import to_memory_format
from swarmctl.policy.qnet import GlobalLocalQNetwork, QNet, QNetwork, make_network
from swarmctl.world.beliefs import VARIANT_CHANNELS
from swarmctl.world.config import WorldConfig
from swarmctl.world.env import SearchEnv

TRAIN_EPISODE_OFFSET = 1_000_000_000  # training episodes never overlap evaluation episodes
PREFILL_EPISODE_OFFSET = 2_000_000_000
LAYOUT = torch.channels_last  # the training networks' memory format


def explore(
    q: np.ndarray, cfg: TrainConfig, value: float, rng: np.random.Generator, allowed: np.ndarray | None = None
) -> np.ndarray:
    """Exploratory actions for Q-values q (N, 5), among the `allowed` (N, 5) moves when given."""
    if allowed is not None:
        q = np.where(allowed, q, -np.inf)
    if cfg.exploration == "softmax":
        return softmax_sample(q, value, rng.random(len(q)))
    greedy = q.argmax(axis=1)
    if allowed is None:
        random = rng.integers(0, q.shape[1], size=len(q))
    else:  # uniform among the allowed moves
        random = softmax_sample(np.where(allowed, 0.0, -np.inf), 1.0, rng.random(len(q)))
    return np.where(rng.random(len(q)) < value, random, greedy)


def _observed(obs: np.ndarray | None) -> np.ndarray:
    """The observations a SearchEnv made with observations=True (as every one here) returns."""
    assert obs is not None
    return obs


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


def greedy_eval(
    net: torch.nn.Module,
    world: WorldConfig,
    cfg: TrainConfig,
    device: torch.device,
    blocked: np.ndarray | None = None,
    steps: int | None = None,
    episodes: int | None = None,
) -> dict:
    """Success rate and mean duration on the fixed held-out episodes, softmax tau = eval_tau (under the
    deployment rules when cfg.rules); `blocked`: every episode on that fixed map."""
    steps = cfg.eval_steps if steps is None else steps
    env = SearchEnv(world, batch=cfg.eval_episodes if episodes is None else episodes, stop_at_success=True)
    obs = _observed(env.reset(seed=cfg.eval_seed, blocked=blocked))
    rng = np.random.default_rng(cfg.eval_seed)
    for _ in range(steps):
        if env.done.all():
            break
        with torch.inference_mode():
            q = net(torch.from_numpy(obs.reshape(-1, *obs.shape[2:])).to(device)).cpu().numpy()
        if cfg.rules:
            q = np.where(rule_mask(env), q, -np.inf)
        actions = softmax_sample(q, cfg.eval_tau, rng.random(q.shape[0])).reshape(env.batch, env.uavs)
        step_obs, _, _, _ = env.step(actions)
        obs = _observed(step_obs)
    duration = np.where(env.done, env.duration, steps)
    return {"success_rate": float(env.done.mean()), "mean_steps": float(duration.mean())}


def held_out_eval(
    net: torch.nn.Module, world: WorldConfig, cfg: TrainConfig, device: torch.device, held_out: list | None
) -> dict:
    """The held-out evaluation: on the world trained (the paper), or, with a curriculum, on each of its
    held-out worlds (eval_episodes split between them), with the mean success as the rate."""
    if not held_out:
        return greedy_eval(net, world, cfg, device)
    per = max(1, cfg.eval_episodes // len(held_out))
    rows = {w.name: greedy_eval(net, w.cfg, cfg, device, w.blocked, w.steps, per) for w in held_out}
    return {
        "success_rate": float(np.mean([r["success_rate"] for r in rows.values()])),
        "mean_steps": float(np.mean([r["mean_steps"] for r in rows.values()])),
        "worlds": rows,
    }


def gradient_step(
    q_net: QNet, target_net: QNet, optimizer: torch.optim.Optimizer, batch: tuple, cfg: TrainConfig
) -> torch.Tensor:
    """One double-DQN gradient step on a minibatch (o, a, r, o'); returns the loss (a tensor on the
    device, not read here).

    The online and target networks' forwards on o' are one pass (learn.kernels.twin_forward, the same
    numbers). The online network on o and o' in one call of 2 x 64 rows was measured and not taken:
    1.6x the separate calls (the backward then runs over the o' rows too). Nor were,
    on one thread (CPU time, 2-core AMD EPYC, busy): torch.compile (inductor) of the loss, 39-49 ms a
    step against eager's 42-49 after 149 s of compiling; onnxruntime for the no-grad forwards, as
    fast as torch's channels-last ones at 64 rows (9.4 against 9.5 ms); RAdam(foreach=True), 0.4 ms
    less a step but other bits (1e-4 apart after 50 steps; 0.18 ms in a later measurement). The step
    is the oneDNN convolutions' time: per 64 rows about 5.4 ms forward with the ReLUs fused (conv2
    3.9), 12.5 ms backward (conv2 5.0 + 4.5 for data and weights); with the acting forward that is
    ~30 ms of convolutions a joint step of the bench's setting, whose FLOP ceiling is ~19 ms."""
    o, a, r, o2 = batch
    with torch.no_grad():
        if cfg.double:
            online_q, target_q = twin_forward(q_net, target_net, o2)
            next_q = target_q.gather(1, online_q.argmax(dim=1, keepdim=True)).squeeze(1)
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


@dataclass
class Progress:
    """The trainer's counters: all that, with the networks, optimiser, replay and random states, a
    resumed run needs to continue where it stopped."""

    episodes_done: int = 0
    joint_steps: int = 0
    samples: int = 0
    updates: int = 0
    update_credit: float = 0.0
    rounds: int = 0
    next_eval: int = 0
    train_seconds: float = 0.0
    train_cpu_seconds: float = 0.0  # CPU time of the process in the training loop (all its threads)
    wall_seconds: float = 0.0  # of the earlier sessions of a resumed run
    evals: list = field(default_factory=list)


def replay_path(out: Path) -> Path:
    """Where a run keeps its replay memory for --resume: NAME.replay.pt beside NAME.pt (not committed)."""
    return out.with_name(out.stem + ".replay.pt")


def train(
    world: WorldConfig,
    cfg: TrainConfig,
    seed: int,
    out: Path,
    init: Path | None = None,
    device: str = "cpu",
    progress: bool = True,
    metrics_path: Path | None = None,
    resume: bool = False,
    stop: Callable[[], bool] | None = None,
) -> dict:
    """Train the shared Q-network; writes the checkpoint to `out` (and the one of the best held-out
    evaluation to best_path(out)) and returns its metadata.

    resume: continue the run whose checkpoint is `out` (its networks, optimiser, counters and random
    states; its replay memory from replay_path(out), refilled with random episodes if it is lost).
    stop: polled after every round; when it returns True the run saves everything --resume needs and
    returns (its metadata carries "stopped": True)."""
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
    curriculum = Curriculum(CURRICULA[cfg.curriculum], world, seed) if cfg.curriculum else None
    held_out = held_out_worlds(world, cfg.curriculum) if cfg.curriculum else None  # as curriculum

    # networks, optimiser, replay
    if init is not None:
        q_net, init_info = load_checkpoint(init, window=world.window)
        if q_net.variant != world.variant:
            q_net = _transplant(q_net, make_network(world.variant, world.window), init)
        q_net.train()
    else:
        q_net, init_info = make_network(world.variant, world.window), None
    # channels-last activations: oneDNN's convolutions run a gradient step 1.4x faster in that layout
    # and each convolution with its ReLU in one primitive, without page faults on every gradient step's
    # activations (learn.kernels)
    fuse_conv_relu(to_memory_format(q_net, LAYOUT, dev))
    keep_freed_memory()
    target_net = to_memory_format(copy.deepcopy(q_net), LAYOUT, dev)
    optimizer = torch.optim.RAdam(q_net.parameters(), lr=cfg.lr)
    obs_shape = (VARIANT_CHANNELS[world.variant], world.window, world.window)
    replay = ReplayMemory(cfg.replay_capacity, obs_shape, seed=seed, device=dev)
    state = Progress(next_eval=cfg.eval_every)
    refill = cfg.prefill_episodes
    if resume:
        state, refill = _resume(out, q_net, target_net, optimizer, replay, rng, cfg, dev)

    def start_round(round_index: int, at: float, n: int, first: int) -> tuple[SearchEnv, np.ndarray, int]:
        """The environment of a round (the curriculum's world at progress `at`, or the one world),
        reset to episodes first..first+n-1; returns it, its observations and the episode length."""
        if curriculum is None:
            env = SearchEnv(world, batch=n, stop_at_success=False)
            return env, _observed(env.reset(seed, range(first, first + n))), cfg.episode_lengths[round_index % 2]
        for attempt in range(10):
            w = curriculum.world(round_index, at, attempt)
            env = SearchEnv(w.cfg, batch=n, stop_at_success=False)
            try:
                return env, _observed(env.reset(seed, range(first, first + n), w.blocked)), w.steps
            except ScenarioError:  # one of its episodes cannot be drawn: take the round's next world
                continue
        raise ScenarioError(f"the curriculum drew 10 worlds for round {round_index} that its episodes do not fit")

    # 1. prefill the replay with random-policy episodes (again, after a resume that lost its replay)
    prefill_batch = max(1, min(refill, 100))
    done_prefill, round_index = 0, 0
    while done_prefill < refill:
        n = min(prefill_batch, refill - done_prefill)
        first = PREFILL_EPISODE_OFFSET + state.episodes_done + done_prefill
        env, obs, length = start_round(-1 - round_index, state.episodes_done / cfg.episodes, n, first)
        for _ in range(length):
            actions = rng.integers(0, 5, size=(n, env.uavs))
            step_obs, reward, _, _ = env.step(actions)
            next_obs = _observed(step_obs)
            replay.add(obs.reshape(-1, *obs_shape), actions.ravel(), reward.ravel(), next_obs.reshape(-1, *obs_shape))
            obs = next_obs
        done_prefill += n
        round_index += 1

    # 2. train
    metrics_path = metrics_path or out.with_suffix(".csv")
    metrics_path.parent.mkdir(parents=True, exist_ok=True)
    metrics_file = open(metrics_path, "a" if resume and metrics_path.exists() else "w", newline="")
    writer = csv.writer(metrics_file)
    if metrics_file.tell() == 0:
        writer.writerow(METRICS)

    def save(resume_state: bool = False) -> dict:
        """Write the checkpoint as it stands (at every evaluation, at the end, when stopped)."""
        wall = state.wall_seconds + time.time() - start_time
        metadata = {
            "scenario": "curriculum " + cfg.curriculum if cfg.curriculum else world.scenario,
            "episodes": state.episodes_done,
            "episodes_planned": cfg.episodes,
            "seed": seed,
            "git_commit": git_commit(),
            "wall_time_s": round(wall, 1),
            "samples": state.samples,
            "joint_steps": state.joint_steps,
            "updates": state.updates,
            "samples_per_s": round(state.samples / max(wall, 1e-9), 1),
            # in the training loop only: acting, stepping, replay and gradient steps (no prefill, evaluation, saving)
            "train_samples_per_s": round(state.samples / max(state.train_seconds, 1e-9), 1),
            # the same per CPU second of the process: what a busy machine's waiting for a core leaves out
            "train_samples_per_cpu_s": round(state.samples / max(state.train_cpu_seconds, 1e-9), 1),
            "evals": state.evals,
            "final_eval": state.evals[-1] if state.evals else None,
            "init": model_reference(init, init_info) if init and init_info else None,  # (given together)
            "init_metadata": init_info["metadata"] if init_info else None,
            "torch": str(torch.__version__),
            "device": str(dev),
        }
        saved = to_memory_format(copy.deepcopy(q_net).cpu(), torch.contiguous_format)
        snapshot = None
        if resume_state:
            state.wall_seconds = wall
            snapshot = _resume_state(state, target_net, optimizer, replay, rng)
            replay.save(replay_path(out))
            state.wall_seconds -= time.time() - start_time  # this session's share is added at the next save
        save_checkpoint(out, saved, world.as_dict(), asdict(cfg), metadata, resume=snapshot)
        return metadata

    recent_loss, recent_success = [], []
    bar = tqdm(total=cfg.episodes, initial=state.episodes_done, unit="ep", disable=not progress, desc="train")
    metadata: dict = {}
    explore_value = cfg.exploration_value(state.episodes_done / cfg.episodes)
    while state.episodes_done < cfg.episodes:
        round_start, round_cpu = time.perf_counter(), time.process_time()
        p = min(cfg.parallel_envs, cfg.episodes - state.episodes_done)
        first = TRAIN_EPISODE_OFFSET + state.episodes_done
        env, obs, length = start_round(state.rounds, state.episodes_done / cfg.episodes, p, first)
        obs_t = torch.from_numpy(obs.reshape(-1, *obs_shape)).to(dev)  # each observation crosses to the device once
        succeeded = np.zeros(p, dtype=bool)
        losses = []  # on the device: read once a round, not once a gradient step
        for _ in range(length):
            explore_value = cfg.exploration_value(state.episodes_done / cfg.episodes)
            with torch.inference_mode():
                q = q_net(obs_t).cpu().numpy()
            actions = explore(q, cfg, explore_value, rng, rule_mask(env) if cfg.rules else None).reshape(p, env.uavs)
            step_obs, reward, success, _ = env.step(actions)
            succeeded |= success
            next_t = torch.from_numpy(_observed(step_obs).reshape(-1, *obs_shape)).to(dev)
            replay.add(obs_t, actions.ravel(), reward.ravel(), next_t)
            obs_t = next_t
            state.joint_steps += 1
            state.samples += p * env.uavs

            if replay.size >= cfg.batch_size:  # without prefill, learning waits for one batch of samples
                state.update_credit += cfg.updates_per_step
            while state.update_credit >= 1.0:
                state.update_credit -= 1.0
                losses.append(gradient_step(q_net, target_net, optimizer, replay.sample(cfg.batch_size, LAYOUT), cfg))
                state.updates += 1
                if state.updates % cfg.target_update_every == 0:
                    target_net.load_state_dict(q_net.state_dict())
        if losses:
            recent_loss.extend(torch.stack(losses).cpu().tolist())
        state.train_seconds += time.perf_counter() - round_start
        state.train_cpu_seconds += time.process_time() - round_cpu
        state.rounds += 1
        state.episodes_done += p
        recent_success.extend(succeeded.tolist())
        recent_loss, recent_success = recent_loss[-200:], recent_success[-200:]
        wall = state.wall_seconds + time.time() - start_time
        eval_row = {}
        snapshot_due = state.episodes_done in cfg.snapshots
        stopping = stop is not None and stop()
        if state.episodes_done >= state.next_eval or state.episodes_done >= cfg.episodes or snapshot_due:
            q_net.eval()
            eval_row = held_out_eval(q_net, world, cfg, dev, held_out)
            q_net.train()
            state.evals.append({"episodes": state.episodes_done, **eval_row})
            if state.episodes_done >= state.next_eval:
                state.next_eval += cfg.eval_every
            metadata = save(resume_state=cfg.keep_resume and state.episodes_done < cfg.episodes)
            if snapshot_due:
                shutil.copyfile(out, snapshot_path(out, state.episodes_done))
            if max(state.evals, key=_eval_rank) is state.evals[-1]:  # the best so far on the held-out episodes
                shutil.copyfile(out, best_path(out))
        mean_loss = float(np.mean(recent_loss)) if recent_loss else float("nan")
        writer.writerow(
            [
                state.episodes_done,
                state.joint_steps,
                state.samples,
                state.updates,
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
            samples_s=f"{state.samples / max(state.train_seconds, 1e-9):.0f}",
            success=f"{np.mean(recent_success):.2f}",
            loss=f"{mean_loss:.4f}",
            eval=f"{state.evals[-1]['success_rate']:.2f}" if state.evals else "-",
        )
        if stopping and state.episodes_done < cfg.episodes:
            metadata = {**save(resume_state=True), "stopped": True}
            break
    bar.close()
    metrics_file.close()
    return metadata  # the evaluation after the last round saved the final checkpoint


def _transplant(source: QNet, target: QNet, path: Path) -> QNet:
    """Start a global-local network from a paper network's local convolutions (the same layers on the
    same three channels); the whole-map branch and the head start fresh."""
    if not (isinstance(source, QNetwork) and isinstance(target, GlobalLocalQNetwork)):  # features, local
        raise InputError(f"--init {path}: a {source.variant} network cannot start a {target.variant} one")
    target.local.load_state_dict(source.features.state_dict())
    return target


METRICS = [
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


def _resume_state(state: Progress, target_net, optimizer, replay: ReplayMemory, rng: np.random.Generator) -> dict:
    """What a checkpoint's `resume` field holds (plain data and tensors: loads with weights_only)."""
    return {
        "progress": asdict(state),
        "target": {k: v.detach().cpu() for k, v in target_net.state_dict().items()},
        "optimizer": optimizer.state_dict(),
        "rng": rng.bit_generator.state,
        "torch_rng": torch.get_rng_state(),
        "replay": replay.state(),
    }


def resume_snapshot(out: Path) -> tuple[QNet, dict, dict]:
    """A stopped run's checkpoint: its network, its info and the state it saved to resume (InputError,
    one line, when it holds none)."""
    net, info = load_checkpoint(out)
    snapshot = info.get("resume")
    if not snapshot:
        raise InputError(
            f"{out}: holds no state to resume (the run finished, or was not saved to resume); "
            "train without --resume, or give the checkpoint of a stopped run"
        )
    return net, info, snapshot


def same_options(out: Path, saved: dict, wanted: dict) -> None:
    """A resumed run goes on with its own options: InputError naming the first of `wanted` (name ->
    value) that its checkpoint's train config `saved` has otherwise."""
    for key, value in wanted.items():
        if saved.get(key) != value:
            raise InputError(
                f"{out}: was trained with {key} = {saved.get(key)!r}, not {value!r}; resume with the run's own options"
            )


def _resume(
    out: Path,
    q_net,
    target_net,
    optimizer,
    replay: ReplayMemory,
    rng: np.random.Generator,
    cfg: TrainConfig,
    dev: torch.device,
) -> tuple[Progress, int]:
    """Load a stopped run's state into the fresh networks, optimiser, replay and generator; returns the
    counters and how many random episodes must refill a lost replay (0 when it was found)."""
    net, info, snapshot = resume_snapshot(out)
    keys = ("parallel_envs", "batch_size", "replay_capacity", "curriculum", "rules", "exploration")
    same_options(out, info.get("train") or {}, {key: getattr(cfg, key) for key in keys})
    q_net.load_state_dict(net.state_dict())
    target_net.load_state_dict(snapshot["target"])
    optimizer.load_state_dict(snapshot["optimizer"])
    rng.bit_generator.state = snapshot["rng"]
    torch.set_rng_state(snapshot["torch_rng"])
    progress = snapshot["progress"]
    state = Progress(**progress)
    refill = 0
    path = replay_path(out)
    if not replay.load(path, snapshot["replay"]):
        refill = max(1, cfg.prefill_episodes)
        print(
            f"train: {path} is missing or does not match the run; refilling the replay with {refill} random "
            "episodes before going on",
            flush=True,
        )
    return state, refill
