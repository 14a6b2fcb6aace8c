"""`swarmctl replay --verify` on fresh demo recordings (ddql softmax with the shipped model, frontier):
every decision reproduced, a planted mismatch listed, the checkpoint checked by its hash, old and
damaged recordings."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from swarmctl.cli import main
from swarmctl.geo.grid import GeoGrid
from swarmctl.mission.events import check_event
from swarmctl.policy.checkpoint import load_checkpoint, save_checkpoint
from swarmctl.replay import verify as verify_module
from swarmctl.world.moves import MOVE_NAMES, MOVES
from tests.test_mission_cli import small_mission

ROOT = Path(__file__).resolve().parent.parent
MODEL = ROOT / "models" / "obstacles-3uav.pt"


def _demo(base: Path, policy: str) -> Path:
    mission = small_mission(base)
    out = base / "run"
    argv = ["demo", "--mission", str(mission), "--uavs", "3", "--seed", "4", "--speedup", "30", "--out", str(out)]
    assert main(argv + ["--quiet", "--end-action", "hover", "--policy", policy]) in (0, 1)
    return out


@pytest.fixture(scope="module")
def ddql_demo(tmp_path_factory) -> Path:
    """The shipped model as the demo flies it (softmax, straggler=frontier) on the 10 x 10 test grid."""
    return _demo(tmp_path_factory.mktemp("verify-ddql"), f"ddql:{MODEL}:straggler=frontier")


@pytest.fixture(scope="module")
def frontier_demo(tmp_path_factory) -> Path:
    return _demo(tmp_path_factory.mktemp("verify-frontier"), "frontier")


def _verify(rec: Path, out: Path, *extra: str) -> tuple[int, dict | None]:
    code = main(["replay", str(rec), "--verify", "--out", str(out), "--quiet", *extra])
    report = json.loads((out / "verify.json").read_text()) if (out / "verify.json").is_file() else None
    return code, report


def _decisions(rec: Path) -> int:
    lines = [json.loads(x) for x in (rec / "events.jsonl").read_text().splitlines()]
    return sum(len(e["vehicles"]) for e in lines if e["event"] == "step")


def _rewrite(path: Path, change) -> None:
    """Rewrite a JSON-lines file, each line through change(obj) -> obj."""
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    path.write_text("".join(json.dumps(change(e)) + "\n" for e in lines))


def _copy(rec: Path, tmp_path: Path) -> Path:
    out = tmp_path / "rec"
    shutil.copytree(rec, out, ignore=shutil.ignore_patterns("replay"))
    return out


@pytest.mark.parametrize("which", ["ddql_demo", "frontier_demo"])
def test_every_decision_of_a_fresh_demo_is_reproduced(which, request, tmp_path, capsys):
    rec = request.getfixturevalue(which)
    mission = json.loads((rec / "events.jsonl").read_text().splitlines()[0])
    assert mission["seed"] == 4
    if which == "ddql_demo":
        assert mission["weights_sha256"] == load_checkpoint(MODEL)[1]["weights_sha256"]
        assert mission["forward"] in ("torch", "onnx+onednn", "torch+onednn")  # what `auto` picks
    for line in (rec / "inputs.jsonl").read_text().splitlines():
        assert check_event(json.loads(line), strict=True) == "inputs"
    code = main(["replay", str(rec), "--verify", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    report = json.loads((tmp_path / "verify.json").read_text())
    assert code == 0, out
    assert report["decisions"] == report["checked"] == _decisions(rec) > 10
    assert report["mismatches"] == [] and report["unchecked"] == {}
    assert report["reproduced"] + report["ties"] == report["checked"] and report["probable"] == 0
    assert report["guarded"] == report["decisions"]
    assert f"{report['decisions']} decisions" in out and "every decision reproduced" in out


def test_the_ddql_recording_shows_the_rules_the_guard_and_the_hand_off(ddql_demo):
    """What the ddql check goes through: refused moves and held cells in the guard's view, and the
    straggler's moves from the frontier planner (so those paths are checked, not skipped)."""
    events = [json.loads(x) for x in (ddql_demo / "events.jsonl").read_text().splitlines()]
    inputs = [json.loads(x) for x in (ddql_demo / "inputs.jsonl").read_text().splitlines()]
    records = [r for e in events if e["event"] == "step" for r in e["vehicles"]]
    assert any(r.get("by") == "frontier" for r in records)
    assert any(e["held"] for e in inputs)
    assert all(len(e["vehicles"]) == len(e["map"]) == len(e["since"]) for e in inputs)


def _plant(rec: Path, want_softmax: bool) -> tuple[int, str, str]:
    """Change a recorded move of the first round to the move onto the map the policy ranks last (the
    policy's first choice when it has no Q-values); returns the step, vehicle and planted move."""
    blocked = GeoGrid.load(rec / "grid.npz").blocked
    planted: list = []

    def change(e: dict) -> dict:
        if e["event"] != "step" or planted:
            return e
        for r in e["vehicles"]:
            if r.get("by") is not None or (r["q"] is not None) != want_softmax:
                continue
            x, y = r["cell"]
            onto = [
                m
                for m in range(1, 5)
                if MOVE_NAMES[m] != r["move"]
                and 0 <= x + MOVES[m][0] < blocked.shape[0]
                and 0 <= y + MOVES[m][1] < blocked.shape[1]
                and not blocked[x + MOVES[m][0], y + MOVES[m][1]]
            ]
            if onto:
                m = min(onto, key=lambda m: r["q"][m]) if r["q"] else onto[0]
                r["move"] = MOVE_NAMES[m]
                planted.append((e["step"], r["vehicle"], r["move"]))
                break
        return e

    _rewrite(rec / "events.jsonl", change)
    return planted[0]


@pytest.mark.parametrize("which", ["ddql_demo", "frontier_demo"])
def test_a_planted_mismatch_is_listed_and_exits_1(which, request, tmp_path, capsys):
    rec = _copy(request.getfixturevalue(which), tmp_path)
    step, vehicle, move = _plant(rec, which == "ddql_demo")
    code = main(["replay", str(rec), "--verify", "--out", str(tmp_path / "out")])
    out = capsys.readouterr().out
    assert code == 1
    report = json.loads((tmp_path / "out" / "verify.json").read_text())
    wrong = [m for m in report["mismatches"] if m["kind"] == "decision"]
    assert [(m["step"], m["vehicle"], m["recorded"]) for m in wrong] == [(step, vehicle, move)]
    assert wrong[0]["recomputed"] != move
    assert f"mismatch: step {step} {vehicle}: recorded move {move}, recomputed {wrong[0]['recomputed']}" in out
    if which == "ddql_demo":  # the softmax draw was reproduced: the planted move's probability is listed
        assert wrong[0]["probability"] is not None and wrong[0]["probability"] < 0.5
        assert 0 < wrong[0]["recomputed_probability"] <= 1
        assert "p(recorded) = " in out and "p(recomputed) = " in out
    assert report["checked"] == _decisions(rec)


def test_a_planted_guard_change_is_listed(frontier_demo, tmp_path):
    rec = _copy(frontier_demo, tmp_path)
    done: list = []

    def change(e: dict) -> dict:
        if e["event"] == "step" and not done:
            for r in e["vehicles"]:
                if r["guarded"] != "stay":
                    r["guarded"], r["refused"] = "stay", "held by another vehicle"
                    done.append((e["step"], r["vehicle"]))
                    break
        return e

    _rewrite(rec / "events.jsonl", change)
    code, report = _verify(rec, tmp_path / "out")
    assert code == 1
    assert [(m["step"], m["vehicle"], m["kind"]) for m in report["mismatches"]] == [(*done[0], "guard")]


def _altered_model(tmp_path: Path) -> Path:
    net, info = load_checkpoint(MODEL)
    with torch.no_grad():
        next(net.parameters()).add_(1e-3)
    path = tmp_path / "other.pt"
    save_checkpoint(path, net, info["world"], info["train"], info["metadata"])
    return path


def test_a_checkpoint_with_another_hash_is_refused_naming_both(ddql_demo, tmp_path, capsys):
    other = _altered_model(tmp_path)
    code, report = _verify(ddql_demo, tmp_path / "out", "--model", str(other))
    err = capsys.readouterr().err.strip()
    recorded = json.loads((ddql_demo / "events.jsonl").read_text().splitlines()[0])["weights_sha256"]
    new = load_checkpoint(other)[1]["weights_sha256"]
    assert code == 2 and report is None
    assert err.count("\n") == 0 and recorded in err and new in err and "--model" in err


def test_a_checkpoint_that_moved_is_named_with_the_fix_and_found_with_model(ddql_demo, tmp_path, capsys):
    rec = _copy(ddql_demo, tmp_path)
    gone = tmp_path / "elsewhere" / "obstacles-3uav.pt"

    def move(e: dict) -> dict:
        if e["event"] == "mission":
            e["policy"] = e["policy"].replace(str(MODEL), str(gone))
        return e

    _rewrite(rec / "events.jsonl", move)
    code, _ = _verify(rec, tmp_path / "a")
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0 and str(gone) in err and "--model PATH" in err
    code, report = _verify(rec, tmp_path / "b", "--model", str(MODEL))
    assert code == 0 and report["checked"] == _decisions(rec)


def test_a_recording_from_before_the_inputs_cannot_be_verified(frontier_demo, tmp_path, capsys):
    rec = _copy(frontier_demo, tmp_path)
    (rec / "inputs.jsonl").unlink()

    def old(e: dict) -> dict:
        for key in ("seed", "weights_sha256", "forward"):
            e.pop(key, None) if e["event"] == "mission" else None
        return e

    _rewrite(rec / "events.jsonl", old)
    code, report = _verify(rec, tmp_path / "out")
    err = capsys.readouterr().err.strip()
    assert code == 2 and report is None
    assert err.count("\n") == 0 and "cannot verify" in err and "recorded before" in err
    # the replay itself still reads it
    assert main(["replay", str(rec), "--out", str(tmp_path / "replay"), "--quiet", "--fps", "5"]) == 0


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--model", str(MODEL)], "--model"),  # a planner's recording has no checkpoint
        (["--min-probability", "2"], "--min-probability"),
    ],
)
def test_bad_verify_options_are_one_line_and_exit_2(frontier_demo, tmp_path, capsys, extra, needle):
    assert main(["replay", str(frontier_demo), "--verify", "--out", str(tmp_path), "--quiet", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and needle in err and "Traceback" not in err


def test_a_bare_tlog_has_no_decisions_to_verify(frontier_demo, tmp_path, capsys):
    assert main(["replay", str(frontier_demo / "mission.tlog"), "--verify", "--out", str(tmp_path), "--quiet"]) == 2
    assert "holds no decisions" in capsys.readouterr().err


def test_a_damaged_inputs_line_leaves_its_rounds_unchecked_until_the_next_whole_map(frontier_demo, tmp_path):
    rec = _copy(frontier_demo, tmp_path)
    lines = (rec / "inputs.jsonl").read_text().splitlines()
    broken = json.loads(lines[2])
    broken["maps"] = ["not base64!"] * len(broken["maps"]) if broken["maps"] else broken["maps"]
    broken["positions"] = "not base64!"
    lines[2] = json.dumps(broken)
    lines[4] = lines[4][: len(lines[4]) // 2]  # a line cut short: skipped as damage
    (rec / "inputs.jsonl").write_text("\n".join(lines) + "\n")
    code, report = _verify(rec, tmp_path / "out")
    assert code == 0 and report["mismatches"] == []
    assert sum(report["unchecked"].values()) == report["decisions"] - report["checked"] > 0
    assert any("could not be read" in why for why in report["unchecked"])
    assert any("no inputs line" in why for why in report["unchecked"])
    assert any("damaged" in n for n in report["notes"])


def _decided(q, move, allowed=(True,) * 5, draw=0.5):
    return verify_module._Network(move, np.array(q, dtype=np.float64), "d", None, np.array(allowed), draw)


@pytest.mark.parametrize("tau", [None, 0.1])
def test_moves_within_the_tie_of_the_best_pass_either_way(tau):
    q = [0.0, 1.0, 1.0 - 5e-5, 0.2, 0.3]
    record = {"move": "east", "q": q, "obs": "d"}
    assert verify_module.judge_network(record, _decided(q, 1), tau, 0.01) == "tie"
    why, _p = verify_module.judge_network({**record, "move": "west"}, _decided(q, 1), tau, 0.01)
    assert "west" not in why and ("below the best" in why if tau is None else "draw" in why)
    # a move the rules forbid is no tie, however close its Q-value
    why, _p = verify_module.judge_network(record, _decided(q, 1, (True, True, False, True, True)), tau, 0.01)
    assert "do not allow" in why


def test_a_real_recording_from_before_the_inputs_says_so(tmp_path, capsys):
    """The three-copter SITL recording in tests/data was flown before the decision inputs were kept."""
    rec = ROOT / "tests" / "data" / "logs" / "sitl3-mission"
    assert main(["replay", str(rec), "--verify", "--out", str(tmp_path), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "cannot verify" in err and "recorded before" in err
