"""The search table of docs/RESULTS.md: every policy on every setting, on held-out episodes.

    python tools/planner_table.py --seed 61206                   # every setting (hours on 2 cores)
    python tools/planner_table.py --seed 61206 --only chicago big10
    python tools/planner_table.py --seed 61206 --skip-la         # LA(4) left out (slow on big maps)
    python tools/planner_table.py --report                       # the Markdown tables from what is done

Each (setting, policy) is one `swarmctl eval` run written to results/planners/SEED/SETTING/POLICY.json
as soon as it ends, and skipped when that file is there: the run resumes where it stopped. Every
policy of a setting plays the same episodes (episode i depends on (seed, i) only). The Markdown
tables give success with its standard error, mean steps and x oracle.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmctl.geo.grid import GeoGrid  # noqa: E402
from swarmctl.learn.evaluate import run_policy  # noqa: E402
from swarmctl.world.config import WorldConfig  # noqa: E402

CHICAGO = "missions/chicago-loop/grid.npz"
NETWORKS = [
    "models/cluster-2uav.pt",
    "models/sparse-2uav.pt",
    "models/obstacles-3uav.pt",
    "models/obstacles-3uav.stage3.pt",
    "models/city.pt",
    "models/search.pt",  # swarmctl train-search (models/search.md)
]
POLICIES = [
    "coordinated",
    "coordinated:hover=first",  # the defer rule's ablation
    "frontier",
    "frontier:hover=defer",
    "la:4",
    "lawnmower",
    "random",
    *[f"ddql:{n}" for n in NETWORKS],
    "oracle",
]

SETTINGS: dict[str, dict] = {
    "chicago": dict(
        title="Chicago Loop grid, 3 UAVs, 3 sparse targets, 300 steps",
        world=dict(scenario="sparse", uavs=3, targets=3),
        grid=CHICAGO,
        steps=300,
        episodes=200,
        command="--grid missions/chicago-loop/grid.npz --scenario sparse --uavs 3 --targets 3 --steps 300",
    ),
    "big10": dict(
        title="50 x 50, 10 UAVs, 16 targets in 4 clusters, eta 0.1, 100 steps",
        world=dict(scenario="cluster", map_size=50, uavs=10, targets=16, clusters=4, obstacles=0.1),
        steps=100,
        command="--scenario cluster --map 50 --uavs 10 --targets 16 --clusters 4 --obstacles 0.1 --steps 100",
    ),
    "obstacles3": dict(
        title="20 x 20, 3 UAVs, 4 targets in a cluster, obstacles eta 0.1, 40 steps",
        world=dict(scenario="cluster", obstacles=0.1, uavs=3, targets=4),
        steps=40,
        command="--scenario cluster --obstacles 0.1 --uavs 3 --targets 4 --steps 40",
    ),
    "cluster2": dict(
        title="20 x 20 cluster, 2 UAVs, 4 targets, 40 steps",
        world=dict(scenario="cluster", uavs=2, targets=4),
        steps=40,
        command="--scenario cluster --uavs 2 --targets 4 --steps 40",
    ),
    "sparse2": dict(
        title="20 x 20 sparse, 2 UAVs, 4 targets, 40 steps",
        world=dict(scenario="sparse", uavs=2, targets=4),
        steps=40,
        command="--scenario sparse --uavs 2 --targets 4 --steps 40",
    ),
    "big24": dict(
        title="24 x 24, 2 UAVs, 8 targets in 2 clusters, 100 steps (the paper's big maps)",
        world=dict(scenario="cluster", map_size=24, uavs=2, targets=8, clusters=2),
        steps=100,
        command="--scenario cluster --map 24 --uavs 2 --targets 8 --clusters 2 --steps 100",
    ),
    "big50": dict(
        title="50 x 50, 2 UAVs, 16 targets in 4 clusters, 100 steps (the paper's big maps)",
        world=dict(scenario="cluster", map_size=50, uavs=2, targets=16, clusters=4),
        steps=100,
        command="--scenario cluster --map 50 --uavs 2 --targets 16 --clusters 4 --steps 100",
    ),
}


def slug(policy: str) -> str:
    return re.sub(r"[^A-Za-z0-9.=-]+", "_", policy)


def world_of(setting: dict):
    cfg = WorldConfig(**setting["world"])
    if "grid" not in setting:
        return cfg, None
    grid = GeoGrid.load(ROOT / setting["grid"])
    return replace(cfg, map_size=max(grid.width, grid.height), obstacles=0.0), grid.blocked.copy()


def run(seed: int, names: list[str], policies: list[str], out: Path) -> None:
    for name in names:
        setting = SETTINGS[name]
        cfg, blocked = world_of(setting)
        episodes = setting.get("episodes", 300)
        for policy in policies:
            path = out / str(seed) / name / f"{slug(policy)}.json"
            if path.exists():
                continue
            t0 = time.time()
            result = run_policy(cfg, policy, episodes, seed, setting["steps"], progress=False, blocked=blocked)
            result["wall_s"] = round(time.time() - t0, 1)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(result))
            print(
                f"{name:>10} {policy:>36}: {result['success_rate']:.3f} {result['mean_steps']:.1f} "
                f"({result['wall_s']:.0f} s)",
                flush=True,
            )


def report(seed: int, names: list[str], out: Path) -> str:
    lines = []
    for name in names:
        setting = SETTINGS[name]
        folder = out / str(seed) / name
        rows = {}
        for policy in POLICIES:
            path = folder / f"{slug(policy)}.json"
            if path.exists():
                rows[policy] = json.loads(path.read_text())
        if not rows:
            continue
        episodes = next(iter(rows.values()))["episodes"]
        lines += [f"### {setting['title']} ({episodes} episodes, seed {seed})", ""]
        lines += ["| policy | success | mean steps | x oracle |", "| --- | --- | --- | --- |"]
        for policy, r in rows.items():
            p, n = r["success_rate"], r["episodes"]
            se = math.sqrt(p * (1 - p) / n)
            ratio = r.get("duration_ratio_to_oracle")
            name_cell = f"**{policy}**" if policy == "coordinated" else policy
            lines.append(
                f"| {name_cell} | {p:.3f} +- {se:.3f} | {r['mean_steps']:.1f} | "
                f"{'-' if ratio is None else f'{ratio:.2f}'} |"
            )
        lines += ["", f"`swarmctl eval {setting['command']} --episodes {episodes} --seed {seed} --policy ...`", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=61206, help="the held-out episodes' seed")
    ap.add_argument("--only", nargs="*", choices=list(SETTINGS), help="these settings only")
    ap.add_argument("--policies", nargs="*", help="these policies only (default: every policy of the table)")
    ap.add_argument("--skip-la", action="store_true", help="leave LA(4) out")
    ap.add_argument("--report", action="store_true", help="print the Markdown tables of what is done")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "planners")
    args = ap.parse_args()
    names = args.only or list(SETTINGS)
    if args.report:
        print(report(args.seed, names, args.out))
        return
    policies = args.policies or [p for p in POLICIES if not (args.skip_la and p.startswith("la:"))]
    run(args.seed, names, policies, args.out)


if __name__ == "__main__":
    main()
