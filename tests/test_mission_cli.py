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
from swarmctl.mavlink.codec import Endpoint
from swarmctl.mission.plan import make_plan
from swarmctl.mission.spec import load_spec
from tests.mission_support import small_grid, small_mission

ROOT = Path(__file__).resolve().parent.parent


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
    bus = summary["knowledge_bus"]  # the agents shared in the demo's process
    assert bus["channel"] == "ideal" and bus["delivered"] > 0 and bus["lost"] == 0
    assert "complete: 3 targets found" in capsys.readouterr().out


@pytest.mark.slow
def test_sigterm_mid_mission_gives_every_vehicle_its_end_action_and_exits_130(tmp_path):
    mission = small_mission(tmp_path)
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


def test_demo_flies_the_coordinated_planner_and_says_why():
    from swarmctl.mission import cli as mission_cli

    policy, note = mission_cli.default_policy()
    assert policy.spec == "coordinated" and policy.hover == "defer"
    assert "best measured policy" in note and "docs/RESULTS.md" in note


BAD = [
    (["demo", "--uavs", "0"], "'--uavs'"),
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
    # no detector, no [knowledge] section: said before take-off, and no address is made up
    assert "sensing: no detector, so this is a coverage search" in out.out and ", no detector" in out.out
    assert "knowledge: shared in this process (no hub to run)" in out.out and "14600" not in out.out


def test_fly_names_each_vehicles_detector_and_a_channel_it_does_not_use(tmp_path, monkeypatch, capsys):
    path = small_mission(tmp_path)
    path.write_text(
        path.read_text()
        + 'detector = "mavlink"\n[[vehicles]]\nname = "b"\nconnection = "udpin:127.0.0.1:14552"\nsysid = 2\n'
        + '[knowledge]\nchannel = "udpout:127.0.0.1:14600"\n'
    )
    monkeypatch.setattr("sys.stdin", io.StringIO("n\n"))
    assert main(["fly", str(path)]) == 1
    out = capsys.readouterr().out
    assert (
        "vehicle a: sysid 1, autopilot as its heartbeat says, udpin:127.0.0.1:14551, detector on its MAVLink link"
        in out
    )
    assert "1 of 2 vehicles have a detector for the targets (the others search by coverage only)" in out
    assert "[knowledge] channel udpout:127.0.0.1:14600 is for swarmctl agent, fly does not use it" in out


def test_an_agent_without_a_knowledge_channel_is_refused_with_exit_2(tmp_path, capsys):
    path = small_mission(tmp_path)
    assert main(["agent", str(path), "--vehicle", "a", "--yes"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.endswith(
        f"{path}: [knowledge] channel is missing, and agents in separate processes (swarmctl agent) share knowledge "
        'only through it; add [knowledge] channel = "udpout:HOST:PORT" (a MAVLink router or telemetry mesh that '
        "forwards TUNNEL messages to every vehicle's agent), or fly every vehicle from one computer with swarmctl fly"
    )


def test_a_vehicle_may_name_its_detector_socket(tmp_path):
    assert make_plan(load_spec(small_mission(tmp_path))).detectors == {}  # none: a coverage search
    path = small_mission(tmp_path)
    path.write_text(path.read_text() + 'detector = "udp:127.0.0.1:14650"\n')
    plan = make_plan(load_spec(path))
    assert plan.detectors == {0: Endpoint("udpin", "127.0.0.1", 14650)}
    assert make_plan(load_spec(path), detector="udp:127.0.0.1:14700").detectors[0].port == 14700  # agent --detector
    assert make_plan(load_spec(path), detector="mavlink").detectors == {0: "mavlink"}  # on its own link
    with pytest.raises(InputError, match=r"--detector 'tcp:x'"):
        make_plan(load_spec(path), detector="tcp:x")
    path.write_text(path.read_text().replace("udp:127.0.0.1:14650", "tcp:x"))
    with pytest.raises(InputError, match=r"vehicles\[0\]\.detector"):
        load_spec(path)


def test_a_mission_with_the_fence_on_says_so_before_it_flies(tmp_path, monkeypatch, capsys):
    path = small_mission(tmp_path, fence="true")
    assert make_plan(load_spec(path)).spec.mission.fence is True
    monkeypatch.setattr("sys.stdin", io.StringIO("n\n"))
    assert main(["fly", str(path)]) == 1
    assert "fence: the area's boundary, uploaded to every vehicle before take-off" in capsys.readouterr().out
    assert make_plan(load_spec(small_mission(tmp_path))).spec.mission.fence is False


def test_a_grid_planned_at_300_m_flown_at_40_m_is_refused(tmp_path, capsys):
    path = small_mission(tmp_path, small_grid(altitude=300.0), altitude="40.0")
    assert main(["fly", str(path), "--yes"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert "mission.altitude = 40 is below the 300 m the grid grid.npz was planned for" in err
    assert "`swarmctl plan ... --altitude 40`, or fly at the grid's altitude" in err


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "1000.0"])
def test_bad_numbers_in_a_mission_file_exit_2(tmp_path, capsys, value):
    assert main(["fly", str(small_mission(tmp_path, altitude=value)), "--yes"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"mission.altitude = {value}: must be a finite" in err


def test_fly_says_when_it_flies_above_the_grids_altitude(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("sys.stdin", io.StringIO("n\n"))
    assert main(["fly", str(small_mission(tmp_path, altitude="55.0"))]) == 1
    out = capsys.readouterr().out
    assert "altitude 55 m above home (above the 40 m the grid was planned for" in out
    assert "sensor footprint 30 m round each cell reached (3 cells)" in out


def test_fly_loads_the_checkpoint_once(tmp_path, monkeypatch, capsys):
    import torch

    from swarmctl.mission.controller import Controller
    from swarmctl.mission.recorder import Recorder
    from swarmctl.policy.checkpoint import save_checkpoint
    from swarmctl.policy.qnet import QNetwork

    save_checkpoint(tmp_path / "m.pt", QNetwork(20), {}, {}, {})
    loads = []
    real = torch.load
    monkeypatch.setattr(torch, "load", lambda *a, **k: loads.append(a[0]) or real(*a, **k))
    path = small_mission(tmp_path, policy='"ddql:m.pt:tau=0.05"')
    monkeypatch.setattr("sys.stdin", io.StringIO("n\n"))
    assert main(["fly", str(path)]) == 1, capsys.readouterr().err
    assert len(loads) == 1
    loads.clear()
    plan = make_plan(load_spec(path))
    rec = Recorder(tmp_path / "rec")
    try:
        controller = Controller(plan, rec)
    finally:
        rec.close()
    assert len(loads) == 1 and controller.policy is plan.policy  # the controller flies the plan's policy
