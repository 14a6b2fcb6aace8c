"""Obstacles (eta 0.1): the cluster model trained on maps with obstacles with 2, 3 and 4 UAVs (one
training run each, the same recipe), each evaluated greedy and softmax on 2, 3 and 4 UAVs."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from tools.exp.common import (
    CLUSTER,
    FAST_TRAIN,
    OBSTACLES,
    PLANNERS,
    SEARCH_LABEL,
    by_policy,
    eval_run,
    markdown,
    rows,
    save,
    train_run,
)

NAME = "obstacles"
TITLE = "Obstacles (eta 0.1): models trained on 2, 3 and 4 UAVs, greedy and softmax"
PAPER = "Obstacles (eta = 0.1): models trained with more UAVs do better; softmax helps; DDQL beats LA(4)."
PRESETS = {
    "full": dict(train_uavs=[2, 3, 4], test_uavs=[2, 3, 4], train_episodes=750, test_episodes=500, steps=40),
    "fast": dict(
        train_uavs=[2, 3],
        test_uavs=[3],
        train_episodes=10,
        test_episodes=12,
        steps=40,
        train=FAST_TRAIN,
    ),
}


def _world(u: int) -> dict:
    return dict(scenario="cluster", uavs=u, obstacles=0.1)


def runs(p: dict, seed: int) -> list:
    out = [
        train_run(f"train-u{u}", _world(u), p, seed, CLUSTER, p["train_episodes"], eval_steps=40)
        for u in p["train_uavs"]
    ]
    for t in p["test_uavs"]:
        learned, inputs = {}, {"shipped": OBSTACLES}
        for u in p["train_uavs"]:
            learned[f"trained on {u} UAVs, softmax"] = f"ddql:{{m{u}}}"
            learned[f"trained on {u} UAVs, greedy"] = f"ddql-greedy:{{m{u}}}"
            inputs[f"m{u}"] = f"@train-u{u}"
        learned["models/obstacles-3uav.pt, softmax"] = "ddql:{shipped}"
        learned["models/obstacles-3uav.pt, greedy"] = "ddql-greedy:{shipped}"
        out.append(eval_run(f"eval-test-u{t}", _world(t), p, seed, learned, inputs=inputs))
    return out


def summarise(p: dict, seed: int, results: dict) -> dict:
    table, panels = [], []
    for t in p["test_uavs"]:
        res = by_policy(results.get(f"eval-test-u{t}"))
        if not res:
            continue
        table += rows(list(res.values()), test_uavs=t)
        panels.append(
            dict(
                test_uavs=t,
                softmax=[res[f"trained on {u} UAVs, softmax"]["success_rate"] for u in p["train_uavs"]],
                greedy=[res[f"trained on {u} UAVs, greedy"]["success_rate"] for u in p["train_uavs"]],
                planners={k: res[k]["success_rate"] for k in PLANNERS},
                shipped=res["models/obstacles-3uav.pt, softmax"]["success_rate"],
                search=res[SEARCH_LABEL]["success_rate"],
            )
        )
    ours = "; ".join(
        f"{q['test_uavs']} UAVs: softmax "
        + "/".join(f"{v:.2f}" for v in q["softmax"])
        + ", greedy "
        + "/".join(f"{v:.2f}" for v in q["greedy"])
        + f" (trained on {'/'.join(map(str, p['train_uavs']))}), LA(4) {q['planners']['la:4']:.2f}"
        + f", search.pt {q['search']:.2f}, coordinated {q['planners']['coordinated']:.2f}"
        for q in panels
    )
    return dict(panels=panels, table=table, train_uavs=p["train_uavs"], ours=ours or "(no runs done yet)")


def figure(s: dict, path) -> None:
    n = max(1, len(s["panels"]))
    fig, axes = plt.subplots(1, n, figsize=(max(8.0, 4.2 * n), 4.4), squeeze=False)
    x = np.arange(len(s["train_uavs"]))
    for ax, q in zip(axes[0], s["panels"]):
        ax.bar(x - 0.18, q["softmax"], 0.36, label="softmax (ddql:PATH)")
        ax.bar(x + 0.18, q["greedy"], 0.36, label="greedy (ddql-greedy:PATH)")
        for (name, v), style in zip(q["planners"].items(), ("-", "--", ":", (0, (1, 4)))):
            ax.axhline(v, color="k", ls=style, lw=1, label=name)
        ax.axhline(q["shipped"], color="tab:red", ls="-.", lw=1, label="models/obstacles-3uav.pt (softmax)")
        ax.axhline(q["search"], color="tab:green", ls="-", lw=1.5, label=SEARCH_LABEL)
        ax.set_xticks(x, [f"trained on {u}" for u in s["train_uavs"]], fontsize=8)
        ax.set_title(f"tested with {q['test_uavs']} UAVs", fontsize=9)
        ax.set_ylim(0, 1)
        ax.legend(fontsize=6, loc="upper left")
    axes[0][0].set_ylabel("success probability")
    save(fig, path, PAPER, s["ours"])


def table(s: dict) -> str:
    return markdown(s["table"], ["test_uavs", "policy", "success", "mean_steps", "x_oracle", "collisions"])
