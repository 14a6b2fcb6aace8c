"""Transfer learning: the 3000+ episode cluster and sparse models trained N_t more episodes in the
other scenario (cluster <-> sparse), 2 and 3 UAVs, and the CDF of episode duration at a 60-step
limit (the paper's transfer-learning CDFs).

One training run per (direction, swarm size) keeps its checkpoint at every N_t (TrainConfig.snapshots,
as tools/training_curve.py does); the paper trains a run per N_t, each annealed over its own length.
"""

from __future__ import annotations

import matplotlib.pyplot as plt

from tools.exp.common import (
    CLUSTER,
    FAST_TRAIN,
    SPARSE,
    beside,
    by_policy,
    eval_run,
    markdown,
    rows,
    save,
    train_run,
)

NAME = "transfer"
TITLE = "Transfer learning: cluster <-> sparse"
PAPER = (
    "Cluster 3000 beats LA(4) except at the 60-step limit; Sparse 3000 + 750 TL episodes is close to "
    "Cluster 3000; the same holds swapped, and with 3 UAVs."
)
SOURCES = {"cluster": CLUSTER, "sparse": SPARSE}
CDF_AT = (20, 40)  # the table reads the CDF at these steps too
PRESETS = {
    "full": dict(uavs=[2, 3], n_t=[125, 250, 375, 750], test_episodes=500, steps=60),
    "fast": dict(
        uavs=[2],
        n_t=[5, 10],
        test_episodes=12,
        steps=60,
        train=FAST_TRAIN,
    ),
}


def _other(scenario: str) -> str:
    return "sparse" if scenario == "cluster" else "cluster"


def runs(p: dict, seed: int) -> list:
    out = []
    for src in SOURCES:
        dst = _other(src)
        for u in p["uavs"]:
            world = dict(scenario=dst, uavs=u)
            key = f"train-{src}-to-{dst}-u{u}"
            out.append(train_run(key, world, p, seed, SOURCES[src], max(p["n_t"]), snapshots=list(p["n_t"])))
            learned = {f"{src} 3000+ (N_t = 0)": "ddql:{src}"}
            learned |= {f"{src} 3000+ + {n} {dst}": f"ddql:{{m{n}}}" for n in p["n_t"]}
            learned[f"{dst} model (own scenario)"] = "ddql:{own}"
            inputs = {"src": SOURCES[src], "own": SOURCES[dst]}
            inputs |= {f"m{n}": f"@{key}" + ("" if n == max(p["n_t"]) else f".ep{n}") for n in p["n_t"]}
            out.append(eval_run(f"eval-{src}-to-{dst}-u{u}", world, p, seed, learned, inputs=inputs))
    return out


def summarise(p: dict, seed: int, results: dict) -> dict:
    panels, table, others = [], [], {}
    for src in SOURCES:
        dst = _other(src)
        for u in p["uavs"]:
            res = by_policy(results.get(f"eval-{src}-to-{dst}-u{u}"))
            if not res:
                continue
            panels.append(
                dict(src=src, dst=dst, uavs=u, cdf={k: r["steps_cdf"] for k, r in res.items() if k != "oracle"})
            )
            others[(f"{src} -> {dst}", u)] = beside(res)
            for row in rows(list(res.values()), direction=f"{src} -> {dst}", uavs=u):
                cdf = res[row["policy"]]["steps_cdf"]
                table.append({**row, **{f"done_by_{t}": cdf[t - 1] for t in CDF_AT if t <= len(cdf)}})
    best = {}
    for row in table:
        if f"+ {max(p['n_t'])} " in row["policy"]:
            best[(row["direction"], row["uavs"])] = row["success"]
    la = {(r["direction"], r["uavs"]): r["success"] for r in table if r["policy"] == "la:4"}
    own = {(r["direction"], r["uavs"]): r["success"] for r in table if "own scenario" in r["policy"]}
    ours = "; ".join(
        f"{d}, {u} UAVs: +{max(p['n_t'])} TL {best[(d, u)]:.2f}, own model {own[(d, u)]:.2f}, LA(4) {la[(d, u)]:.2f}"
        + (f", {others[(d, u)]}" if others.get((d, u)) else "")
        for (d, u) in best
    )
    return dict(panels=panels, table=table, ours=ours or "(no runs done yet)")


def figure(s: dict, path) -> None:
    n = max(1, len(s["panels"]))
    fig, axes = plt.subplots(1, n, figsize=(max(8.0, 4.2 * n), 4.6), squeeze=False)
    for ax, panel in zip(axes[0], s["panels"]):
        for label, cdf in panel["cdf"].items():
            style = "-" if label.startswith(panel["src"]) else ("--" if "own" in label else ":")
            ax.plot(range(1, len(cdf) + 1), cdf, style, label=label, lw=1.2)
        ax.set_title(f"{panel['src']} -> {panel['dst']}, {panel['uavs']} UAVs", fontsize=9)
        ax.set_xlabel("episode duration (steps)")
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, loc="lower right")
    axes[0][0].set_ylabel("fraction of episodes done")
    save(fig, path, PAPER, s["ours"])


def table(s: dict) -> str:
    cols = ["direction", "uavs", "policy", *(f"done_by_{t}" for t in CDF_AT), "success", "mean_steps", "x_oracle"]
    return markdown(s["table"], cols)
