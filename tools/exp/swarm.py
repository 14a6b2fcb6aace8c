"""Large swarms: 10 and 12 UAVs, 16 targets in 4 clusters on a 50 x 50 map with obstacles, 100 steps,
the shipped models with no retraining, under each knowledge channel: ideal, the distance model
with 10 m and with 20 m cells, none."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from tools.exp.common import OBSTACLES, PLANNERS, SEARCH_LABEL, by_policy, eval_run, markdown, rows, save

NAME = "swarm"
TITLE = "10 and 12 UAVs, 16 targets in 4 clusters, channels"
PAPER = (
    "10 and 12 UAVs, 16 targets in 4 clusters, large map with obstacles: DDQL with no retraining slightly beats "
    "LA; 10 m cells lose little, 20 m cells lose a lot, no communication is worst."
)
CHANNELS = {
    "ideal": dict(channel="ideal"),
    "model, 10 m cells": dict(channel="model", cell_size=10.0),
    "model, 20 m cells": dict(channel="model", cell_size=20.0),
    "none": dict(channel="none"),
}
LEARNED = {"models/obstacles-3uav.pt": "ddql:{obstacles}"}
PRESETS = {
    "full": dict(uavs=[10, 12], map=50, targets=16, clusters=4, eta=0.1, test_episodes=100, steps=100),
    "fast": dict(uavs=[4], map=16, targets=8, clusters=4, eta=0.1, test_episodes=6, steps=30),
}


def _key(u: int, name: str) -> str:
    return f"eval-u{u}-{name.replace(', ', '-').replace(' ', '')}"


def runs(p: dict, seed: int) -> list:
    out = []
    for u in p["uavs"]:
        for name, channel in CHANNELS.items():
            world = dict(
                scenario="cluster",
                map_size=p["map"],
                uavs=u,
                targets=p["targets"],
                clusters=p["clusters"],
                obstacles=p["eta"],
                **channel,
            )
            inputs = {"obstacles": OBSTACLES}
            out.append(eval_run(_key(u, name), world, p, seed, LEARNED, inputs=inputs))
    return out


def summarise(p: dict, seed: int, results: dict) -> dict:
    table, panels = [], []
    for u in p["uavs"]:
        bars = {}
        for name in CHANNELS:
            res = by_policy(results.get(_key(u, name)))
            table += rows(list(res.values()), uavs=u, channel=name)
            for label, r in res.items():
                if label != "oracle":
                    bars.setdefault(label, {})[name] = r["success_rate"]
        panels.append(dict(uavs=u, bars=bars))
    la = {(r["uavs"], r["channel"]): r["success"] for r in table if r["policy"] == "la:4"}
    search = {(r["uavs"], r["channel"]): r["success"] for r in table if r["policy"] == SEARCH_LABEL}
    learned = [r for r in table if r["policy"] == "models/obstacles-3uav.pt"]
    ours = "; ".join(
        f"{r['uavs']} UAVs {r['channel']}: DDQL {r['success']:.2f} vs LA(4) {la[(r['uavs'], r['channel'])]:.2f}"
        + (f", search.pt {search[(r['uavs'], r['channel'])]:.2f}" if (r["uavs"], r["channel"]) in search else "")
        for r in learned
    )
    return dict(table=table, panels=panels, ours=ours or "(no runs done yet)")


def figure(s: dict, path) -> None:
    n = max(1, len(s["panels"]))
    fig, axes = plt.subplots(1, n, figsize=(max(8.0, 5.2 * n), 4.4), squeeze=False)
    names = list(CHANNELS)
    x = np.arange(len(names))
    for ax, q in zip(axes[0], s["panels"]):
        labels = list(q["bars"])
        width = 0.8 / max(1, len(labels))
        for i, label in enumerate(labels):
            ys = [q["bars"][label].get(c, np.nan) for c in names]
            ax.bar(
                x + (i - (len(labels) - 1) / 2) * width, ys, width, label=label, hatch="//" if label in PLANNERS else ""
            )
        ax.set_xticks(x, names, fontsize=7)
        ax.set_title(f"{q['uavs']} UAVs", fontsize=9)
        ax.set_ylim(0, 1)
        ax.legend(fontsize=6, loc="upper right")
    axes[0][0].set_ylabel("success probability")
    save(fig, path, PAPER, s["ours"])


def table(s: dict) -> str:
    return markdown(s["table"], ["uavs", "channel", "policy", "success", "mean_steps", "x_oracle", "collisions"])
