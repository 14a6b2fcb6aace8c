"""The Chicago Loop grid (missions/chicago-loop/grid.npz, 50 x 50 cells of 10 m, 12.4 % blocked):
3 UAVs, 3 targets drawn by the sparse rule in its largest free region, 300 steps; the failures
counted from the per-episode records (how many vehicles were still searching, the straggler's
distance to the nearest free target)."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from tools.exp.common import CLUSTER, OBSTACLES, PLANNERS, beside, by_policy, eval_run, markdown, rows, save

NAME = "chicago"
TITLE = "The Chicago Loop grid, 3 UAVs, 3 targets"
PAPER = "Real map (Chicago Loop, 50 x 50 cells of 10 m, 11 % obstacles): DDQL about as fast as LA."
GRID = "missions/chicago-loop/grid.npz"
LEARNED = {
    "models/obstacles-3uav.pt": "ddql:{obstacles}",
    "models/obstacles-3uav.pt:straggler=frontier": "ddql:{obstacles}:straggler=frontier",
    "models/cluster-2uav.pt": "ddql:{cluster}",
}
PRESETS = {
    "full": dict(uavs=3, targets=3, test_episodes=100, steps=300),
    "fast": dict(uavs=3, targets=3, test_episodes=4, steps=40),
}


def runs(p: dict, seed: int) -> list:
    world = dict(scenario="sparse", uavs=p["uavs"], targets=p["targets"])
    inputs = {"obstacles": OBSTACLES, "cluster": CLUSTER, "grid": GRID}
    return [eval_run("eval-chicago", world, p, seed, LEARNED, inputs=inputs, grid="{grid}")]


def failures(result: dict) -> dict:
    """Failed episodes by the number of vehicles still searching at the end, and the lone
    straggler's distances to the nearest free target."""
    failed = [e for e in result.get("per_episode", []) if not e["success"]]
    counts: dict[int, int] = {}
    for e in failed:
        counts[len(e.get("searching", []))] = counts.get(len(e.get("searching", [])), 0) + 1
    distances = [e["straggler_distance"] for e in failed if e.get("straggler_distance") is not None]
    return dict(
        failed=len(failed),
        by_searching=dict(sorted(counts.items())),
        straggler_share=(counts.get(1, 0) / len(failed)) if failed else None,
        straggler_distance_median=float(np.median(distances)) if distances else None,
    )


def summarise(p: dict, seed: int, results: dict) -> dict:
    res = by_policy(results.get("eval-chicago"))
    table = rows(list(res.values()))
    for row in table:
        f = failures(res[row["policy"]])
        row["failures"] = f["failed"]
        row["one_straggler_share"] = f["straggler_share"]
        row["straggler_distance_median"] = f["straggler_distance_median"]
    cdf = {k: r["steps_cdf"] for k, r in res.items() if k != "oracle"}
    fails = {k: failures(r)["by_searching"] for k, r in res.items() if k != "oracle"}
    ours = "(no runs done yet)"
    if res:
        learned, la = res["models/obstacles-3uav.pt"], res["la:4"]
        ours = (
            f"models/obstacles-3uav.pt {learned['success_rate']:.2f} in {learned['mean_steps']:.0f} steps, "
            f"LA(4) {la['success_rate']:.2f} in {la['mean_steps']:.0f}, "
            f"frontier {res['frontier']['success_rate']:.2f}, {beside(res)}, "
            f"oracle {res['oracle']['mean_steps']:.0f} steps"
        )
    return dict(table=table, cdf=cdf, failures=fails, ours=ours)


def figure(s: dict, path) -> None:
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4.4))
    for label, cdf in s["cdf"].items():
        a.plot(range(1, len(cdf) + 1), cdf, ":" if label in PLANNERS else "-", label=label, lw=1.2)
    a.set_xlabel("episode duration (steps)")
    a.set_ylabel("fraction of episodes done")
    a.set_ylim(0, 1)
    a.grid(alpha=0.3)
    a.legend(fontsize=6, loc="upper left")
    labels = list(s["failures"])
    counts = sorted({n for f in s["failures"].values() for n in map(int, f)})
    bottom = np.zeros(len(labels))
    for n in counts:
        ys = np.array([s["failures"][k].get(n, s["failures"][k].get(str(n), 0)) for k in labels], dtype=float)
        b.bar(range(len(labels)), ys, bottom=bottom, label=f"{n} vehicle{'s' if n != 1 else ''} still searching")
        bottom += ys
    b.set_xticks(range(len(labels)), labels, rotation=25, ha="right", fontsize=6)
    b.set_ylabel("failed episodes")
    b.legend(fontsize=6)
    save(fig, path, PAPER, s["ours"], 0.1)


def table(s: dict) -> str:
    cols = ["policy", "success", "mean_steps", "x_oracle", "collisions", "failures", "one_straggler_share"]
    return markdown(s["table"], cols + ["straggler_distance_median"])
