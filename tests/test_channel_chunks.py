"""Lossy channels do not depend on the batch: each message's loss is keyed by (seed, episode, step,
sender, receiver), so `swarmctl eval --batch` never changes a result, whatever the channel."""

import numpy as np
import pytest

from swarmctl.learn.evaluate import evaluate
from swarmctl.world import WorldConfig
from swarmctl.world.channel import Channel
from swarmctl.world.env import SearchEnv

LOSSY = [("model", 0.0), ("fixed", 0.3)]
EVERY = [("ideal", 0.0), ("none", 0.0), *LOSSY]


@pytest.mark.parametrize(("channel", "loss"), LOSSY)
def test_eval_per_episode_results_are_the_same_for_every_batch(channel, loss):
    cfg = WorldConfig(uavs=3, targets=4, obstacles=0.1, channel=channel, loss=loss)
    a, b, c = (
        evaluate(cfg, ["frontier"], 14, 3, 25, chunk=chunk, progress=False)[0]["per_episode"] for chunk in (1, 7, 250)
    )
    assert a == b == c


@pytest.mark.parametrize(("channel", "loss"), EVERY)
def test_eval_results_do_not_depend_on_the_chunk_size_under_any_channel(channel, loss):
    cfg = WorldConfig(uavs=3, targets=4, obstacles=0.1, channel=channel, loss=loss)
    specs = ["la:2", "frontier", "lawnmower", "random"]
    whole = evaluate(cfg, specs, 12, seed=3, steps=25, progress=False)
    chunked = evaluate(cfg, specs, 12, seed=3, steps=25, chunk=5, progress=False)
    for x, y in zip(whole, chunked):
        assert x["per_episode"] == y["per_episode"], x["policy"]
        assert x["steps_cdf"] == y["steps_cdf"] and x["collisions_per_episode"] == y["collisions_per_episode"]


@pytest.mark.parametrize(("channel", "loss"), [("fixed", 0.5), ("model", 0.0)])
def test_an_episode_loses_the_same_messages_alone_or_in_a_batch(channel, loss):
    cfg = WorldConfig(map_size=20, uavs=4, targets=4, channel=channel, loss=loss, cell_size=40.0)
    big = SearchEnv(cfg, batch=6, stop_at_success=False, observations=False)
    big.reset(seed=9, episodes=range(10, 16))
    alone = SearchEnv(cfg, batch=1, stop_at_success=False, observations=False)
    alone.reset(seed=9, episodes=[13])
    rng = np.random.default_rng(0)
    for _ in range(12):
        assert (big.known_pos[3] == alone.known_pos[0]).all() and (big.explored[3] == alone.explored[0]).all()
        assert (big.known_hover[3] == alone.known_hover[0]).all()
        moves = rng.integers(0, 5, (6, 4))
        big.step(moves)
        alone.step(moves[3:4])


def test_losses_are_keyed_by_seed_episode_step_sender_and_receiver():
    channel = Channel("fixed", loss=0.5)
    dist = np.zeros((2, 5, 5))
    episodes = np.array([4, 8])
    base = channel.lost(dist, 1, episodes, 3)
    assert base.shape == (2, 5, 5)
    assert 0.25 < base.mean() < 0.75
    # the same draws for the same key, in any batch
    assert (channel.lost(dist[:1], 1, episodes[1:], 3)[0] == base[1]).all()
    # another seed, episode or step: other draws
    assert (channel.lost(dist, 2, episodes, 3) != base).any()
    assert (channel.lost(dist, 1, episodes + 1, 3) != base).any()
    assert (channel.lost(dist, 1, episodes, 4) != base).any()
    # a link's two directions are separate messages, drawn separately
    assert (base != base.transpose(0, 2, 1)).any()
    # ideal never loses, none always does; neither draws
    assert not Channel("ideal").lost(dist, 1, episodes, 3).any()
    assert Channel("none").lost(dist, 1, episodes, 3).all()


def test_a_lossy_world_still_delivers_about_one_minus_p():
    env = SearchEnv(WorldConfig(channel="fixed", loss=0.3), batch=2000, stop_at_success=False, observations=False)
    env.reset(seed=1)
    assert (env.known_pos[:, 0, 1, 0] >= 0).mean() == pytest.approx(0.7, abs=0.04)
