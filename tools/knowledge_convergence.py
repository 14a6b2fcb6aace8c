"""How many digest rounds the swarm's maps need to agree under packet loss (real UDP, loopback radio).

Each run: U vehicles random-walk on an M x M grid for --steps steps (sensing a radius-3 disc), then
keep stepping in place; counted is the number of digest periods after the last move until every
vehicle holds the same map. Prints the histogram over seeds, with push (default) and pull only.

    python tools/knowledge_convergence.py --seeds 100 --loss 0.3
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from swarmctl.knowledge.exchange import KnowledgeExchange  # noqa: E402
from swarmctl.knowledge.model import Knowledge, disc_cells  # noqa: E402
from swarmctl.sim.radio import Radio, wait_quiet  # noqa: E402
from swarmctl.world.channel import Channel  # noqa: E402
from swarmctl.world.moves import MOVES  # noqa: E402


def rounds_to_converge(
    vehicles: int, size: int, steps: int, loss: float, digest_every: int, seed: int, push: bool, max_rounds: int = 50
) -> int:
    rng = np.random.default_rng(seed)
    phi, obstacle = rng.random((size, size)), rng.random((size, size)) < 0.1
    cells = [rng.integers(0, size, 2) for _ in range(vehicles)]
    with Radio(Channel("fixed", loss=loss), seed=seed) as radio:
        agents: list[KnowledgeExchange] = []
        try:
            for v in range(vehicles):
                agents.append(
                    KnowledgeExchange(Knowledge(size, size, v), 1, radio.address, digest_every=digest_every, push=push)
                )
                radio.add_peer(agents[-1].address, system_id=v + 1)

            def step(t: int, move: bool) -> None:
                for v, a in enumerate(agents):
                    if move:
                        cells[v] = np.clip(cells[v] + MOVES[rng.integers(0, 5)], 0, size - 1)
                    c = disc_cells(tuple(cells[v]), size, size)
                    a.step(t, tuple(cells[v]), False, c, phi[c[:, 0], c[:, 1]], obstacle[c[:, 0], c[:, 1]])
                wait_quiet(radio, agents)

            for t in range(1, steps + 1):
                step(t, True)
            extra = 0
            while not all(agents[0].knowledge.same_map(a.knowledge) for a in agents):
                extra += 1
                if extra > max_rounds * digest_every:
                    return -1
                step(steps + extra, False)
            return -(-extra // digest_every)
        finally:
            for a in agents:
                a.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=3)
    ap.add_argument("--size", type=int, default=20)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--loss", type=float, default=0.3)
    ap.add_argument("--digest-every", type=int, default=5)
    ap.add_argument("--seeds", type=int, default=100)
    args = ap.parse_args(argv)
    for push in (True, False):
        hist = Counter(
            rounds_to_converge(args.vehicles, args.size, args.steps, args.loss, args.digest_every, s, push)
            for s in range(args.seeds)
        )
        print(
            f"{'push + pull' if push else 'pull only'}: digest rounds after the last move -> runs: "
            + ", ".join(f"{r}: {n}" for r, n in sorted(hist.items())),
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
