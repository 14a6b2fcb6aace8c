"""The command line: eval's JSON contract, bench's JSON keys, and bad input as one line + exit 2."""

import json
import subprocess
import sys

import pytest

from swarmctl.cli import main


def run(*args):
    proc = subprocess.run([sys.executable, "-m", "swarmctl.cli", *args], capture_output=True, text=True, timeout=300)
    return proc.returncode, proc.stdout, proc.stderr


def test_eval_json_holds_one_result_per_policy(tmp_path):
    out = tmp_path / "r.json"
    code = main(
        [
            "eval",
            "--episodes",
            "20",
            "--policy",
            "la:2",
            "--policy",
            "oracle",
            "--seed",
            "3",
            "--json",
            str(out),
            "--no-progress",
        ]
    )
    assert code == 0
    data = json.loads(out.read_text())
    assert [r["policy"] for r in data["results"]] == ["la:2", "oracle"]
    for r in data["results"]:
        for key in ("success_rate", "mean_steps", "steps_cdf", "episodes", "policy", "scenario", "seed"):
            assert key in r
        assert r["episodes"] == 20 and r["seed"] == 3 and len(r["steps_cdf"]) == 40
        assert r["scenario"]["map_size"] == 20 and r["scenario"]["uavs"] == 2 and r["scenario"]["targets"] == 4
        assert r["scenario"]["window"] == 20 and r["scenario"]["steps"] == 40


def test_single_policy_json_is_still_a_list(tmp_path):
    out = tmp_path / "r.json"
    assert main(["eval", "--episodes", "5", "--policy", "random", "--json", str(out), "--no-progress"]) == 0
    assert len(json.loads(out.read_text())["results"]) == 1


def test_bench_json_names_units_and_measures_the_limits_in_the_same_run(tmp_path, monkeypatch):
    # the search trainer's figures have their own test (tests/test_bench_search.py)
    monkeypatch.setattr("swarmctl.bench.search_training_figures", lambda *args, **kwargs: {})
    out = tmp_path / "b.json"
    assert main(["bench", "--seconds", "0.05", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    for key in (
        "ddql_decision_ms_batch1",
        "qnet_flop_limit_ms_batch1",
        "la4_decision_ms_batch1",
        "ddql_paper_decision_ms_batch1",
        "env_vehicle_steps_per_s_batch1",
        "env_vehicle_steps_per_s_batch1_no_obs",
        "env_vehicle_steps_per_s_batch256",
        "env_vehicle_steps_per_s_batch256_no_obs",
        "env_m50_u10_vehicle_steps_per_s_batch64",
        "train_samples_per_s",
        "train_flop_ceiling_samples_per_s",
        *(f"coordinated_decision_ms_per_vehicle_chicago_u{n}" for n in (3, 12, 50)),
        *(f"frontier_decision_ms_per_vehicle_chicago_u{n}" for n in (3, 12, 50)),
    ):
        assert data[key] > 0, key
    for n in (3, 12, 50):  # the planners' ratio is of the same run's figures
        ratio = data[f"coordinated_over_frontier_decision_u{n}"]
        assert ratio == pytest.approx(
            data[f"coordinated_decision_ms_per_vehicle_chicago_u{n}"]
            / data[f"frontier_decision_ms_per_vehicle_chicago_u{n}"]
        )
    # the limit is the network's 4.88 MFLOP at the matmul rate of this very run
    assert data["qnet_flop_limit_ms_batch1"] == pytest.approx(4.88448e6 / (data["matmul_gflop_per_s"] * 1e9) * 1e3)
    assert data["ddql_decision_over_flop_limit"] == pytest.approx(
        data["ddql_decision_ms_batch1"] / data["qnet_flop_limit_ms_batch1"]
    )
    # the training ceiling: per sample one forward and 64 / 16 x 5 forwards' worth of gradient step, at
    # the matmul rate measured around the training
    per_sample = 4.88448e6 * (1 + 64 / 16 * 5)
    assert data["train_flop_ceiling_samples_per_s"] == pytest.approx(
        data["train_matmul_gflop_per_s"] * 1e9 / per_sample
    )
    m = data["machine"]
    assert m["threads"] == 1 and m["cpu_count"] >= 1 and m["cpu_model"] and m["torch"] and m["numpy"]
    assert m["cpu"]["name"] and m["cpu_model"].startswith(m["cpu"]["name"])
    assert len(m["load_average_before"]) == 3 and len(m["load_average_after"]) == 3


@pytest.mark.parametrize(
    "args, needle",
    [
        (["eval", "--policy", "nonsense"], "--policy"),
        (["eval", "--policy", "la:x"], "la:4"),
        (["eval", "--policy", "random", "--map", "0"], "--map"),
        (["eval", "--policy", "random", "--window", "0"], "--window"),
        (["eval", "--policy", "random", "--targets", "200"], "--targets"),
        (["eval", "--policy", "random", "--obstacles", "0.95"], "--obstacles"),
        (["eval", "--policy", "random", "--map", "3", "--uavs", "10"], "--uavs"),
        (["eval", "--policy", "random", "--episodes", "0"], "--episodes"),
        (["eval", "--policy", "random", "--steps", "0"], "--steps"),
        (["eval", "--scenario", "sparse", "--targets", "9", "--policy", "random", "--no-progress"], "--targets"),
        (["eval", "--policy", "random", "--uavs", "many"], "--uavs"),
    ],
)
def test_bad_input_is_one_clear_line_and_exit_2(args, needle):
    code, out, err = run(*args)
    assert code == 2
    assert "Traceback" not in err
    assert needle in err
    lines = [line for line in err.splitlines() if line.strip().startswith("swarmctl: error") or "Error" in line]
    assert len(lines) == 1


def test_eval_plays_episodes_on_a_real_grid(tmp_path):
    from pathlib import Path

    grid = Path(__file__).resolve().parent.parent / "missions" / "chicago-loop" / "grid.npz"
    out = tmp_path / "r.json"
    code = main(
        [
            "eval",
            "--grid",
            str(grid),
            "--scenario",
            "cluster",
            "--uavs",
            "2",
            "--targets",
            "4",
            "--steps",
            "60",
            "--episodes",
            "4",
            "--policy",
            "frontier",
            "--policy",
            "oracle",
            "--no-progress",
            "--json",
            str(out),
        ]
    )
    assert code == 0
    rows = json.loads(out.read_text())["results"]
    assert rows[0]["scenario"]["grid"] == str(grid) and rows[0]["scenario"]["map_size"] == 50
    assert rows[1]["success_rate"] == 1.0  # every target of these episodes lies well within 60 steps
    code, _, err = run("eval", "--grid", str(tmp_path / "none.npz"), "--policy", "frontier")
    assert code == 2 and "none.npz" in err and "Traceback" not in err


def test_every_numeric_option_of_every_command_is_bounded_and_refuses_nan():
    """Options, not tests of each: a new float option made with click's own type (which lets NaN
    through) or an unbounded integer fails here until it uses swarmctl.bounds.real / whole."""
    import click

    from swarmctl.bounds import FiniteRange
    from swarmctl.cli import cli as root

    def commands(group, path):
        for name, command in group.commands.items():
            if isinstance(command, click.Group):
                yield from commands(command, [*path, name])
            else:
                yield [*path, name], command

    loose, bounded = [], 0
    for path, command in commands(root, []):
        for param in command.params:
            kind = param.type
            bounded += isinstance(kind, FiniteRange)
            if isinstance(kind, click.types.FloatParamType) and not isinstance(kind, FiniteRange):
                loose.append(f"{' '.join(path)} {param.opts[0]}: a float that takes NaN")
            elif isinstance(kind, click.types.IntParamType) and not isinstance(kind, click.IntRange):
                loose.append(f"{' '.join(path)} {param.opts[0]}: an integer without bounds")
    assert loose == []
    assert len(list(commands(root, []))) >= 9 and bounded >= 20  # the walk reached the options
