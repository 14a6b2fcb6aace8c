"""The recording can never take the flight down: a write that fails (a full disk, an I/O error, a
read-only mount, a removed folder) is reported once, the recording degrades (the tlog and the bulky
files first, then events.jsonl) and the mission's end is written into the space reserved for it; a
MAVLink listener that raises is reported once and its vehicle judged silent; `swarmctl demo` on a
400 KB disk gives every vehicle its end action and exits 2 without a traceback."""

from __future__ import annotations

import asyncio
import errno
import json
import logging
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

import swarmctl.mission.recorder as recorder_module
from swarmctl.mavlink.autopilots.ardupilot import ArduPilotVehicle
from swarmctl.mavlink.errors import CommandTimeout
from swarmctl.mavlink.network import MavlinkLink
from swarmctl.mission.events import check_event
from swarmctl.mission.recorder import BULKY, Recorder, reserve_for
from tests.mavlink_support import mock_vehicles, run, until
from tests.mission_support import small_grid, small_mission

ROOT = Path(__file__).resolve().parent.parent
FRAME = bytes.fromhex("fd09000001010000000000000000000203510403") + bytes(2)  # 22 bytes, a HEARTBEAT's length


class FullDisk:
    """A disk of `free` bytes for what the recorder writes through recorder._write, its reserve
    included: a write that does not fit is written in part, then the next fails with `error` (as the
    kernel does). `error` other than ENOSPC: the device fails after `free` bytes, whatever is freed."""

    def __init__(self, free: int, error: int = errno.ENOSPC):
        self.free, self.error = free, error
        self.failures = 0

    def write(self, fd: int, data: Any) -> int:
        n = len(data)
        if n <= self.free:
            self.free -= n
            return os.write(fd, data)
        if self.free > 0:
            part, self.free = self.free, 0
            return os.write(fd, data[:part])
        self.failures += 1
        raise OSError(self.error, os.strerror(self.error))

    def install(self, patch: Any) -> None:
        """Into the recorder (`patch(object, name, value)`: pytest's monkeypatch.setattr, or setattr)."""
        disk = self

        def make_reserve(rec: Recorder, size: int) -> int | None:
            if size > disk.free:
                raise OSError(errno.ENOSPC, f"{os.strerror(errno.ENOSPC)}: the reserve does not fit")
            disk.free -= size
            rec._held = size
            return -1 if size > 0 else None

        def release(rec: Recorder) -> None:
            if rec._reserve is not None:
                rec._reserve = None
                if disk.error == errno.ENOSPC:  # freed space helps a full disk, not a failing one
                    disk.free += rec._held

        patch(recorder_module, "_write", self.write)
        patch(Recorder, "_make_reserve", make_reserve)
        patch(Recorder, "_release", release)


def lines_of(path: Path) -> list[dict]:
    """Every line of a JSON-lines file, each of which must parse and follow the schema."""
    text = path.read_text()
    assert text == "" or text.endswith("\n"), "the last line is cut short"
    out = [json.loads(line) for line in text.splitlines()]
    for line in out:
        check_event(line, strict=True)
    return out


def recording_errors(caplog) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.name == "swarmctl.mission.recorder" and r.levelno >= logging.ERROR]


def step(rec: Recorder, n: int) -> None:
    rec.plain_event("step", step=n, vehicles=[], others=[], decide_ms=0.5)


@pytest.mark.parametrize("error", [errno.ENOSPC, errno.EIO, errno.EROFS], ids=["ENOSPC", "EIO", "EROFS"])
def test_a_failing_disk_is_reported_once_and_the_recording_degrades_to_whole_lines(
    tmp_path, monkeypatch, caplog, error
):
    disk = FullDisk(free=reserve_for(2) + 6000, error=error)
    disk.install(monkeypatch.setattr)
    rec = Recorder(tmp_path, reserve=reserve_for(2))
    try:
        rec.event(
            "mission",
            name="m",
            policy="random",
            altitude=20,
            end_action="land",
            grid=[5, 5],
            vehicles=["a"],
            fence=None,
        )
        for n in range(1, 400):  # packets, steps and their inputs until the disk gives out, and beyond
            for _ in range(20):
                rec.packet(FRAME)
            rec.flush()
            step(rec, n)
        assert set(BULKY) | {"events.jsonl"} <= set(rec.lost)
        rec.ending()
        rec.event("end", outcome="time limit", step=399)
        rec.event("end_action", vehicle="a", action="land", cell=[1, 1])
        final = rec.write_summary({"steps": 399, "recording_lost": dict(rec.lost)})
    finally:
        rec.close()
    errors = recording_errors(caplog)
    assert len(errors) == 1 and errors[0].exc_info is None  # one line, no traceback
    name = errno.errorcode[error]
    assert f"({name})" in errors[0].getMessage() and str(tmp_path) in errors[0].getMessage()
    events = lines_of(tmp_path / "events.jsonl")  # whole lines only, whatever was cut
    assert (tmp_path / "mission.tlog").stat().st_size % (8 + len(FRAME)) == 0  # whole packets only
    lost = {e["file"]: e["error"] for e in events if e["event"] == "recording_lost"}
    if error == errno.ENOSPC:  # the reserve made room for the end
        assert final is not None and json.loads(final.read_text())["running"] is False
        assert [e["event"] for e in events[-2:]] == ["end", "end_action"]
        assert lost["mission.tlog"].endswith(f"({name})") or lost["events.jsonl"].endswith(f"({name})")
        assert set(lost) == set(BULKY) | {"events.jsonl"}
    else:  # a device that fails keeps failing: the summary is lost too, and said so
        assert final is None and "summary.json" in rec.lost


def test_the_reserve_is_what_the_end_is_written_into(tmp_path, monkeypatch, caplog):
    """The disk fills only at the mission's end: the reserve, kept until then, is released, the bulky
    files stop, and the line that did not fit is written after all."""
    disk = FullDisk(free=reserve_for(1) + 3000)
    disk.install(monkeypatch.setattr)
    rec = Recorder(tmp_path, reserve=reserve_for(1))
    try:
        step(rec, 1)
        rec.ending()
        assert not rec.lost and rec._reserve is not None  # nothing lost yet: the reserve is kept
        for n in range(2, 60):
            step(rec, n)
        rec.event("end", outcome="complete", step=60)
        assert rec.write_summary({"steps": 60}) is not None
    finally:
        rec.close()
    events = lines_of(tmp_path / "events.jsonl")
    assert events[-1]["event"] == "end" and [e["step"] for e in events if e["event"] == "step"] == list(range(1, 60))
    assert set(rec.lost) == set(BULKY)  # stopped to keep the room for the end: events.jsonl lost nothing
    assert len(recording_errors(caplog)) == 1


def test_a_removed_folder_is_reported_once_and_nothing_raises(tmp_path, caplog):
    folder = tmp_path / "rec"
    rec = Recorder(folder)
    try:
        step(rec, 1)
        shutil.rmtree(folder)
        for n in range(2, 5):
            step(rec, n)
            assert rec.write_summary({"steps": n}, running=True) is None
        rec.ending()
        assert rec.write_summary({"steps": 4}) is None
    finally:
        rec.close()
    errors = recording_errors(caplog)
    assert len(errors) == 1 and "summary.json" in errors[0].getMessage() and "(ENOENT)" in errors[0].getMessage()
    assert "summary.json" in rec.lost


def test_a_recording_without_room_for_its_end_is_refused_before_anything_flies(tmp_path):
    with pytest.raises(OSError, match="kept for the end of the recording"):
        Recorder(tmp_path, reserve=2**62)


# --- MAVLink listeners --------------------------------------------------------------------------------


def test_a_listener_that_raises_is_reported_once_and_its_vehicle_judged_silent(caplog):
    calls = {"per message": 0, "batch": 0}

    def broken(msg: Any) -> None:
        calls["per message"] += 1
        raise ValueError("no room for it")

    def broken_batch(msgs: list) -> None:
        calls["batch"] += 1
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    async def scenario() -> tuple[bool, list[str], bool]:
        link = await MavlinkLink("udpin:127.0.0.1:0").open()
        try:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")):
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                link.add_batch_listener(broken_batch)
                link.add_listener(broken, ("HEARTBEAT",))
                await until(lambda: v.lost, 5)
                received = link.stats.received
                await until(lambda: link.stats.received > received + 20, 5)  # its messages still come
                await asyncio.sleep(1.5)  # heartbeats among them
                still_lost = v.lost
                await v.close()
                return still_lost, [e for _t, _s, e in link.events], 1 in link.silenced
        finally:
            await link.close()

    started = time.monotonic()
    still_lost, events, silenced = run(scenario())
    assert time.monotonic() - started < 20
    assert still_lost and silenced and events == ["seen", "lost"]  # as the watchdog judges a silent one
    assert calls == {"per message": 1, "batch": 1}  # neither called again
    errors = [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 2 and all(r.exc_info is None for r in errors)  # one line each, no traceback
    text = " ".join(r.getMessage() for r in errors)
    assert "broken" in text and "vehicle 1 is treated as silent" in text and "broken_batch" in text


def test_a_silenced_vehicle_is_still_sent_its_end_action():
    # its link is up, so its own GCS failsafe will not act: the controller's end action still goes out
    # (Controller._end_action), unconfirmed, since its answers are no longer followed
    def broken(msg: Any) -> None:
        raise ValueError("no room for it")

    async def scenario() -> tuple[str | None, str]:
        link = await MavlinkLink("udpin:127.0.0.1:0").open()
        try:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")) as (mock,):
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                assert v.silenced is None
                link.add_listener(broken, ("HEARTBEAT",))
                await until(lambda: v.lost, 5)
                with pytest.raises(CommandTimeout):  # no acknowledgement is heard
                    await v.rtl()
                await until(lambda: mock.mode_name == "RTL", 5)
                why, mode = v.silenced, mock.mode_name
                await v.close()
                return why, mode
        finally:
            await link.close()

    why, mode = run(scenario())
    assert why is not None and "broken" in why and mode == "RTL"


# --- the demo on a 400 KB disk --------------------------------------------------------------------------

# the child's recorder on a simulated 400 KB disk, where no tmpfs can be mounted
RUNNER = """
import sys
from tests.test_full_disk import FullDisk
FullDisk(int(sys.argv[1])).install(setattr)
from swarmctl.cli import main
sys.exit(main(sys.argv[2:]))
"""


def _mount_tmpfs(where: Path, size: str) -> bool:
    if not hasattr(os, "geteuid") or os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], capture_output=True)
    return done.returncode == 0


@pytest.fixture
def small_disk(tmp_path):
    """(a folder on a 400 KB tmpfs, True), or (a plain folder, False) where none can be mounted."""
    where = tmp_path / "disk"
    where.mkdir()
    mounted = _mount_tmpfs(where, "400k")
    try:
        yield where, mounted
    finally:
        if mounted:
            subprocess.run(["umount", "-l", str(where)], capture_output=True)


def test_the_demo_on_a_400_kb_disk_ends_every_flight_and_exits_2_without_a_traceback(tmp_path, small_disk):
    disk, mounted = small_disk
    room = reserve_for(3) + 40 * 1024  # the reserve, and a little for the flight: the disk fills early on
    mission = small_mission(tmp_path, saved_grid=small_grid(20, 20))
    mission.write_text(mission.read_text() + "[flight]\ntakeoff_at_once = 3\n")  # the test's time: all at once
    out = disk / "run"
    argv = ["demo", "--mission", str(mission), "--uavs", "3", "--policy", "random", "--speedup", "30"]
    argv += ["--out", str(out), "--no-live", "--time-limit", "1", "--end-action", "land"]
    if mounted:
        st = os.statvfs(disk)
        (disk / "ballast").write_bytes(bytes(st.f_bavail * st.f_frsize - room))
        command = [sys.executable, "-m", "swarmctl.cli", *argv]
    else:
        command = [sys.executable, "-c", RUNNER, str(room), *argv]
    started = time.monotonic()
    done = subprocess.run(
        command,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=120,
    )
    took = time.monotonic() - started
    err = done.stderr
    assert done.returncode == 2, err
    assert "Traceback" not in err, err
    disk_lines = [line for line in err.splitlines() if "No space left on device" in line]
    assert len(disk_lines) == 1 and disk_lines[0].startswith("recording: cannot write"), err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["running"] is False and summary["recording_lost"], summary
    assert [v["end_action"] for v in summary["vehicles"]] == ["land"] * 3, summary["vehicles"]
    assert {v["end_state"] for v in summary["vehicles"]} == {"landed"}
    events = lines_of(out / "events.jsonl")
    kinds = [e["event"] for e in events]
    assert "recording_lost" in kinds and kinds.count("end") == 1 and kinds.count("end_action") == 3
    assert "incomplete" in done.stdout
    print(f"demo on {'a 400 KB tmpfs' if mounted else 'a simulated full disk'}: {took:.1f} s; stderr:\n{err}")
