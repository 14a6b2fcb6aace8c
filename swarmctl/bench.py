"""`swarmctl bench`: environment throughput and planner decision times on this machine."""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import click
import numpy as np

from swarmctl.bounds import real, writable_file
from swarmctl.policy.lookahead import LookAhead
from swarmctl.world.config import WorldConfig
from swarmctl.world.env import SearchEnv


def _timed(fn, min_seconds: float) -> tuple[float, int]:
    """Call fn repeatedly for at least min_seconds; returns (seconds, calls)."""
    fn()  # warm-up
    calls, start = 0, time.perf_counter()
    while True:
        fn()
        calls += 1
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            return elapsed, calls


def env_throughput(cfg: WorldConfig, batch: int, observations: bool, seconds: float) -> float:
    """Vehicle-steps per second of random joint moves, observations included if asked."""
    env = SearchEnv(cfg, batch=batch, stop_at_success=False, observations=observations)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.integers(0, 5, size=(64, batch, cfg.uavs))
    i = iter(range(10**9))
    elapsed, calls = _timed(lambda: env.step(actions[next(i) % 64]), seconds)
    return calls * batch * cfg.uavs / elapsed


def la_decision_seconds(depth: int, seconds: float) -> float:
    """Time of one LA(depth) decision for one vehicle (batch of one episode, U = 2)."""
    env = SearchEnv(WorldConfig(), batch=1, observations=False)
    env.reset(seed=0)
    policy = LookAhead(depth)
    policy.reset(env.beliefs(), 0)
    elapsed, calls = _timed(lambda: policy.act(env.beliefs()), seconds)
    return elapsed / (calls * env.uavs)


def ddql_decision_seconds(batch_episodes: int, seconds: float, options: str = "") -> float:
    """Time of one DDQL decision per vehicle, as `ddql:PATH[options]` makes it: observation, forward
    pass, the option rules and softmax sampling.

    The weights do not change the cost, so an untrained network of the paper's architecture is timed."""
    import tempfile

    from swarmctl.policy.checkpoint import save_checkpoint
    from swarmctl.policy.ddql import make_ddql_policy
    from swarmctl.policy.qnet import QNetwork

    world = WorldConfig()
    env = SearchEnv(world, batch=batch_episodes, observations=False)
    env.reset(seed=0)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "untrained.pt"
        save_checkpoint(path, QNetwork(world.window), world.as_dict(), {}, {})
        policy = make_ddql_policy(f"ddql:{path}{options}")
    policy.reset(env.beliefs(), 0)
    elapsed, calls = _timed(lambda: policy.act(env.beliefs()), seconds)
    return elapsed / (calls * batch_episodes * env.uavs)


PAPER_OPTIONS = ":taken=keep:hover=no:mask=no"  # the paper's DDQL Soft: the network and softmax alone


def run_bench(seconds: float = 2.0) -> dict:
    """All benchmark figures, keys naming their unit."""
    m20 = WorldConfig()
    m50 = WorldConfig(map_size=50, uavs=10, targets=16, clusters=4, obstacles=0.1)
    out = {
        "machine": {
            "cpu_count": os.cpu_count(),
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "python": platform.python_version(),
            "numpy": np.__version__,
        },
        "env_vehicle_steps_per_s": env_throughput(m20, 256, True, seconds),
        "env_vehicle_steps_per_s_no_obs": env_throughput(m20, 256, False, seconds),
        "env_m50_u10_vehicle_steps_per_s": env_throughput(m50, 64, True, seconds),
        "env_m50_u10_vehicle_steps_per_s_no_obs": env_throughput(m50, 64, False, seconds),
        "la4_decision_ms": 1000.0 * la_decision_seconds(4, seconds),
        "ddql_decision_ms_batch1": 1000.0 * ddql_decision_seconds(1, seconds),
        "ddql_decision_ms_per_vehicle_batch256": 1000.0 * ddql_decision_seconds(256, seconds),
        "ddql_paper_decision_ms_batch1": 1000.0 * ddql_decision_seconds(1, seconds, PAPER_OPTIONS),
    }
    out["la4_over_ddql_decision_time"] = out["la4_decision_ms"] / out["ddql_decision_ms_batch1"]
    env = SearchEnv(m20, batch=256, stop_at_success=False)
    env.reset(seed=0)
    elapsed, calls = _timed(env.observe, seconds)
    out["observe_ms_per_batch_256x2"] = 1000.0 * elapsed / calls
    return out


@click.command("bench")
@click.option("--seconds", type=real(0, 600, above=True), default=2.0, show_default=True, help="Time per measurement.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, path_type=Path), help="Write the figures here.")
def bench_command(seconds, json_path):
    """Measure environment throughput (M=20 U=2 B=256; M=50 U=10 B=64) and LA(4) and DDQL decision times."""
    if json_path is not None:
        writable_file(json_path, "--json")
    results = run_bench(seconds)
    for key, value in results.items():
        if key != "machine":
            click.echo(f"{key:>42}: {value:,.3f}")
    m = results["machine"]
    click.echo(f"{'machine':>42}: {m['cpu_count']} cores, {m['processor']}, Python {m['python']}, numpy {m['numpy']}")
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps(results, indent=1))
        click.echo(f"wrote {json_path}")
