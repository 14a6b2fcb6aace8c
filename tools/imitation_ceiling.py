"""How well can the scales network imitate the coordinated planner at all? Behaviour cloning alone, no RL.

    python tools/imitation_ceiling.py --setting obstacles3 --batches 24 --epochs 8 --labels one all
    python tools/imitation_ceiling.py --setting big10 --batches 4 --epochs 6 --order no yes --flown 100

Records the planner's episodes (32 a batch, seeds 1000 + k; held-out states from 4 batches at seed 5000),
fits a fresh ScalesQNetwork (seed 0, Adam 1e-3, batch 128) to its moves among the moves the recipe allows,
and reports on the held-out states the share of greedy moves equal to the planner's and inside its set of
equally good moves (CoordinatedPolicy.labels), then flies the network greedily on `--flown` episodes of
seed 9000 (success: every target held, as eval's). Variants:
- `--labels one|all`: cross-entropy on the planner's tie-broken move, or the log-likelihood of its set;
- `--order no|yes`: the observation alone, or with a fourth crop channel per scale counting only the other
  vehicles earlier in mission order (the planner plans the vehicles in that order).
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from planner_table import SETTINGS, world_of  # noqa: E402

from swarmctl.learn.search_recipe import search_mask  # noqa: E402
from swarmctl.policy.coordinated import CoordinatedPolicy  # noqa: E402
from swarmctl.policy.qnet import ScalesQNetwork  # noqa: E402
from swarmctl.world import SearchEnv  # noqa: E402
from swarmctl.world.beliefs import SCALES_VARIANT, Beliefs  # noqa: E402
from swarmctl.world.observe import observe  # noqa: E402


class OrderedScalesQNetwork(ScalesQNetwork):
    crop_channels = 8  # the 7 of each scale and the earlier vehicles' count


def observation(beliefs: Beliefs, order: bool) -> np.ndarray:
    """(B, U, C, 11, 11): the scales observation, with `order` the earlier vehicles' counts beside each crop."""
    obs = observe(beliefs, False)
    if not order:
        return obs
    earlier = copy.copy(beliefs)
    earlier._maps, earlier._ready = dict(beliefs._maps), dict(beliefs._ready)
    later = np.arange(beliefs.vehicles)[None, None, :] > beliefs.me[..., None]
    positions = beliefs.positions.copy()
    positions[np.broadcast_to(later, positions.shape[:3])] = -1  # the later vehicles unknown
    earlier.positions = positions
    counts = observe(earlier, False)
    parts = []
    for i in range(3):
        parts += [obs[:, :, 7 * i : 7 * i + 7], counts[:, :, 7 * i + 3 : 7 * i + 4]]
    return np.concatenate([*parts, obs[:, :, 21:24]], axis=2)


def record(setting: dict, seed: int, batches: int, order: bool) -> list[np.ndarray]:
    """The planner's states: observations, moves, sets of equally good moves, allowed moves."""
    cfg, blocked = world_of(setting)
    cfg = type(cfg)(**{**cfg.as_dict(), "variant": SCALES_VARIANT, "window": 11})
    xs, ys, sets, masks = [], [], [], []
    for k in range(batches):
        env = SearchEnv(cfg, batch=32, stop_at_success=True, observations=False)
        env.reset(seed=seed + k, blocked=blocked)
        teacher = CoordinatedPolicy()
        teacher.horizon = setting["steps"]
        teacher.reset(env.beliefs(), seed + k)
        for _ in range(setting["steps"]):
            live = ~env.done
            if not live.any():
                break
            beliefs = env.beliefs()
            moves, ties = teacher.labels(beliefs)
            obs = observation(beliefs, order)
            xs.append(obs[live].reshape(-1, *obs.shape[2:]))
            ys.append(moves[live].reshape(-1))
            sets.append(ties[live].reshape(-1, 5))
            masks.append(search_mask(beliefs)[live].reshape(-1, 5))
            env.step(moves)
    return [np.concatenate(a) for a in (xs, ys, sets, masks)]


def fit(data: list[np.ndarray], labels: str, order: bool, epochs: int) -> ScalesQNetwork:
    torch.manual_seed(0)
    net = (OrderedScalesQNetwork if order else ScalesQNetwork)(11)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    x, y, sets, masks = (torch.from_numpy(a) for a in data)
    for _ in range(epochs):
        perm = torch.randperm(len(x))
        for i in range(0, len(x), 128):
            idx = perm[i : i + 128]
            q = net(x[idx]).masked_fill(~masks[idx], -1e9)
            if labels == "one":
                loss = F.cross_entropy(q, y[idx].long())
            else:
                loss = (torch.logsumexp(q, 1) - torch.logsumexp(q.masked_fill(~sets[idx], -1e9), 1)).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
    return net


def flown(net: ScalesQNetwork, setting: dict, episodes: int, order: bool) -> float:
    cfg, blocked = world_of(setting)
    cfg = type(cfg)(**{**cfg.as_dict(), "variant": SCALES_VARIANT, "window": 11})
    env = SearchEnv(cfg, batch=episodes, stop_at_success=True, observations=False)
    env.reset(seed=9000, blocked=blocked)
    for _ in range(setting["steps"]):
        if env.done.all():
            break
        beliefs = env.beliefs()
        obs = observation(beliefs, order)
        with torch.no_grad():
            q = net(torch.from_numpy(obs.reshape(-1, *obs.shape[2:]))).reshape(*obs.shape[:2], 5).numpy()
        env.step(np.where(search_mask(beliefs), q, -np.inf).argmax(-1))
    return float(env.done.mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--setting", choices=list(SETTINGS), default="obstacles3")
    ap.add_argument("--batches", type=int, default=24, help="training batches of 32 planner episodes")
    ap.add_argument("--epochs", type=int, default=8)
    ap.add_argument("--labels", nargs="+", choices=["one", "all"], default=["one"])
    ap.add_argument("--order", nargs="+", choices=["no", "yes"], default=["no"])
    ap.add_argument("--flown", type=int, default=200, help="episodes flown by each fitted network")
    args = ap.parse_args()
    torch.set_num_threads(1)
    setting, t0 = SETTINGS[args.setting], time.time()
    print(f"{'labels':<7} {'order':<6} {'samples':>8} {'exact':>6} {'in set':>7} {'flown':>6}")
    for order in (o == "yes" for o in args.order):
        train, test = record(setting, 1000, args.batches, order), record(setting, 5000, 4, order)
        for labels in args.labels:
            net = fit(train, labels, order, args.epochs)
            with torch.no_grad():
                q = net(torch.from_numpy(test[0])).masked_fill(~torch.from_numpy(test[3]), -1e9)
            greedy = q.argmax(1).numpy()
            exact = float((greedy == test[1]).mean())
            in_set = float(test[2][np.arange(len(greedy)), greedy].mean())
            success = flown(net, setting, args.flown, order)
            print(
                f"{labels:<7} {'yes' if order else 'no':<6} {len(train[0]):>8} {exact:6.3f} {in_set:7.3f} "
                f"{success:6.3f}   ({time.time() - t0:.0f} s)",
                flush=True,
            )


if __name__ == "__main__":
    main()
