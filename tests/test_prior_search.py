"""Searching with a prior and a detector that misses: swarmctl.world.prior, the simulator's passes,
detections and POS, the coordinated planner's density, and the `pos` finish line."""

import numpy as np
import pytest

from swarmctl.cli import main
from swarmctl.errors import ScenarioError
from swarmctl.learn.evaluate import run_policy
from swarmctl.policy.registry import make_policy
from swarmctl.world import prior as prior_model
from swarmctl.world.config import WorldConfig
from swarmctl.world.draws import DETECTIONS, uniform
from swarmctl.world.env import SearchEnv
from swarmctl.world.moves import EAST, STAY, WEST
from tests.helpers import make_env, make_scenario


# --- the formulas ---------------------------------------------------------------------------------
def test_pos_is_a_probability_that_grows_with_the_passes():
    rng = np.random.default_rng(0)
    free = rng.random((12, 9)) > 0.2
    prior = prior_model.normalise_prior(rng.random((12, 9)), free)
    assert prior.sum() == pytest.approx(1.0) and (prior[~free] == 0).all()
    passes = np.zeros((12, 9), dtype=np.uint8)
    for pod in (0.3, 0.7, 1.0):
        last = prior_model.pos(prior, passes, pod)
        assert last == 0.0
        for _ in range(6):
            more = prior_model.add_passes(passes, rng.random((12, 9)) > 0.5)
            now = prior_model.pos(prior, more, pod)
            assert 0.0 <= now <= 1.0 and now >= last - 1e-12
            last, passes = now, more
        passes = np.zeros((12, 9), dtype=np.uint8)
    counts = rng.integers(0, 5, (12, 9)).astype(np.uint8)  # the table of powers = the powers
    assert np.array_equal(prior_model.residual(prior, counts, 0.6), prior * 0.4 ** counts.astype(np.float64))
    assert prior_model.add_passes(np.full(3, 250, np.uint8), np.full(3, 9)).tolist() == [255] * 3


def test_with_pod_1_and_a_uniform_prior_pos_is_the_explored_share_and_density_the_unexplored_map():
    free = np.ones((7, 5), dtype=bool)
    free[2, 3] = False
    explored = np.zeros((7, 5), dtype=bool)
    explored[:3] = True
    prior = prior_model.uniform_prior(free)
    assert prior_model.pos(prior, explored, 1.0) == pytest.approx((explored & free).sum() / free.sum())
    density = prior_model.density(prior, explored, 1.0, free)
    assert density.dtype == np.float32 and np.allclose(density[free], (~explored)[free])


@pytest.mark.parametrize(
    "weights, match",
    [(-np.ones((3, 3)), ">= 0"), (np.full((3, 3), np.nan), "finite"), (np.zeros((3, 3)), "no weight")],
)
def test_bad_priors_and_pods_are_refused_with_what_to_fix(weights, match):
    with pytest.raises(ScenarioError, match=match):
        prior_model.normalise_prior(weights, np.ones((3, 3), dtype=bool))
    for pod in (0.0, 1.5, float("nan")):
        with pytest.raises(ScenarioError, match="probability of detection"):
            prior_model.check_pod(pod)
    with pytest.raises(ScenarioError, match="--pod"):
        WorldConfig(pod=0.0)
    with pytest.raises(ScenarioError, match="--pos-goal"):
        WorldConfig(pos_goal=1.2)


# --- the simulator --------------------------------------------------------------------------------
def test_a_pass_is_a_cell_entering_the_footprint_and_staying_adds_none():
    env = make_env(9, [[8, 8]], [[4, 4]], fov=1.0, finish="pos")
    disc = env.passes.reshape(9, 9).copy()
    assert disc.sum() == 5 and disc[4, 4] == 1  # the start's disc: a pass
    env.step(np.array([[STAY]]))
    assert np.array_equal(env.passes.reshape(9, 9), disc)  # staying: no pass
    env.step(np.array([[EAST]]))  # (6, 4), (5, 3), (5, 5) enter the footprint; (4, 4), (5, 4) stay in it
    env.step(np.array([[WEST]]))  # back: (3, 4), (4, 3), (4, 5) enter it again
    passes = env.passes.reshape(9, 9)
    assert passes[4, 4] == 1 and passes[5, 4] == 1 and passes[6, 4] == 1 and passes[5, 5] == 1
    assert passes[3, 4] == 2 and passes[4, 3] == 2 and passes[4, 5] == 2 and passes.sum() == 11
    assert env.team_pos()[0] == pytest.approx(8 / 81)  # pod 1, uniform: the explored share
    assert len(env.pos_trace) == 4


def test_a_target_in_the_disc_is_detected_with_the_draw_below_pod_and_else_stays_unknown():
    pod, misses = 0.5, 0
    for seed in range(12):
        env = SearchEnv(WorldConfig(map_size=9, uavs=1, targets=1, fov=1.0, pod=pod, finish="found"), batch=1)
        env.reset_to([make_scenario(9, [[4, 5]], [[4, 4]])], seed=seed)
        detected = uniform(seed, env.episodes, 0, env._decider_ids, DETECTIONS, (1,))[0, 0, 0] < pod
        b = env.beliefs()
        assert bool(b.targets[0, 0, 4, 5]) == detected == (env.found_step[0, 0] == 0)
        if not detected:
            misses += 1
            assert not env.hovering_now().any() and b.phi_hat[0, 0, 4, 4] == 0.0  # nothing shows it
            assert b.density[0, 0, 4, 5] == pytest.approx(0.5)  # one pass at pod 0.5: half the prior left
            assert b.uniform_density[0, 0, 4, 5] == pytest.approx(0.5)
    assert 0 < misses < 12


def test_detections_and_pos_do_not_depend_on_the_batch():
    cfg = WorldConfig(
        scenario="prior", map_size=12, uavs=2, targets=3, pod=0.6, finish="pos", channel="fixed", loss=0.3
    )
    weights = np.add.outer(np.arange(12.0), np.arange(12.0))

    def play(episodes):
        env = SearchEnv(cfg, batch=len(episodes), observations=False)
        env.reset(7, episodes, prior=weights)
        policy = make_policy("coordinated:hover=no")
        policy.reset(env.beliefs(), 7)
        for _ in range(12):
            env.step(policy.act(env.beliefs()))
        passes = env.passes.reshape(env.batch, 12, 12)
        assert np.allclose(env.team_pos(), prior_model.pos(env.prior, passes, cfg.pod), rtol=0, atol=1e-12)
        return np.stack(env.pos_trace, 1), env.found_step, env.known_targets, env.believed_passes

    together = play([0, 1, 2])
    for i in range(3):
        alone = play([i])
        for a, b in zip(together, alone):
            assert np.array_equal(a[i], b[0])


def test_the_prior_scenario_draws_the_targets_where_the_prior_is():
    weights = np.zeros((10, 10))
    weights[7:, 7:] = 1.0
    env = SearchEnv(WorldConfig(scenario="prior", map_size=10, uavs=2, targets=4), batch=5, observations=False)
    env.reset(1, prior=weights)
    assert (env.targets >= 7).all()
    with pytest.raises(ScenarioError, match="shape"):
        env.reset(1, prior=np.ones((9, 10)))


def test_the_pos_finish_line_ends_the_episode_when_pos_reaches_the_goal():
    env = make_env(10, [[9, 9]], [[0, 5]], fov=1.0, finish="pos", pos_goal=0.1)
    steps = 0
    while not env.done[0]:
        env.step(np.array([[EAST]]))
        steps += 1
    trace = np.array(env.pos_trace)[:, 0]
    assert trace[-1] >= 0.1 - 1e-9 > trace[-2] and env.pos_step[0] == steps == env.duration[0]


# --- the planner ----------------------------------------------------------------------------------
def test_with_pod_1_and_no_prior_the_planner_moves_as_it_did():
    cfg = WorldConfig(map_size=14, uavs=3, targets=3, obstacles=0.1, channel="fixed", loss=0.4)
    env = SearchEnv(cfg, batch=6, stop_at_success=False, observations=False)
    env.reset(5)
    plain, blind = make_policy("coordinated"), make_policy("coordinated:prior=no")
    plain.reset(env.beliefs(), 5)
    blind.reset(env.beliefs(), 5)
    for _ in range(25):
        b = env.beliefs()
        assert np.array_equal(b.density, ~b.explored) and b.density is b.uniform_density
        moves = plain.act(b)
        assert np.array_equal(moves, blind.act(b))
        env.step(moves)


def test_the_planner_that_weighs_the_prior_heads_for_the_hotspot_first():
    weights = np.ones((15, 15))
    weights[:4, :] = 40.0  # the west strip holds most of the probability
    cfg = WorldConfig(map_size=15, uavs=1, targets=1, finish="pos", fov=2.0)
    for spec, west in (("coordinated:hover=no", True), ("coordinated:prior=no:hover=no", False)):
        env = SearchEnv(cfg, batch=1, observations=False)
        env.reset_to([make_scenario(15, [[14, 14]], [[9, 7]])], prior=weights)
        policy = make_policy(spec)
        policy.reset(env.beliefs(), 0)
        for _ in range(6):
            env.step(policy.act(env.beliefs()))
        assert (env.pos[0, 0, 0] <= 5) == west


def test_eval_reports_pos_and_takes_a_hotspot_prior_and_refuses_a_bad_one(tmp_path, capsys):
    cfg = WorldConfig(scenario="prior", map_size=10, uavs=2, targets=2, finish="pos", pos_goal=0.5, pod=0.8)
    r = run_policy(cfg, "coordinated", 3, 0, 40, progress=False, prior=np.ones((10, 10)))
    assert r["pos_goal_rate"] == r["success_rate"] and 0 < r["mean_final_pos"] <= 1
    assert len(r["pos_by_step"]) == 41 and r["pos_by_step"][0] > 0
    assert r["mean_pos_goal_steps"] == r["mean_steps"]
    base = ["--map", "10", "--uavs", "2", "--targets", "2", "--episodes", "2", "--steps", "5", "--no-progress"]
    ok = main(["eval", *base, "--policy", "coordinated", "--prior", "hotspot:0.7:0.2:3", "--pod", "0.7"])
    assert ok == 0 and "prior hotspot:0.7:0.2:3" in capsys.readouterr().out
    np.savez(tmp_path / "p.npz", prior=np.ones((9, 10)))
    for prior, says in ((str(tmp_path / "p.npz"), "shape"), ("hotspot:2:0.2", "share"), ("hotspot:x", "hotspot:")):
        assert main(["eval", *base, "--policy", "coordinated", "--prior", prior]) == 2
        err = capsys.readouterr().err
        assert says in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_with_a_detector_that_misses_the_planner_never_stops_passing():
    """No cell is ever cleared below pod 1: a vehicle whose best goal were its own cell would stay, and
    staying makes no pass; the planner flies on (every step adds passes)."""
    env = SearchEnv(WorldConfig(map_size=10, uavs=2, targets=2, pod=0.5, finish="pos", pos_goal=1.0), batch=2)
    env.reset(4, prior=np.ones((10, 10)))
    policy = make_policy("coordinated:hover=no")
    policy.reset(env.beliefs(), 4)
    for _ in range(40):
        before = env.passes.sum(1, dtype=np.int64)
        env.step(policy.act(env.beliefs()))
        assert (env.passes.sum(1, dtype=np.int64) > before).all()
