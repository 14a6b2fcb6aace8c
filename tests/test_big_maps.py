"""The big-map model's pieces: the global-local observation, its network and checkpoints, the city
maps, the curriculum, the exploration reward, and a resumable training run."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.knowledge.model import Knowledge
from swarmctl.learn.city_maps import CityMaps
from swarmctl.learn.curriculum import CURRICULA, Curriculum
from swarmctl.learn.ddql import TrainConfig, replay_path, train
from swarmctl.policy.checkpoint import load_checkpoint, save_checkpoint
from swarmctl.policy.qnet import GlobalLocalQNetwork, QNetwork, make_network
from swarmctl.world import SearchEnv, WorldConfig
from swarmctl.world.beliefs import GLOBAL_LOCAL_VARIANT
from swarmctl.world.observe_global import bin_edges, pooled_around


def brute_pool(m: np.ndarray, pos, side: int, fill: float) -> np.ndarray:
    """pooled_around for one map and channel, cell by cell."""
    w, h = m.shape
    big = np.full((3 * w, 3 * h), fill)
    big[w : 2 * w, h : 2 * h] = m
    crop = big[w + pos[0] - (w - 1) : w + pos[0] + w, h + pos[1] - (h - 1) : h + pos[1] + h]
    sx, ex = bin_edges(2 * w - 1, side)
    sy, ey = bin_edges(2 * h - 1, side)
    return np.array([[crop[sx[i] : ex[i], sy[j] : ey[j]].mean() for j in range(side)] for i in range(side)])


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(3, 30), st.integers(3, 30), st.sampled_from([4, 8, 20]))
def test_the_pooled_whole_map_is_the_mean_of_each_bin_around_the_vehicle(seed, w, h, side):
    rng = np.random.default_rng(seed)
    maps = rng.random((2, 1, w, h)).astype(np.float32)
    pos = np.stack([rng.integers(0, w, 2), rng.integers(0, h, 2)], axis=1)
    got = pooled_around(maps, pos, side, np.array([-0.2]))
    for n in range(2):
        assert np.allclose(got[n, 0], brute_pool(maps[n, 0], pos[n], side, -0.2), atol=1e-5)


def test_the_global_local_observation_sees_the_whole_map_at_any_size():
    for size in (12, 20, 50):
        env = SearchEnv(WorldConfig(map_size=size, uavs=3, targets=4, variant=GLOBAL_LOCAL_VARIANT), batch=2)
        obs = env.reset(seed=1)
        assert obs.shape == (2, 3, 7, 20, 20)
        paper = SearchEnv(WorldConfig(map_size=size, uavs=3, targets=4), batch=2).reset(seed=1)
        assert np.array_equal(obs[:, :, :3], paper)  # channels 0-2 are the paper's
        # one unexplored cell in a far corner: every vehicle sees it in its pooled map, wherever it is
        env.explored[:] = True
        env.explored[:, :, size - 1, size - 1] = False
        pooled = env.observe()[:, :, 3]
        assert (pooled.reshape(2, 3, -1).max(-1) > 0).all()
        assert (env.observe()[:, :, 3].sum((-1, -2)) > 0).all()


def test_a_global_local_model_is_saved_loaded_and_flown_from_the_field(tmp_path):
    net = GlobalLocalQNetwork(20)
    path = tmp_path / "gl.pt"
    save_checkpoint(path, net, WorldConfig(variant=GLOBAL_LOCAL_VARIANT).as_dict(), {}, {})
    loaded, info = load_checkpoint(path)
    assert isinstance(loaded, GlobalLocalQNetwork) and info["variant"] == GLOBAL_LOCAL_VARIANT
    from swarmctl.mission.decide import FieldPolicy

    policy = FieldPolicy(f"ddql:{path}", seed=0)
    assert policy.settings.variant == GLOBAL_LOCAL_VARIANT
    kn = Knowledge(50, 40, vehicle_id=1)
    kn.set_position(0, (10, 30))
    kn.sense_truth(np.zeros((50, 40)), np.zeros((50, 40), dtype=bool))
    choice = policy.choose([kn], step=0, vehicles=3)[0]
    assert choice.q is not None and 0 <= choice.move < 5
    # a paper model evaluates in a world of the other variant: it observes in its own
    env = SearchEnv(WorldConfig(variant=GLOBAL_LOCAL_VARIANT), batch=1)
    env.reset(seed=0)
    from swarmctl.policy.ddql import DDQLPolicy

    paper = tmp_path / "paper.pt"
    save_checkpoint(paper, QNetwork(20), WorldConfig().as_dict(), {}, {})
    p = DDQLPolicy(str(paper))
    p.reset(env.beliefs(), 0)
    assert p.decide(env.beliefs()).obs.shape[2] == 3


def test_a_checkpoint_whose_variant_does_not_fit_its_network_is_refused(tmp_path):
    path = tmp_path / "odd.pt"
    save_checkpoint(path, QNetwork(20), {}, {}, {})
    payload = torch.load(path, weights_only=True)
    payload["variant"] = GLOBAL_LOCAL_VARIANT
    torch.save(payload, path)
    from swarmctl.errors import InputError

    with pytest.raises(InputError, match="does not go with"):
        load_checkpoint(path)


def test_city_maps_block_about_the_fraction_asked():
    maps = CityMaps.load()
    rng = np.random.default_rng(3)
    for fraction in (0.05, 0.1, 0.2):
        got = [maps.sample(rng, 40, 50, fraction).mean() for _ in range(6)]
        assert abs(np.mean(got) - fraction) < 0.06 and all(g.shape == () for g in got)


def test_the_curriculum_is_the_same_for_the_same_seed_and_grows_the_maps():
    base = WorldConfig(variant=GLOBAL_LOCAL_VARIANT)
    a, b = Curriculum(CURRICULA["city"], base, 5), Curriculum(CURRICULA["city"], base, 5)
    early = [a.world(r, 0.0) for r in range(6)]
    assert [w.name for w in early] == [b.world(r, 0.0).name for r in range(6)]
    late = [a.world(r, 0.95) for r in range(20)]
    assert max(w.cfg.map_size for w in early) <= 24 < max(w.cfg.map_size for w in late)
    assert all(w.cfg.window == 20 and w.cfg.variant == GLOBAL_LOCAL_VARIANT for w in early + late)
    for w in late[:5]:  # every drawn world holds its episodes
        SearchEnv(w.cfg, batch=2).reset(seed=0, blocked=w.blocked)


def test_the_exploration_reward_pays_for_new_cells_only():
    env = SearchEnv(WorldConfig(map_size=20, uavs=1, targets=1, explore_reward=1.0), batch=1, stop_at_success=False)
    env.reset(seed=0)
    x, y = env.pos[0, 0]
    move = 2 if x < 19 else 4  # east, or west at the border
    _, r1, _, _ = env.step(np.array([[move]]))
    _, r2, _, _ = env.step(np.array([[4 if move == 2 else 2]]))  # back where it came from: nothing new
    assert 0.0 < r1[0, 0] <= 7 / 29 + 1e-6 and r2[0, 0] == pytest.approx(0.0)


def small_run(**kw) -> TrainConfig:
    return TrainConfig(
        episodes=16,
        parallel_envs=4,
        prefill_episodes=4,
        eval_every=8,
        eval_episodes=8,
        batch_size=16,
        replay_capacity=3000,
        threads=1,
        curriculum="smoke",
        keep_resume=True,
        **kw,
    )


def test_a_stopped_run_resumes_bit_for_bit_and_a_lost_replay_is_refilled(tmp_path, capsys):
    world = WorldConfig(variant=GLOBAL_LOCAL_VARIANT, window=8, explore_reward=0.5)
    train(world, small_run(), 0, tmp_path / "straight.pt", progress=False)
    rounds = []

    def stop() -> bool:
        rounds.append(1)
        return len(rounds) == 2

    first = train(world, small_run(), 0, tmp_path / "resumed.pt", progress=False, stop=stop)
    assert first["stopped"] and first["episodes"] == 8 and replay_path(tmp_path / "resumed.pt").is_file()
    last = train(world, small_run(), 0, tmp_path / "resumed.pt", progress=False, resume=True)
    assert last["episodes"] == 16
    a, _ = load_checkpoint(tmp_path / "straight.pt")
    b, info = load_checkpoint(tmp_path / "resumed.pt")
    assert all(torch.equal(x, y) for x, y in zip(a.parameters(), b.parameters()))
    assert info["resume"] is None  # a finished run keeps no resume state
    rounds.clear()
    train(world, small_run(), 0, tmp_path / "lost.pt", progress=False, stop=stop)
    replay_path(tmp_path / "lost.pt").unlink()
    train(world, small_run(), 0, tmp_path / "lost.pt", progress=False, resume=True)
    assert "refilling the replay" in capsys.readouterr().out


def test_a_paper_model_starts_a_global_local_one_with_its_convolutions(tmp_path):
    paper = tmp_path / "paper.pt"
    net = QNetwork(8)
    save_checkpoint(paper, net, WorldConfig(window=8).as_dict(), {}, {})
    world = WorldConfig(variant=GLOBAL_LOCAL_VARIANT, window=8)
    cfg = TrainConfig(
        episodes=4,
        parallel_envs=4,
        prefill_episodes=0,
        eval_every=4,
        eval_episodes=4,
        batch_size=64,
        replay_capacity=2000,
        threads=1,
    )
    train(world, cfg, 0, tmp_path / "gl.pt", init=paper, progress=False)
    gl, _ = load_checkpoint(tmp_path / "gl.pt")
    assert isinstance(gl, GlobalLocalQNetwork)
    assert make_network(GLOBAL_LOCAL_VARIANT, 8).local[0].weight.shape == gl.local[0].weight.shape
