"""Per-vehicle decision time of the scales-v1 network against the paper's, in one run, one thread.

    python tools/time_scales.py [--repeats 200] [--loss P]

For each row count (vehicles deciding in one call) it times the inference forward the policies use
(swarmctl.policy.forward, backend "auto") of the paper's QNetwork at F = 20 and of ScalesQNetwork at
S = 11, alternating the two call by call so that the machine's other load falls on both alike, and
prints the median microseconds a vehicle; then the same for a whole decision's observation and
forward on a simulator's beliefs (20 x 20 and 50 x 50 maps, 5 steps in), and the scales
observation's path search alone (pixel_distances). The simulator shares knowledge ideally (an
episode's vehicles hold the same maps, and the scales observation sums them once); --loss P shares
it over a channel losing P of the messages instead, so that the vehicles' maps differ. Prints nproc
and the load average first.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import numpy as np
import torch

from swarmctl.policy.forward import Forward, make_forward
from swarmctl.policy.qnet import QNetwork, ScalesQNetwork, forward_flops, scales_forward_flops
from swarmctl.world import SearchEnv, WorldConfig
from swarmctl.world.beliefs import PAPER_VARIANT, SCALES_VARIANT
from swarmctl.world.observe import observe
from swarmctl.world.observe_scales import pixel_counts, pixel_distances


def paired_medians(a: Callable[[], object], b: Callable[[], object], repeats: int) -> tuple[float, float]:
    """Median seconds of a call of `a` and of `b`, timed alternately."""
    for _ in range(5):
        a(), b()
    ta, tb = [], []
    for _ in range(repeats):
        start = time.perf_counter()
        a()
        middle = time.perf_counter()
        b()
        ta.append(middle - start)
        tb.append(time.perf_counter() - middle)
    return float(np.median(ta)), float(np.median(tb))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=200)
    parser.add_argument(
        "--loss", type=float, default=None, help="share over a lossy channel (fixed loss): beliefs differ by vehicle"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    print(f"nproc {os.cpu_count()}, load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    paper, scales = QNetwork(20).eval(), ScalesQNetwork(11).eval()
    print(f"FLOPs a vehicle: paper {forward_flops(20) / 1e6:.2f} M, scales {scales_forward_flops(11) / 1e6:.2f} M")
    fa, fb = make_forward(paper), make_forward(scales)
    rng = np.random.default_rng(0)
    print(f"forward ({fa.name}), us a vehicle:   rows   paper   scales   ratio")
    for rows in (1, 3, 16, 64, 256):
        xa = rng.random((rows, 3, 20, 20), dtype=np.float32)
        xb = rng.random((rows, 24, 11, 11), dtype=np.float32)
        ta, tb = paired_medians(lambda xa=xa: fa(xa), lambda xb=xb: fb(xb), args.repeats)
        print(f"{'':32}{rows:5} {1e6 * ta / rows:7.1f} {1e6 * tb / rows:8.1f} {tb / ta:7.2f}")
    print("observe + forward, us a vehicle:   map  batch x uavs   paper   scales   ratio   (scales' BFS)")
    for size, batch, uavs in ((20, 1, 3), (50, 1, 3), (20, 64, 3), (50, 64, 3)):
        sharing = {} if args.loss is None else {"channel": "fixed", "loss": args.loss}
        world = WorldConfig(map_size=size, uavs=uavs, targets=uavs, obstacles=0.1, **sharing)
        env = SearchEnv(world, batch=batch)
        env.reset(seed=1)
        for _ in range(5):
            env.step(rng.integers(0, 5, (batch, uavs)))

        def decide(forward: Forward, variant: str, window: int, env: SearchEnv = env) -> np.ndarray:
            """Fresh beliefs each call, as a decision gets them: their maps are computed in it."""
            obs = observe(env.beliefs().with_settings(variant=variant, window=window))
            return forward(obs.reshape(-1, *obs.shape[2:]))

        repeats = max(args.repeats // 4, 10)
        ta, tb = paired_medians(lambda: decide(fa, PAPER_VARIANT, 20), lambda: decide(fb, SCALES_VARIANT, 11), repeats)
        n = batch * uavs
        counts, _ = pixel_counts(env.beliefs().with_settings(variant=SCALES_VARIANT, window=11))
        bfs, _ = paired_medians(lambda c=counts: pixel_distances(c, 11), lambda: None, repeats)
        print(
            f"{'':32}{size:6} {batch:6} x {uavs}  {1e6 * ta / n:7.1f} {1e6 * tb / n:8.1f} {tb / ta:7.2f}"
            f"   ({1e6 * bfs / n:.1f})"
        )


if __name__ == "__main__":
    main()
