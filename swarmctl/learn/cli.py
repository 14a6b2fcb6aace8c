"""`swarmctl eval`: compare policies on the same episodes."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import click

from swarmctl.bounds import SEED, real, require_memory, whole, writable_file
from swarmctl.cli_options import require, require_world_memory, world_config, world_options
from swarmctl.learn.curriculum import CURRICULA, curriculum_side
from swarmctl.learn.evaluate import DEFAULT_CHUNK, evaluate
from swarmctl.policy.registry import POLICY_HELP
from swarmctl.world.beliefs import PAPER_VARIANT, VARIANT_CHANNELS
from swarmctl.world.config import FINISHES


def format_table(results: list[dict]) -> str:
    """The eval results as an aligned text table."""
    head = ("policy", "success", "mean steps", "x oracle", "collisions/ep", "ms/decision")
    rows = []
    for r in results:
        ms = r["decision_ms_per_vehicle"]
        ratio = r["duration_ratio_to_oracle"]
        rows.append(
            (
                r["policy"],
                f"{r['success_rate']:.3f}",
                f"{r['mean_steps']:.2f}",
                f"{ratio:.2f}" if ratio is not None else "-",
                f"{r['collisions_per_episode']:.3f}",
                f"{ms:.3f}" if ms is not None else "-",
            )
        )
    widths = [max(len(str(x)) for x in col) for col in zip(head, *rows)]
    line = lambda cells: "  ".join(
        str(c).rjust(w) if i else str(c).ljust(w) for i, (c, w) in enumerate(zip(cells, widths))
    )
    return "\n".join([line(head), line(["-" * w for w in widths]), *map(line, rows)])


MAX_STEPS = 100_000  # a test or held-out episode's step limit
MAX_EPISODES = 10_000_000


@click.command("eval")
@world_options
@click.option(
    "--steps", type=whole(1, MAX_STEPS), default=40, show_default=True, help="Step limit N of a test episode."
)
@click.option("--episodes", type=whole(1, MAX_EPISODES), default=500, show_default=True, help="Test episodes E.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Episode seed: same seed, same episodes.")
@click.option(
    "--policy",
    "policies",
    multiple=True,
    required=True,
    metavar="POLICY",
    help=f"Repeatable; all run on the same episodes. One of: {POLICY_HELP}.",
)
@click.option(
    "--json",
    "json_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help='Write {"results": [...]} with success_rate, mean_steps, steps_cdf, ...',
)
@click.option(
    "--grid",
    "grid_file",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Play every episode on this real area's grid (from `swarmctl plan`): its blocked cells are the "
    "obstacles, targets and starts are drawn by the scenario's rules in its largest free region; "
    "--map and --obstacles do not apply.",
)
@click.option(
    "--batch",
    type=whole(1, 100_000),
    default=DEFAULT_CHUNK,
    show_default=True,
    help="Episodes stepped at once (memory and speed only: results do not depend on it).",
)
@click.option(
    "--threads",
    type=whole(1, 256),
    default=1,
    show_default=True,
    help="Torch and onnxruntime CPU threads for the policies.",
)
@click.option(
    "--finish",
    type=click.Choice(FINISHES),
    default="held",
    show_default=True,
    help="When an episode succeeds: held (the paper's: every vehicle on a target of its own), found (every "
    "target inside some vehicle's sensing disc) or covered (every free cell reachable from the starts "
    "sensed). found and covered accept fewer targets than vehicles; the oracle bound is for held only.",
)
@click.option("--progress/--no-progress", default=True, help="Show a progress bar on a terminal.")
def eval_command(steps, episodes, seed, policies, json_path, grid_file, batch, threads, finish, progress, **kwargs):
    """Evaluate policies: success rate, mean episode duration, duration CDF, against the oracle bound."""
    cfg = world_config(kwargs, finish=finish)
    from swarmctl.policy.threads import set_inference_threads

    set_inference_threads(threads)
    blocked, where, cells = None, f"M={cfg.map_size}", None
    if grid_file is not None:
        from swarmctl.geo.grid import GeoGrid

        grid = GeoGrid.load(grid_file)
        blocked = grid.blocked.copy()
        cfg = replace(cfg, map_size=max(grid.width, grid.height), obstacles=0.0)
        where, cells = f"grid {grid_file} ({grid.width} x {grid.height}, {blocked.mean():.1%} blocked)", blocked.size
    require_world_memory(cfg, min(episodes, batch), f"{min(episodes, batch)} episodes at {where}", cells)
    if json_path is not None:
        writable_file(json_path, "--json")
    results = evaluate(cfg, list(policies), episodes, seed, steps, chunk=batch, progress=progress, blocked=blocked)
    if grid_file is not None:
        for r in results:
            r["scenario"]["grid"] = str(grid_file)
    click.echo(
        f"{cfg.scenario}, {where}, U={cfg.uavs}, K={cfg.targets}"
        + (f", eta={cfg.obstacles}" if grid_file is None else "")
        + f", N={steps}, {episodes} episodes, seed {seed}, channel {cfg.channel}, finish {cfg.finish}"
    )
    click.echo(format_table(results))
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps({"results": results}, indent=1))
        click.echo(f"wrote {json_path}")


@click.command("train")
@world_options
@click.option("--episodes", type=whole(1, MAX_EPISODES), default=3000, show_default=True, help="Training episodes N_e.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed: same seed, same machine, same model.")
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Checkpoint to write, e.g. models/cluster-2uav.pt (metrics go next to it as .csv).",
)
@click.option(
    "--init", type=click.Path(dir_okay=False, path_type=Path), help="Start from this checkpoint (transfer learning)."
)
@click.option("--device", type=click.Choice(["auto", "cpu", "cuda"]), default="auto", show_default=True)
@click.option("--exploration", type=click.Choice(["softmax", "egreedy"]), default="softmax", show_default=True)
@click.option(
    "--temperature",
    nargs=2,
    type=real(0, 1000, above=True),
    default=(1.0, 0.1),
    show_default=True,
    metavar="START END",
    help="Softmax exploration temperature, annealed linearly over the run.",
)
@click.option(
    "--epsilon",
    nargs=2,
    type=real(0, 1),
    default=(1.0, 0.0),
    show_default=True,
    metavar="START END",
    help="Epsilon-greedy exploration, annealed linearly over the run.",
)
@click.option(
    "--rules/--no-rules",
    default=False,
    show_default=True,
    help="Explore and evaluate under the deployment rules of ddql:PATH (hover on a free target, no move "
    "off the map or into a known obstacle); --no-rules is the paper.",
)
@click.option("--parallel", type=whole(1, 4096), default=16, show_default=True, help="Episodes stepped together.")
@click.option("--batch-size", type=whole(1, 65536), default=64, show_default=True)
@click.option(
    "--updates-per-step",
    type=real(0, 64, above=True),
    default=1.0,
    show_default=True,
    help="Gradient steps per joint step of the parallel episodes.",
)
@click.option("--lr", type=real(0, 1, above=True), default=5e-4, show_default=True, help="RAdam learning rate.")
@click.option(
    "--prefill", type=whole(0, 1_000_000), default=1000, show_default=True, help="Random episodes in the replay first."
)
@click.option("--replay", "replay_capacity", type=whole(1), default=100_000, show_default=True, help="Replay capacity.")
@click.option(
    "--target-every", type=whole(1, 10**9), default=500, show_default=True, help="n_q: steps between target copies."
)
@click.option("--plain-target", is_flag=True, help="Use the plain target-network target, not double DQN.")
@click.option(
    "--eval-every", type=whole(1, MAX_EPISODES), default=250, show_default=True, help="Episodes between evaluations."
)
@click.option("--eval-episodes", type=whole(1, 1_000_000), default=200, show_default=True)
@click.option(
    "--eval-steps",
    type=whole(1, MAX_STEPS),
    default=40,
    show_default=True,
    help="Step limit of the held-out episodes (the paper: 40 on 20 x 20, 100 on big maps).",
)
@click.option("--threads", type=whole(1, 256), default=2, show_default=True, help="Torch CPU threads.")
@click.option(
    "--variant",
    type=click.Choice(sorted(VARIANT_CHANNELS)),
    default=PAPER_VARIANT,
    show_default=True,
    help="Observation and network: the paper's window, or global-local-v1 (the window + the whole map pooled).",
)
@click.option(
    "--explore-reward",
    type=real(0.0, 10.0),
    default=0.0,
    show_default=True,
    help="Reward per sensing disc of cells a vehicle newly explores (0: the paper's reward).",
)
@click.option(
    "--curriculum",
    type=click.Choice(sorted(CURRICULA)),
    default=None,
    help="Train on many worlds, small maps to large (swarmctl.learn.curriculum); the world options set "
    "only the observation (window, fov, rho) then.",
)
@click.option(
    "--resume",
    is_flag=True,
    help="Continue the stopped run whose checkpoint is --out (its networks, optimiser, replay and random "
    "states); give the run's own options.",
)
@click.option(
    "--keep-resume/--no-keep-resume",
    default=None,
    help="At every evaluation save what --resume needs (the replay memory beside --out as NAME.replay.pt). "
    "Default: on with --curriculum or --resume.",
)
@click.option("--progress/--no-progress", default=True)
def train_command(
    episodes,
    seed,
    out,
    init,
    device,
    exploration,
    temperature,
    epsilon,
    rules,
    parallel,
    batch_size,
    updates_per_step,
    lr,
    prefill,
    replay_capacity,
    target_every,
    plain_target,
    eval_every,
    eval_episodes,
    eval_steps,
    threads,
    variant,
    explore_reward,
    curriculum,
    resume,
    keep_resume,
    progress,
    **kwargs,
):
    """Train the shared Q-network with DDQL and write a checkpoint with its config and metadata."""
    import torch

    from swarmctl.learn.ddql import TrainConfig, train

    world = replace(world_config(kwargs), variant=variant, explore_reward=explore_reward)
    require(not resume or out.is_file(), f"--resume: {out} does not exist; give the --out of the stopped run")
    require(replay_capacity >= batch_size, f"--replay {replay_capacity} must hold at least one batch ({batch_size})")
    require(world.window >= 8, f"--window {world.window}: the network needs F >= 8")
    obs_floats = VARIANT_CHANNELS[variant] * world.window**2
    require_memory(
        replay_capacity * (2 * 2 * obs_floats + 12),  # o and o' as float16, the action and the reward
        f"--replay {replay_capacity} samples of {obs_floats:,}-value observations",
        "give a smaller --replay (the paper's is 100000)",
    )
    busiest = max(parallel, min(prefill, 100), eval_episodes)  # the largest batch of episodes stepped at once
    biggest = replace(world, map_size=max(world.map_size, curriculum_side(curriculum))) if curriculum else world
    require_world_memory(biggest, busiest, f"{busiest} parallel or held-out episodes at M={biggest.map_size}")
    if init is not None:
        require(init.is_file(), f"--init {init}: no such checkpoint file")
    writable_file(out, "--out")
    writable_file(out.with_suffix(".csv"), "--out")
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    require(device != "cuda" or torch.cuda.is_available(), "--device cuda: no CUDA device here; use --device cpu")
    cfg = TrainConfig(
        episodes=episodes,
        parallel_envs=parallel,
        batch_size=batch_size,
        updates_per_step=updates_per_step,
        lr=lr,
        prefill_episodes=prefill,
        replay_capacity=replay_capacity,
        target_update_every=target_every,
        double=not plain_target,
        exploration=exploration,
        rules=rules,
        temperature_start=temperature[0],
        temperature_end=temperature[1],
        epsilon_start=epsilon[0],
        epsilon_end=epsilon[1],
        eval_every=eval_every,
        eval_episodes=eval_episodes,
        eval_steps=eval_steps,
        threads=threads,
        curriculum=curriculum,
        keep_resume=bool(curriculum or resume) if keep_resume is None else keep_resume,
    )
    stop = _stop_on_signals()
    meta = train(world, cfg, seed, out, init=init, device=device, progress=progress, resume=resume, stop=stop)
    if meta.get("stopped"):
        click.echo(
            f"stopped after {meta['episodes']} episodes; saved {out} and its replay: continue with the same "
            "command and --resume",
            err=True,
        )
        raise click.exceptions.Exit(130)
    final = meta["final_eval"] or {}
    click.echo(
        f"wrote {out} ({meta['wall_time_s']:.0f} s, {meta['samples']} samples, {meta['updates']} updates); "
        f"held-out success {final.get('success_rate', float('nan')):.3f}, "
        f"mean steps {final.get('mean_steps', float('nan')):.2f}"
    )


def _stop_on_signals():
    """SIGINT / SIGTERM ask the training to stop after its round and save what --resume needs."""
    import signal

    asked = []

    def handler(signum, _frame):
        if asked:  # a second signal: stop now
            raise KeyboardInterrupt
        asked.append(signum)

    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            signal.signal(sig, handler)
        except ValueError:  # not the main thread (tests calling main() from a worker)
            pass
    return lambda: bool(asked)
