"""The mission commands: demo end to end, SIGTERM mid-mission, bad input (exit 2, one line)."""

from __future__ import annotations

import io
import json
import os
import signal
import socket
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from swarmctl.cli import main
from swarmctl.errors import InputError
from tests.mission_support import small_grid

ROOT = Path(__file__).resolve().parent.parent


def small_mission(tmp_path: Path, **mission: str) -> Path:
    small_grid().save(tmp_path / "grid.npz")
    fields = {"name": '"small"', "grid": '"grid.npz"', "policy": '"frontier"', "end_action": '"hover"', **mission}
    body = "[mission]\n" + "".join(f"{k} = {v}\n" for k, v in fields.items())
    body += '[[vehicles]]\nname = "a"\nconnection = "udpin:127.0.0.1:14551"\nsysid = 1\n'
    path = tmp_path / "mission.toml"
    path.write_text(body)
    return path


@pytest.mark.slow
@pytest.mark.parametrize("policy", ["frontier", "la:4"])
def test_demo_on_a_small_mission_writes_the_recording_and_the_picture(tmp_path, capsys, policy):
    mission = small_mission(tmp_path)
    out = tmp_path / "run"
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # a ground station watching
    gcs.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    gcs.bind(("127.0.0.1", 0))
    gcs.setblocking(False)
    code = main(
        [
            "demo",
            "--mission",
            str(mission),
            "--uavs",
            "3",
            "--seed",
            "4",
            "--speedup",
            "30",
            "--out",
            str(out),
            "--no-live",
            "--end-action",
            "hover",
            "--policy",
            policy,
            "--gcs",
            f"udpout:127.0.0.1:{gcs.getsockname()[1]}",
        ]
    )
    assert code == 0, capsys.readouterr().err
    parser, seen = mavutil.mavlink.MAVLink(None), set()
    while True:
        try:
            data = gcs.recv(65535)
        except BlockingIOError:
            break
        seen |= {m.get_srcSystem() for m in parser.parse_buffer(data) or [] if m.get_type() == "HEARTBEAT"}
    gcs.close()
    assert seen == {1, 2, 3}  # the ground station saw every vehicle
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "complete" and len(summary["targets_found"]) == 3
    assert sorted(map(tuple, summary["hidden_targets"])) == sorted(tuple(t["cell"]) for t in summary["targets_found"])
    for name in ("mission.tlog", "events.jsonl", "grid.npz", "mission.png", "mission.toml"):
        assert (out / name).stat().st_size > 0
    points = json.loads((out / "targets.geojson").read_text())["features"]
    got = sorted((p["geometry"]["coordinates"][1], p["geometry"]["coordinates"][0]) for p in points)
    want = sorted((t["lat"], t["lon"]) for t in summary["targets_found"])
    assert np.allclose(got, want, atol=1e-6, rtol=0)
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    marks = ET.parse(out / "targets.kml").getroot().findall(".//k:Placemark/k:Point/k:coordinates", ns)
    in_kml = sorted((float(c.text.split(",")[1]), float(c.text.split(",")[0])) for c in marks)
    assert np.allclose(in_kml, want, atol=1e-6, rtol=0)
    assert summary["knowledge_radio"]["forwarded"] > 0
    assert "complete: 3 targets found" in capsys.readouterr().out


@pytest.mark.slow
def test_sigterm_mid_mission_gives_every_vehicle_its_end_action_and_exits_130(tmp_path):
    mission = small_mission(tmp_path, time_limit="300.0")
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "swarmctl.cli",
            "demo",
            "--mission",
            str(mission),
            "--uavs",
            "3",
            "--policy",
            "random",
            "--speedup",
            "30",
            "--out",
            str(out),
            "--no-live",
            "--end-action",
            "rtl",
        ],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        events = out / "events.jsonl"
        deadline = time.monotonic() + 120
        while not (events.is_file() and '"event":"step"' in events.read_text()):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no search step within 120 s"
            time.sleep(0.1)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "interrupted"
    assert [v["end_action"] for v in summary["vehicles"]] == ["rtl"] * 3
    assert [v["end_state"] for v in summary["vehicles"]] == ["landed at home"] * 3
    lines = (out / "events.jsonl").read_text().splitlines()
    assert json.loads(lines[-1])["event"] in ("state", "end_action")  # closed after the end actions


def test_demo_flies_the_shipped_obstacle_model_and_falls_back_to_frontier_without_it(tmp_path, monkeypatch):
    from swarmctl.mission import cli as mission_cli

    monkeypatch.chdir(ROOT)
    policy, note = mission_cli.default_policy()
    assert policy == f"ddql:{ROOT / 'models' / 'obstacles-3uav.pt'}:straggler=frontier" and note is None
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(mission_cli, "ROOT", tmp_path)
    assert mission_cli.default_policy() == ("frontier", "models/obstacles-3uav.pt is not there")
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "obstacles-3uav.pt").write_bytes(b"not a checkpoint")
    policy, note = mission_cli.default_policy()
    assert policy == "frontier" and "cannot be used" in note


BAD = [
    (["demo", "--uavs", "0"], "--uavs 0"),
    (["demo", "--policy", "oracle"], "oracle"),
    (["demo", "--policy", "ddql:/nonexistent/model.pt"], "model.pt"),
    (["demo", "--speedup", "-1"], "--speedup"),
    (["demo", "--gcs", "udpin:0.0.0.0:14550"], "--gcs"),
    (["fly", "/nonexistent/mission.toml"], "no such mission file"),
]


@pytest.mark.parametrize("argv,needle", BAD)
def test_bad_input_is_one_line_and_exit_2(argv, needle, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_bad_mission_files_exit_2(tmp_path, capsys):
    assert main(["fly", str(small_mission(tmp_path, policy='"oracle"')), "--yes"]) == 2
    assert "oracle" in capsys.readouterr().err
    bad = small_mission(tmp_path)
    bad.write_text(bad.read_text() + '[knowledge]\nchannel = "udpin:0.0.0.0:14600"\n')
    assert main(["fly", str(bad), "--yes"]) == 2
    err = capsys.readouterr().err
    assert "knowledge.channel" in err and len(err.strip().splitlines()) == 1
    assert main(["agent", str(small_mission(tmp_path)), "--vehicle", "zulu", "--yes"]) == 2
    assert "zulu" in capsys.readouterr().err


def test_fly_prints_the_plan_and_does_not_fly_without_confirmation(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("sys.stdin", io.StringIO("n\n"))
    assert main(["fly", str(small_mission(tmp_path))]) == 1
    out = capsys.readouterr()
    assert "grid 10 x 10 cells of 10 m" in out.out and "vehicle a: sysid 1" in out.out
    assert "not flown" in out.err


def test_a_vehicle_may_name_its_detector_socket(tmp_path):
    from swarmctl.mission.config import load_mission
    from swarmctl.mission.service import plan_from_config

    path = small_mission(tmp_path)
    path.write_text(path.read_text() + 'detector = "udp:127.0.0.1:14650"\n')
    plan = plan_from_config(load_mission(path))
    assert plan.detectors == {0: ("127.0.0.1", 14650)}
    path.write_text(path.read_text().replace("udp:127.0.0.1:14650", "tcp:x"))
    with pytest.raises(InputError, match=r"vehicles\[0\]\.detector"):
        load_mission(path)


def test_a_mission_with_the_fence_on_says_so_before_it_flies(tmp_path, monkeypatch, capsys):
    from swarmctl.mission.config import load_mission
    from swarmctl.mission.service import plan_from_config

    path = small_mission(tmp_path, fence="true")
    assert plan_from_config(load_mission(path)).fence is True
    monkeypatch.setattr("sys.stdin", io.StringIO("n\n"))
    assert main(["fly", str(path)]) == 1
    assert "fence: the area's boundary, uploaded to every vehicle before take-off" in capsys.readouterr().out
    assert plan_from_config(load_mission(small_mission(tmp_path))).fence is False
