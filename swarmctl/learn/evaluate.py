"""Evaluation with the paper's metrics: success probability, episode duration, its CDF.

All policies of one call see identical episodes: episode i depends only on (seed, i), and each
policy's own randomness is keyed by (seed, episode, step, vehicle) (swarmctl.policy.draws), so the
chunk size never changes a result. Policies decide only for the episodes still running.

Success, and so `success_rate`, `mean_steps` and `steps_cdf`, is under the world's finish line
(`WorldConfig.finish`): `held` (the paper's, the default), `found` or `covered` (swarmctl.world.env).
The oracle bound (`oracle_mean_steps`, `duration_ratio_to_oracle`, the `oracle` policy) exists for
`held` only: the others give None, and the `oracle` policy is refused. `found` adds `found_steps` per
episode and `mean_first_find_steps`; `covered` adds `covered_fraction` and `mean_covered_fraction`.

Every finish line reports the search's probability of success (POS, swarmctl.world.prior: against the
prior given, uniform without one, whatever the policy reads): `mean_pos_goal_steps` (the steps until POS
reached `pos_goal`, the step limit for an episode that never did), `pos_goal_rate`, `mean_final_pos`
and `pos_by_step` (the mean POS after each step, 0 the starts'; an episode that ended keeps its last);
per episode `pos_goal_step` (None: not reached) and `final_pos`; under found, covered and pos,
`targets_found`. The finish line `pos` succeeds when POS reaches pos_goal.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from tqdm import tqdm

from swarmctl.errors import InputError
from swarmctl.policy.oracle import OracleBound
from swarmctl.policy.registry import make_policy
from swarmctl.world.config import WorldConfig
from swarmctl.world.env import SearchEnv
from swarmctl.world.paths import UNREACHABLE, grid_distances

DEFAULT_CHUNK = 250


def _chunks(episodes: int, chunk: int):
    for start in range(0, episodes, chunk):
        yield start, min(chunk, episodes - start)


def episode_records(env: SearchEnv, durations: np.ndarray, success: np.ndarray) -> list[dict[str, Any]]:
    """One record per episode of `env` as it ended: `episode` (its index), `steps`, `success`,
    `on_target` (per vehicle, the index of the target whose cell it ends on, or None), `searching`
    (the vehicles without a target of their own: off any target, or sharing one with a
    lower-numbered vehicle), and `straggler_distance`: when exactly one vehicle is searching (the
    paper's straggler), its BFS steps over the free cells to the nearest target no vehicle is on
    (None otherwise, or when none is reachable); `collisions`, the steps with a collision. Under the
    finish line `found`, `found_steps`: the step each target was first sensed, in increasing order, None
    for each target never sensed; under `covered`, `covered_fraction`: the share of the reachable free
    cells sensed by the end."""
    at = (env.pos[:, :, None, :] == env.targets[:, None, :, :]).all(-1)  # (B, U, K)
    on = np.where(at.any(-1), at.argmax(-1), -1)
    searching = ~env.hovering_now()
    free = ~at.any(1)  # (B, K) targets no vehicle is on
    lone = np.flatnonzero((searching.sum(1) == 1) & free.any(1))
    distance = np.full(env.batch, -1, dtype=np.int64)
    if len(lone):
        src = np.zeros((len(lone), env.width, env.height), dtype=bool)
        for row, b in enumerate(lone):
            cells = env.targets[b][free[b]]
            src[row, cells[:, 0], cells[:, 1]] = True
        dist = grid_distances(~env.obstacles[lone], src)
        who = searching[lone].argmax(1)
        d = dist[np.arange(len(lone)), env.pos[lone, who, 0], env.pos[lone, who, 1]]
        distance[lone] = np.where(d >= UNREACHABLE, -1, d)
    finish = env.cfg.finish
    covered = env.covered_fraction() if finish == "covered" else None
    records: list[dict[str, Any]] = [
        {
            "episode": int(env.episodes[b]),
            "steps": int(durations[b]),
            "success": bool(success[b]),
            "on_target": [None if k < 0 else int(k) for k in on[b]],
            "searching": [int(u) for u in np.flatnonzero(searching[b])],
            "straggler_distance": None if distance[b] < 0 else int(distance[b]),
            "collisions": int(env.collisions[b]),
        }
        for b in range(env.batch)
    ]
    for i, record in enumerate(records):
        if finish == "found":
            steps = np.sort(env.found_step[i])
            record["found_steps"] = [int(s) for s in steps[steps >= 0]] + [None] * int((steps < 0).sum())
        elif covered is not None:  # finish "covered"
            record["covered_fraction"] = float(covered[i])
    return records


def check_finish(cfg: WorldConfig, policy) -> None:
    """The oracle bound is a bound on the `held` finish line only: InputError for another."""
    if isinstance(policy, OracleBound) and cfg.finish != "held":
        raise InputError(
            f"--policy oracle: the oracle bound is defined for --finish held only (not --finish {cfg.finish}); "
            "leave --policy oracle out"
        )


def run_policy(
    cfg: WorldConfig,
    spec: str,
    episodes: int,
    seed: int,
    steps: int,
    chunk: int = DEFAULT_CHUNK,
    progress: bool = True,
    blocked: np.ndarray | None = None,
    prior: np.ndarray | None = None,
    pos_traces: bool = False,
) -> dict:
    """Run one policy on episodes 0..E-1 of `seed` (on the fixed map `blocked` when given, with the
    prior `prior` (W, H) when given); returns the per-policy result record (with `pos_traces`, each
    episode's POS after every step too: `pos_by_step`)."""
    policy = make_policy(spec)
    check_finish(cfg, policy)
    held = cfg.finish == "held"
    durations, successes, oracle = [], [], []
    records: list[dict[str, Any]] = []
    collisions = 0
    traces: list[np.ndarray] = []  # (n, steps + 1) per chunk
    act_seconds, decisions = 0.0, 0
    bar = tqdm(total=episodes, desc=f"{spec:>12}", unit="ep", disable=not progress, leave=False)
    for start, n in _chunks(episodes, chunk):
        # policies observe for themselves
        env = SearchEnv(cfg, batch=n, stop_at_success=True, observations=False, track_pos=True)
        env.reset(seed, range(start, start + n), blocked, prior)
        if held:
            bound = OracleBound().durations(env)
            oracle.append(np.minimum(bound, steps))
        if isinstance(policy, OracleBound):
            durations.append(np.where(bound <= steps, bound, steps).astype(np.int64))
            successes.append(bound <= steps)
            records += [
                {"episode": int(e), "steps": int(d), "success": bool(ok)}
                for e, d, ok in zip(env.episodes, durations[-1], successes[-1])
            ]
            bar.update(n)
            continue
        if hasattr(policy, "horizon"):
            policy.horizon = steps  # planners that time their parking to the step limit
        policy.reset(env.beliefs(), seed)
        for _ in range(steps):
            live = ~env.done
            if not live.any():
                break
            actions = np.zeros((n, env.uavs), dtype=np.int64)  # finished episodes stay frozen anyway
            t0 = time.perf_counter()
            actions[live] = policy.act(env.beliefs(None if live.all() else live))  # the live episodes only
            act_seconds += time.perf_counter() - t0
            decisions += int(live.sum()) * env.uavs  # the vehicles decided for
            env.step(actions)
        durations.append(np.where(env.done, env.duration, steps))
        successes.append(env.done.copy())
        chunk_records = episode_records(env, durations[-1], successes[-1])
        trace = np.stack(env.pos_trace, axis=1)  # (n, steps taken + 1)
        traces.append(np.concatenate([trace, np.repeat(trace[:, -1:], steps + 1 - trace.shape[1], 1)], 1))
        for i, record in enumerate(chunk_records):
            if pos_traces:
                record["pos_by_step"] = traces[-1][i].tolist()
            record["pos_goal_step"] = int(env.pos_step[i]) if env.pos_step[i] >= 0 else None
            record["final_pos"] = float(trace[i, -1])
            if cfg.finish != "held":  # (found_step is kept for the other finish lines)
                record["targets_found"] = int((env.found_step[i] >= 0).sum())
        records += chunk_records
        collisions += int(env.collisions.sum())
        bar.update(n)
    bar.close()
    d = np.concatenate(durations)
    success = np.concatenate(successes)
    mean_oracle = float(np.concatenate(oracle).mean()) if held else None
    cdf = [(float(((d <= t) & success).mean())) for t in range(1, steps + 1)]
    result = {
        "policy": spec,
        "scenario": {**cfg.as_dict(), "steps": steps},
        "seed": seed,
        "episodes": episodes,
        "finish": cfg.finish,
        "success_rate": float(success.mean()),
        "mean_steps": float(d.mean()),
        "steps_cdf": cdf,
        "oracle_mean_steps": mean_oracle,
        "duration_ratio_to_oracle": float(d.mean() / mean_oracle)
        if mean_oracle is not None and mean_oracle > 0
        else None,
        "collisions_per_episode": collisions / episodes,
        "decision_ms_per_vehicle": (1000.0 * act_seconds / decisions) if decisions else None,
    }
    if cfg.finish == "found":  # the first find of each episode; an episode without one counts as the limit
        first = [min((s for s in r["found_steps"] if s is not None), default=steps) for r in records]
        result["mean_first_find_steps"] = float(np.mean(first))
    elif cfg.finish == "covered":
        result["mean_covered_fraction"] = float(np.mean([r["covered_fraction"] for r in records]))
    if traces:  # (the oracle bound flies nothing)
        goal_steps = [steps if r["pos_goal_step"] is None else r["pos_goal_step"] for r in records]
        result["pos_goal"] = cfg.pos_goal
        result["pos_goal_rate"] = float(np.mean([r["pos_goal_step"] is not None for r in records]))
        result["mean_pos_goal_steps"] = float(np.mean(goal_steps))
        result["mean_final_pos"] = float(np.mean([r["final_pos"] for r in records]))
        result["pos_by_step"] = [float(x) for x in np.concatenate(traces).mean(0)]
        if cfg.finish != "held":
            result["mean_targets_found"] = float(np.mean([r["targets_found"] for r in records]))
    result["per_episode"] = records
    return result


def evaluate(
    cfg: WorldConfig,
    specs: list[str],
    episodes: int,
    seed: int,
    steps: int,
    chunk: int = DEFAULT_CHUNK,
    progress: bool = True,
    blocked: np.ndarray | None = None,
    prior: np.ndarray | None = None,
) -> list[dict]:
    """Evaluate every policy on the same episodes (on the fixed map `blocked` when given, with the prior
    `prior` when given)."""
    for spec in specs:
        check_finish(cfg, make_policy(spec))  # fail on a bad spec, or the oracle off `held`, before any work
    return [run_policy(cfg, s, episodes, seed, steps, chunk, progress, blocked, prior) for s in specs]
