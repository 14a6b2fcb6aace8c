"""Finish lines: `held` (the paper's success), `found` (every target sensed) and `covered` (every
reachable free cell sensed), in the world, in eval's results and through `swarmctl eval --finish`."""

import json

import numpy as np
import pytest

from swarmctl.cli import main
from swarmctl.errors import InputError, ScenarioError
from swarmctl.learn.evaluate import evaluate
from swarmctl.world import SearchEnv, WorldConfig
from swarmctl.world.moves import EAST, NORTH, STAY
from swarmctl.world.scenario import generate_scenario
from tests.helpers import make_env


def step(env, *moves):
    return env.step(np.array([moves]))


def test_found_succeeds_on_the_step_the_last_target_enters_a_disc_and_not_before():
    # fov 1: the disc is the cell and its 4 neighbours; target 0 is 2 north of vehicle 0, target 1 3 of vehicle 1
    env = make_env(10, [[0, 2], [9, 9]], [[0, 0], [9, 6]], fov=1.0, finish="found")
    assert (env.found_step == -1).all()
    _, _, success, _ = step(env, NORTH, NORTH)
    assert not success[0] and not env.done[0]
    assert env.found_step[0].tolist() == [1, -1]
    _, _, success, _ = step(env, NORTH, NORTH)  # vehicle 1 reaches (9, 8): (9, 9) enters its disc
    assert success[0] and env.done[0] and env.duration[0] == 2
    assert env.found_step[0].tolist() == [1, 2]
    step(env, EAST, STAY)  # frozen, as under held
    assert tuple(env.pos[0, 0]) == (0, 2)


def test_found_at_reset_is_step_0_and_success_comes_after_the_first_move():
    env = make_env(8, [[1, 0], [6, 7]], [[0, 0], [6, 6]], fov=1.0, finish="found")
    assert env.found_step[0].tolist() == [0, 0] and not env.done[0]
    _, _, success, _ = step(env, STAY, STAY)
    assert success[0] and env.duration[0] == 1


def test_held_is_unchanged_and_later_than_found_on_the_same_moves():
    moves = [(EAST, NORTH), (STAY, NORTH), (NORTH, STAY)]
    durations, rewards = {}, {}
    for finish in ("held", "found"):
        env = make_env(8, [[1, 0], [6, 7]], [[0, 0], [6, 5]], fov=1.0, finish=finish, stop_at_success=False)
        for t, (a, b) in enumerate(moves, 1):
            _, reward, success, _ = step(env, a, b)
            rewards.setdefault(finish, []).append(reward[0].tolist())
            if success[0] and finish not in durations:
                durations[finish] = t
    assert durations == {"found": 1, "held": 2}  # held: both on targets only after the second move
    assert rewards["held"] == rewards["found"] == [[1, 0], [1, 1], [0, 1]]  # the reward never reads it
    assert WorldConfig().finish == "held"


def test_covered_succeeds_when_the_last_reachable_cell_is_sensed_and_ignores_a_pocket():
    # 5 x 5, a wall at x = 1 closes off the column x = 0 (5 cells nobody can reach, never sensed with fov 1)
    wall = [(1, y) for y in range(5)]
    env = make_env(5, [[4, 2]], [[3, 0]], obstacles=wall, fov=1.0, finish="covered")
    assert env.covered_fraction()[0] == pytest.approx(4 / 15)
    for t in range(1, 4):
        _, _, success, _ = step(env, NORTH)
        assert not success[0] and env.covered_fraction()[0] < 1.0, t
    _, _, success, _ = step(env, NORTH)  # at (3, 4): (2, 4) and (4, 4), the last reachable cells
    assert success[0] and env.done[0] and env.duration[0] == 4
    assert env.covered_fraction()[0] == 1.0
    assert not env.explored[0, 0, 0].any()  # the pocket was never sensed, yet the map counts as covered


def test_covered_fraction_is_only_for_covered_worlds():
    with pytest.raises(ValueError, match="covered"):
        make_env(6, [[5, 5]], [[0, 0]], finish="found").covered_fraction()


@pytest.mark.parametrize("channel", ["none", "model"])
def test_the_sensed_union_equals_the_union_of_the_vehicles_knowledge(channel):
    cfg = WorldConfig(map_size=10, uavs=3, targets=3, window=10, channel=channel, finish="covered")
    env = SearchEnv(cfg, batch=4, stop_at_success=False, observations=False)
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(8):
        env.step(rng.integers(0, 5, size=(4, 3)))
        assert (env._sensed.reshape(env.explored[:, 0].shape) == env.explored.any(1)).all()


def test_fewer_targets_than_vehicles_are_accepted_off_held_and_refused_under_held():
    for finish in ("found", "covered"):
        cfg = WorldConfig(targets=1, uavs=3, finish=finish)
        s = generate_scenario(cfg, 0, 0)
        assert len(s.targets) == 1 and len(s.starts) == 3
    with pytest.raises(ScenarioError, match=r"--targets 1 < --uavs 3: .*--finish found\|covered"):
        WorldConfig(targets=1, uavs=3)
    with pytest.raises(ScenarioError, match="--finish"):
        WorldConfig(finish="someday")


WORLD = dict(map_size=8, uavs=2, targets=3, obstacles=0.1, window=8)


@pytest.mark.parametrize("finish", ["held", "found", "covered"])
def test_eval_results_carry_the_finish_line_and_its_figures(finish):
    # random: on these episodes some succeed and some fail under every finish line
    (r,) = evaluate(WorldConfig(**WORLD, finish=finish), ["random"], episodes=10, seed=2, steps=40, progress=False)
    per = r["per_episode"]
    assert 0 < r["success_rate"] < 1
    assert r["finish"] == finish == r["scenario"]["finish"]
    assert np.mean([e["success"] for e in per]) == pytest.approx(r["success_rate"])
    assert np.mean([e["steps"] for e in per]) == pytest.approx(r["mean_steps"])
    if finish == "held":
        assert r["oracle_mean_steps"] > 0 and r["duration_ratio_to_oracle"] > 0
    else:
        assert r["oracle_mean_steps"] is None and r["duration_ratio_to_oracle"] is None
    assert ("mean_first_find_steps" in r) == (finish == "found")
    assert ("mean_covered_fraction" in r) == (finish == "covered")
    if finish == "found":
        firsts = []
        for e in per:
            found = e["found_steps"]
            assert len(found) == 3
            known = [s for s in found if s is not None]
            assert known == sorted(known) and found[: len(known)] == known
            assert e["success"] == (len(known) == 3)
            if e["success"]:
                assert e["steps"] == max(1, known[-1])
            firsts.append(known[0] if known else 40)
        assert r["mean_first_find_steps"] == pytest.approx(np.mean(firsts))
    if finish == "covered":
        fractions = [e["covered_fraction"] for e in per]
        assert all(0 < f <= 1 for f in fractions)
        assert all((f == 1.0) == e["success"] for f, e in zip(fractions, per))
        assert r["mean_covered_fraction"] == pytest.approx(np.mean(fractions))


def test_found_results_do_not_depend_on_the_batch():
    world = WorldConfig(**{**WORLD, "uavs": 3, "targets": 1}, finish="found")
    a, b = (
        evaluate(world, ["la:2", "random"], episodes=8, seed=4, steps=12, chunk=chunk, progress=False)
        for chunk in (1, 7)
    )
    for x, y in zip(a, b):
        x.pop("decision_ms_per_vehicle"), y.pop("decision_ms_per_vehicle")
        assert x == y


def test_the_oracle_bound_is_refused_off_held():
    with pytest.raises(InputError, match="--finish held only"):
        evaluate(WorldConfig(finish="covered"), ["random", "oracle"], episodes=2, seed=0, steps=5, progress=False)


def test_eval_cli_finish_found(tmp_path, capsys):
    out = tmp_path / "r.json"
    args = ["eval", "--map", "10", "--window", "10", "--uavs", "3", "--targets", "1", "--episodes", "6"]
    args += ["--steps", "20", "--batch", "4", "--policy", "frontier", "--no-progress"]
    assert main([*args, "--finish", "found", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "finish found" in text.splitlines()[0]
    row = next(line for line in text.splitlines() if line.startswith("frontier")).split()
    assert row[3] == "-"  # no oracle column off held
    (r,) = json.loads(out.read_text())["results"]
    assert r["finish"] == "found" and "mean_first_find_steps" in r and "found_steps" in r["per_episode"][0]

    assert main(args) == 2  # held, the default: 1 target for 3 vehicles is refused
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--finish found|covered" in err
    assert main([*args, "--finish", "covered", "--policy", "oracle"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--finish held only" in err
