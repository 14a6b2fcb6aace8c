"""Reproduce the paper's training figure: success probability vs training episodes.

For each seed and each exploration rule (softmax, epsilon-greedy) this trains one model for the
largest episode count, keeps the checkpoint as it stood at every count (TrainConfig.snapshots), and
evaluates each snapshot on the same test episodes with softmax tau 0.1. The figure shows the mean over
seeds with min/max bars and LA(4) as a line. Results go to training_curve.json after every run, so an
interrupted job keeps what it finished, and one job per exploration (`--explorations softmax`) can
run on each core; `--plot-only` redraws the PNG from that file.

    python tools/training_curve.py --out results/training-curve --seeds 5 --episodes 250 750 1000 3000

The paper trains a separate model per count, each with its exploration annealed over its own length.
That costs 2 x seeds x (sum of the counts) episodes, 50,000 for the full figure: 15-18 core-hours
here. Snapshots of one run per seed cost 2 x seeds x (largest count), 30,000 episodes. The defaults
(`--parallel 10 --updates-per-step 1.25`: one gradient step per 16 vehicle transitions, 37,500 per
3000 episodes, the recipe of models/cluster-2uav.pt's first stage) took 45-57 min of training per
run on one core with a second run beside it: 8.5 core-hours for the figure's 10 runs. A fifth of
those gradient steps (`--updates-per-step 0.25`, 14 min per run) learns nothing in 3000 episodes:
success 0.01-0.02 for both rules, seed 0. A snapshot taken early in a run was trained while
exploration was still high, which the paper's protocol avoids.
`--map 6 --targets 2 --episodes 20 40` gives a quick smoke run.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import time
from dataclasses import asdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from swarmctl.learn.ddql import TrainConfig, snapshot_path, train  # noqa: E402
from swarmctl.learn.evaluate import evaluate  # noqa: E402
from swarmctl.world import WorldConfig  # noqa: E402

EXPLORATIONS = ("softmax", "egreedy")


def plot(results: dict, out: Path) -> None:
    """Mean success per count over the seeds run so far, min/max bars, LA(4) as a line."""
    counts = results["episodes"]
    fig, ax = plt.subplots(figsize=(6, 4))
    for exploration, style in zip(EXPLORATIONS, ("o-", "s--")):
        runs = results["runs"].get(exploration, [])
        if not runs:
            continue
        s = np.array(runs)
        mean = s.mean(0)
        ax.errorbar(
            counts,
            mean,
            yerr=[mean - s.min(0), s.max(0) - mean],
            fmt=style,
            capsize=3,
            label=f"DDQL {exploration} ({len(runs)} seed{'s' if len(runs) != 1 else ''}, min/max)",
        )
    ax.axhline(results["la4_success"], color="k", lw=1, label="LA(4)")
    w = results["world"]
    ax.set_xlabel("training episodes")
    ax.set_ylabel("success probability")
    ax.set_title(f"{w['scenario']}, {w['uavs']} UAVs, {w['map_size']} x {w['map_size']}, {results['steps']} steps")
    ax.set_ylim(0, 1)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(out / "training_curve.png", dpi=120)
    plt.close(fig)


def record(
    json_path: Path, exploration: str, seed: int, success: list, success_rules: list, wall: float, train_config: dict
) -> dict:
    """Add one run to training_curve.json under a lock, so jobs for different explorations can share it."""
    with open(json_path.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        results = json.loads(json_path.read_text())
        results["runs"].setdefault(exploration, []).append(success)
        results["runs_with_rules"].setdefault(exploration, []).append(success_rules)
        results["seeds"].setdefault(exploration, []).append(seed)
        results["wall_s"].setdefault(exploration, []).append(round(wall, 1))
        results["train_config"] = train_config
        json_path.write_text(json.dumps(results, indent=1))
    return results


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("results/training-curve"))
    ap.add_argument("--scenario", default="cluster")
    ap.add_argument("--map", type=int, default=20)
    ap.add_argument("--uavs", type=int, default=2)
    ap.add_argument("--targets", type=int, default=4)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--explorations", nargs="+", choices=EXPLORATIONS, default=list(EXPLORATIONS))
    ap.add_argument("--episodes", type=int, nargs="+", default=[250, 750, 1000, 3000])
    ap.add_argument("--eval-episodes", type=int, default=500)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--parallel", type=int, default=10, help="must divide every count")
    ap.add_argument("--updates-per-step", type=float, default=1.25)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--plot-only", action="store_true", help="redraw the PNG from training_curve.json")
    args = ap.parse_args()

    args.out.mkdir(parents=True, exist_ok=True)
    json_path = args.out / "training_curve.json"
    if args.plot_only:
        plot(json.loads(json_path.read_text()), args.out)
        print(f"wrote {args.out / 'training_curve.png'}")
        return

    world = WorldConfig(
        scenario=args.scenario,
        map_size=args.map,
        uavs=args.uavs,
        targets=args.targets,
        window=min(20, max(8, args.map)),
    )
    counts = sorted(args.episodes)
    if any(n % args.parallel for n in counts):
        ap.error(f"--parallel {args.parallel} must divide every count in --episodes {counts}")
    results = json.loads(json_path.read_text()) if json_path.exists() else {}
    if results and (results.get("episodes") != counts or results.get("world") != world.as_dict()):
        ap.error(
            f"{json_path} holds runs of another setting (episodes {results.get('episodes')}); "
            "use another --out, or the same --episodes and world options to add seeds to it"
        )
    if not results:
        la = evaluate(world, ["la:4"], args.eval_episodes, seed=0, steps=args.steps, progress=False)[0]
        results = {
            "episodes": counts,
            "world": world.as_dict(),
            "steps": args.steps,
            "eval_seed": 0,
            "eval_episodes": args.eval_episodes,
            "la4_success": la["success_rate"],
            "runs": {},
            "runs_with_rules": {},
            "seeds": {},
            "train_config": None,
            "wall_s": {},
        }
        json_path.write_text(json.dumps(results, indent=1))
    for seed in args.seeds:
        for exploration in args.explorations:
            if seed in results["seeds"].get(exploration, []):
                continue  # finished in an earlier invocation
            cfg = TrainConfig(
                episodes=counts[-1],
                parallel_envs=args.parallel,
                exploration=exploration,
                updates_per_step=args.updates_per_step,
                snapshots=tuple(counts),
                eval_every=counts[-1],
                eval_episodes=100,
                threads=args.threads,
            )
            path = args.out / f"{exploration}-s{seed}.pt"
            t0 = time.time()
            train(world, cfg, seed=seed, out=path, progress=False)
            wall = time.time() - t0
            # the figure uses the paper's DDQL Soft (the network alone); our decision rules go in the JSON beside
            paper = [f"ddql:{snapshot_path(path, n)}:taken=keep:hover=no:mask=no" for n in counts]
            ours = [f"ddql:{snapshot_path(path, n)}" for n in counts]
            rows = evaluate(world, paper + ours, args.eval_episodes, seed=0, steps=args.steps, progress=False)
            success = [r["success_rate"] for r in rows[: len(counts)]]
            success_rules = [r["success_rate"] for r in rows[len(counts) :]]
            train_config = {k: v for k, v in asdict(cfg).items() if k != "exploration"}
            results = record(json_path, exploration, seed, success, success_rules, wall, train_config)
            plot(results, args.out)
            print(f"{exploration} seed {seed}: success {dict(zip(counts, success))}, {wall / 60:.1f} min", flush=True)
    print(f"wrote {args.out / 'training_curve.png'}")


if __name__ == "__main__":
    main()
