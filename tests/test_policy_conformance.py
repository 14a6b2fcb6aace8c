"""Conformance of every policy on the simulator and the field adapter (in the manner of PettingZoo's
parallel_api_test): the same knowledge, built by SearchEnv.beliefs and by the controller's
beliefs_from_knowledge, gives the same beliefs, the same observation tensor and the same moves; moves
are valid, reproducible, and independent of how episodes are batched."""

from __future__ import annotations

from functools import cached_property

import numpy as np
import pytest

from swarmctl.knowledge.model import Knowledge, Position, beliefs_from_knowledge
from swarmctl.learn.ddql import TrainConfig, train
from swarmctl.policy.registry import make_policy
from swarmctl.world import SearchEnv, WorldConfig
from swarmctl.world.beliefs import SCALES_VARIANT, Beliefs
from swarmctl.world.observe import observe

# sigma2 small: phi is exactly 1 on targets and 0 elsewhere, so the field's quantised phi equals the
# simulator's and the two builders can be compared bit for bit
WORLD = dict(map_size=12, uavs=3, targets=4, obstacles=0.1, window=8, sigma2=0.01)
PLANNERS = ["random", "la:3", "frontier", "lawnmower"]


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    out = tmp_path_factory.mktemp("conformance") / "tiny.pt"
    cfg = TrainConfig(
        episodes=16,
        parallel_envs=8,
        prefill_episodes=8,
        eval_every=16,
        eval_episodes=4,
        batch_size=16,
        replay_capacity=2000,
        threads=1,
    )
    train(WorldConfig(**WORLD), cfg, seed=0, out=out, progress=False)
    return out


def specs(model):
    return PLANNERS + [
        f"ddql:{model}",
        f"ddql-greedy:{model}",
        f"ddql:{model}:taken=keep:hover=no:mask=no",
        f"ddql:{model}:straggler=frontier",
    ]


def played(channel: str, seed: int, steps: int) -> SearchEnv:
    """A batch of episodes after `steps` joint moves of the frontier planner with some random moves
    mixed in: vehicles reach targets and hover, others sit on them, knowledge differs under loss."""
    env = SearchEnv(WorldConfig(**WORLD, channel=channel, loss=0.4), batch=6, stop_at_success=False, observations=False)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    planner = make_policy("frontier")
    planner.reset(env.beliefs(), seed)
    for _ in range(steps):
        moves = planner.act(env.beliefs())
        wild = rng.random(moves.shape) < 0.2
        env.step(np.where(wild, rng.integers(0, 5, moves.shape), moves))
    return env


def knowledge_of(env: SearchEnv, b: int, v: int) -> Knowledge:
    """What the controller's agent v would hold had it lived episode b: its explored cells with their
    phi and obstacles, the positions (and hover flags) it has received, each with the step it came at."""
    k = Knowledge(env.width, env.height, vehicle_id=v)
    x, y = np.nonzero(env.explored[b, v])
    k.sense(np.stack([x, y], 1), env.phi[b, x, y], env.obstacles[b, x, y])
    for u in range(env.uavs):
        cell = env.known_pos[b, v, u]
        if cell[0] >= 0:
            heard = int(env.heard[b, v, u])  # the step of the report v last received from u
            k.merge_position(u, Position(heard, (int(cell[0]), int(cell[1])), bool(env.known_hover[b, v, u])))
    k.add_targets(np.argwhere(env.explored[b, v] & env.target_mask[b]), env.t)
    return k


def field_beliefs(env: SearchEnv, b: int) -> Beliefs:
    ks = [knowledge_of(env, b, v) for v in range(env.uavs)]
    hovering = env.hovering_now()[b].tolist()
    return beliefs_from_knowledge(ks, env.uavs, env.settings, env.t, hovering, episode=int(env.episodes[b]))


CASES = [(0, 0), (1, 4), (2, 10), (3, 18)]


def test_the_cases_cover_hovering_taken_targets_stragglers_and_unknown_peers():
    seen = {"hovering": False, "taken": False, "straggler": False, "unknown peer": False}
    for channel in ("ideal", "fixed"):
        for seed, steps in CASES:
            b = played(channel, seed, steps).beliefs()
            seen["hovering"] |= bool(b.hovering.any())
            seen["taken"] |= bool(b.taken.any())
            seen["straggler"] |= bool(b.last_searching().any())
            seen["unknown peer"] |= bool((b.positions < 0).any())
    assert all(seen.values()), seen


@pytest.mark.parametrize("channel", ["ideal", "none", "fixed"])
@pytest.mark.parametrize("seed, steps", CASES)
def test_both_builders_give_the_same_beliefs_observations_and_moves(model, channel, seed, steps):
    env = played(channel, seed, steps)
    sim = env.beliefs()
    for b in range(env.batch):
        one, field = sim.select([b]), field_beliefs(env, b)
        for name in Beliefs.FIELDS:
            assert np.array_equal(getattr(one, name), getattr(field, name)), name
        for remove_taken in (False, True):
            assert np.array_equal(observe(one, remove_taken), observe(field, remove_taken))
        scales = {"variant": SCALES_VARIANT, "window": 11}  # the crops at 1, 3 and 9 cells a pixel
        assert np.array_equal(observe(one.with_settings(**scales)), observe(field.with_settings(**scales)))
        for spec in specs(model):
            a, c = make_policy(spec), make_policy(spec)
            a.reset(one, 7)
            c.reset(field, 7)
            assert np.array_equal(a.act(one), c.act(field)), spec


@pytest.mark.parametrize("channel", ["ideal", "fixed"])
def test_moves_are_valid_reproducible_and_independent_of_the_batch(model, channel):
    env = played(channel, 5, 4)
    beliefs = env.beliefs()
    for spec in specs(model):
        whole = make_policy(spec)
        whole.reset(beliefs, 11)
        moves = whole.act(beliefs)
        assert moves.shape == (env.batch, env.uavs) and moves.dtype.kind == "i"
        assert ((moves >= 0) & (moves < 5)).all(), spec
        again = make_policy(spec)
        again.reset(beliefs, 11)
        assert np.array_equal(again.act(beliefs), moves), spec
        for b in (2, 0):  # an episode alone, and in another order, moves as it did in the batch
            alone = make_policy(spec)
            alone.reset(beliefs.select([b]), 11)
            assert np.array_equal(alone.act(beliefs.select([b]))[0], moves[b]), spec


def test_beliefs_hold_no_truth():
    """Beliefs carry what vehicles know; the hidden target list and the true maps are not in them."""
    assert set(Beliefs.FIELDS) == {
        "explored",
        "phi_hat",
        "obstacles",
        "targets",
        "positions",
        "hovering",
        "me",
        "episodes",
        "step",
        "step_limit",
        "heard",
    }
    b = played("ideal", 3, 2).beliefs()
    derived = {k for k, v in vars(Beliefs).items() if isinstance(v, cached_property)}  # views of the fields
    public = {k for k in vars(b) if not k.startswith("_")} - derived
    properties = {k for k, v in vars(Beliefs).items() if isinstance(v, property)}  # phi_hat, obstacles, targets
    assert public | (properties & set(Beliefs.FIELDS)) == set(Beliefs.FIELDS) | {"settings"}
    assert not b.targets[~b.explored].any() and (b.phi_hat[~b.explored] == 1).all()
    assert not b.obstacles[~b.explored].any()
