"""Re-run the evaluations behind the tables of docs/guide.md, docs/RESULTS.md and the model cards.

    python tools/eval_tables.py                       # every table (about 20 min on one core)
    python tools/eval_tables.py --only cluster-2uav chicago
    python tools/eval_tables.py --list

Each table is one `swarmctl eval` run (all its policies on the same episodes); its JSON is written to
results/eval/NAME.json and its Markdown table printed. The test episodes (seed 0) and the held-out
ones (seed 2026) were never used in training.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmctl.learn.evaluate import evaluate  # noqa: E402
from swarmctl.world.config import WorldConfig  # noqa: E402

CLUSTER, SPARSE, OBST = "models/cluster-2uav.pt", "models/sparse-2uav.pt", "models/obstacles-3uav.pt"
STAGE3 = "models/obstacles-3uav.stage3.pt"
PLANNERS = ["la:4", "lawnmower", "frontier"]
PAPER = ":taken=keep:hover=no:mask=no"  # the paper's DDQL Soft

TABLES: dict[str, dict] = {
    "cluster-2uav": dict(
        world=dict(scenario="cluster"),
        episodes=500,
        steps=40,
        policies=[
            f"ddql:{CLUSTER}",
            f"ddql:{CLUSTER}{PAPER}",
            f"ddql:{CLUSTER}:hover=no:mask=no",
            f"ddql:{CLUSTER}:taken=keep:mask=no",
            f"ddql:{CLUSTER}:mask=no",
            f"ddql-greedy:{CLUSTER}",
            f"ddql:{CLUSTER}:straggler=frontier",
            *PLANNERS,
            "random",
            "oracle",
        ],
    ),
    "cluster-2uav-guard": dict(
        world=dict(scenario="cluster", guard=True), episodes=500, steps=40, policies=[f"ddql:{CLUSTER}", *PLANNERS]
    ),
    "sparse-2uav": dict(
        world=dict(scenario="sparse"),
        episodes=500,
        steps=40,
        policies=[
            f"ddql:{SPARSE}",
            f"ddql:{SPARSE}{PAPER}",
            f"ddql:{SPARSE}:hover=no:mask=no",
            f"ddql:{SPARSE}:taken=keep:mask=no",
            f"ddql:{SPARSE}:mask=no",
            f"ddql-greedy:{SPARSE}",
            f"ddql:{SPARSE}:straggler=frontier",
            *PLANNERS,
            "random",
            "oracle",
        ],
    ),
    "obstacles-3uav": dict(
        world=dict(scenario="cluster", uavs=3, obstacles=0.1),
        episodes=500,
        steps=40,
        policies=[
            f"ddql:{OBST}",
            f"ddql:{OBST}:straggler=frontier",
            f"ddql:{OBST}{PAPER}",
            f"ddql:{OBST}:hover=no",
            f"ddql:{OBST}:mask=no",
            f"ddql-greedy:{OBST}",
            f"ddql:{STAGE3}",
            *PLANNERS,
            "random",
            "oracle",
        ],
    ),
    "obstacles-3uav-stage3": dict(
        world=dict(scenario="cluster", uavs=3, obstacles=0.1),
        episodes=500,
        steps=40,
        policies=[
            f"ddql:{STAGE3}",
            f"ddql:{STAGE3}{PAPER}",
            f"ddql:{STAGE3}:hover=no",
            f"ddql:{STAGE3}:mask=no",
            f"ddql-greedy:{STAGE3}",
        ],
    ),
    "obstacles-3uav-heldout": dict(
        world=dict(scenario="cluster", uavs=3, obstacles=0.1),
        episodes=300,
        steps=40,
        seed=2026,
        policies=[f"ddql:{OBST}", f"ddql:{OBST}:straggler=frontier", "la:4", "frontier", "oracle"],
    ),
    "chicago": dict(
        world=dict(scenario="sparse", uavs=3, targets=3),
        episodes=100,
        steps=300,
        grid="missions/chicago-loop/grid.npz",
        policies=[
            "frontier",
            "lawnmower",
            "la:4",
            f"ddql:{STAGE3}",
            f"ddql:{OBST}",
            f"ddql:{OBST}:straggler=frontier",
            f"ddql:{CLUSTER}",
            "oracle",
        ],
    ),
    **{
        f"channel-{name}": dict(
            world=dict(scenario="cluster", map_size=30, uavs=4, targets=8, clusters=2, **channel),
            episodes=200,
            steps=60,
            policies=["la:4", "frontier"],
        )
        for name, channel in (
            ("ideal", dict(channel="ideal")),
            ("model-10m", dict(channel="model", cell_size=10.0)),
            ("model-20m", dict(channel="model", cell_size=20.0)),
            ("none", dict(channel="none")),
        )
    },
}


def run(name: str, spec: dict, out: Path, progress: bool) -> list[dict]:
    """One table: evaluate its policies, write results/eval/NAME.json, return the results."""
    cfg = WorldConfig(**spec["world"])
    blocked = None
    if spec.get("grid"):
        from swarmctl.geo.grid import GeoGrid

        grid = GeoGrid.load(ROOT / spec["grid"])
        blocked = grid.blocked.copy()
        cfg = replace(cfg, map_size=max(grid.width, grid.height), obstacles=0.0)
    t0 = time.time()
    results = evaluate(
        cfg, spec["policies"], spec["episodes"], spec.get("seed", 0), spec["steps"], progress=progress, blocked=blocked
    )
    for r in results:
        if spec.get("grid"):
            r["scenario"]["grid"] = spec["grid"]
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps({"results": results, "wall_s": round(time.time() - t0, 1)}, indent=1))
    return results


def markdown(results: list[dict]) -> str:
    lines = [
        "| policy | success | mean steps | x oracle | collisions / episode | ms / decision |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for r in results:
        ratio, ms = r["duration_ratio_to_oracle"], r["decision_ms_per_vehicle"]
        lines.append(
            f"| {r['policy']} | {r['success_rate']:.3f} | {r['mean_steps']:.2f} | "
            f"{'-' if ratio is None else f'{ratio:.2f}'} | {r['collisions_per_episode']:.3f} | "
            f"{'-' if ms is None else f'{ms:.3f}'} |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="+", metavar="NAME", help="run these tables only")
    ap.add_argument("--list", action="store_true", help="list the tables and exit")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "eval")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args()
    if args.list:
        for name, spec in TABLES.items():
            print(f"{name}: {spec['episodes']} episodes, {len(spec['policies'])} policies")
        return
    names = args.only or list(TABLES)
    unknown = [n for n in names if n not in TABLES]
    if unknown:
        ap.error(f"unknown table {', '.join(unknown)}; --list shows them")
    for name in names:
        results = run(name, TABLES[name], args.out, not args.no_progress)
        print(f"\n## {name}\n\n{markdown(results)}", flush=True)


if __name__ == "__main__":
    main()
