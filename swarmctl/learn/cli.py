"""`swarmctl eval`: compare policies on the same episodes; `swarmctl train` and `train-search`: train them."""

from __future__ import annotations

import io
import json
import zipfile
import zlib
from dataclasses import replace
from pathlib import Path

import click
import numpy as np

from swarmctl.bounds import MAX_THREADS, SEED, read_limited, require_memory, whole, writable_file
from swarmctl.cli_options import (
    field_default,
    options_from,
    require,
    require_world_memory,
    values_from,
    world_config,
    world_options,
)
from swarmctl.errors import InputError
from swarmctl.learn.curriculum import curriculum_side
from swarmctl.learn.evaluate import DEFAULT_CHUNK, evaluate
from swarmctl.learn.search_config import SearchConfig
from swarmctl.learn.train_config import MAX_EPISODES, MAX_STEPS, TrainConfig
from swarmctl.policy.registry import POLICY_HELP
from swarmctl.world.beliefs import VARIANT_CHANNELS
from swarmctl.world.config import WorldConfig
from swarmctl.world.prior import hotspot_prior, normalise_prior


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


EVAL_WORLD = ("finish", "pod", "pos_goal")  # WorldConfig fields that eval sets besides the world's options
PRIOR_MAX_BYTES = 64 * 2**20
PRIOR_HELP = (
    "Where the person is likely to be: a .npz file with an array `prior` of the map's shape (non-negative "
    "weights, normalised over each episode's free cells), or hotspot:SHARE:AREA[:SEED], SHARE of the "
    "probability on about AREA of the free cells round two random centres (swarmctl.world.prior.hotspot_prior, "
    "drawn with SEED, default 0). Planners that read it search where it is likely; POS is always against it "
    "(uniform without it). --scenario prior draws the targets from it."
)


def load_prior(text: str, free: np.ndarray) -> np.ndarray:
    """The prior `--prior` names, (W, H) float64 weights for a map whose free cells are `free` (W, H):
    hotspot:SHARE:AREA[:SEED] made on `free`, or a .npz file's array `prior` of that shape."""
    if text.startswith("hotspot:"):
        parts = text.split(":")[1:]
        try:
            share, area = float(parts[0]), float(parts[1])
            seed = int(parts[2]) if len(parts) == 3 else 0
            if len(parts) not in (2, 3) or seed < 0:
                raise ValueError
        except (ValueError, IndexError):
            raise InputError(
                f"--prior {text!r}: write hotspot:SHARE:AREA[:SEED], as in hotspot:0.7:0.2:1 (SEED a whole number >= 0)"
            ) from None
        return hotspot_prior(free, share, area, np.random.default_rng(seed))
    path = Path(text)
    data = read_limited(path, "prior file", PRIOR_MAX_BYTES, "--prior")
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            prior = np.asarray(npz["prior"])
    except KeyError:
        raise InputError(
            f"--prior {path}: the .npz file has no array named `prior`; save it with np.savez(path, prior=...)"
        ) from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise InputError(
            f"--prior {path}: not a .npz file ({type(exc).__name__}); save it with np.savez(path, prior=...)"
        ) from None
    if prior.shape != free.shape or prior.dtype.kind not in "biuf":
        raise InputError(
            f"--prior {path}: `prior` is a {prior.dtype} array of shape {prior.shape}; give numbers of the map's "
            f"shape {free.shape}"
        )
    normalise_prior(prior, free, f"--prior {path}")  # the weights checked once, here
    return prior.astype(np.float64)


TRAIN_WORLD = ("variant", "explore_reward")  # ... and train
TRAIN_FIRST = ("episodes",)  # the TrainConfig fields train sets, in the order of its help
TRAIN_HYPERPARAMETERS = (
    "exploration",
    "temperature_start",  # --temperature START END
    "epsilon_start",  # --epsilon START END
    "rules",
    "parallel_envs",
    "batch_size",
    "updates_per_step",
    "lr",
    "prefill_episodes",
    "replay_capacity",
    "target_update_every",
    "double",  # --plain-target
    "eval_every",
    "eval_episodes",
    "eval_steps",
    "threads",
)
TRAIN_LAST = ("curriculum",)
TRAIN_RESUME = ("keep_resume",)  # default None on the command line: on with --curriculum or --resume


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
    type=whole(1, MAX_THREADS),
    default=1,
    show_default=True,
    help="Torch and onnxruntime CPU threads for the policies.",
)
@options_from(WorldConfig, EVAL_WORLD)
@click.option("--prior", "prior_text", default=None, metavar="FILE|hotspot:SHARE:AREA[:SEED]", help=PRIOR_HELP)
@click.option("--progress/--no-progress", default=True, help="Show a progress bar on a terminal.")
def eval_command(steps, episodes, seed, policies, json_path, grid_file, batch, threads, prior_text, progress, **kwargs):
    """Evaluate policies: success rate, mean episode duration, duration CDF, against the oracle bound."""
    cfg = world_config(kwargs, **values_from(WorldConfig, kwargs, EVAL_WORLD))
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
    prior = None
    if prior_text is not None:
        free = ~blocked if blocked is not None else np.ones((cfg.map_size, cfg.map_size), dtype=bool)
        prior = load_prior(prior_text, free)
    if json_path is not None:
        writable_file(json_path, "--json")
    results = evaluate(
        cfg, list(policies), episodes, seed, steps, chunk=batch, progress=progress, blocked=blocked, prior=prior
    )
    for r in results:
        if grid_file is not None:
            r["scenario"]["grid"] = str(grid_file)
        r["scenario"]["prior"] = prior_text
    click.echo(
        f"{cfg.scenario}, {where}, U={cfg.uavs}, K={cfg.targets}"
        + (f", eta={cfg.obstacles}" if grid_file is None else "")
        + f", N={steps}, {episodes} episodes, seed {seed}, channel {cfg.channel}, finish {cfg.finish}"
        + (f", pod {cfg.pod:g}" if cfg.pod < 1 else "")
        + (f", prior {prior_text}" if prior_text is not None else "")
    )
    click.echo(format_table(results))
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps({"results": results}, indent=1))
        click.echo(f"wrote {json_path}")


@click.command("train")
@world_options
@options_from(TrainConfig, TRAIN_FIRST)
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
@options_from(TrainConfig, TRAIN_HYPERPARAMETERS)
@options_from(WorldConfig, TRAIN_WORLD)
@options_from(TrainConfig, TRAIN_LAST)
@click.option(
    "--resume",
    is_flag=True,
    help="Continue the stopped run whose checkpoint is --out (its networks, optimiser, replay and random "
    "states); give the run's own options.",
)
@options_from(TrainConfig, TRAIN_RESUME, overrides={"keep_resume": {"default": None}})
@click.option("--progress/--no-progress", default=True)
def train_command(seed, out, init, device, resume, progress, **kwargs):
    """Train the shared Q-network with DDQL and write a checkpoint with its config and metadata."""

    from swarmctl.learn.ddql import train

    settings = values_from(TrainConfig, kwargs, TRAIN_FIRST + TRAIN_HYPERPARAMETERS + TRAIN_LAST + TRAIN_RESUME)
    world = world_config(kwargs, **values_from(WorldConfig, kwargs, TRAIN_WORLD))
    replay_capacity, batch_size = settings["replay_capacity"], settings["batch_size"]
    curriculum = settings["curriculum"]
    if settings["keep_resume"] is None:
        settings["keep_resume"] = bool(curriculum or resume)
    require(not resume or out.is_file(), f"--resume: {out} does not exist; give the --out of the stopped run")
    require(replay_capacity >= batch_size, f"--replay {replay_capacity} must hold at least one batch ({batch_size})")
    require(world.window >= 8, f"--window {world.window}: the network needs F >= 8")
    obs_floats = VARIANT_CHANNELS[world.variant] * world.window**2
    require_memory(
        replay_capacity * (2 * 2 * obs_floats + 12),  # o and o' as float16, the action and the reward
        f"--replay {replay_capacity} samples of {obs_floats:,}-value observations",
        f"give a smaller --replay (the paper's is {field_default(TrainConfig, 'replay_capacity')})",
    )
    # the largest batch of episodes stepped at once
    busiest = max(settings["parallel_envs"], min(settings["prefill_episodes"], 100), settings["eval_episodes"])
    biggest = replace(world, map_size=max(world.map_size, curriculum_side(curriculum))) if curriculum else world
    require_world_memory(biggest, busiest, f"{busiest} parallel or held-out episodes at M={biggest.map_size}")
    if init is not None:
        require(init.is_file(), f"--init {init}: no such checkpoint file")
    writable_file(out, "--out")
    writable_file(out.with_suffix(".csv"), "--out")
    device = _device(device)
    cfg = TrainConfig(**settings)
    stop = _stop_on_signals()
    meta = train(world, cfg, seed, out, init=init, device=device, progress=progress, resume=resume, stop=stop)
    _exit_if_stopped(meta, out, "its replay")
    final = meta["final_eval"] or {}
    click.echo(
        f"wrote {out} ({meta['wall_time_s']:.0f} s, {meta['samples']} samples, {meta['updates']} updates); "
        f"held-out success {final.get('success_rate', float('nan')):.3f}, "
        f"mean steps {final.get('mean_steps', float('nan')):.2f}"
    )


SEARCH_FIELDS = (  # the SearchConfig fields train-search sets, in the order of its help
    "seed",
    "episodes",
    "parallel_envs",
    "threads",
    "curriculum",
    "stages",
    "advance_share",
    "current_share",
    "reward_target",
    "reward_cell",
    "step_cost",
    "success_bonus",
    "collision_penalty",
    "gamma",
    "n_step",
    "nstep_weight",
    "margin",
    "margin_form",
    "margin_weight",
    "teacher_ties",
    "l2",
    "lr",
    "batch_size",
    "updates_per_step",
    "target_update_every",
    "pretrain_updates",
    "replay_capacity",
    "demo_episodes",
    "dagger_capacity",
    "dagger_every",
    "demo_share_start",  # --demo-share START END
    "epsilon_start",  # --epsilon START END
    "eval_every",
    "val_episodes",
    "val_seed",
    "test_episodes",
    "test_seed",
    "keep_resume",
)
SEARCH_WORLD = ("window", "fov", "variant", "remove_taken")  # the observation; the stages set the rest


@click.command("train-search")
@options_from(SearchConfig, SEARCH_FIELDS)
@options_from(WorldConfig, SEARCH_WORLD)
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Checkpoint to write, e.g. models/search.pt (NAME.best.pt the best on the validation seed, NAME.csv "
    "the metrics, NAME.test.json the test report, NAME.replay.pt the stores for --resume).",
)
@click.option("--device", type=click.Choice(["auto", "cpu", "cuda"]), default="auto", show_default=True)
@click.option(
    "--resume",
    is_flag=True,
    help="Continue the stopped run whose checkpoint is --out (networks, optimiser, counters, stores, random "
    "states); give the run's own options.",
)
@click.option(
    "--tensorboard",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Also write TensorBoard scalars to this folder (needs the tensorboard package).",
)
@click.option("--progress/--no-progress", default=True)
def train_search_command(out, device, resume, tensorboard, progress, **kwargs):
    """Train the shared Q-network with the search recipe: team reward, deep Q-learning from the coordinated
    planner's demonstrations and DAgger labels, a curriculum opened by competence (swarmctl.learn.search_recipe)."""

    from swarmctl.learn.search_recipe import train

    cfg = SearchConfig(**values_from(SearchConfig, kwargs, SEARCH_FIELDS))
    world = WorldConfig(**values_from(WorldConfig, kwargs, SEARCH_WORLD))
    require(world.window >= 8, f"--window {world.window}: the network needs F >= 8")
    require(not resume or out.is_file(), f"--resume: {out} does not exist; give the --out of the stopped run")
    require(cfg.batch_size <= cfg.replay_capacity, f"--replay {cfg.replay_capacity} must hold a batch")
    stages = cfg.curriculum_stages()
    worlds = [w for s in stages for w in s.worlds]
    slot = VARIANT_CHANNELS[world.variant] * world.window**2 * 2 + 64  # a float16 observation and its numbers
    demos = sum(cfg.demo_episodes * w.uavs * (w.steps + 1) for w in worlds)
    require_memory(
        slot * (len(stages) * (cfg.replay_capacity + cfg.dagger_capacity) + demos),
        f"the stores of {len(stages)} stages ({cfg.replay_capacity:,} + {cfg.dagger_capacity:,} samples each, "
        f"and up to {demos:,} of demonstrations)",
        "give a smaller --replay, --dagger-capacity or --demo-episodes, or fewer --stages",
    )
    for w in worlds:
        require_world_memory(
            replace(world, map_size=w.map_size, uavs=w.uavs, targets=w.targets), cfg.parallel_envs, w.name
        )
    writable_file(out, "--out")
    writable_file(out.with_suffix(".csv"), "--out")
    device = _device(device)
    stop = _stop_on_signals()
    meta = train(world, cfg, out, device=device, progress=progress, resume=resume, stop=stop, tensorboard=tensorboard)
    _exit_if_stopped(meta, out, "its stores")
    final = meta["final_eval"] or {}
    click.echo(
        f"wrote {out} ({meta['wall_time_s']:.0f} s, {meta['samples']} samples, {meta['updates']} updates, "
        f"stage {meta['stage_reached'] + 1} of {len(stages)}); validation success "
        f"{final.get('success_rate', float('nan')):.3f} (the teacher's on its stage "
        f"{final.get('teacher_stage_success', float('nan')):.3f})"
    )
    for name, row in (meta.get("test") or {}).get("student", {}).items():
        teacher = meta["test"]["teacher"][name]
        click.echo(
            f"test {name}: success {row['success_rate']:.3f} (teacher {teacher['success_rate']:.3f}), "
            f"mean steps {row['mean_steps']:.2f} (teacher {teacher['mean_steps']:.2f})"
        )


def _device(device: str) -> str:
    """--device as torch names it: auto is cuda where there is one, else cpu."""
    import torch

    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    require(device != "cuda" or torch.cuda.is_available(), "--device cuda: no CUDA device here; use --device cpu")
    return device


def _exit_if_stopped(meta: dict, out: Path, kept: str) -> None:
    """A run stopped by a signal says what it saved and how to go on, and exits 130."""
    if meta.get("stopped"):
        click.echo(
            f"stopped after {meta['episodes']} episodes; saved {out} and {kept}: continue with the same command "
            "and --resume",
            err=True,
        )
        raise click.exceptions.Exit(130)


def _stop_on_signals():
    """SIGINT / SIGTERM ask the training to stop after its round and save what --resume needs."""
    import signal

    asked: list[int] = []

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
