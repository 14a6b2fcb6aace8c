"""What one run does, by task name: train a model, evaluate policies, measure decision costs, fly a
swarm over MAVLink. Each task takes JSON parameters (input files already resolved to paths) and a
scratch folder, and returns (result, {suffix: output file path}).
"""

from __future__ import annotations

import os
from pathlib import Path

from tools.exp.runs import ROOT


def world_config(world: dict):
    from swarmctl.world.config import WorldConfig

    return WorldConfig(**world)


def train_task(params: dict, folder: Path) -> tuple[dict, dict]:
    """ddql.train from `init` (a checkpoint path, or none) on `world` with the TrainConfig fields of
    `train`; the checkpoint, and its snapshots at `train.snapshots`, come back as outputs."""
    from swarmctl.learn.ddql import TrainConfig, snapshot_path, train

    cfg = TrainConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in params["train"].items()})
    out = folder / "model.pt"
    init = Path(params["init"]) if params.get("init") else None
    meta = train(world_config(params["world"]), cfg, params["seed"], out, init=init, progress=False)
    outputs = {"pt": out}
    for n in cfg.snapshots:
        outputs[f"ep{n}.pt"] = snapshot_path(out, n)
    keep = ("episodes", "seed", "wall_time_s", "samples", "updates", "train_samples_per_s", "evals", "git_commit")
    return {k: meta[k] for k in keep}, outputs


def eval_task(params: dict, folder: Path) -> tuple[dict, dict]:
    """swarmctl eval: `policies` on `episodes` episodes of `seed` (on the grid file `grid` when given),
    all on the same episodes; the results as `swarmctl eval --json` writes them."""
    from dataclasses import replace

    from swarmctl.learn.evaluate import evaluate
    from swarmctl.policy.threads import set_inference_threads

    set_inference_threads(1)
    cfg = world_config(params["world"])
    blocked = None
    if params.get("grid"):
        from swarmctl.geo.grid import GeoGrid

        grid = GeoGrid.load(params["grid"])
        blocked = grid.blocked.copy()
        cfg = replace(cfg, map_size=max(grid.width, grid.height), obstacles=0.0)
    results = evaluate(
        cfg, params["policies"], params["episodes"], params["seed"], params["steps"], progress=False, blocked=blocked
    )
    for r, label in zip(results, params.get("labels", params["policies"])):
        r["policy"] = label  # the spec as the experiment names it, not the run's scratch path
    return {"results": results}, {}


def cost_task(params: dict, folder: Path) -> tuple[dict, dict]:
    """Decision times per vehicle at batch 1 and batched (swarmctl bench's measurement) for each policy
    of `policies` on the paper's 20 x 20, 2-UAV setting, with the machine's matmul FLOP rate."""
    from swarmctl.bench import decision_seconds, machine, matmul_flops_per_s
    from swarmctl.policy.registry import make_policy
    from swarmctl.policy.threads import set_inference_threads

    set_inference_threads(1)
    seconds = params["seconds"]
    load_before = os.getloadavg()
    rows, flops = {}, {}
    for label, spec in zip(params["labels"], params["policies"]):
        policy = make_policy(spec)
        rows[label] = {f"ms_batch{b}": 1000.0 * decision_seconds(policy, b, seconds) for b in params["batches"]}
        flops[label] = network_flops(policy)
    training = {label: training_stages(path) for label, path in params.get("checkpoints", {}).items()}
    rate = matmul_flops_per_s(seconds)
    host = {**machine(1), "load_average_before": load_before, "load_average_after": os.getloadavg()}
    result = {"decision": rows, "flops": flops, "training": training, "matmul_flop_per_s": rate, "machine": host}
    return result, {}


def network_flops(policy) -> int | None:
    """FLOPs of one forward of the policy's network for one observation, counted from the network it
    loaded (None: a planner, or a network with no count)."""
    from swarmctl.policy.qnet import QNetwork, ScalesQNetwork, forward_flops, scales_forward_flops

    net = getattr(policy, "net", None)
    if isinstance(net, ScalesQNetwork):
        return scales_forward_flops(net.window)
    if isinstance(net, QNetwork):
        return forward_flops(net.window)
    return None


def training_stages(path: str) -> list[dict]:
    """The training stages behind a checkpoint, first stage first (its metadata and the init chain)."""
    from swarmctl.policy.checkpoint import load_checkpoint

    _, info = load_checkpoint(path)
    stages, meta = [], info["metadata"]
    while meta:
        stages.append({k: meta.get(k) for k in ("episodes", "wall_time_s", "samples", "updates", "device", "torch")})
        meta = meta.get("init_metadata")
    return stages[::-1]


def mavlink_task(params: dict, folder: Path) -> tuple[dict, dict]:
    """One simulator episode flown through the MAVLink path (tools.exp.flown)."""
    from tools.exp.flown import fly_episode

    return fly_episode(params, folder), {}


TASKS = {"train": train_task, "eval": eval_task, "cost": cost_task, "mavlink": mavlink_task}
__all__ = ["TASKS", "ROOT"]
