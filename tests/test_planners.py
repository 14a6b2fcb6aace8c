"""Planners on hand-built cases, BFS distances, the oracle bound, and eval reproducibility."""

from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.learn.evaluate import evaluate
from swarmctl.policy.lookahead import LookAhead
from swarmctl.policy.oracle import OracleBound, bottleneck
from swarmctl.policy.planners import FrontierPolicy, LawnmowerPolicy, sweep_waypoints
from swarmctl.world import WorldConfig
from swarmctl.world.moves import EAST, NORTH, STAY
from swarmctl.world.paths import UNREACHABLE, grid_distances
from swarmctl.world.scenario import fov_offsets
from tests.helpers import make_env


def bfs(passable, start):
    w, h = passable.shape
    dist = np.full((w, h), UNREACHABLE)
    dist[start] = 0
    q = deque([start])
    while q:
        x, y = q.popleft()
        for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            nx, ny = x + dx, y + dy
            if 0 <= nx < w and 0 <= ny < h and passable[nx, ny] and dist[nx, ny] == UNREACHABLE:
                dist[nx, ny] = dist[x, y] + 1
                q.append((nx, ny))
    return dist


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.integers(3, 12), st.floats(0.0, 0.4))
def test_grid_distances_match_a_plain_bfs(seed, size, density):
    rng = np.random.default_rng(seed)
    passable = rng.random((size, size)) >= density
    start = (int(rng.integers(size)), int(rng.integers(size)))
    passable[start] = True
    src = np.zeros((1, size, size), dtype=bool)
    src[0][start] = True
    assert (grid_distances(passable[None], src)[0] == bfs(passable, start)).all()


def test_la_heads_for_the_unexplored_side_and_hovers_on_a_target():
    # the vehicle's west and south are explored and empty; unexplored cells lie east and north
    env = make_env(20, [[19, 19]], [[2, 2]])
    la = LookAhead(4)
    la.reset(env.beliefs(), 0)
    assert la.act(env.beliefs())[0, 0] in (NORTH, EAST)
    env = make_env(20, [[5, 5], [15, 15]], [[5, 5], [0, 19]])
    la.reset(env.beliefs(), 0)
    assert la.act(env.beliefs())[0, 0] == STAY


def test_la_eliminates_a_target_another_vehicle_hovers_on():
    # vehicle 1 hovers on target (6, 6); vehicle 0 at (6, 4) sees it and must not walk onto it
    env = make_env(12, [[6, 6], [11, 11]], [[6, 4], [6, 6]])
    la = LookAhead(2)
    la.reset(env.beliefs(), 0)
    value = la.value_maps(env.beliefs())[0, 0]
    assert value[6, 5] == 0.0  # the bump of an occupied target is gone
    assert value[6, 6] == -np.inf  # and the hovering vehicle's cell is blocked: it stays, the guard keeps it
    assert la.act(env.beliefs())[0, 1] == STAY


def test_la_never_moves_into_a_known_obstacle_or_off_the_map():
    env = make_env(8, [[7, 7]], [[0, 0]], obstacles=[(1, 0), (0, 1)])
    la = LookAhead(3)
    la.reset(env.beliefs(), 0)
    for _ in range(20):
        a = la.act(env.beliefs())
        _, _, _, info = env.step(a)
        assert info.valid.all()


def test_oracle_bottleneck_assignment_by_hand():
    cost = np.array([[1, 9], [2, 3]])
    assert bottleneck(cost) == 3  # 0->0 (1), 1->1 (3), not 0->1/1->0 (9)
    env = make_env(10, [[9, 0], [0, 9]], [[5, 0], [0, 4]])
    assert OracleBound().durations(env)[0] == 5  # 4 to (9, 0) and 5 to (0, 9)


def test_oracle_counts_steps_around_obstacles():
    wall = [(2, y) for y in range(0, 5)]
    env = make_env(6, [[4, 0]], [[0, 0]], obstacles=wall)
    assert OracleBound().durations(env)[0] == 4 + 2 * 5


def test_lawnmower_lanes_sense_every_cell():
    for size, uavs in [(20, 2), (20, 3), (13, 1), (50, 10)]:
        seen = np.zeros((size, size), dtype=bool)
        off = fov_offsets(3.0)
        for lane in sweep_waypoints(size, size, uavs, 3.0):
            for (x0, y0), (x1, y1) in zip(lane[:-1], lane[1:]):
                xs = np.linspace(x0, x1, abs(x1 - x0) + abs(y1 - y0) + 1).round().astype(int)
                ys = np.linspace(y0, y1, abs(x1 - x0) + abs(y1 - y0) + 1).round().astype(int)
                for x, y in zip(xs, ys):
                    c = off + [x, y]
                    c = c[((c >= 0) & (c < size)).all(1)]
                    seen[c[:, 0], c[:, 1]] = True
        assert seen.all(), (size, uavs)


@pytest.mark.parametrize("policy", [LawnmowerPolicy, FrontierPolicy])
def test_sweeping_planners_find_targets_on_an_open_map(policy):
    env = make_env(20, [[18, 18], [17, 2]], [[0, 0], [1, 0]])
    p = policy()
    p.reset(env.beliefs(), 0)
    for _ in range(120):
        if env.done[0]:
            break
        env.step(p.act(env.beliefs()))
    assert env.done[0]


def test_eval_is_reproducible_and_policies_share_episodes():
    cfg = WorldConfig()
    a = evaluate(cfg, ["la:2", "oracle"], 30, seed=4, steps=40, progress=False)
    b = evaluate(cfg, ["la:2", "oracle"], 30, seed=4, steps=40, progress=False)
    for r1, r2 in zip(a, b):
        assert r1["success_rate"] == r2["success_rate"] and r1["steps_cdf"] == r2["steps_cdf"]
    assert a[0]["oracle_mean_steps"] == a[1]["oracle_mean_steps"] == a[1]["mean_steps"]
    c = evaluate(cfg, ["oracle"], 30, seed=5, steps=40, progress=False)
    assert c[0]["mean_steps"] != a[1]["mean_steps"]


def test_eval_metrics_are_consistent():
    r = evaluate(WorldConfig(), ["la:4"], 40, seed=0, steps=40, progress=False)[0]
    cdf = np.array(r["steps_cdf"])
    assert len(cdf) == 40 and (np.diff(cdf) >= 0).all()
    assert cdf[-1] == pytest.approx(r["success_rate"])
    assert r["mean_steps"] >= r["oracle_mean_steps"]


def test_eval_results_do_not_depend_on_the_chunk_size():
    cfg = WorldConfig(uavs=3, targets=4, obstacles=0.1)
    specs = ["la:2", "frontier", "lawnmower", "random"]
    whole = evaluate(cfg, specs, 24, seed=3, steps=30, progress=False)
    chunked = evaluate(cfg, specs, 24, seed=3, steps=30, chunk=5, progress=False)
    for a, b in zip(whole, chunked):
        assert a["steps_cdf"] == b["steps_cdf"] and a["collisions_per_episode"] == b["collisions_per_episode"], a[
            "policy"
        ]


def test_frontier_keeps_searchers_out_of_a_hovering_vehicles_cell():
    # vehicle 0 hovers on (5, 5); vehicle 1 two cells south of it, the only other known target far away
    env = make_env(12, [[5, 5], [11, 11]], [[5, 5], [5, 3]])
    b = env.beliefs()
    assert b.hovering_self[0].tolist() == [True, False] and b.held[0, 1, 5, 5] and not b.held[0, 0, 5, 5]
    p = FrontierPolicy()
    p.reset(b, 0)
    goals = p.goals(b)
    assert goals[0, 0].tolist() == [5, 5] and goals[0, 1].tolist() != [5, 5]
    for _ in range(15):
        moves = p.act(env.beliefs())
        assert moves[0, 0] == STAY
        env.step(moves)
        assert env.pos[0, 1].tolist() != [5, 5]
