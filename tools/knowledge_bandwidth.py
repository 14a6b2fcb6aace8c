"""Measure the knowledge-sharing bandwidth: bytes per second per vehicle at one step per second.

Runs the real stack (KnowledgeExchange endpoints and the loopback Radio over UDP on 127.0.0.1) with
vehicles sweeping their strip of the map lawnmower-style (lanes 2 * fov + 1 apart, so every step
explores new cells: a busy case) and counts the MAVLink bytes every vehicle sends: whole MAVLink 2
frames, headers and checksums included (not the radio modem's own framing). Prints a markdown table
for docs/knowledge.md.

    python tools/knowledge_bandwidth.py                       # 3 and 12 vehicles, 20 x 20 and 50 x 50
    python tools/knowledge_bandwidth.py --loss 0 0.3 --steps 100
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from swarmctl.knowledge.exchange import KnowledgeExchange  # noqa: E402
from swarmctl.knowledge.model import Knowledge, disc_cells  # noqa: E402
from swarmctl.sim.radio import Radio, wait_quiet  # noqa: E402
from swarmctl.world.channel import Channel  # noqa: E402

RADIO_BPS = 57_600  # a SiK-style telemetry radio, shared by the whole swarm


def lawnmower_paths(vehicles: int, size: int, fov: int = 3) -> list[list[tuple[int, int]]]:
    """One boustrophedon path per vehicle over its vertical strip of the map."""
    edges = np.linspace(0, size, vehicles + 1).astype(int)
    paths = []
    for v in range(vehicles):
        x0, x1 = edges[v], max(edges[v + 1], edges[v] + 1)
        lanes = list(range(min(x0 + fov, x1 - 1), x1, 2 * fov + 1)) or [x0]
        path: list[tuple[int, int]] = []
        for i, x in enumerate(lanes):
            ys = range(size) if i % 2 == 0 else range(size - 1, -1, -1)
            if path:  # walk across to the next lane
                px, py = path[-1]
                path += [(xx, py) for xx in range(px + 1, x)]
            path += [(x, y) for y in ys]
        paths.append(path)
    return paths


def measure(vehicles: int, size: int, steps: int, loss: float, digest_every: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    phi, obstacle = rng.random((size, size)), rng.random((size, size)) < 0.1
    paths = lawnmower_paths(vehicles, size)
    channel = Channel("fixed", loss=loss) if loss > 0 else Channel("ideal")
    per_step = np.zeros((steps, vehicles))
    with Radio(channel, seed=seed) as radio:
        agents = []
        try:
            for v in range(vehicles):
                agents.append(KnowledgeExchange(Knowledge(size, size, v), 1, radio.address, digest_every=digest_every))
                radio.add_peer(agents[-1].address, system_id=v + 1)
            for t in range(steps):
                before = [a.stats["sent_bytes"] for a in agents]
                for v, a in enumerate(agents):
                    cell = paths[v][min(t, len(paths[v]) - 1)]
                    c = disc_cells(cell, size, size)
                    a.step(t, cell, False, c, phi[c[:, 0], c[:, 1]], obstacle[c[:, 0], c[:, 1]])
                wait_quiet(radio, agents, timeout=60.0)
                per_step[t] = [a.stats["sent_bytes"] - b for a, b in zip(agents, before)]
            converged = all(agents[0].knowledge.same_map(a.knowledge) for a in agents)
            explored = float(agents[0].knowledge.explored.mean())
        finally:
            for a in agents:
                a.close()
    mean = per_step.mean()
    swarm_peak = per_step.sum(1).max()
    return {
        "vehicles": vehicles,
        "grid": f"{size} x {size}",
        "loss": loss,
        "mean": mean,
        "peak": per_step.max(),
        "swarm_bps": mean * vehicles * 8,
        "swarm_peak_bps": swarm_peak * 8,
        "explored": explored,
        "converged": converged,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, nargs="+", default=[3, 12])
    ap.add_argument("--grids", type=int, nargs="+", default=[20, 50])
    ap.add_argument("--loss", type=float, nargs="+", default=[0.0, 0.3])
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--digest-every", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    print(
        f"{args.steps} steps at 1 step/s, digest every {args.digest_every} steps, lawnmower sweep; "
        f"radio {RADIO_BPS / 1000:.1f} kbit/s shared by the swarm\n"
    )
    print(
        "| grid | vehicles | loss | mean B/s per vehicle | peak B/s per vehicle | swarm mean kbit/s "
        "| share of 57.6 kbit/s | busiest second, swarm kbit/s | explored | maps equal at end |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |")
    for size in args.grids:
        for n in args.vehicles:
            for loss in args.loss:
                r = measure(n, size, args.steps, loss, args.digest_every, args.seed)
                print(
                    f"| {r['grid']} | {n} | {loss:.0%} | {r['mean']:.0f} | {r['peak']:.0f} | "
                    f"{r['swarm_bps'] / 1000:.1f} | {r['swarm_bps'] / RADIO_BPS:.0%} | "
                    f"{r['swarm_peak_bps'] / 1000:.1f} | {r['explored']:.0%} | "
                    f"{'yes' if r['converged'] else 'no'} |",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
