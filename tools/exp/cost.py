"""The cost table: FLOPs per decision (policy.qnet.forward_flops), decision times measured as
`swarmctl bench` measures them (swarmctl.bench.decision_seconds: 20 x 20, 2 UAVs, batch 1 and
batched), and the shipped models' training wall time from their checkpoints' metadata."""

from __future__ import annotations

import matplotlib.pyplot as plt

from tools.exp.common import CLUSTER, OBSTACLES, SEARCH, SEARCH_LABEL, SPARSE, markdown, save
from tools.exp.runs import Run

NAME = "cost"
TITLE = "Cost: FLOPs and time per decision, training time"
PAPER = "One LA(4) decision takes about 15x as long as one DDQL decision; the network costs 4,899,309 operations."
POLICIES = {
    "ddql:PATH (our rules)": "ddql:{cluster}",
    "DDQL Soft (the paper's)": "ddql:{cluster}:taken=keep:hover=no:mask=no",
    "ddql-greedy:PATH": "ddql-greedy:{cluster}",
    SEARCH_LABEL: "ddql:{search}",
    "la:4": "la:4",
    "lawnmower": "lawnmower",
    "frontier": "frontier",
}
MODELS = {
    "models/cluster-2uav.pt": CLUSTER,
    "models/sparse-2uav.pt": SPARSE,
    "models/obstacles-3uav.pt": OBSTACLES,
    SEARCH: SEARCH,
}
PRESETS = {"full": dict(seconds=2.0, batches=[1, 256]), "fast": dict(seconds=0.05, batches=[1, 8])}


def runs(p: dict, seed: int) -> list:
    inputs = {"cluster": CLUSTER, "search": SEARCH} | {f"model{i}": path for i, path in enumerate(MODELS.values())}
    params = dict(
        policies=list(POLICIES.values()),
        labels=list(POLICIES),
        seconds=p["seconds"],
        batches=p["batches"],
        checkpoints={label: f"{{model{i}}}" for i, label in enumerate(MODELS)},
        seed=seed,
    )
    return [Run("cost", "cost", params, inputs)]


def summarise(p: dict, seed: int, results: dict) -> dict:
    from swarmctl.policy.qnet import forward_flops

    r = results.get("cost")
    if r is None:
        return dict(table=[], training=[], ours="(no runs done yet)")
    flops = forward_flops(20)
    limit_ms = 1000.0 * flops / r["matmul_flop_per_s"]
    # runs before the count was recorded: every ddql policy flew the paper network at F = 20
    counted = r.get("flops") or {k: flops if k.startswith(("ddql", "DDQL")) else None for k in r["decision"]}
    table = []
    for label, times in r["decision"].items():
        row = {"policy": label, "flops_per_decision": counted[label]}
        row |= {f"ms_per_vehicle_batch{b}": times[f"ms_batch{b}"] for b in p["batches"]}
        table.append(row)
    for n in dict.fromkeys(v for v in counted.values() if v):
        table.append(
            {
                "policy": f"FLOP limit of a {n / 1e6:.2f} MFLOP network (matmul rate)",
                "flops_per_decision": n,
                "ms_per_vehicle_batch1": 1000.0 * n / r["matmul_flop_per_s"],
            }
        )
    training = []
    for label, stages in r["training"].items():
        training.append(
            dict(
                model=label,
                stages=len(stages),
                episodes=sum(s["episodes"] or 0 for s in stages),
                samples=sum(s["samples"] or 0 for s in stages),
                wall_min=sum(s["wall_time_s"] or 0 for s in stages) / 60.0,
                device=stages[-1]["device"],
            )
        )
    ddql, la = r["decision"]["ddql:PATH (our rules)"]["ms_batch1"], r["decision"]["la:4"]["ms_batch1"]
    search = r["decision"].get(SEARCH_LABEL, {}).get("ms_batch1")
    load = r["machine"].get("load_average_before")
    ours = (
        f"LA(4) {la:.3f} ms vs DDQL {ddql:.3f} ms per decision at batch 1 ({la / ddql:.2f}x); "
        + (f"models/search.pt {search:.3f} ms ({search / ddql:.2f}x DDQL); " if search else "")
        + f"the paper's network {flops:,} FLOPs, {limit_ms:.3f} ms at the matmul rate measured beside it "
        f"({r['matmul_flop_per_s'] / 1e9:.0f} GFLOP/s" + (f", load average {load[0]:.1f})" if load else ")")
    )
    return dict(table=table, training=training, ours=ours, machine=r["machine"])


def figure(s: dict, path) -> None:
    fig, ax = plt.subplots(figsize=(7, 4.2))
    rows_ = [r for r in s["table"] if r.get("ms_per_vehicle_batch1") is not None]
    ax.barh([r["policy"] for r in rows_], [r["ms_per_vehicle_batch1"] for r in rows_])
    ax.set_xlabel("ms per vehicle decision, batch 1, one thread")
    ax.invert_yaxis()
    ax.tick_params(axis="y", labelsize=7)
    save(fig, path, PAPER, s["ours"])


def table(s: dict) -> str:
    return markdown(s["table"]) + "\n\n" + markdown(s["training"])
