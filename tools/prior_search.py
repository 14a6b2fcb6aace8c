"""Searching with a prior (docs/RESULTS.md, "Searching with a prior"): the coordinated planner that weighs
the prior against the same planner ignoring it, on the Chicago Loop grid.

    nice -n 10 python tools/prior_search.py                  # run (seed 45045), write the JSON and the figure
    python tools/prior_search.py --report                    # the Markdown table from the JSON
    python tools/prior_search.py --write-prior prior.npz     # the hotspot prior, for swarmctl eval --prior

3 UAVs, 3 targets drawn from the prior (scenario `prior`), 300 steps, finish line `pos` at 0.9; the prior
puts 70 % of the probability on 20 % of the grid's free cells round two centres (prior.hotspot_prior,
drawn with HOTSPOT_SEED; `swarmctl eval --prior hotspot:0.7:0.2:1` makes the same). Every planner plays
the same episodes (episode i depends on (seed, i) only), so differences are paired.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmctl.figures import pyplot  # noqa: E402
from swarmctl.geo.grid import GeoGrid  # noqa: E402
from swarmctl.learn.evaluate import run_policy  # noqa: E402
from swarmctl.world.config import WorldConfig  # noqa: E402
from swarmctl.world.prior import hotspot_prior  # noqa: E402

GRID = ROOT / "missions/chicago-loop/grid.npz"
HOTSPOT_SEED, SHARE, AREA = 1, 0.7, 0.2
PODS = (1.0, 0.7)
HOVERS = ("no", "defer")  # no: the team searches on after a find (POS is the goal); defer: the default rule
STEPS, UAVS, TARGETS, GOAL = 300, 3, 3, 0.9
EARLY = 0.5  # a second POS level whose steps are reported


def prior_and_blocked() -> tuple[np.ndarray, np.ndarray]:
    blocked = GeoGrid.load(GRID).blocked.copy()
    return hotspot_prior(~blocked, SHARE, AREA, np.random.default_rng(HOTSPOT_SEED)), blocked


def specs(hover: str) -> tuple[str, str]:
    return f"coordinated:hover={hover}", f"coordinated:prior=no:hover={hover}"


def first_step(trace: list[float], level: float) -> int:
    """The step POS first reached `level`, the step limit when never."""
    hits = np.flatnonzero(np.asarray(trace) >= level - 1e-9)
    return int(hits[0]) if len(hits) else STEPS


def run(seed: int, episodes: int, out: Path) -> dict:
    prior, blocked = prior_and_blocked()
    w, h = blocked.shape
    runs: dict[str, dict] = {}
    for pod in PODS:
        cfg = WorldConfig(
            scenario="prior", uavs=UAVS, targets=TARGETS, map_size=max(w, h), finish="pos", pos_goal=GOAL, pod=pod
        )
        for hover in HOVERS:
            for spec in specs(hover):
                t0 = time.perf_counter()
                r = run_policy(cfg, spec, episodes, seed, STEPS, chunk=100, progress=False, blocked=blocked,
                               prior=prior, pos_traces=True)  # fmt: skip
                per = r["per_episode"]
                runs[f"{pod:g} {spec}"] = {
                    "pod": pod,
                    "policy": spec,
                    "success_rate": r["success_rate"],
                    "goal_steps": [first_step(e["pos_by_step"], GOAL) for e in per],
                    "early_steps": [first_step(e["pos_by_step"], EARLY) for e in per],
                    "final_pos": [e["final_pos"] for e in per],
                    "targets_found": [e["targets_found"] for e in per],
                    "pos_by_step": r["pos_by_step"],
                }
                print(f"pod {pod:g} {spec}: success {r['success_rate']:.3f}, steps to POS {GOAL} "
                      f"{r['mean_pos_goal_steps']:.1f} ({time.perf_counter() - t0:.0f} s)", flush=True)  # fmt: skip
    result = {
        "seed": seed,
        "episodes": episodes,
        "steps": STEPS,
        "grid": str(GRID.relative_to(ROOT)),
        "prior": f"hotspot:{SHARE}:{AREA}:{HOTSPOT_SEED}",
        "pos_goal": GOAL,
        "runs": runs,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result))
    return result


def mean_se(x: list[float] | np.ndarray) -> tuple[float, float]:
    a = np.asarray(x, dtype=np.float64)
    return float(a.mean()), float(a.std(ddof=1) / math.sqrt(len(a))) if len(a) > 1 else 0.0


def report(result: dict) -> str:
    runs = result["runs"]
    n = result["episodes"]
    lines = [
        f"| pod | hover | planner | success (POS >= {GOAL}) | steps to POS {GOAL} | prior - ignoring (paired) "
        f"| steps to POS {EARLY} | prior - ignoring | final POS | targets found |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for pod in PODS:
        for hover in HOVERS:
            aware, blind = (runs[f"{pod:g} {s}"] for s in specs(hover))
            for name, r in (("prior", aware), ("ignoring the prior", blind)):
                p = r["success_rate"]
                goal, goal_se = mean_se(r["goal_steps"])
                early, early_se = mean_se(r["early_steps"])
                fpos, fpos_se = mean_se(r["final_pos"])
                found = np.mean(r["targets_found"])
                diff = diff_early = "-"
                if r is aware:
                    d, d_se = mean_se(np.subtract(aware["goal_steps"], blind["goal_steps"]))
                    e, e_se = mean_se(np.subtract(aware["early_steps"], blind["early_steps"]))
                    diff, diff_early = f"{d:+.1f} ± {d_se:.1f}", f"{e:+.1f} ± {e_se:.1f}"
                lines.append(
                    f"| {pod:g} | {hover} | {name} | {p:.3f} ± {math.sqrt(p * (1 - p) / n):.3f} "
                    f"| {goal:.1f} ± {goal_se:.1f} | {diff} | {early:.1f} ± {early_se:.1f} | {diff_early} "
                    f"| {fpos:.3f} ± {fpos_se:.3f} | {found:.2f} |"
                )
    return "\n".join(lines)


def figure(result: dict, path: Path) -> None:
    plt = pyplot()
    prior, blocked = prior_and_blocked()
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.6), gridspec_kw=dict(width_ratios=[1, 1.3]))
    shown = np.ma.masked_where(blocked, prior * (~blocked).sum())  # in units of a uniform prior's cell
    left.set_facecolor("0.55")
    im = left.imshow(shown.T, origin="lower", cmap="viridis")
    fig.colorbar(im, ax=left, fraction=0.046, label="prior / uniform prior (grey: blocked)")
    left.set_title(f"prior: {SHARE:.0%} on {AREA:.0%} of the free cells (seed {HOTSPOT_SEED})")
    left.set_xlabel("x (cells of 10 m)")
    left.set_ylabel("y")
    steps = np.arange(result["steps"] + 1)
    for pod, style in zip(PODS, ("-", "--")):
        for spec, colour, name in zip(specs("no"), ("C0", "C1"), ("weighs the prior", "ignores the prior")):
            r = result["runs"][f"{pod:g} {spec}"]
            right.plot(steps, r["pos_by_step"], style, color=colour, label=f"{name}, pod {pod:g}")
    right.axhline(GOAL, color="0.5", lw=0.8)
    right.set_xlabel("step")
    right.set_ylabel("mean POS (an episode stops at 0.9)")
    right.set_ylim(0, 1)
    right.set_title(f"coordinated planner, 3 UAVs, {result['episodes']} episodes, seed {result['seed']}")
    right.legend(loc="lower right")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=45045, help="Episode seed (45045: never used for tuning).")
    ap.add_argument("--episodes", type=int, default=200)
    ap.add_argument("--report", action="store_true", help="Print the table from the JSON; run nothing.")
    ap.add_argument("--write-prior", type=Path, help="Write the hotspot prior as a .npz for eval --prior; run nothing.")
    ap.add_argument("--figure", type=Path, default=ROOT / "docs/prior-search.png")
    args = ap.parse_args()
    if args.write_prior is not None:
        np.savez_compressed(args.write_prior, prior=prior_and_blocked()[0])
        print(f"wrote {args.write_prior}")
        return
    out = ROOT / f"results/prior_search/{args.seed}.json"
    result = json.loads(out.read_text()) if args.report else run(args.seed, args.episodes, out)
    if not args.report:
        figure(result, args.figure)
        print(f"wrote {out.relative_to(ROOT)} and {args.figure}")
    print(report(result))


if __name__ == "__main__":
    main()
