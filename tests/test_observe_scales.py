"""The scales observation (swarmctl.world.observe_scales) and its network: hand-built cases, a
cell-by-cell reference, the bit-set BFS against the paths module's, the field's builder against the
simulator's, batch independence (shared tables, the few deciders' Python paths), the same shape on
every map, and the network's forward, backward, FLOPs and checkpoints."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from swarmctl.knowledge.model import Knowledge
from swarmctl.policy.checkpoint import load_checkpoint, save_checkpoint
from swarmctl.policy.qnet import ScalesQNetwork, make_network, parameter_count, scales_forward_flops
from swarmctl.world import SearchEnv, WorldConfig
from swarmctl.world import beliefs as beliefs_module
from swarmctl.world import observe_scales as scales_module
from swarmctl.world.beliefs import SCALES_VARIANT, VARIANT_CHANNELS, Beliefs, ObservationSettings
from swarmctl.world.observe import observe
from swarmctl.world.observe_scales import (
    CELLS_PER_PIXEL,
    CHANNELS,
    DISTANCE_CELLS,
    MARGIN,
    SCALE_CHANNELS,
    UNREACHED,
    pixel_steps,
)
from swarmctl.world.paths import UNREACHABLE, grid_distances
from tests.test_decide_few import random_beliefs
from tests.test_policy_conformance import CASES, field_beliefs, played

SIDE = 11
MID = SIDE // 2
CHANNEL = {name: i for i, name in enumerate(SCALE_CHANNELS)}
SETTINGS = ObservationSettings(window=SIDE, variant=SCALES_VARIANT)


def channel(obs: np.ndarray, scale: int, name: str) -> np.ndarray:
    """(..., S, S) one channel of one scale (cells a pixel) of observations (..., 24, S, S)."""
    return obs[..., CELLS_PER_PIXEL.index(scale) * len(SCALE_CHANNELS) + CHANNEL[name], :, :]


def one_vehicle(w, h, me, explored=None, obstacles=(), targets=(), others=(), step=0, step_limit=None) -> Beliefs:
    """The beliefs of one decider (vehicle 0) at `me` on a w x h map, everything explored unless
    `explored` says otherwise; `others`: (x, y, hovering) of the vehicles it knows of."""
    shape = (1, 1, w, h)
    seen = np.ones(shape, dtype=bool) if explored is None else np.asarray(explored, dtype=bool).reshape(shape)
    blocked, found = np.zeros(shape, dtype=bool), np.zeros(shape, dtype=bool)
    for x, y in obstacles:
        blocked[0, 0, x, y] = True
    for x, y in targets:
        found[0, 0, x, y] = True
    cells = [tuple(me)] + [(x, y) for x, y, _ in others]
    hovering = [False] + [hv for _, _, hv in others]
    phi = np.where(seen, found.astype(np.float32), 1.0)
    return Beliefs(
        seen,
        phi,
        blocked & seen,
        found & seen,
        np.array(cells)[None, None],
        np.array(hovering)[None, None],
        np.zeros((1, 1), dtype=int),
        [0],
        step,
        SETTINGS,
        step_limit=step_limit,
    )


def pixel_distance(obstacles: np.ndarray, x0: int, y0: int, k: int) -> np.ndarray:
    """(S, S) the distance channel of one scale (k cells a pixel) pixel by pixel: a BFS over the
    (S + 2 MARGIN)^2 pixels round the vehicle's, a pixel passable when a cell of it on the map is not an
    obstacle, the vehicle's always; d steps read d k less k // 2 per axis off the vehicle's pixel."""
    grid = SIDE + 2 * MARGIN
    passable = np.zeros((1, grid, grid), dtype=bool)
    for i in range(grid):
        for j in range(grid):
            x = x0 + (i - MARGIN - MID) * k - k // 2
            y = y0 + (j - MARGIN - MID) * k - k // 2
            cells = obstacles[max(x, 0) : max(x + k, 0), max(y, 0) : max(y + k, 0)]
            passable[0, i, j] = cells.size > 0 and not cells.all()
    source = np.zeros_like(passable)
    source[0, MARGIN + MID, MARGIN + MID] = True
    steps = grid_distances(passable, source)[0, MARGIN : MARGIN + SIDE, MARGIN : MARGIN + SIDE]
    off = (np.arange(SIDE) != MID).astype(int)
    cells = steps * k - (k // 2) * (off[:, None] + off[None, :])
    return np.where(steps == UNREACHABLE, 1.0, np.minimum(cells, DISTANCE_CELLS) / DISTANCE_CELLS)


def reference(beliefs: Beliefs, b: int, u: int) -> np.ndarray:
    """(21, S, S): the crop channels of one decider, pixel by pixel on a map padded with each channel's
    off-map value."""
    explored, obstacles = beliefs.explored[b, u], beliefs.obstacles[b, u]
    free = beliefs.targets[b, u] & ~beliefs.hover_cells[b, u]
    x0, y0 = beliefs.pos[b, u]
    unexplored = np.pad(~explored, 1, constant_values=False)
    near = unexplored[2:, 1:-1] | unexplored[:-2, 1:-1] | unexplored[1:-1, 2:] | unexplored[1:-1, :-2]
    frontier = explored & ~obstacles & near
    pad = SIDE * 9
    maps = {  # name: (map, off-map value, pooling)
        "unexplored": (~explored, 0.0, np.mean),
        "blocked": (obstacles, 1.0, np.mean),
        "free targets": (free, 0.0, np.sum),
        "frontier": (frontier, 0.0, np.max),
    }
    out = np.zeros((len(CELLS_PER_PIXEL), len(SCALE_CHANNELS), SIDE, SIDE))
    for s, k in enumerate(CELLS_PER_PIXEL):
        for name, (cells, fill, pooling) in maps.items():
            padded = np.pad(cells.astype(float), pad, constant_values=fill)
            for i in range(SIDE):
                for j in range(SIDE):
                    x = x0 + (i - MID) * k - k // 2 + pad
                    y = y0 + (j - MID) * k - k // 2 + pad
                    out[s, CHANNEL[name], i, j] = pooling(padded[x : x + k, y : y + k])
        out[s, CHANNEL["distance"]] = pixel_distance(obstacles, x0, y0, k)
        for n in np.flatnonzero(beliefs.others[b, u]):
            i, j = (beliefs.positions[b, u, n] - (x0, y0) + MID * k + k // 2) // k
            if 0 <= i < SIDE and 0 <= j < SIDE:
                out[s, CHANNEL["holding" if beliefs.hovering[b, u, n] else "searching"], i, j] += 1
    return out.reshape(-1, SIDE, SIDE)


def test_the_variant_is_registered_with_its_channels():
    assert VARIANT_CHANNELS[SCALES_VARIANT] == CHANNELS == 24 == ScalesQNetwork.in_channels
    assert isinstance(make_network(SCALES_VARIANT, SIDE), ScalesQNetwork)


def test_a_vehicle_in_a_corner_sees_off_the_map_as_blocked():
    obs = observe(one_vehicle(20, 20, (0, 0)))[0, 0]
    blocked = channel(obs, 1, "blocked")
    off = (np.arange(SIDE) < MID)[:, None] | (np.arange(SIDE) < MID)[None, :]
    assert (blocked[off] == 1).all() and (blocked[~off] == 0).all()
    assert (channel(obs, 1, "distance")[off] == 1).all() and (channel(obs, 1, "unexplored") == 0).all()
    assert np.isclose(channel(obs, 3, "blocked")[MID, MID], 5 / 9)  # 3 x 3 round (0, 0): 4 cells on the map
    assert np.isclose(channel(obs, 9, "blocked")[MID, MID], 56 / 81)  # 9 x 9: 5 x 5 on the map
    assert channel(obs, 1, "distance")[MID + 3, MID + 4] == np.float32(7 / DISTANCE_CELLS)


def test_a_target_held_by_a_hovering_teammate_is_not_free():
    beliefs = one_vehicle(20, 20, (10, 10), targets=[(12, 10), (10, 13)], others=[(12, 10, True), (8, 8, False)])
    obs = observe(beliefs)[0, 0]
    free = channel(obs, 1, "free targets")
    assert free[MID, MID + 3] == 1 and free.sum() == 1  # (10, 13) only: (12, 10) is held
    assert channel(obs, 1, "holding")[MID + 2, MID] == 1 and channel(obs, 1, "holding").sum() == 1
    assert channel(obs, 1, "searching")[MID - 2, MID - 2] == 1 and channel(obs, 1, "searching").sum() == 1
    # one free target, two vehicles searching (this one and the one at (8, 8)), a swarm of 3
    assert np.allclose(obs[21:, 0, 0], [(1 - 2) / 3, 1.0, 0.3]) and (obs[21:] == obs[21:, :1, :1]).all()


def test_frontier_cells_are_explored_free_cells_next_to_unexplored_ones():
    explored = np.zeros((20, 20), dtype=bool)
    explored[5:10, 5:10] = True
    beliefs = one_vehicle(20, 20, (7, 7), explored=explored, obstacles=[(5, 7)])
    frontier = channel(observe(beliefs)[0, 0], 1, "frontier")
    expected = np.zeros((20, 20), dtype=bool)
    expected[5:10, 5:10] = True
    expected[6:9, 6:9] = False  # inside: no unexplored neighbour
    expected[5, 7] = False  # a known obstacle is no frontier
    assert np.array_equal(frontier.astype(bool), expected[7 - MID : 7 + MID + 1, 7 - MID : 7 + MID + 1])
    assert channel(observe(beliefs)[0, 0], 3, "frontier")[MID, MID] == 0  # the 3 x 3 round the vehicle: inside


def test_the_path_distance_goes_round_a_wall_and_through_unexplored_cells():
    wall = [(12, y) for y in range(0, 15)]  # a wall east of the vehicle with a gap at y >= 15
    explored = np.ones((20, 20), dtype=bool)
    explored[14:, :] = False  # the far side unexplored: it counts as passable
    beliefs = one_vehicle(20, 20, (10, 10), explored=explored, obstacles=wall)
    distance = channel(observe(beliefs)[0, 0], 1, "distance")
    # (13, 10) is 3 cells east, behind the wall: up to y = 15, across, and down again
    assert distance[MID + 3, MID] == np.float32((5 + 3 + 5) / DISTANCE_CELLS)
    assert distance[MID + 2, MID] == 1  # on the wall: unreachable
    assert distance[MID - 4, MID] == np.float32(4 / DISTANCE_CELLS)
    assert distance[MID + 5, MID] == np.float32((5 + 5 + 5) / DISTANCE_CELLS)  # (15, 10): unexplored, passable


def test_a_detour_out_of_the_crop_is_seen_within_the_margin():
    # a wall from y = 0 to y = 16 at x = 12: the gap at y = 17 is 2 cells beyond the crop (y 5 .. 15)
    beliefs = one_vehicle(20, 20, (10, 10), obstacles=[(12, y) for y in range(0, 17)])
    distance = channel(observe(beliefs)[0, 0], 1, "distance")
    assert MARGIN >= 2 and distance[MID + 3, MID] == np.float32((7 + 3 + 7) / DISTANCE_CELLS)
    walled = one_vehicle(40, 40, (10, 10), obstacles=[(12, y) for y in range(0, 10 + MID + MARGIN + 1)])
    assert channel(observe(walled)[0, 0], 1, "distance")[MID + 3, MID] == 1  # the gap beyond the search: none


def test_the_coarse_scales_search_their_own_pixels():
    obs = observe(one_vehicle(64, 64, (30, 30)))[0, 0]  # an open map: the nearest cell's steps
    for k in CELLS_PER_PIXEL:
        distance = channel(obs, k, "distance") * DISTANCE_CELLS
        for i, j in [(MID + 1, MID), (MID, MID - 2), (MID + 1, MID + 1), (MID - 3, MID + 2)]:
            nearest = sum(max(abs(d) * k - k // 2, 0) for d in (i - MID, j - MID))
            assert np.isclose(distance[i, j], min(nearest, DISTANCE_CELLS)), (k, i, j)
    # a wall 3 cells thick (x = 32 .. 34: pixel MID + 1 of 3 cells) from y = 0 to 44 (pixel MID + 5 ends at 43)
    wall = [(x, y) for x in range(32, 35) for y in range(0, 45)]
    distance = channel(observe(one_vehicle(64, 64, (30, 30), obstacles=wall))[0, 0], 3, "distance")
    assert distance[MID + 1, MID] == 1  # the wall's pixel
    # the pixel east of it (cells 36 .. 38): round the wall's end, 5 pixels up, 2 across, 5 down
    assert np.isclose(distance[MID + 2, MID] * DISTANCE_CELLS, 12 * 3 - 1)


def test_the_scales_pixels_cover_1_3_and_9_cells():
    x, y = 30, 30
    beliefs = one_vehicle(64, 64, (x, y), targets=[(x + 4, y), (x, y - 13)])
    obs = observe(beliefs)[0, 0]
    for k in CELLS_PER_PIXEL:
        free = channel(obs, k, "free targets")
        east = MID + (4 + k // 2) // k  # the pixel holding the cell 4 east
        south = MID + (-13 + k // 2) // k
        seen = {(east, MID)} | ({(MID, south)} if south >= 0 else set())
        assert {tuple(c) for c in np.argwhere(free)} == seen, k
    explored = np.zeros((64, 64), dtype=bool)
    explored[: x + 1, :] = True  # up to the vehicle's column
    obs = observe(one_vehicle(64, 64, (x, y), explored=explored))[0, 0]
    unexplored = {k: channel(obs, k, "unexplored") for k in CELLS_PER_PIXEL}
    assert unexplored[1][MID, MID] == 0 and unexplored[1][MID + 1, MID] == 1
    assert np.isclose(unexplored[3][MID, MID], 1 / 3) and unexplored[3][MID + 1, MID] == 1  # x - 1 .. x + 1
    assert np.isclose(unexplored[9][MID, MID], 4 / 9) and unexplored[9][MID - 1, MID] == 0  # x - 4 .. x + 4


def test_the_steps_left_read_the_beliefs_step_limit():
    assert observe(one_vehicle(20, 20, (3, 3), step=10, step_limit=40))[0, 0, 22, 0, 0] == np.float32(0.75)
    assert observe(one_vehicle(20, 20, (3, 3), step=10))[0, 0, 22, 0, 0] == 1  # no limit known
    assert one_vehicle(20, 20, (3, 3), step_limit=40).select([0]).step_limit == 40


@pytest.mark.parametrize("seed, w, h, vehicles", [(0, 12, 9, 4), (1, 23, 30, 5), (2, 5, 40, 3)])
def test_the_observation_is_the_pixel_by_pixel_reference(seed, w, h, vehicles):
    """Random maps, known and unknown vehicles, some hovering, some sharing a cell, deciders on obstacles."""
    beliefs = random_beliefs(seed, 2, 2, vehicles, w, h, SIDE).with_settings(variant=SCALES_VARIANT)
    obs = observe(beliefs)
    assert obs.shape == (2, 2, CHANNELS, SIDE, SIDE) and obs.dtype == np.float32
    for b in range(2):
        for u in range(2):
            assert np.allclose(obs[b, u, :21], reference(beliefs, b, u), rtol=0, atol=1e-7), (b, u)


@pytest.mark.parametrize("seed, n, x, y", [(3, 4, 30, 20), (4, 9, 15, 15), (5, 1, 1, 7)])
def test_the_bitset_bfs_is_the_bfs_of_the_paths_module(seed, n, x, y):
    rng = np.random.default_rng(seed)
    passable = np.zeros((n, x + 2, y + 2), dtype=bool)
    passable[:, 1:-1, 1:-1] = rng.random((n, x, y)) < 0.7
    source = (int(rng.integers(0, x)), int(rng.integers(0, y)))
    sources = np.zeros((n, x, y), dtype=bool)
    sources[:, source[0], source[1]] = True
    expected = grid_distances(passable[:, 1:-1, 1:-1] | sources, sources)
    for limit in (DISTANCE_CELLS, 5):
        steps = pixel_steps(passable, source, limit)
        assert steps.dtype == np.uint8 and np.array_equal(steps, np.where(expected < limit, expected, UNREACHED))


@pytest.mark.parametrize("channel_model", ["ideal", "fixed"])
def test_the_field_and_the_simulator_observe_the_same(channel_model):
    for seed, steps in CASES:
        env = played(channel_model, seed, steps)
        sim = env.beliefs().with_settings(variant=SCALES_VARIANT, window=SIDE)
        for b in range(env.batch):
            field = field_beliefs(env, b).with_settings(variant=SCALES_VARIANT, window=SIDE)
            assert np.array_equal(observe(sim.select([b])), observe(field))


def test_a_deciders_observation_does_not_depend_on_the_rest_of_the_batch():
    env = played("fixed", 5, 8)
    beliefs = env.beliefs().with_settings(variant=SCALES_VARIANT, window=SIDE)
    whole = observe(beliefs)
    order = np.arange(env.batch)[::-1]
    assert np.array_equal(observe(beliefs.select(order)), whole[order])
    for b in (0, 3):
        assert np.array_equal(observe(beliefs.select([b]))[0], whole[b])


@pytest.mark.parametrize("channel_model", ["ideal", "fixed"])
def test_shared_tables_and_the_few_deciders_paths_observe_the_same(channel_model, monkeypatch):
    """Deciders with the same maps share a summed table (always for a few, by bytes; from SHARE_CELLS by
    numpy) and a few deciders' vehicles and held targets are Python arithmetic: all give the same."""
    env = played(channel_model, 6, 10)
    beliefs = env.beliefs().with_settings(variant=SCALES_VARIANT, window=SIDE)
    shared = scales_module.shared_rows(beliefs)
    if channel_model == "ideal":  # every vehicle knows what every other does: one table an episode
        assert np.array_equal(shared, np.repeat(np.arange(env.batch) * env.cfg.uavs, env.cfg.uavs))
    expected = [observe(beliefs.select([b]))[0] for b in range(env.batch)]
    small = beliefs_module.SMALL
    monkeypatch.setattr(scales_module, "SHARE_FEW", 0)
    for cells in (0, 1 << 40):  # shared and not
        monkeypatch.setattr(scales_module, "SHARE_CELLS", cells)
        assert np.array_equal(scales_module.shared_rows(beliefs), shared)
        assert np.array_equal(observe(beliefs), np.stack(expected))
        monkeypatch.setattr(beliefs_module, "SMALL", 0)  # no crews: the batched paths
        for b in range(env.batch):
            assert np.array_equal(observe(beliefs.select([b]))[0], expected[b])
        monkeypatch.setattr(beliefs_module, "SMALL", small)


def test_the_observation_has_one_shape_on_every_map_and_a_network_learns_from_it():
    net = ScalesQNetwork(SIDE)
    for size in (20, 50, 100):
        world = WorldConfig(map_size=size, uavs=2, targets=2, window=SIDE, variant=SCALES_VARIANT)
        obs = SearchEnv(world, batch=1).reset(seed=size)
        assert obs.shape == (1, 2, CHANNELS, SIDE, SIDE)
        q = net(torch.from_numpy(obs.reshape(2, CHANNELS, SIDE, SIDE)))
        assert q.shape == (2, 5)
        q.square().mean().backward()
        assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in net.parameters())
        net.zero_grad()


def test_the_networks_flops_and_parameters():
    net = ScalesQNetwork(SIDE)
    macs = 0

    def count(module: torch.nn.Module, _: tuple[torch.Tensor, ...], out: torch.Tensor) -> None:
        nonlocal macs
        per_output = module.weight[0].numel()
        macs += out.numel() * per_output

    for m in net.modules():
        if isinstance(m, torch.nn.Conv2d | torch.nn.Linear):
            m.register_forward_hook(count)
    net(torch.zeros(1, CHANNELS, SIDE, SIDE))
    assert scales_forward_flops(SIDE) == 2 * macs == 2_448_032
    assert parameter_count(net) == 126_661


def test_a_scales_model_is_saved_loaded_and_decides_in_the_simulator_and_the_field(tmp_path):
    path = tmp_path / "scales.pt"
    world = WorldConfig(variant=SCALES_VARIANT, window=SIDE)
    save_checkpoint(path, ScalesQNetwork(SIDE), world.as_dict(), {}, {})
    loaded, info = load_checkpoint(path)
    assert isinstance(loaded, ScalesQNetwork) and info["variant"] == SCALES_VARIANT and loaded.window == SIDE
    from swarmctl.mission.decide import FieldPolicy
    from swarmctl.policy.ddql import DDQLPolicy

    policy = DDQLPolicy(str(path))
    env = SearchEnv(world, batch=2)
    env.reset(seed=0)
    policy.reset(env.beliefs(), 0)
    decision = policy.decide(env.beliefs())
    assert decision.obs.shape == (2, world.uavs, CHANNELS, SIDE, SIDE) and decision.moves.shape == (2, world.uavs)
    field = FieldPolicy(f"ddql:{path}", seed=0)
    assert field.settings.variant == SCALES_VARIANT and field.settings.window == SIDE
    kn = Knowledge(50, 40, vehicle_id=1)
    kn.set_position(0, (10, 30))
    kn.sense_truth(np.zeros((50, 40)), np.zeros((50, 40), dtype=bool))
    choice = field.choose([kn], step=0, vehicles=3)[0]
    assert choice.q is not None and 0 <= choice.move < 5
