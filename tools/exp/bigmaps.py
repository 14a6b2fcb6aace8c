"""Big maps: models trained at M = 24 (from the cluster model, without and with obstacles), tested on
M = 24, 30, 40, 50 with 1-4 clusters of targets, without and with obstacles, 100-step episodes."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from tools.exp.common import (
    CLUSTER,
    FAST_TRAIN,
    PLANNERS,
    SEARCH_LABEL,
    by_policy,
    eval_run,
    markdown,
    rows,
    save,
    train_run,
)

NAME = "bigmaps"
TITLE = "Big maps: trained at M = 24, tested up to M = 50 with 1-4 clusters"
PAPER = (
    "Trained on M = 24, tested up to M = 50 with more clusters (100-step episodes): DDQL beats LA, more so on "
    "bigger maps; with obstacles it needs retraining on small maps."
)
PRESETS = {
    "full": dict(
        maps=[24, 30, 40, 50],
        clusters=[1, 2, 3, 4],
        etas=[0.0, 0.1],
        uavs=2,
        targets_per_cluster=4,
        train_map=24,
        train_clusters=2,
        train_episodes=750,
        test_episodes=100,
        steps=100,
    ),
    "fast": dict(
        maps=[10, 14],
        clusters=[2],
        etas=[0.0, 0.1],
        uavs=2,
        targets_per_cluster=2,
        train_map=10,
        train_clusters=1,
        train_episodes=10,
        test_episodes=6,
        steps=30,
        train=FAST_TRAIN,
    ),
}
MODELS = {0.0: "trained at M = 24", 0.1: "trained at M = 24 with obstacles"}


def _pct(eta: float) -> int:
    return round(100 * eta)  # run keys carry no dots


def _world(p: dict, m: int, c: int, eta: float) -> dict:
    return dict(
        scenario="cluster", map_size=m, uavs=p["uavs"], clusters=c, targets=p["targets_per_cluster"] * c, obstacles=eta
    )


def runs(p: dict, seed: int) -> list:
    out = []
    for eta in p["etas"]:
        world = _world(p, p["train_map"], p["train_clusters"], eta)
        out.append(
            train_run(f"train-eta{_pct(eta)}", world, p, seed, CLUSTER, p["train_episodes"], eval_steps=p["steps"])
        )
    for eta in p["etas"]:
        for m in p["maps"]:
            for c in p["clusters"]:
                learned = {MODELS[e]: f"ddql:{{m{i}}}" for i, e in enumerate(p["etas"])}
                learned["models/cluster-2uav.pt (M = 20)"] = "ddql:{cluster}"
                inputs = {f"m{i}": f"@train-eta{_pct(e)}" for i, e in enumerate(p["etas"])} | {"cluster": CLUSTER}
                out.append(
                    eval_run(f"eval-M{m}-C{c}-eta{_pct(eta)}", _world(p, m, c, eta), p, seed, learned, inputs=inputs)
                )
    return out


def summarise(p: dict, seed: int, results: dict) -> dict:
    table, curves = [], {}
    for eta in p["etas"]:
        for c in p["clusters"]:
            for m in p["maps"]:
                res = by_policy(results.get(f"eval-M{m}-C{c}-eta{_pct(eta)}"))
                table += rows(list(res.values()), eta=eta, clusters=c, map=m)
                for label, r in res.items():
                    if label != "oracle":
                        curves.setdefault(f"{eta}|{c}|{label}", []).append((m, r["success_rate"]))
    own = [r for r in table if r["policy"] == MODELS.get(r["eta"])]
    la = {(r["eta"], r["clusters"], r["map"]): r["success"] for r in table if r["policy"] == "la:4"}
    ahead = sum(r["success"] > la[(r["eta"], r["clusters"], r["map"])] for r in own)
    ours = f"the M = 24 model of each obstacle setting ahead of LA(4) in {ahead} of {len(own)} settings"
    if own:
        big = [r for r in own if r["map"] == max(p["maps"])]
        ours += f"; at M = {max(p['maps'])}: " + ", ".join(
            f"eta {r['eta']} C {r['clusters']} {r['success']:.2f} vs {la[(r['eta'], r['clusters'], r['map'])]:.2f}"
            for r in big
        )
    search = [r for r in table if r["policy"] == SEARCH_LABEL]
    if search:
        coordinated = {(r["eta"], r["clusters"], r["map"]): r["success"] for r in table if r["policy"] == "coordinated"}
        keys = [(r["eta"], r["clusters"], r["map"]) for r in search]
        ours += (
            f"; models/search.pt mean success {np.mean([r['success'] for r in search]):.2f} over {len(search)} "
            f"settings (LA(4) {np.mean([la[k] for k in keys]):.2f}, coordinated "
            f"{np.mean([coordinated[k] for k in keys]):.2f})"
        )
    return dict(table=table, curves=curves, etas=p["etas"], clusters=p["clusters"], ours=ours)


def figure(s: dict, path) -> None:
    rows_, cols = len(s["etas"]), len(s["clusters"])
    fig, axes = plt.subplots(rows_, cols, figsize=(max(8.0, 3.3 * cols), 2.9 * rows_ + 0.9), squeeze=False)
    for i, eta in enumerate(s["etas"]):
        for j, c in enumerate(s["clusters"]):
            ax = axes[i][j]
            for key, pts in s["curves"].items():
                e, cc, label = key.split("|", 2)
                if float(e) == eta and int(cc) == c and pts:
                    ms, ys = zip(*pts)
                    style = ":" if label in PLANNERS else "-"
                    ax.plot(ms, ys, style, marker="o", ms=3, label=label, lw=1.2)
            ax.set_title(f"eta {eta}, {c} cluster{'s' if c > 1 else ''}", fontsize=8)
            ax.set_ylim(0, 1)
            ax.grid(alpha=0.3)
            if i == rows_ - 1:
                ax.set_xlabel("map side M")
            if j == 0:
                ax.set_ylabel("success")
    if axes[0][0].get_legend_handles_labels()[0]:
        axes[0][0].legend(fontsize=5, loc="lower left")
    save(fig, path, PAPER, s["ours"], 0.1)


def table(s: dict) -> str:
    return markdown(s["table"], ["eta", "clusters", "map", "policy", "success", "mean_steps", "x_oracle", "collisions"])
