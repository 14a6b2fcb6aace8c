"""Reproduce the paper's training figure: success probability vs training episodes.

For each exploration rule (softmax, epsilon-greedy), each of S seeds and each episode count N_e, train
a model for N_e episodes (its exploration schedule annealed over its own length, like the paper's
separate runs) and evaluate it on the same test episodes; plot the mean with min/max bars and LA(4)
as a line. Writes PNG + JSON.

    python tools/training_curve.py --out results/training-curve --seeds 5 --episodes 250 750 1000 3000

The full figure costs 2 x seeds x (sum of the counts) training episodes: many hours on a 2-core CPU. `--map 6 --targets 2 --episodes 16 32` gives a quick smoke run.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from swarmctl.learn.ddql import TrainConfig, train  # noqa: E402
from swarmctl.learn.evaluate import evaluate  # noqa: E402
from swarmctl.world import WorldConfig  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("results/training-curve"))
    ap.add_argument("--scenario", default="cluster")
    ap.add_argument("--map", type=int, default=20)
    ap.add_argument("--uavs", type=int, default=2)
    ap.add_argument("--targets", type=int, default=4)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--episodes", type=int, nargs="+", default=[250, 750, 1000, 3000])
    ap.add_argument("--eval-episodes", type=int, default=500)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--parallel", type=int, default=8)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()

    world = WorldConfig(scenario=args.scenario, map_size=args.map, uavs=args.uavs, targets=args.targets,
                        window=min(20, max(8, args.map)))
    counts = sorted(args.episodes)
    args.out.mkdir(parents=True, exist_ok=True)
    results: dict = {"episodes": counts, "runs": {}}
    for exploration in ("softmax", "egreedy"):
        per_seed = []
        for seed in range(args.seeds):
            snapshots = []
            for n in counts:
                # one training run per count keeps each schedule annealed over its own length, as in the paper
                cfg = TrainConfig(episodes=n, parallel_envs=args.parallel, exploration=exploration,
                                  eval_every=n, eval_episodes=100, threads=args.threads)
                path = args.out / f"{exploration}-s{seed}-{n}.pt"
                train(world, cfg, seed=seed, out=path, progress=False)
                r = evaluate(world, [f"ddql:{path}"], args.eval_episodes, seed=0, steps=args.steps, progress=False)[0]
                snapshots.append(r["success_rate"])
                print(f"{exploration} seed {seed} episodes {n}: success {r['success_rate']:.3f}", flush=True)
            per_seed.append(snapshots)
        results["runs"][exploration] = per_seed
    la = evaluate(world, ["la:4"], args.eval_episodes, seed=0, steps=args.steps, progress=False)[0]
    results["la4_success"] = la["success_rate"]
    (args.out / "training_curve.json").write_text(json.dumps(results, indent=1))

    fig, ax = plt.subplots(figsize=(6, 4))
    for exploration, style in (("softmax", "o-"), ("egreedy", "s--")):
        s = np.array(results["runs"][exploration])
        mean = s.mean(0)
        ax.errorbar(counts, mean, yerr=[mean - s.min(0), s.max(0) - mean], fmt=style, capsize=3,
                    label=f"DDQL {exploration} ({args.seeds} seeds, min/max)")
    ax.axhline(la["success_rate"], color="k", lw=1, label="LA(4)")
    ax.set_xlabel("training episodes")
    ax.set_ylabel("success probability")
    ax.set_title(f"{args.scenario}, {args.uavs} UAVs, {args.map} x {args.map}, {args.steps} steps")
    ax.set_ylim(0, 1)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out / "training_curve.png", dpi=120)
    print(f"wrote {args.out / 'training_curve.png'}")


if __name__ == "__main__":
    main()
