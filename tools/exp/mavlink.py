"""A large swarm flown through the MAVLink path next to the simulator: the simulator's episodes
(10 UAVs, 16 targets in 4 clusters, 50 x 50, eta 0.1, the channel model with 10 m cells) flown by
mock autopilots over loopback UDP with the real controller (tools.exp.flown), and the same episodes
in the simulator with the controller's guard."""

from __future__ import annotations

import re

import matplotlib.pyplot as plt
import numpy as np

from tools.exp.common import OBSTACLES, PLANNERS, by_policy, markdown, save
from tools.exp.runs import Run

NAME = "mavlink"
TITLE = "A large swarm over MAVLink next to the simulator"
PAPER = "(not in the paper: the simulator's figures are meant to carry over to the flown swarm)"
POLICIES = {"models/obstacles-3uav.pt": "ddql:{obstacles}", "frontier": "frontier"}
PRESETS = {
    "full": dict(
        world=dict(
            scenario="cluster",
            map_size=50,
            uavs=10,
            targets=16,
            clusters=4,
            obstacles=0.1,
            channel="model",
            cell_size=10.0,
        ),
        episodes=3,
        steps=100,
        speedup=20.0,
        time_limit=600.0,
    ),
    "fast": dict(
        world=dict(scenario="cluster", map_size=10, uavs=2, targets=2, obstacles=0.1, channel="model", cell_size=10.0),
        episodes=1,
        steps=30,
        speedup=40.0,
        time_limit=60.0,
        policies=["frontier"],
    ),
}


def _flown_key(label: str, episode: int) -> str:
    return "flown-" + re.sub(r"[^A-Za-z0-9]+", "-", label) + f"-e{episode}"


def _policies(p: dict) -> dict:
    return {k: v for k, v in POLICIES.items() if k in p.get("policies", POLICIES)}


def runs(p: dict, seed: int) -> list:
    policies = _policies(p)
    inputs = {"obstacles": OBSTACLES}
    world = {**p["world"], "guard": True}  # the controller's guard, as the flown swarm has it
    others = [q for q in [*PLANNERS, "oracle"] if q not in policies]  # in the simulator only
    sim = dict(
        world=world,
        policies=[*policies.values(), *others],
        labels=[*policies, *others],
        episodes=p["episodes"],
        seed=seed,
        steps=p["steps"],
    )
    out = [Run("simulator", "eval", sim, inputs)]
    for label, spec in policies.items():
        for e in range(p["episodes"]):
            params = dict(
                world=p["world"], policy=spec, label=label, seed=seed, episode=e, steps=p["steps"], speedup=p["speedup"]
            )
            params["time_limit"] = p["time_limit"]
            out.append(Run(_flown_key(label, e), "mavlink", params, inputs))
    return out


def summarise(p: dict, seed: int, results: dict) -> dict:
    sim = by_policy(results.get("simulator"))
    table = []
    for label in _policies(p):
        simulated = {e["episode"]: e for e in sim.get(label, {}).get("per_episode", [])}
        for e in range(p["episodes"]):
            flown = results.get(_flown_key(label, e))
            s = simulated.get(e)
            table.append(
                dict(
                    policy=label,
                    episode=e,
                    simulator_success=None if s is None else s["success"],
                    simulator_steps=None if s is None else s["steps"],
                    mavlink_success=None if flown is None else flown["success"],
                    mavlink_steps=None if flown is None else flown["steps"],
                    mavlink_outcome=None if flown is None else flown["outcome"],
                    knowledge_lost=None
                    if flown is None
                    else f"{flown['knowledge_lost']} of {flown['knowledge_delivered'] + flown['knowledge_lost']}",
                )
            )
    for label, r in sim.items():
        if label not in _policies(p):
            for e in r["per_episode"]:
                table.append(
                    dict(policy=label, episode=e["episode"], simulator_success=e["success"], simulator_steps=e["steps"])
                )
    parts = []
    for label in _policies(p):
        mine = [
            r
            for r in table
            if r["policy"] == label and r["mavlink_success"] is not None and r["simulator_success"] is not None
        ]
        if mine:
            parts.append(
                f"{label}: simulator {sum(r['simulator_success'] for r in mine)}/{len(mine)} in "
                f"{np.mean([r['simulator_steps'] for r in mine]):.0f} steps, MAVLink "
                f"{sum(r['mavlink_success'] for r in mine)}/{len(mine)} in "
                f"{np.mean([r['mavlink_steps'] for r in mine]):.0f}"
            )
    return dict(table=table, ours="; ".join(parts) or "(no runs done yet)")


def figure(s: dict, path) -> None:
    fig, ax = plt.subplots(figsize=(8, 4.2))
    done = [r for r in s["table"] if r.get("mavlink_steps") is not None and r["simulator_steps"] is not None]
    x = np.arange(len(done))
    ax.bar(x - 0.2, [r["simulator_steps"] for r in done], 0.4, label="simulator (guard, same episode)")
    ax.bar(x + 0.2, [r["mavlink_steps"] for r in done], 0.4, label="MAVLink: mocks, controller, channel model")
    for i, r in enumerate(done):
        for dx, ok in ((-0.2, r["simulator_success"]), (0.2, r["mavlink_success"])):
            ax.text(i + dx, 1, "ok" if ok else "x", ha="center", fontsize=7, color="w")
    ax.set_xticks(x, [f"{r['policy'].split('/')[-1]}\nepisode {r['episode']}" for r in done], fontsize=6)
    ax.set_ylabel("steps (the limit when not done)")
    ax.legend(fontsize=7)
    save(fig, path, PAPER, s["ours"])


def table(s: dict) -> str:
    return markdown(s["table"])
