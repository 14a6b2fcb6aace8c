"""`swarmctl eval`: compare policies on the same episodes."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import click

from swarmctl.cli_options import require, world_config, world_options
from swarmctl.learn.curriculum import CURRICULA
from swarmctl.learn.evaluate import DEFAULT_CHUNK, evaluate
from swarmctl.policy.registry import POLICY_HELP
from swarmctl.world.beliefs import PAPER_VARIANT, VARIANT_CHANNELS


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


@click.command("eval")
@world_options
@click.option("--steps", type=int, default=40, show_default=True, help="Step limit N of a test episode.")
@click.option("--episodes", type=int, default=500, show_default=True, help="Test episodes E.")
@click.option("--seed", type=int, default=0, show_default=True, help="Episode seed: same seed, same episodes.")
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
    type=int,
    default=DEFAULT_CHUNK,
    show_default=True,
    help="Episodes stepped at once (memory and speed only: results do not depend on it).",
)
@click.option(
    "--threads", type=int, default=1, show_default=True, help="Torch and onnxruntime CPU threads for the policies."
)
@click.option("--progress/--no-progress", default=True, help="Show a progress bar on a terminal.")
def eval_command(steps, episodes, seed, policies, json_path, grid_file, batch, threads, progress, **kwargs):
    """Evaluate policies: success rate, mean episode duration, duration CDF, against the oracle bound."""
    cfg = world_config(kwargs)
    require(steps >= 1, f"--steps {steps} must be >= 1")
    require(episodes >= 1, f"--episodes {episodes} must be >= 1")
    require(batch >= 1, f"--batch {batch} must be >= 1")
    require(threads >= 1, f"--threads {threads} must be >= 1")
    from swarmctl.policy.threads import set_inference_threads

    set_inference_threads(threads)
    blocked, where = None, f"M={cfg.map_size}"
    if grid_file is not None:
        from swarmctl.geo.grid import GeoGrid

        grid = GeoGrid.load(grid_file)
        blocked = grid.blocked.copy()
        cfg = replace(cfg, map_size=max(grid.width, grid.height), obstacles=0.0)
        where = f"grid {grid_file} ({grid.width} x {grid.height}, {blocked.mean():.1%} blocked)"
    results = evaluate(cfg, list(policies), episodes, seed, steps, chunk=batch, progress=progress, blocked=blocked)
    if grid_file is not None:
        for r in results:
            r["scenario"]["grid"] = str(grid_file)
    click.echo(
        f"{cfg.scenario}, {where}, U={cfg.uavs}, K={cfg.targets}"
        + (f", eta={cfg.obstacles}" if grid_file is None else "")
        + f", N={steps}, {episodes} episodes, seed {seed}, channel {cfg.channel}"
    )
    click.echo(format_table(results))
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps({"results": results}, indent=1))
        click.echo(f"wrote {json_path}")


@click.command("train")
@world_options
@click.option("--episodes", type=int, default=3000, show_default=True, help="Training episodes N_e.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed: same seed, same machine, same model.")
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
    type=float,
    default=(1.0, 0.1),
    show_default=True,
    metavar="START END",
    help="Softmax exploration temperature, annealed linearly over the run.",
)
@click.option(
    "--epsilon",
    nargs=2,
    type=float,
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
@click.option("--parallel", type=int, default=16, show_default=True, help="Episodes stepped together.")
@click.option("--batch-size", type=int, default=64, show_default=True)
@click.option(
    "--updates-per-step",
    type=float,
    default=1.0,
    show_default=True,
    help="Gradient steps per joint step of the parallel episodes.",
)
@click.option("--lr", type=float, default=5e-4, show_default=True, help="RAdam learning rate.")
@click.option("--prefill", type=int, default=1000, show_default=True, help="Random episodes in the replay first.")
@click.option("--replay", "replay_capacity", type=int, default=100_000, show_default=True, help="Replay capacity.")
@click.option("--target-every", type=int, default=500, show_default=True, help="n_q: steps between target copies.")
@click.option("--plain-target", is_flag=True, help="Use the plain target-network target, not double DQN.")
@click.option("--eval-every", type=int, default=250, show_default=True, help="Episodes between evaluations.")
@click.option("--eval-episodes", type=int, default=200, show_default=True)
@click.option(
    "--eval-steps",
    type=int,
    default=40,
    show_default=True,
    help="Step limit of the held-out episodes (the paper: 40 on 20 x 20, 100 on big maps).",
)
@click.option("--threads", type=int, default=2, show_default=True, help="Torch CPU threads.")
@click.option(
    "--variant",
    type=click.Choice(sorted(VARIANT_CHANNELS)),
    default=PAPER_VARIANT,
    show_default=True,
    help="Observation and network: the paper's window, or global-local-v1 (the window + the whole map pooled).",
)
@click.option(
    "--explore-reward",
    type=click.FloatRange(0.0, 10.0),
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
    require(episodes >= 1, f"--episodes {episodes} must be >= 1")
    require(not resume or out.is_file(), f"--resume: {out} does not exist; give the --out of the stopped run")
    require(parallel >= 1, f"--parallel {parallel} must be >= 1")
    require(batch_size >= 1, f"--batch-size {batch_size} must be >= 1")
    require(updates_per_step > 0, f"--updates-per-step {updates_per_step} must be > 0")
    require(lr > 0, f"--lr {lr} must be > 0")
    require(prefill >= 0, f"--prefill {prefill} must be >= 0")
    require(replay_capacity >= batch_size, f"--replay {replay_capacity} must hold at least one batch ({batch_size})")
    require(target_every >= 1, f"--target-every {target_every} must be >= 1")
    require(
        eval_every >= 1 and eval_episodes >= 1 and eval_steps >= 1,
        "--eval-every, --eval-episodes and --eval-steps must be >= 1",
    )
    require(threads >= 1, f"--threads {threads} must be >= 1")
    require(min(temperature) > 0, f"--temperature {temperature[0]} {temperature[1]}: temperatures must be > 0")
    require(all(0 <= e <= 1 for e in epsilon), f"--epsilon {epsilon[0]} {epsilon[1]}: epsilons must be in [0, 1]")
    require(world.window >= 8, f"--window {world.window}: the network needs F >= 8")
    if init is not None:
        require(init.is_file(), f"--init {init}: no such checkpoint file")
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
