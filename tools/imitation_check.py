"""How closely a network follows its teacher, the coordinated planner: on the states the teacher visits and
on the states the network visits itself (the teacher labelling them, as DAgger does).

    python tools/imitation_check.py runs/search/search.pt --episodes 32 --seed 77 [--only big10 cluster2]

Per setting of tools/planner_table.py: the share of vehicle-steps where the network's greedy move (over the
moves its rules allow) is the teacher's move, where it is one of the moves the teacher rates as good
(CoordinatedPolicy.labels: the teacher breaks ties between equally short moves at random), and how many of
the teacher's moves had such a tie. A network that takes a move outside the teacher's set chose another
goal or another path length: a real disagreement, not a tie-break. Prints a table; `--json` writes it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from planner_table import SETTINGS, world_of  # noqa: E402

from swarmctl.policy.base import allowed_moves  # noqa: E402
from swarmctl.policy.coordinated import CoordinatedPolicy  # noqa: E402
from swarmctl.policy.ddql import DDQLPolicy  # noqa: E402
from swarmctl.world import SearchEnv  # noqa: E402


def follow(checkpoint: str, setting: dict, episodes: int, seed: int, driver: str) -> dict:
    """The agreement figures of one setting, the teacher (driver "teacher") or the network driving."""
    cfg, blocked = world_of(setting)
    env = SearchEnv(cfg, batch=episodes, stop_at_success=True, observations=False)
    env.reset(seed=seed, blocked=blocked)
    teacher, student = CoordinatedPolicy(), DDQLPolicy(checkpoint)
    teacher.horizon = setting["steps"]
    teacher.reset(env.beliefs(), seed)
    student.reset(env.beliefs(), seed)
    exact = in_set = tied = total = 0
    for _ in range(setting["steps"]):
        live = ~env.done
        if not live.any():
            break
        beliefs = env.beliefs()
        moves, ties = teacher.labels(beliefs)
        q = student.decide(beliefs).q
        allowed = allowed_moves(beliefs, student.hover, student.mask, student.hold)
        greedy = np.where(allowed, q, -np.inf).argmax(-1)
        rows = np.broadcast_to(live[:, None], moves.shape)
        exact += int((greedy == moves)[rows].sum())
        in_set += int(np.take_along_axis(ties, greedy[..., None], -1)[..., 0][rows].sum())
        tied += int((ties.sum(-1) > 1)[rows].sum())
        total += int(rows.sum())
        env.step(moves if driver == "teacher" else greedy)
    return {
        "driver": driver,
        "vehicle_steps": total,
        "exact": exact / max(1, total),
        "in_teachers_set": in_set / max(1, total),
        "teacher_tied": tied / max(1, total),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint")
    ap.add_argument("--episodes", type=int, default=32)
    ap.add_argument("--seed", type=int, default=77)
    ap.add_argument("--only", nargs="*", choices=list(SETTINGS), default=["chicago", "big10", "obstacles3", "cluster2"])
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    rows = []
    print(f"{'setting':<12} {'driver':<8} {'exact':>6} {'in set':>7} {'tied':>6} {'vehicle-steps':>14}")
    for name in args.only:
        for driver in ("teacher", "network"):
            r = {"setting": name, **follow(args.checkpoint, SETTINGS[name], args.episodes, args.seed, driver)}
            rows.append(r)
            print(
                f"{name:<12} {driver:<8} {r['exact']:6.3f} {r['in_teachers_set']:7.3f} {r['teacher_tied']:6.3f} "
                f"{r['vehicle_steps']:14d}",
                flush=True,
            )
    if args.json:
        args.json.write_text(json.dumps({"checkpoint": args.checkpoint, "seed": args.seed, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
