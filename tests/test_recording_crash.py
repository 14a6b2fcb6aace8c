"""A recording that survives a crash: demos killed with SIGKILL at several points leave every file
readable up to that moment (events.jsonl with every step flown, a complete running summary.json,
knowledge.jsonl, a tlog pymavlink reads to its end), and `swarmctl replay` replays the folder."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from swarmctl.cli import main
from swarmctl.mission.events import check_event
from swarmctl.mission.recorder import Recorder
from tests.mission_support import small_grid, small_mission

ROOT = Path(__file__).resolve().parent.parent
SUMMARY_KEYS = {"mission", "policy", "outcome", "targets_found", "steps", "vehicles", "messages", "running"}


def step_lines(events: Path) -> int:
    if not events.is_file():
        return 0
    return events.read_text(errors="replace").count('"event":"step"')


def has_line(events: Path, text: str) -> bool:
    return events.is_file() and text in events.read_text(errors="replace")


def summary_vehicles(out: Path) -> int:
    path = out / "summary.json"
    return len(json.loads(path.read_text())["vehicles"]) if path.is_file() else 0


# kill points: (name, condition on the run folder and the seconds since the start)
KILL_AT = {
    "during take-off": lambda out, s: (
        has_line(out / "events.jsonl", '"state":"takeoff"')
        and step_lines(out / "events.jsonl") == 0
        and summary_vehicles(out) == 3
    ),
    "after 5 steps": lambda out, s: step_lines(out / "events.jsonl") >= 5,
    "10 s in": lambda out, s: s >= 10.0 and step_lines(out / "events.jsonl") >= 1,  # in the search by then
}


class Demo:
    """A demo in a child process, its stderr read as it comes (the progress lines name the steps)."""

    def __init__(self, tmp: Path, name: str):
        folder = tmp / re.sub(r"\W+", "-", name)
        folder.mkdir()
        mission = small_mission(folder, saved_grid=small_grid(20, 20))
        self.out = folder / "run"
        argv = ["demo", "--mission", str(mission), "--uavs", "3", "--policy", "random", "--speedup", "30"]
        argv += ["--out", str(self.out), "--no-live", "--time-limit", "600", "--end-action", "hover"]
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "swarmctl.cli", *argv],
            cwd=ROOT,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.started = time.monotonic()
        self.stderr: list[str] = []
        self.reader = threading.Thread(target=lambda: self.stderr.extend(self.proc.stderr), daemon=True)
        self.reader.start()

    def kill_when(self, condition, timeout: float = 150.0) -> float:
        """SIGKILL as soon as condition(out, seconds) holds; returns the wall-clock time of the kill."""
        deadline = time.monotonic() + timeout
        while not condition(self.out, time.monotonic() - self.started):
            assert self.proc.poll() is None, "".join(self.stderr)
            assert time.monotonic() < deadline, f"condition not reached in {timeout:g} s"
            time.sleep(0.05)
        killed = time.time()
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(30)
        self.reader.join(10)
        return killed

    def last_reported_step(self) -> int:
        steps = [int(m.group(1)) for line in self.stderr if (m := re.match(r"step (\d+) ", line))]
        return max(steps, default=0)


@pytest.fixture(scope="module")
def killed(tmp_path_factory) -> dict[str, tuple[Demo, float]]:
    """Three demos started together, each killed at its own point."""
    tmp = tmp_path_factory.mktemp("crash")
    demos = {name: Demo(tmp, name) for name in KILL_AT}
    try:
        return {name: (demo, demo.kill_when(KILL_AT[name])) for name, demo in demos.items()}
    finally:
        for demo in demos.values():
            if demo.proc.poll() is None:
                demo.proc.kill()
                demo.proc.wait()


def readable_lines(path: Path) -> list[dict]:
    """Every line parses and follows the schema, except at most a partial last one."""
    lines = path.read_text().split("\n")
    records = []
    for i, line in enumerate(lines):
        if not line:
            continue
        try:
            obj = json.loads(line)
        except json.JSONDecodeError:
            assert i == len(lines) - 1, f"{path.name}: line {i + 1} of {len(lines)} does not parse"
            continue
        check_event(obj, strict=True)
        records.append(obj)
    return records


@pytest.mark.slow
@pytest.mark.parametrize("point", list(KILL_AT))
def test_a_killed_demo_leaves_every_step_flown_in_events_jsonl(killed, point):
    demo, _ = killed[point]
    events = readable_lines(demo.out / "events.jsonl")
    assert events[0]["event"] == "mission"
    steps = [e["step"] for e in events if e["event"] == "step"]
    assert steps == list(range(1, len(steps) + 1))  # none missing, none twice
    assert len(steps) >= demo.last_reported_step()  # the step line is out before the progress line
    if point == "after 5 steps":
        assert len(steps) >= 5
    knowledge = demo.out / "knowledge.jsonl"
    if knowledge.is_file():
        assert max((k["step"] for k in readable_lines(knowledge)), default=0) <= len(steps)


@pytest.mark.slow
@pytest.mark.parametrize("point", list(KILL_AT))
def test_a_killed_demo_leaves_the_running_summary_and_a_tlog_read_to_its_end(killed, point):
    demo, when = killed[point]
    summary = json.loads((demo.out / "summary.json").read_text())
    assert SUMMARY_KEYS <= set(summary) and summary["running"] is True and summary["outcome"] is None
    assert summary["steps"] <= step_lines(demo.out / "events.jsonl")
    assert [v["name"] for v in summary["vehicles"]] == ["uav1", "uav2", "uav3"]
    log = mavutil.mavlink_connection(str(demo.out / "mission.tlog"))
    stamps = []
    while (msg := log.recv_match()) is not None:
        if msg.get_type() != "BAD_DATA":
            stamps.append(msg._timestamp)
    assert stamps, "nothing in the tlog"
    # flushed every TLOG_FLUSH_S: at most the last moment is lost (while vehicles connect, the controller's
    # 1 Hz heartbeat may be the only traffic; in the search each vehicle sends telemetry at 20 Hz)
    assert when - stamps[-1] < (2.5 if point == "during take-off" else 1.5)


@pytest.mark.slow
def test_replay_reads_a_killed_recording(killed, tmp_path, capsys):
    demo, _ = killed["after 5 steps"]
    out = tmp_path / "replay"
    assert main(["replay", str(demo.out), "--out", str(out), "--quiet", "--fps", "5"]) == 0, capsys.readouterr().err
    assert (out / "map.html").stat().st_size > 0 and (out / "summary.txt").stat().st_size > 0


def test_summary_json_is_replaced_whole_and_says_whether_the_mission_runs(tmp_path):
    rec = Recorder(tmp_path)
    try:
        rec.write_summary({"steps": 3}, running=True)
        assert json.loads((tmp_path / "summary.json").read_text()) == {"steps": 3, "running": True}
        rec.write_summary({"steps": 4})
        assert json.loads((tmp_path / "summary.json").read_text()) == {"steps": 4, "running": False}
        assert sorted(p.name for p in tmp_path.iterdir()) == ["events.jsonl", "mission.tlog", "summary.json"]
    finally:
        rec.close()


def test_each_event_line_is_on_disk_as_soon_as_it_is_written(tmp_path):
    rec = Recorder(tmp_path)
    try:
        for step in range(1, 4):
            rec.event("step", step=step, vehicles=[], others=[], decide_ms=0.1)
            # another reader sees it at once: nothing waits in the recorder's buffer
            assert (tmp_path / "events.jsonl").read_text().count("\n") == step
        rec.packet(b"\xfd" + bytes(20))
        deadline = time.monotonic() + 5
        while (tmp_path / "mission.tlog").stat().st_size == 0:  # the flusher thread writes it out
            assert time.monotonic() < deadline, "tlog not flushed within 5 s"
            time.sleep(0.05)
    finally:
        rec.close()
