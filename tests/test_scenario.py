"""The paper's scenario rules, checked over many seeds."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.errors import ScenarioError
from swarmctl.world import WorldConfig, generate_scenario, value_map
from swarmctl.world.paths import UNREACHABLE, grid_distances
from swarmctl.world.scenario import fov_offsets

seeds = st.integers(0, 2**31 - 1)
episodes = st.integers(0, 10_000)


def pairwise(points):
    d = points[:, None, :] - points[None, :, :]
    dist = np.sqrt((d**2).sum(-1))
    return dist[~np.eye(len(points), dtype=bool)]


@settings(max_examples=200, deadline=None)
@given(seeds, episodes)
def test_sparse_targets_are_more_than_d_sparse_apart(seed, ep):
    s = generate_scenario(WorldConfig(scenario="sparse"), seed, ep)
    assert pairwise(s.targets).min() > 8.0


@settings(max_examples=200, deadline=None)
@given(seeds, episodes, st.integers(1, 4))
def test_cluster_targets_are_more_than_one_apart(seed, ep, clusters):
    cfg = WorldConfig(scenario="cluster", map_size=24, targets=8, clusters=clusters)
    s = generate_scenario(cfg, seed, ep)
    assert len(s.targets) == 8
    assert pairwise(s.targets).min() > 1.0
    assert (s.targets >= 0).all() and (s.targets < 24).all()


def _rect_cells(rect):
    x0, y0, w, h = rect
    xs, ys = np.meshgrid(np.arange(x0, x0 + w), np.arange(y0, y0 + h), indexing="ij")
    return np.stack([xs.ravel(), ys.ravel()], axis=1)


@settings(max_examples=150, deadline=None)
@given(seeds, episodes, st.sampled_from(["sparse", "cluster"]), st.sampled_from([0.05, 0.1, 0.2]))
def test_obstacle_rules(seed, ep, scenario, eta):
    cfg = WorldConfig(scenario=scenario, obstacles=eta)
    s = generate_scenario(cfg, seed, ep)
    m = cfg.map_size
    assert s.obstacles.mean() >= eta
    union = np.zeros_like(s.obstacles)
    for i, rect in enumerate(s.obstacle_rects):
        cells = _rect_cells(rect)
        assert 1 <= rect[2] <= cfg.obstacle_max and 1 <= rect[3] <= cfg.obstacle_max
        assert (cells >= 0).all() and (cells < m).all(), "rectangle inside the map"
        to_targets = np.sqrt(((cells[:, None] - s.targets[None]) ** 2).sum(-1))
        assert to_targets.min() > 1.0, "every obstacle cell more than 1 from every target"
        for other in s.obstacle_rects[:i]:
            oc = _rect_cells(other)
            assert np.sqrt(((cells[:, None] - oc[None]) ** 2).sum(-1)).min() >= 2.0
        union[cells[:, 0], cells[:, 1]] = True
    assert (union == s.obstacles).all()


@settings(max_examples=150, deadline=None)
@given(seeds, episodes, st.sampled_from(["sparse", "cluster"]), st.sampled_from([0.0, 0.1, 0.2]), st.integers(1, 4))
def test_starts_distinct_free_and_every_target_reachable_from_every_start(seed, ep, scenario, eta, uavs):
    cfg = WorldConfig(scenario=scenario, obstacles=eta, uavs=uavs)
    s = generate_scenario(cfg, seed, ep)
    assert len({tuple(p) for p in s.starts}) == uavs
    assert not s.obstacles[s.starts[:, 0], s.starts[:, 1]].any()
    assert not {tuple(p) for p in s.starts} & {tuple(t) for t in s.targets}
    src = np.zeros((1, *s.obstacles.shape), dtype=bool)
    src[0, s.starts[:, 0], s.starts[:, 1]] = True
    for start in s.starts:
        one = np.zeros_like(src)
        one[0, start[0], start[1]] = True
        dist = grid_distances(~s.obstacles[None], one)[0]
        assert (dist[s.targets[:, 0], s.targets[:, 1]] < UNREACHABLE).all()


def test_same_seed_same_episode_and_episodes_differ():
    cfg = WorldConfig(obstacles=0.1)
    a, b = generate_scenario(cfg, 7, 3), generate_scenario(cfg, 7, 3)
    assert (a.targets == b.targets).all() and (a.obstacles == b.obstacles).all() and (a.starts == b.starts).all()
    c = generate_scenario(cfg, 7, 4)
    assert not ((a.targets == c.targets).all() and (a.starts == c.starts).all())


def test_value_map_values_and_cutoff():
    phi = value_map(np.array([[5, 5]]), 12, 12)
    assert phi[5, 5] == 1.0
    assert phi[6, 5] == pytest.approx(np.exp(-0.5))
    assert phi[6, 6] == pytest.approx(np.exp(-1.0))
    assert phi[8, 5] == pytest.approx(np.exp(-4.5))  # 0.011 >= 0.01: kept
    assert phi[8, 6] == 0.0  # exp(-5) = 0.0067 < 0.01: cut
    two = value_map(np.array([[1, 1], [3, 1]]), 6, 6)
    assert two[2, 1] == pytest.approx(np.exp(-0.5))  # max over targets, not a sum


def test_value_map_of_no_targets_is_zero_everywhere():
    """A search with nothing hidden (the simulated detector used to crash on it: zero-size array)."""
    none = value_map(np.zeros((0, 2), dtype=np.int64), 7, 5)
    assert none.shape == (7, 5) and none.dtype == np.float32 and not none.any()
    batched = value_map(np.zeros((3, 0, 2), dtype=np.int64), 4, 6)
    assert batched.shape == (3, 4, 6) and not batched.any()


def test_fov_disc_has_29_cells_for_radius_3():
    off = fov_offsets(3.0)
    assert len(off) == 29
    assert ((off**2).sum(1) <= 9).all()


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(map_size=0), "--map"),
        (dict(uavs=0), "--uavs"),
        (dict(targets=101), "--targets"),
        (dict(obstacles=0.9), "--obstacles"),
        (dict(window=0), "--window"),
        (dict(map_size=3, uavs=9), "--uavs"),
        (dict(clusters=5), "--clusters"),
    ],
)
def test_impossible_requests_name_the_parameter(kwargs, name):
    with pytest.raises(ScenarioError, match=name):
        WorldConfig(**kwargs)


def test_sparse_targets_that_cannot_fit_fail_after_retries():
    with pytest.raises(ScenarioError, match="--targets"):
        generate_scenario(WorldConfig(scenario="sparse", targets=9), 0, 0)


def _random_map(seed: int, width: int, height: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    blocked = np.zeros((width, height), dtype=bool)
    for _ in range(rng.integers(2, 8)):  # rectangles, some of them walls that split the map
        x, y = rng.integers(0, width), rng.integers(0, height)
        blocked[x : x + rng.integers(1, width // 2 + 2), y : y + rng.integers(1, 4)] = True
    return blocked


@settings(max_examples=150, deadline=None)
@given(
    seeds, episodes, st.sampled_from(["sparse", "cluster"]), st.integers(12, 30), st.integers(12, 30), st.integers(1, 4)
)
def test_episodes_on_a_fixed_map_keep_it_and_draw_in_its_largest_free_region(seed, ep, scenario, w, h, uavs):
    from swarmctl.world.paths import largest_free_region

    blocked = _random_map(seed, w, h)
    region = largest_free_region(blocked)
    if region.sum() < 40:
        return  # too little room for the paper's target spacing
    cfg = WorldConfig(scenario=scenario, uavs=uavs, targets=4, d_sparse=2.0)
    s = generate_scenario(cfg, seed, ep, blocked)
    assert s.obstacles.shape == (w, h) and (s.obstacles == blocked).all()
    assert region[s.targets[:, 0], s.targets[:, 1]].all() and region[s.starts[:, 0], s.starts[:, 1]].all()
    assert len({tuple(c) for c in s.targets}) == 4 and len({tuple(c) for c in s.starts}) == uavs
    assert not {tuple(c) for c in s.targets} & {tuple(c) for c in s.starts}
    if scenario == "sparse":
        assert pairwise(s.targets).min() > 2.0
    again = generate_scenario(cfg, seed, ep, blocked)
    assert (again.targets == s.targets).all() and (again.starts == s.starts).all()


def test_episodes_without_a_fixed_map_are_the_ones_they_always_were():
    """The fixed-map option leaves the paper's generator, and every published result, untouched."""
    s = generate_scenario(WorldConfig(scenario="sparse", obstacles=0.1, uavs=3), 0, 0)
    t = generate_scenario(WorldConfig(scenario="sparse", obstacles=0.1, uavs=3), 0, 0, None)
    assert (s.targets == t.targets).all() and (s.obstacles == t.obstacles).all() and (s.starts == t.starts).all()


def test_a_fixed_map_too_small_for_the_episode_fails_naming_the_region():
    blocked = np.ones((10, 10), dtype=bool)
    blocked[:3, :3] = False  # 9 free cells
    with pytest.raises(ScenarioError, match="largest free region \\(9 cells\\)"):
        generate_scenario(WorldConfig(scenario="sparse", uavs=2, targets=4), 0, 0, blocked)
