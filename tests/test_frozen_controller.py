"""A frozen controller: `swarmctl fly` stopped (SIGSTOP) for 8 s mid-search, then continued (SIGCONT).

The mock vehicles live in this process (SimSwarm's one thread) and the controller in a child process,
so stopping the controller leaves the vehicles flying: their own GCS failsafe (5 s of wall-clock time
without the controller's heartbeat, whatever the mocks' speed-up) sends them home. When the controller
runs again it must see the link loss, take the vehicles back from their failsafe (rejoin) and search on
with every one of them; a mode a pilot chose meanwhile must be left alone.

One mission is flown for the module (`frozen`); each test reads what it left behind."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from pymavlink import mavutil

from swarmctl.sim.swarm import SimSwarm
from tests.mission_support import small_grid

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
FREEZE_S = 8.0
SPEEDUP = 10.0
FAILSAFE_S = 5.0  # the mocks' GCS failsafe timeout, wall-clock seconds
TIMEOUT = 60.0
WATCHED = ("uav1", "uav2", "uav3")  # left to their failsafe alone
PILOTED = "uav4"  # its pilot takes it over (LOITER) after its failsafe acted, while the controller is frozen


@dataclass
class Flight:
    events: list[dict]  # events.jsonl, whole
    before: int  # how many of them were written before the freeze
    frozen: tuple[float, float]  # SIGSTOP and SIGCONT, time.monotonic()
    ended: float  # SIGTERM, time.monotonic(): the end actions follow
    samples: list[tuple[float, dict]] = field(default_factory=list)  # (monotonic, name -> MockState)
    output: str = ""  # what `swarmctl fly` printed (stdout and stderr)
    returncode: int | None = None
    summary: dict = field(default_factory=dict)
    failsafe_texts: dict[int, list[str]] = field(default_factory=dict)  # sysid -> STATUSTEXTs in the tlog

    def after(self) -> list[dict]:
        return self.events[self.before :]

    def states(self, name: str) -> list[dict]:
        return [e for e in self.after() if e["event"] == "state" and e["vehicle"] == name]


def read_events(path: Path) -> list[dict]:
    """The whole lines of events.jsonl written so far (a line being written is left for the next read)."""
    if not path.exists():
        return []
    text = path.read_text()
    return [json.loads(line) for line in text[: text.rfind("\n") + 1].splitlines()]


def poll(condition, timeout: float, what: str, proc: subprocess.Popen | None = None):
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the controller exited ({proc.returncode}) while waiting for {what}")
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def write_mission(folder: Path, swarm: SimSwarm) -> Path:
    swarm.grid.save(folder / "grid.npz")
    body = (
        '[mission]\nname = "frozen"\ngrid = "grid.npz"\npolicy = "frontier"\nend_action = "land"\n'
        # end_timeout 0: the test's time, not the landings'
        "[timing]\nstep_period = 0.2\ntime_limit = 300\nend_timeout = 0\n"
        f"[flight]\ntakeoff_at_once = {len(swarm.mocks)}\n"
    )
    for i, mock in enumerate(swarm.mocks):
        body += f'[[vehicles]]\nname = "uav{i + 1}"\nsysid = {i + 1}\n'
        body += f'connection = "udpout:127.0.0.1:{mock.local_port}"\n'
    path = folder / "mission.toml"
    path.write_text(body)
    return path


def all_searching_since(events: list[dict], start: int, names: tuple[str, ...]) -> list[dict]:
    """The step records from events[start:] in which every one of `names` searches."""
    return [e for e in events[start:] if e["event"] == "step" and set(names) <= {v["vehicle"] for v in e["vehicles"]}]


def rejoined(events: list[dict], start: int, name: str) -> int | None:
    """Index of the `search` state (rejoined) of `name` after events[start], None before it."""
    for i in range(start, len(events)):
        e = events[i]
        if e["event"] == "state" and e["vehicle"] == name and e["state"] == "search" and e.get("rejoined"):
            return i
    return None


@pytest.fixture(scope="module")
def frozen(tmp_path_factory) -> Flight:
    folder = tmp_path_factory.mktemp("frozen")
    out = folder / "rec"
    grid = small_grid(16, 16, altitude=10.0)
    with SimSwarm(grid, uavs=4, seed=5, speedup=SPEEDUP, gcs_failsafe=FAILSAFE_S, carry_detectors=False) as swarm:
        mocks = {f"uav{i + 1}": m for i, m in enumerate(swarm.mocks)}
        samples: list[tuple[float, dict]] = []
        sampling = threading.Event()

        def sample() -> None:
            while not sampling.wait(0.02):
                samples.append((time.monotonic(), {name: m.state() for name, m in mocks.items()}))

        sampler = threading.Thread(target=sample, name="frozen-sampler", daemon=True)
        sampler.start()
        log = (folder / "output.txt").open("w")
        command = [sys.executable, "-m", "swarmctl.cli", "fly", str(write_mission(folder, swarm))]
        proc = subprocess.Popen(
            [*command, "--yes", "--no-live", "--out", str(out)],
            cwd=ROOT,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        events_file = out / "events.jsonl"
        try:
            poll(
                lambda: len(all_searching_since(read_events(events_file), 0, (*WATCHED, PILOTED))) >= 2,
                TIMEOUT,
                "two steps with every vehicle searching",
                proc,
            )
            os.kill(proc.pid, signal.SIGSTOP)
            stopped = time.monotonic()
            try:
                before = len(read_events(events_file))
                poll(
                    lambda: all(s.gcs_failsafe and s.mode == "RTL" for s in samples[-1][1].values()),
                    FREEZE_S - 0.5,
                    "every vehicle's GCS failsafe",
                )
                with mocks[PILOTED]._lock:
                    mocks[PILOTED]._set_mode_name("LOITER")  # as the pilot's mode switch would
                time.sleep(max(0.0, stopped + FREEZE_S - time.monotonic()))  # the deliberate stop
            finally:
                os.kill(proc.pid, signal.SIGCONT)
                resumed = time.monotonic()

            def everyone_back() -> bool:
                events = read_events(events_file)
                done = [rejoined(events, before, name) for name in WATCHED]
                if None in done:
                    return False
                return len(all_searching_since(events, max(done) + 1, WATCHED)) >= 3

            poll(everyone_back, TIMEOUT, "every vehicle to rejoin and search three steps", proc)
        finally:
            ended = time.monotonic()
            if proc.poll() is None:
                proc.send_signal(signal.SIGCONT)
                proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            log.close()
            sampling.set()
            sampler.join()
    flight = Flight(read_events(events_file), before, (stopped, resumed), ended, samples)
    flight.output = (folder / "output.txt").read_text()
    flight.returncode = proc.returncode
    flight.summary = json.loads((out / "summary.json").read_text())
    tlog = mavutil.mavlink_connection(str(out / "mission.tlog"))
    while (m := tlog.recv_match(type="STATUSTEXT")) is not None:
        flight.failsafe_texts.setdefault(m.get_srcSystem(), []).append(m.text)
    return flight


def test_the_vehicles_failsafes_act_while_the_controller_is_frozen(frozen):
    start, end = frozen.frozen
    during = [s for t, s in frozen.samples if start < t < end]
    for name in WATCHED:
        assert any(s[name].gcs_failsafe and s[name].mode == "RTL" and s[name].armed for s in during), name
        # the controller heard it too, once it ran again: the failsafe's STATUSTEXT is in its tlog
        assert "GCS Failsafe" in frozen.failsafe_texts.get(int(name[3:]), []), name


def test_after_the_freeze_every_vehicle_is_reported_lost_and_back_and_rejoins(frozen):
    after = frozen.after()
    for sysid in (1, 2, 3, 4):
        changes = [e["change"] for e in after if e["event"] == "link" and e["sysid"] == sysid]
        assert changes[:2] == ["lost", "back"], (sysid, changes)
    for name in WATCHED:
        states = frozen.states(name)
        assert [e["state"] for e in states][:3] == ["lost", "rejoin", "search"], (name, states)
        assert states[0]["last_cell"] is not None and states[2]["rejoined"] is True


def test_the_search_goes_on_with_every_vehicle_taken_back_from_its_failsafe(frozen):
    events = frozen.events
    back = max(rejoined(events, frozen.before, name) for name in WATCHED)
    steps = all_searching_since(events, back + 1, WATCHED)
    assert steps, "no step after the rejoin with every vehicle searching"
    last = [s for t, s in frozen.samples if t < frozen.ended][-1]
    assert all(last[name].mode == "GUIDED" and last[name].armed for name in WATCHED), last
    assert frozen.returncode == 130  # SIGTERM: the end actions, then "interrupted"
    assert frozen.summary["running"] is False and frozen.summary["outcome"] == "interrupted"
    timeouts = [e for e in frozen.after() if e["event"] == "step_timeout"]
    # a step in flight when the controller froze may time out; none after the vehicles rejoined
    assert all(events.index(e) < back for e in timeouts), timeouts


def test_a_mode_the_pilot_chose_while_the_controller_was_frozen_is_left_alone(frozen):
    _, end = frozen.frozen
    modes = {s[PILOTED].mode for t, s in frozen.samples if end < t < frozen.ended}
    assert modes == {"LOITER"}, modes
    states = frozen.states(PILOTED)
    assert any(e["state"] == "override" and e.get("reason") == "pilot" for e in states), states
    assert rejoined(frozen.events, frozen.before, PILOTED) is None, states


def test_the_controller_says_per_vehicle_what_it_found_when_it_resumed(frozen):
    lines = frozen.output.splitlines()
    for name in WATCHED:
        rejoin = [e for e in frozen.states(name) if e["state"] == "rejoin"][0]
        assert rejoin.get("mode") == "RTL" and len(rejoin.get("position", [])) == 3, rejoin
        assert any(name in line and "RTL" in line for line in lines), frozen.output
