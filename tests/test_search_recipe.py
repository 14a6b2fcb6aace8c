"""The search recipe (swarmctl.learn.search_recipe): the team reward, n-step returns, the margin loss,
the demonstrations, the rules, a tiny run that stops and resumes, the held-out city, the command."""

from __future__ import annotations

import importlib.util
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from hypothesis import given
from hypothesis import strategies as st

from swarmctl.cli import cli as root
from swarmctl.cli_options import FieldOption, field_default
from swarmctl.errors import InputError
from swarmctl.learn.cli import SEARCH_FIELDS
from swarmctl.learn.search_config import SEARCH_CURRICULA, SearchConfig, SearchStage, StageWorld
from swarmctl.learn.search_recipe import (
    CityCrops,
    RewardWeights,
    SearchTrainer,
    encode_label,
    labelled_moves,
    margin_loss,
    nstep_returns,
    rollout,
    search_mask,
    split_counts,
    step_team,
    train,
    trajectories,
)
from swarmctl.mission.decide import FieldPolicy
from swarmctl.policy.base import allowed_moves
from swarmctl.policy.coordinated import CoordinatedPolicy
from swarmctl.policy.registry import make_policy
from swarmctl.world.config import WorldConfig
from swarmctl.world.env import SearchEnv
from swarmctl.world.moves import STAY
from swarmctl.world.scenario import Scenario

ROOT = Path(__file__).resolve().parent.parent
N, E, S, W = 1, 2, 3, 4
C, T, STEP, SUCCESS, COLLISION = 0.01, 1.0, 0.05, 10.0, 1.0
WEIGHTS = RewardWeights(target=T, cell=C, step=STEP, success=SUCCESS, collision=COLLISION)


def hand_env(starts, targets, size: int = 8, fov: float = 1.0) -> SearchEnv:
    """One episode on an open size x size map; fov 1: a vehicle senses its cell and its 4 neighbours."""
    cfg = WorldConfig(map_size=size, uavs=len(starts), targets=len(targets), fov=fov, window=8)
    env = SearchEnv(cfg, batch=1, stop_at_success=True)
    scenario = Scenario(np.array(targets), np.zeros((size, size), dtype=bool), np.array(starts), [])
    env.reset_to([scenario])
    return env


def test_team_reward_counts_new_cells_new_targets_collisions_and_the_step():
    env = hand_env(starts=[(1, 1), (3, 1)], targets=[(6, 2), (0, 7)])
    _, r, _ = step_team(env, np.array([[E, E]]), WEIGHTS)  # new: (2,0) (2,2) (5,1) (4,0) (4,2)
    assert r[0] == pytest.approx(5 * C - STEP)
    _, r, _ = step_team(env, np.array([[STAY, E]]), WEIGHTS)  # new: (6,1) (5,0) (5,2)
    assert r[0] == pytest.approx(3 * C - STEP)
    _, r, _ = step_team(env, np.array([[STAY, N]]), WEIGHTS)  # new: (6,2), a target, and (5,3)
    assert r[0] == pytest.approx(2 * C + T - STEP)
    _, r, _ = step_team(env, np.array([[STAY, N]]), WEIGHTS)  # the target is known already: (4,3) (6,3) (5,4)
    assert r[0] == pytest.approx(3 * C - STEP)

    env = hand_env(starts=[(1, 1), (3, 1)], targets=[(6, 2), (0, 7)])
    _, r, _ = step_team(env, np.array([[E, W]]), WEIGHTS)  # both onto (2,1): new (2,0) (2,2)
    assert r[0] == pytest.approx(2 * C - STEP - 2 * COLLISION)


def test_success_is_terminal_and_the_step_limit_a_truncation():
    env = hand_env(starts=[(2, 1), (5, 4)], targets=[(2, 2), (5, 5)])
    cells_only = replace(WEIGHTS, cell=0.0, target=0.0)
    obs = env.last_observations
    run = rollout(env, obs, 5, cells_only, act=lambda env, obs, allowed: np.array([[N, N]]))
    assert run.success.tolist() == [True] and run.live.sum() == 1  # the episode stops at its success
    assert run.rewards[0, 0] == pytest.approx(SUCCESS - STEP)
    t = trajectories(run, n=10, gamma=0.99)
    assert t.sample.tolist() == [True, False, True, False]  # each vehicle: one transition, its last observation
    assert t.disc1[t.sample].tolist() == [0.0, 0.0] and t.disc_n[t.sample].tolist() == [0.0, 0.0]  # no bootstrap

    env = hand_env(starts=[(2, 0), (5, 3)], targets=[(2, 2), (5, 5)])
    run = rollout(env, env.last_observations, 1, cells_only, act=lambda env, obs, allowed: np.array([[N, N]]))
    t = trajectories(run, n=10, gamma=0.99)
    assert run.success.tolist() == [False]
    assert t.disc1[t.sample] == pytest.approx([0.99, 0.99]) and t.disc_n[t.sample] == pytest.approx([0.99, 0.99])
    assert t.ahead[t.sample].tolist() == [1, 1]  # the step limit's observation is the bootstrap


def test_nstep_returns_with_a_terminal_and_a_truncated_end():
    r = np.array([1.0, 2.0, 3.0, 4.0])
    ret, disc, ahead = nstep_returns(r, terminal=False, n=2, gamma=0.5)
    assert ret.tolist() == [2.0, 3.5, 5.0, 4.0]
    assert ahead.tolist() == [2, 2, 2, 1]
    assert disc.tolist() == [0.25, 0.25, 0.25, 0.5]  # the last steps bootstrap from the last observation
    ret, disc, ahead = nstep_returns(r, terminal=True, n=2, gamma=0.5)
    assert ret.tolist() == [2.0, 3.5, 5.0, 4.0] and disc.tolist() == [0.25, 0.25, 0.0, 0.0]
    ret, disc, ahead = nstep_returns(r, terminal=True, n=10, gamma=0.5)
    assert ret[0] == pytest.approx(1 + 1 + 0.75 + 0.5) and ahead.tolist() == [4, 3, 2, 1]
    assert disc.tolist() == [0.0] * 4


def test_the_margin_loss_is_zero_once_the_demonstrated_move_leads_by_the_margin():
    q = torch.tensor([[1.0, 3.0, 1.5, 2.1, 0.0]] * 3)
    allowed = torch.ones(3, 5, dtype=torch.bool)
    allowed[2, 1] = False
    expert = torch.tensor([1, 3, 3])
    loss = margin_loss(q, expert, allowed, 0.8, "max")
    assert loss[0] == 0.0  # 3.0 >= 2.1 + 0.8
    assert loss[1] == pytest.approx(3.0 + 0.8 - 2.1)  # inside the margin: the highest other move
    assert loss[2] == pytest.approx(1.5 + 0.8 - 2.1)  # a masked move does not count
    loss = margin_loss(q, expert, allowed, 0.8, "sum")
    assert loss[0] == 0.0
    assert loss[1] == pytest.approx((3.0 + 0.8 - 2.1) + (1.5 + 0.8 - 2.1))  # every move inside the margin
    assert loss[2] == pytest.approx(1.5 + 0.8 - 2.1)


def test_a_label_naming_several_moves_asks_the_best_of_them_to_lead_the_others_only():
    q = torch.tensor([[1.0, 3.0, 2.9, 0.5, 0.0]] * 2)
    allowed = torch.ones(2, 5, dtype=torch.bool)
    ties = np.zeros((2, 5), dtype=bool)
    ties[0, [1, 2]] = True  # north and east as good: the label asks nothing between them
    label = torch.from_numpy(encode_label(np.array([2, 2]), ties))
    for form in ("max", "sum"):
        loss = margin_loss(q, label, allowed, 0.8, form)
        assert loss[0] == 0.0  # the best labelled move (north, 3.0) leads the others (1.0) by the margin
        assert loss[1] > 0  # east alone: north is inside the margin
    assert margin_loss(q, label, allowed, 0.8, "sum")[1] == pytest.approx(3.0 + 0.8 - 2.9)


@given(st.lists(st.tuples(st.integers(0, 4), st.lists(st.booleans(), min_size=5, max_size=5)), min_size=1))
def test_labels_decode_to_the_teachers_move_and_every_move_as_good(cases):
    moves = np.array([m for m, _ in cases])
    ties = np.array([t for _, t in cases], dtype=bool)
    move, labelled = labelled_moves(torch.from_numpy(encode_label(moves, ties)), 5)
    assert move.tolist() == moves.tolist()
    expected = ties.copy()
    expected[np.arange(len(moves)), moves] = True
    assert np.array_equal(labelled.numpy(), expected)
    plain, only = labelled_moves(torch.from_numpy(moves), 5)  # a label of a run before teacher_ties
    assert plain.tolist() == moves.tolist() and only.sum(1).tolist() == [1] * len(moves)


def test_the_teacher_labels_its_own_move_and_the_moves_as_good_into_free_cells():
    env = SearchEnv(WorldConfig(scenario="cluster", uavs=3, targets=4, obstacles=0.1), batch=8, stop_at_success=False)
    env.reset(seed=3)
    teacher = CoordinatedPolicy()
    teacher.reset(env.beliefs(), 3)
    tied = 0
    for _ in range(20):
        beliefs = env.beliefs()
        moves, ties = teacher.labels(beliefs)
        assert np.array_equal(moves, teacher.act(beliefs))
        assert np.take_along_axis(ties, moves[..., None], -1).all()
        assert not (ties & ~search_mask(beliefs)).any()  # never a move off the map or into a blocked cell
        tied += int((ties.sum(-1) > 1).sum())
        env.step(moves)
    assert tied > 0.05 * 20 * 8 * 3  # ties are common: the label "one" marks as worse a move as good


def test_demonstrations_are_the_same_for_a_seed_whatever_the_batch():
    cfg = WorldConfig(map_size=12, uavs=2, targets=3, window=10)

    def demos(groups):
        runs = []
        for ids in groups:
            env = SearchEnv(cfg, batch=len(ids), stop_at_success=True)
            obs = env.reset(5, ids)
            runs.append(rollout(env, obs, 20, WEIGHTS, teacher=CoordinatedPolicy()))
        return runs

    whole, halves = demos([range(6)]), demos([range(3), range(3, 6)])
    again = demos([range(6)])
    for e in range(6):
        h, j = halves[e // 3], e % 3
        length = int(whole[0].live[:, e].sum())
        assert length == int(h.live[:, j].sum())
        assert np.array_equal(whole[0].actions[:length, e], h.actions[:length, j])
        assert np.array_equal(whole[0].actions[:length, e], whole[0].expert[:length, e])  # the teacher's own moves
        assert np.array_equal(whole[0].rewards[:length, e], h.rewards[:length, j])
        assert np.array_equal(whole[0].obs[: length + 1, e], h.obs[: length + 1, j])
    assert np.array_equal(whole[0].obs, again[0].obs) and np.array_equal(whole[0].actions, again[0].actions)


def test_the_mask_never_forces_stay_on_a_target():
    env = hand_env(starts=[(3, 3), (6, 6)], targets=[(3, 3), (0, 0)])  # vehicle 0 starts on a target
    beliefs = env.beliefs()
    assert beliefs.hovering_self[0, 0]
    assert allowed_moves(beliefs)[0, 0].tolist() == [True, False, False, False, False]  # ddql's default: parked
    assert search_mask(beliefs)[0, 0].all()  # the recipe: stay or go, the network's choice
    env = hand_env(starts=[(0, 0), (1, 0)], targets=[(0, 0), (5, 5)])  # the held cell stays masked for the other
    assert search_mask(env.beliefs())[0, 1].tolist() == [True, True, True, False, False]


def test_split_counts_stratifies_by_stage():
    assert split_counts(10, [5, 0, 0], 0, 0.5) == [10, 0, 0]
    assert split_counts(10, [5, 5, 5], 2, 0.5) == [3, 2, 5]  # 2.5, 2.5, 5: the remainder to the first
    assert split_counts(8, [5, 0, 5], 2, 0.5) == [4, 0, 4]
    assert sum(split_counts(7, [1, 2, 3, 4], 3, 0.25)) == 7


TINY = dict(
    curriculum="tiny",
    stages=1,
    episodes=12,
    parallel_envs=4,
    demo_episodes=4,
    pretrain_updates=5,
    batch_size=16,
    replay_capacity=500,
    dagger_capacity=300,
    eval_every=12,
    val_episodes=2,
    test_episodes=0,
    threads=1,
)
TINY_WORLD = WorldConfig(window=8)


def counters(metadata: dict) -> tuple:
    return tuple(metadata[k] for k in ("episodes", "samples", "demo_samples", "updates", "stage_reached"))


def test_a_tiny_run_trains_saves_resumes_and_ends_where_an_unbroken_one_does(tmp_path):
    cfg = SearchConfig(**TINY)
    whole = train(TINY_WORLD, cfg, tmp_path / "whole.pt", progress=False)
    assert counters(whole) == (12, whole["samples"], whole["demo_samples"], whole["updates"], 0)
    assert whole["updates"] > cfg.pretrain_updates and whole["final_eval"] is not None

    polls = []
    out = tmp_path / "cut.pt"
    stopped = train(TINY_WORLD, cfg, out, progress=False, stop=lambda: polls.append(1) or len(polls) >= 1)
    assert stopped["stopped"] and stopped["episodes"] == 4 and (tmp_path / "cut.replay.pt").is_file()
    with pytest.raises(InputError, match="was trained with lr"):
        train(TINY_WORLD, replace(cfg, lr=cfg.lr / 2), out, progress=False, resume=True)
    saved = torch.load(out, weights_only=True)
    for key in ("pod", "pos_goal"):  # as a checkpoint saved before those world fields existed
        del saved["world"][key]
    del saved["train"]["teacher_ties"]  # and before the option: its labels were the moves alone
    torch.save(saved, out)
    # the demonstrations' share may change on --resume; the change is kept for the run's card
    changed = SearchTrainer(TINY_WORLD, replace(cfg, demo_share_end=0.5), out)
    changed.resume()
    assert changed.state.changes == [{"episode": 4, "option": "demo_share_end", "from": 0.1, "to": 0.5}]
    resumed = train(TINY_WORLD, cfg, out, progress=False, resume=True)
    assert counters(resumed) == counters(whole)
    a, b = torch.load(tmp_path / "whole.pt", weights_only=True), torch.load(out, weights_only=True)
    assert a["weights_sha256"] == b["weights_sha256"]  # the same network, bit for bit
    assert len(open(tmp_path / "cut.csv").read().splitlines()) == 1 + 3  # one row a round, both sessions

    # the rules it was trained under fly it: ddql:PATH without options
    assert b["train"]["recipe"] == {"name": "dqfd-search-v1", "hover": "no", "mask": "yes", "taken": "keep"}
    policy = make_policy(f"ddql:{out}")
    assert (policy.hover, policy.mask, policy.remove_taken) == ("no", True, False)
    policy = make_policy(f"ddql:{out}:hover=first:taken=remove")
    assert (policy.hover, policy.mask, policy.remove_taken) == ("first", True, True)
    paper = make_policy(f"ddql:{ROOT / 'models' / 'cluster-2uav.pt'}")  # no recipe: the old defaults
    assert (paper.hover, paper.mask, paper.remove_taken) == ("first", True, True)
    # a mission flies the recipe's rule too; the paper's networks defer there, as before
    assert FieldPolicy(f"ddql:{out}").hover == "no"
    assert FieldPolicy(f"ddql:{ROOT / 'models' / 'cluster-2uav.pt'}").hover == "defer"

    with pytest.raises(InputError, match="holds no state to resume"):  # a finished run
        train(TINY_WORLD, cfg, out, progress=False, resume=True)


def test_the_chicago_loop_is_never_a_stage_a_world_or_a_city():
    from swarmctl.learn.city_maps import DEFAULT_CITY

    assert "chicago" not in str(DEFAULT_CITY).lower()  # the city crops' footprints: Helsinki
    for stages in SEARCH_CURRICULA.values():
        for stage in stages:
            assert "chicago" not in stage.name.lower()
            for w in stage.worlds:
                assert "chicago" not in w.name.lower()
    with pytest.raises(InputError, match="held-out"):
        StageWorld("Chicago Loop 50x50", 50, 3, 3)
    with pytest.raises(InputError, match="held-out"):
        SearchStage("chicago", (StageWorld("50x50", 50, 3, 3),))
    for path in ("missions/chicago-loop/grid.npz", "missions/data/chicago_loop_neighborhood.geojson"):
        with pytest.raises(InputError, match="Chicago"):
            SearchConfig(city_footprints=str(ROOT / path))
        with pytest.raises(InputError, match="Chicago"):
            CityCrops(str(ROOT / path))


@pytest.mark.skipif(importlib.util.find_spec("tensorboard") is not None, reason="TensorBoard is installed here")
def test_tensorboard_without_the_package_is_a_clear_error_before_any_work(tmp_path):
    with pytest.raises(InputError, match="pip install tensorboard"):
        train(TINY_WORLD, SearchConfig(**TINY), tmp_path / "m.pt", progress=False, tensorboard=tmp_path / "tb")
    assert not (tmp_path / "m.pt").exists()


def test_train_search_help_lists_the_fields_with_the_dataclass_defaults():
    result = CliRunner().invoke(root, ["train-search", "--help"])
    assert result.exit_code == 0
    command = root.commands["train-search"]
    made = {name: p for p in command.params if isinstance(p, FieldOption) for name in p.fields}
    for name in SEARCH_FIELDS:
        option = made[name]
        assert option.opts[0] in result.output
        assert option.default == option.field_default() and not option.own_default
    assert "--n-step" in result.output and f"[default: {field_default(SearchConfig, 'n_step')};" in result.output
    assert made["n_step"].default == 10 == SearchConfig().n_step


def test_a_stop_signal_saves_what_resume_needs_and_exits_cleanly(tmp_path):
    out = tmp_path / "m.pt"
    tiny = "--curriculum=tiny --stages=1 --window=8 --parallel=4 --demo-episodes=4 --pretrain-updates=5 --batch-size=16"
    args = [*tiny.split(), "--replay=500", "--val-episodes=2", "--test-episodes=0", "--threads=1", "--episodes=4000"]
    command = [sys.executable, "-m", "swarmctl.cli", "train-search", *args, f"--out={out}", "--no-progress"]
    proc = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    metrics = out.with_suffix(".csv")
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        if metrics.exists() and len(metrics.read_text().splitlines()) >= 2:  # a round is done
            break
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "continue with the same command and --resume" in err and "Traceback" not in err
    saved = torch.load(out, weights_only=True)
    assert saved["resume"]["progress"]["episodes_done"] >= 4 and out.with_suffix(".replay.pt").is_file()


def test_the_trainer_takes_the_world_s_observation_variant(tmp_path):
    world = WorldConfig(window=8, variant="global-local-v1")
    run = SearchTrainer(world, SearchConfig(**TINY), tmp_path / "m.pt")
    assert run.q_net.variant == "global-local-v1"
    run.open_stage(0)
    assert run.obs_shape == (7, 8, 8)
    run.learn(demos_only=True)
    assert run.state.updates == 1


def test_the_next_stage_opens_at_its_bar_and_the_earlier_one_stays_in_the_replay(tmp_path):
    cfg = SearchConfig(**{**TINY, "stages": 0, "episodes": 12, "eval_every": 4, "advance_share": 0.0})
    out = tmp_path / "m.pt"
    polls: list[int] = []
    stopped = train(TINY_WORLD, cfg, out, progress=False, stop=lambda: polls.append(1) or len(polls) >= 2)
    assert stopped["stage_reached"] == 1 and [e["stage"] for e in stopped["evals"]] == [0, 1]
    assert set(stopped["teacher_val_success"]) == {w.name for s in SEARCH_CURRICULA["tiny"] for w in s.worlds}
    resume = torch.load(out, weights_only=True)["resume"]
    assert set(resume["stores"]) == {"demo0", "demo1", "agent0", "agent1"}  # the first stage's samples kept
    run = SearchTrainer(TINY_WORLD, cfg, out)
    run.resume()
    assert [s.size for s in run.agents][0] > 0 and all(s.size > 0 for s in run.demos)
    assert split_counts(16, [s.size for s in run.demos], 1, cfg.current_share) == [8, 8]


def test_a_run_labelling_every_move_as_good_keeps_those_labels_and_trains(tmp_path):
    cfg = SearchConfig(**{**TINY, "teacher_ties": "all"})
    polls: list[int] = []
    stopped = train(TINY_WORLD, cfg, tmp_path / "m.pt", progress=False, stop=lambda: polls.append(1) or len(polls) >= 1)
    assert stopped["stopped"] and stopped["updates"] > cfg.pretrain_updates
    run = SearchTrainer(TINY_WORLD, cfg, tmp_path / "m.pt")
    run.resume()
    labels = run.demos[0].expert[: run.demos[0].size]
    labels = labels[labels >= 0]
    move, labelled = labelled_moves(labels, 5)
    assert (labelled.sum(1) > 1).any() and (move < 5).all()  # some demonstrations name several moves
    with pytest.raises(InputError, match="teacher_ties"):  # a run resumes with its own labels
        train(TINY_WORLD, replace(cfg, teacher_ties="one"), tmp_path / "m.pt", progress=False, resume=True)
