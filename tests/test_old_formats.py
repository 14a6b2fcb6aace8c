"""Files written before today's changes (git commit d0f4aa4 and earlier) keep loading and stay usable,
one test per format: a mission file, a recording, a checkpoint, a grid. The fixtures live in
tests/data/old/ (their origins: tests/data/old/SOURCES.md); the checkpoint is the shipped
models/obstacles-3uav.pt, unchanged since before d0f4aa4 (its weights hash pins it)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from swarmctl.cli import main
from swarmctl.geo.grid import GeoGrid
from swarmctl.mission.plan import make_plan
from swarmctl.mission.spec import load_spec
from swarmctl.policy.checkpoint import load_checkpoint
from swarmctl.policy.forward import onnx_available
from swarmctl.policy.registry import make_policy
from swarmctl.world import SearchEnv, WorldConfig

ROOT = Path(__file__).resolve().parent.parent
OLD = ROOT / "tests" / "data" / "old"
MODEL = ROOT / "models" / "obstacles-3uav.pt"
MODEL_SHA256 = "0c42552e39324e5fb75db5d3c9549c528454d67bc0c68d885357a67170adfa66"  # as of d0f4aa4


def test_an_old_mission_file_parses_and_plans():
    """missions/chicago-loop/mission.toml as of d0f4aa4 (before finish lines and the coordinated
    planner): a spec with the new keys at their defaults, and a plan over its grid."""
    path = OLD / "chicago-loop" / "mission.toml"
    spec = load_spec(path)
    assert spec.mission.name == "chicago-loop" and spec.mission.policy == "frontier"
    assert [v.name for v in spec.vehicles] == ["alpha", "bravo", "charlie"]
    assert spec.mission.finish == "held"  # the key it predates, at its default
    plan = make_plan(spec, mission_file=path)
    assert plan.grid.blocked.shape == (50, 50)
    assert plan.spec.mission.altitude == 40.0 and plan.spec.mission.cell_size == 10.0
    assert plan.fov == 3.0 and plan.policy is not None


def test_an_old_recording_replays_and_verifies(tmp_path, capsys):
    """A demo recorded by the code of d0f4aa4 (ddql, the shipped model, forward onnx+onednn) replays
    whole, and every decision is reproduced by today's code; without onnxruntime, one line says what
    to install."""
    rec = tmp_path / "rec"
    shutil.copytree(OLD / "demo-d0f4aa4", rec)
    assert main(["replay", str(rec), "--out", str(tmp_path / "replay"), "--quiet"]) == 0
    summary = (tmp_path / "replay" / "summary.txt").read_text()
    assert "complete: 2 targets found, 17 steps" in summary and "skip" not in summary.lower()
    assert "truth: 2 hidden targets, 2 found" in summary
    argv = ["replay", str(rec), "--verify", "--out", str(tmp_path / "out"), "--quiet", "--model", str(MODEL)]
    code = main(argv)
    err = capsys.readouterr().err.strip()
    if not onnx_available():
        assert code == 2 and "\n" not in err and "pip install 'swarmctl[onnx]'" in err
        return
    assert code == 0, err
    report = json.loads((tmp_path / "out" / "verify.json").read_text())
    assert report["ok"] and not report["nothing_checked"] and not report["mismatches"]
    assert report["weights_sha256"] == MODEL_SHA256 and report["forward"] == "onnx+onednn"
    assert report["decisions"] == report["reproduced"] + report["ties"] + report["probable"] > 0


def test_an_old_checkpoint_loads_and_decides():
    """models/obstacles-3uav.pt (format v2, from before d0f4aa4; its world config lacks the keys added
    since, e.g. finish) loads, and a ddql policy on it makes valid moves in its world."""
    net, info = load_checkpoint(MODEL)
    assert info["weights_sha256"] == MODEL_SHA256, (
        "models/obstacles-3uav.pt changed: keep the old one in tests/data/old"
    )
    assert "finish" not in info["world"]  # written before finish lines
    world = WorldConfig(**info["world"])
    env = SearchEnv(world, batch=3, stop_at_success=False, observations=False)
    env.reset(seed=5)
    policy = make_policy(f"ddql:{MODEL}")
    policy.reset(env.beliefs(), 5)
    for _ in range(4):
        moves = policy.act(env.beliefs())
        assert moves.shape == (3, world.uavs) and ((moves >= 0) & (moves < 5)).all()
        env.step(moves)
    assert net.window == info["window"] == world.window


def test_an_old_grid_loads_and_evaluates(tmp_path):
    """missions/chicago-loop/grid.npz as of d0f4aa4: it loads, and eval plays episodes on it."""
    path = OLD / "chicago-loop" / "grid.npz"
    grid = GeoGrid.load(path)
    assert grid.blocked.shape == (50, 50) and grid.cell == 10.0 and grid.altitude == 40.0
    assert round(grid.blocked_fraction, 3) == 0.124
    out = tmp_path / "eval.json"
    argv = ["eval", "--grid", str(path), "--uavs", "3", "--targets", "3", "--episodes", "4", "--steps", "30"]
    assert main(argv + ["--policy", "frontier", "--json", str(out), "--no-progress"]) == 0
    (result,) = json.loads(out.read_text())["results"]
    assert result["episodes"] == len(result["per_episode"]) == 4 and result["scenario"]["map_size"] == 50
    assert 0.0 <= result["success_rate"] <= 1.0 and np.isfinite(result["mean_steps"])
    assert result["oracle_mean_steps"] > 0  # the targets drawn on the grid are reachable
