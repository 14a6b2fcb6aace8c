"""Whole missions against real SITL: `swarmctl fly` in a subprocess, real ArduCopter and PX4 instances,
real sockets, and what the recording and the simulators say afterwards.

    scenario = Scenario("trio", [Craft("alpha", ARDUCOPTER, (0, 0)), ...], time_limit=20.0)
    with Flights([scenario, ...]) as flights:   # every scenario starts at once, each in a thread of its own
        result = flights.result("trio")         # waits for that one; raises SitlError if it could not fly

A scenario holds the instance numbers it flies (ArduCopter -I 0-4 with --sysid N+1, PX4 -i 5-9 with
system id N+1) while it runs; one that needs more than are free waits for them, so any set of scenarios
runs, as many at once as there are instance numbers. Every port follows from the instance numbers (SITL's
own; a detector's socket 14650 + N), so scenarios never collide. Each scenario writes its mission file
(the Chicago Loop grid or the scenario's own, frontier, no [knowledge] section), starts
tools/sitl_detector.py for each vehicle given a detector, and runs fly; `during(flight)` is what happens
meanwhile (kill an instance, SIGTERM fly), each step on a condition read from the recording (no fixed
sleeps). After fly has exited, each surviving vehicle's own simulator is asked where it is (a port fly
did not use). Whatever happens, fly, the detectors and the instances are stopped before a result is
handed out, and before Flights exits.
"""

from __future__ import annotations

import base64
import contextlib
import json
import math
import signal
import sys
import tempfile
import threading
import time
import zlib
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from swarmctl.geo.grid import GeoGrid
from swarmctl.mavlink.codec import distance_m
from tests.px4_support import PX4_INSTANCES, instance_busy, px4_missing, px4_sitl
from tests.sitl_support import (
    ARDUCOPTER_INSTANCES,
    ROOT,
    SimProcess,
    SitlError,
    arducopter_busy,
    arducopter_missing,
    arducopter_sitl,
    mavlink_client,
    stop_all,
    wait_message,
)

ARDUCOPTER, PX4 = "arducopter", "px4"
GRID = ROOT / "missions" / "chicago-loop" / "grid.npz"  # 50 x 50 cells of 10 m, planned for 40 m
FAULT_ENTRY = ROOT / "tests" / "fault_entry.py"  # swarmctl with one part broken (Scenario.fault)
MISSION_ID = 7
ALTITUDE = 40.0
HOME_ALT = 180.0  # metres AMSL at the Chicago Loop
DETECTOR_PORT = 14650  # + the instance number: the mission's detector socket for that vehicle
# SITL's simulated 3300 mAh battery reads 15 % (swarmctl's return_below) about 6 minutes of vehicle time
# after arming: ten times the capacity lets a sped-up flight run its course
BATTERY_MAH = 33000
# the GCS failsafe a user is told to turn on (swarmctl's preflight refuses a vehicle without it): SITL's
# defaults are off (FS_GCS_ENABLE 0, NAV_DLL_ACT 0); 1 = RTL, 2 = return. ArduCopter's FS_GCS_TIMEOUT (5 s)
# counts simulated time: sped up N times it would lapse between two of the controller's 1 Hz heartbeats,
# so it is lengthened by the speed-up (PX4's start-up script does the same with its own)
ARDUCOPTER_FAILSAFE = {"FS_GCS_ENABLE": 1}
GCS_TIMEOUT_S = 5.0  # ArduCopter's default FS_GCS_TIMEOUT, in wall-clock seconds here
PX4_FAILSAFE = {"NAV_DLL_ACT": 2}
POLL_S = 0.2
POOL_WAIT_S = 900.0  # a scenario waits this long for instance numbers (the others' flights end sooner)


class Unavailable(SitlError):
    """The scenario cannot be flown here: a SITL binary is missing (the message is the skip reason)."""


@dataclass(frozen=True)
class Craft:
    """One vehicle of a scenario: its name, its autopilot, the grid cell it starts from, a detector."""

    name: str
    kind: str  # ARDUCOPTER or PX4
    home_cell: tuple[int, int]
    detector: bool = False


@dataclass
class Scenario:
    """A mission to fly against SITL and what happens while it flies."""

    name: str
    crafts: list[Craft]
    time_limit: float  # seconds of search (the mission's [timing] time_limit)
    end_action: str = "rtl"
    policy: str = "frontier"  # the mission's policy (a ddql PATH relative to the repository)
    targets: tuple[tuple[int, int], ...] = ()  # what the detectors see
    arducopter_speedup: float = 5.0
    px4_speed: float = 1.0
    takeoff_at_once: int | None = None  # None: every vehicle climbs at once
    timing: dict[str, float] = field(default_factory=dict)  # more [timing] keys
    during: Callable[[Flight], None] | None = None  # None: let fly run to its end
    deadline: float = 480.0  # wall seconds for the whole flight, end actions included
    grid: GeoGrid | None = None  # the grid flown (saved beside the mission file); None: the Chicago Loop's
    mission: dict[str, str] = field(default_factory=dict)  # more [mission] keys, values as TOML text
    fault: str | None = None  # a part of the controller that raises mid-search (tests/fault_entry.py)

    def needs(self, kind: str) -> int:
        return sum(c.kind == kind for c in self.crafts)

    def unavailable(self) -> str | None:
        """Why it cannot fly here (a binary missing), or None."""
        for kind, missing in ((ARDUCOPTER, arducopter_missing), (PX4, px4_missing)):
            if self.needs(kind) and (why := missing()) is not None:
                return why
        return None


# the swarms the tests and tools/sitl_search.py fly, from cells along the grid's south edge
TRIO = [Craft("alpha", ARDUCOPTER, (0, 0)), Craft("bravo", ARDUCOPTER, (2, 0)), Craft("charlie", ARDUCOPTER, (4, 0))]
PX4_PAIR = [Craft("papa", PX4, (0, 0)), Craft("quebec", PX4, (3, 0))]
MIXED = [Craft("papa", PX4, (0, 0)), Craft("alpha", ARDUCOPTER, (2, 0)), Craft("bravo", ARDUCOPTER, (4, 0))]


# --- the instance numbers: one table for every scenario of this process -----------------------------------


class InstancePool:
    """The tests' SITL instance numbers, handed to one scenario at a time; a number another program's SITL
    holds (its ports bound, PX4's lock) is skipped."""

    def __init__(self) -> None:
        self._held: set[tuple[str, int]] = set()
        self._changed = threading.Condition()

    def _free(self, kind: str) -> list[int]:
        table, busy = (ARDUCOPTER_INSTANCES, arducopter_busy) if kind == ARDUCOPTER else (PX4_INSTANCES, instance_busy)
        return [n for n in table if (kind, n) not in self._held and busy(n) is None]

    @contextlib.contextmanager
    def hold(
        self, arducopters: int, px4s: int, stopping: threading.Event, timeout: float = POOL_WAIT_S
    ) -> Iterator[tuple[list[int], list[int]]]:
        """Wait until that many numbers of each table are free, and hold them until the block ends;
        SitlError after `timeout` seconds (another program's instances hold them)."""
        for kind, count, table in ((ARDUCOPTER, arducopters, ARDUCOPTER_INSTANCES), (PX4, px4s, PX4_INSTANCES)):
            if count > len(table):
                raise SitlError(f"{count} {kind} instances wanted, the table has {len(table)}")
        deadline = time.monotonic() + timeout
        with self._changed:
            while True:
                if stopping.is_set():
                    raise SitlError("stopped while waiting for instance numbers")
                free_ac, free_px4 = self._free(ARDUCOPTER), self._free(PX4)
                if time.monotonic() > deadline:
                    raise SitlError(
                        f"{arducopters} ArduCopter and {px4s} PX4 instance numbers wanted, free after {timeout:g} s: "
                        f"ArduCopter {free_ac}, PX4 {free_px4} (stop the other SITL runs)"
                    )
                if len(free_ac) >= arducopters and len(free_px4) >= px4s:
                    taken = [(ARDUCOPTER, n) for n in free_ac[:arducopters]] + [(PX4, n) for n in free_px4[:px4s]]
                    self._held.update(taken)
                    break
                self._changed.wait(0.5)  # also re-checks what other programs hold
        try:
            yield free_ac[:arducopters], free_px4[:px4s]
        finally:
            with self._changed:
                self._held.difference_update(taken)
                self._changed.notify_all()


POOL = InstancePool()


# --- one flight ---------------------------------------------------------------------------------------------


@dataclass
class Landing:
    """Where a vehicle's own simulator says it is after fly has exited."""

    lat: float
    lon: float
    rel_alt: float
    armed: bool
    from_home_m: float  # horizontal distance to the home it reports


class Flight:
    """A scenario being flown: its instances (by vehicle name), the fly process, the recording."""

    def __init__(self, scenario: Scenario, folder: Path, stopping: threading.Event):
        self.scenario, self.folder, self.stopping = scenario, folder, stopping
        self.recording = folder / "recording"
        self.mission_file = folder / "mission.toml"
        self.instances: dict[str, Any] = {}  # name -> ArduCopterSitl | PX4Sitl
        self.fly: SimProcess | None = None
        self.detectors: list[SimProcess] = []
        self.killed: dict[str, float] = {}  # name -> when (time.monotonic())
        self.marks: dict[str, float] = {}  # what happened when, seconds after fly started
        self._events: list[dict] = []
        self._events_read = 0

    # --- reading the recording while it is written ---------------------------------------------------------
    def summary(self) -> dict | None:
        """summary.json as it is now (replaced whole by fly, so never half written), or None."""
        try:
            return json.loads((self.recording / "summary.json").read_text())
        except (OSError, ValueError):
            return None

    def vehicle(self, name: str) -> dict | None:
        summary = self.summary()
        return None if summary is None else next((v for v in summary["vehicles"] if v["name"] == name), None)

    def events(self) -> list[dict]:
        """events.jsonl's whole lines so far."""
        try:
            with open(self.recording / "events.jsonl", "rb") as f:
                f.seek(self._events_read)
                data = f.read()
        except OSError:
            return self._events
        whole = data[: data.rfind(b"\n") + 1]
        self._events_read += len(whole)
        self._events += [json.loads(line) for line in whole.splitlines() if line.strip()]
        return self._events

    def states(self, name: str) -> list[str]:
        return [e["state"] for e in self.events() if e["event"] == "state" and e["vehicle"] == name]

    def elapsed(self) -> float:
        assert self.fly is not None
        return time.monotonic() - self.fly.started_at

    def mark(self, what: str) -> None:
        self.marks[what] = round(self.elapsed(), 1)

    # --- waiting and acting --------------------------------------------------------------------------------
    def wait(self, condition: Callable[[], Any], timeout: float, what: str, fly_may_exit: bool = False) -> Any:
        """Wait until condition() is true (checked every POLL_S); SitlError when fly exits first (unless
        `fly_may_exit`), after `timeout` seconds, or when the run is stopped. Returns condition()'s value."""
        assert self.fly is not None
        deadline = time.monotonic() + timeout
        while not (value := condition()):
            if self.stopping.is_set():
                raise SitlError(f"{self.scenario.name}: stopped while waiting for {what}")
            if not fly_may_exit and not self.fly.alive():
                raise SitlError(
                    f"{self.scenario.name}: fly exited with {self.fly.process.returncode} while waiting for {what}; "
                    f"{self.vehicles_now()}; its output ends:\n{self.fly.console_tail(3000)}"
                )
            if time.monotonic() > deadline:
                raise SitlError(
                    f"{self.scenario.name}: timed out after {timeout:g} s waiting for {what}; "
                    f"{self.vehicles_now()}; fly's output ends:\n{self.fly.console_tail(3000)}"
                )
            time.sleep(POLL_S)
        return value

    def vehicles_now(self) -> str:
        """The vehicles as summary.json has them now (state, steps, error, when it was written), for errors."""
        summary = self.summary()
        if summary is None:
            return "no summary.json"
        states = ", ".join(
            f"{v['name']} {v['final_state']} {v['steps']} steps" + (f" ({v['error']})" if v.get("error") else "")
            for v in summary["vehicles"]
        )
        return f"summary.json (running {summary.get('running')}): {states}"

    def searching(self, names: Sequence[str], steps: int = 1) -> bool:
        """Every one of these vehicles searches and has made at least `steps` decisions."""
        summary = self.summary()
        if summary is None:
            return False
        by_name = {v["name"]: v for v in summary["vehicles"]}
        return all(by_name[n]["final_state"] in ("search", "hover") and by_name[n]["steps"] >= steps for n in names)

    def steps(self, name: str) -> int:
        v = self.vehicle(name)
        return 0 if v is None else int(v["steps"])

    def kill(self, name: str) -> None:
        """SIGKILL vehicle `name`'s simulator (and its children)."""
        proc = self.instances[name].proc
        proc.process.send_signal(signal.SIGKILL)
        proc.process.wait(10)
        self.killed[name] = time.monotonic()
        self.mark(f"killed {name}")

    def terminate(self) -> None:
        """SIGTERM to fly, as a service manager or Ctrl-C's kin would send it."""
        assert self.fly is not None
        self.fly.process.send_signal(signal.SIGTERM)
        self.mark("SIGTERM")

    def wait_exit(self, timeout: float) -> int:
        """fly's exit status, once it has exited; SitlError after `timeout` seconds or when the run is stopped."""
        assert self.fly is not None
        self.wait(lambda: self.fly.process.poll() is not None, timeout, "fly to exit", fly_may_exit=True)
        return self.fly.process.returncode


@dataclass
class FlightResult:
    """What a flown scenario left: fly's exit status and output, the recording, the simulators' word."""

    scenario: Scenario
    rc: int
    output: str  # fly's stdout and stderr
    summary: dict
    events: list[dict]
    knowledge: list[dict]  # knowledge.jsonl's lines
    landings: dict[str, Landing | None]  # per surviving vehicle (None: its simulator did not say)
    killed: list[str]
    marks: dict[str, float]
    wall_s: float  # fly's run
    grid: GeoGrid

    def vehicle(self, name: str) -> dict:
        return next(v for v in self.summary["vehicles"] if v["name"] == name)

    def cells(self, name: str) -> set[tuple[int, int]]:
        """The distinct cells the vehicle flew to: each decision's cell, and the last one."""
        out = {
            tuple(v["cell"])
            for e in self.events
            if e["event"] == "step"
            for v in e["vehicles"]
            if v["vehicle"] == name and v["cell"] is not None
        }
        last = self.vehicle(name)["cell"]
        return out | ({tuple(last)} if last is not None else set())

    def explored(self, name: str) -> np.ndarray:
        """The vehicle's last knowledge snapshot: explored cells (W, H) bool."""
        lines = [k for k in self.knowledge if k["vehicle"] == name]
        if not lines:
            return np.zeros((self.grid.width, self.grid.height), dtype=bool)
        bits = np.unpackbits(np.frombuffer(zlib.decompress(base64.b64decode(lines[-1]["explored"])), dtype=np.uint8))
        return bits[: self.grid.width * self.grid.height].reshape(self.grid.width, self.grid.height).astype(bool)

    def end_actions(self) -> dict[str, str]:
        return {e["vehicle"]: e["action"] for e in self.events if e["event"] == "end_action"}

    def describe(self) -> str:
        """A few lines for a failing assertion: exit status, outcome, each vehicle, the marks."""
        rows = [f"{self.scenario.name}: rc {self.rc}, outcome {self.summary.get('outcome')}, marks {self.marks}"]
        for v in self.summary.get("vehicles", []):
            rows.append(
                f"  {v['name']}: {v['final_state']} / {v['end_state']}, steps {v['steps']}, "
                f"cells {len(self.cells(v['name']))}, received {v['knowledge_received']}, error {v['error']}, "
                f"landing {self.landings.get(v['name'])}"
            )
        return "\n".join(rows) + "\n--- fly's output ends:\n" + self.output[-2500:]


def mission_text(scenario: Scenario, crafts: dict[str, Any], grid_file: Path = GRID) -> str:
    """The mission file: no [knowledge] section, frontier, the scenario's timing and [mission] keys."""
    timing = {"step_period": 1.0, "time_limit": scenario.time_limit, **scenario.timing}
    at_once = scenario.takeoff_at_once or len(scenario.crafts)
    lines = [
        "[mission]",
        f'name = "sitl-{scenario.name}"',
        f"id = {MISSION_ID}",
        f'grid = "{grid_file}"',
        f"altitude = {ALTITUDE}",
        f'policy = "{policy_spec(scenario.policy)}"',
        f'end_action = "{scenario.end_action}"',
        *(f"{k} = {v}" for k, v in scenario.mission.items()),
        "[timing]",
        *(f"{k} = {float(v)!r}" for k, v in timing.items()),
        "[flight]",
        f"takeoff_at_once = {at_once}",
    ]
    for craft in scenario.crafts:
        sim = crafts[craft.name]
        lines += ["[[vehicles]]", f'name = "{craft.name}"', f'connection = "{sim.connection}"', f"sysid = {sim.sysid}"]
        if craft.detector:
            lines.append(f'detector = "udp:127.0.0.1:{DETECTOR_PORT + sim.instance}"')
    return "\n".join(lines) + "\n"


def policy_spec(policy: str) -> str:
    """The mission file's policy: a ddql model's path made absolute (the mission file lives elsewhere)."""
    kind, sep, rest = policy.partition(":")
    if kind in ("ddql", "ddql-greedy") and sep:
        path, sep2, options = rest.partition(":")
        return f"{kind}:{(ROOT / path).resolve()}{sep2}{options}"
    return policy


def homes(grid: GeoGrid, crafts: Sequence[Craft]) -> list[tuple[float, ...]]:
    out = []
    for c in crafts:
        lat, lon = grid.cell_to_latlon(*c.home_cell)
        out.append((lat, lon, HOME_ALT, 0.0) if c.kind == ARDUCOPTER else (lat, lon, HOME_ALT))
    return out


def detector_process(
    scenario: Scenario, craft: Craft, index: int, sim: Any, folder: Path, grid_file: Path = GRID
) -> SimProcess:
    """tools/sitl_detector.py for an ArduCopter: its SERIAL1 in, the mission's detector socket out."""
    argv = [sys.executable, str(ROOT / "tools" / "sitl_detector.py"), "--telemetry", f"tcp:127.0.0.1:{sim.ports[1]}"]
    argv += ["--sysid", str(sim.sysid), "--grid", str(grid_file), "--mission-id", str(MISSION_ID)]
    argv += ["--altitude", str(ALTITUDE), "--vehicle", str(index)]
    argv += ["--send", f"udp:127.0.0.1:{DETECTOR_PORT + sim.instance}"]
    for x, y in scenario.targets:
        argv += ["--target", f"{x},{y}"]
    return SimProcess(f"detector of {craft.name}", argv, folder / f"detector-{craft.name}")


def landing(craft: Craft, sim: Any, timeout: float = 20.0) -> Landing | None:
    """Where the vehicle's simulator says it is, on a port fly did not use (ArduCopter: SERIAL2; PX4: the
    API link, free again once fly has exited); None if it does not say within `timeout` seconds."""
    from pymavlink import mavutil

    mav = mavutil.mavlink
    address = f"tcp:127.0.0.1:{sim.ports[2]}" if craft.kind == ARDUCOPTER else sim.connection
    try:
        with mavlink_client(address, source_system=253) as conn:
            hb = wait_message(conn, "HEARTBEAT", timeout, sysid=sim.sysid)

            def ask() -> None:
                for msg_id in (mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mav.MAVLINK_MSG_ID_HOME_POSITION):
                    conn.mav.command_long_send(sim.sysid, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0, msg_id, 0, 0, 0, 0, 0, 0)

            pos = wait_message(conn, "GLOBAL_POSITION_INT", timeout, sysid=sim.sysid, every=ask)
            home = wait_message(conn, "HOME_POSITION", timeout, sysid=sim.sysid, every=ask)
            hb = wait_message(conn, "HEARTBEAT", timeout, sysid=sim.sysid)
    except (SitlError, OSError):
        return None
    lat, lon = pos.lat / 1e7, pos.lon / 1e7
    return Landing(
        lat,
        lon,
        pos.relative_alt / 1000.0,
        bool(hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED),
        distance_m(lat, lon, home.latitude / 1e7, home.longitude / 1e7),
    )


def fly_scenario(scenario: Scenario, stopping: threading.Event, keep: Path | None = None) -> FlightResult:
    """Fly one scenario from start to end (see the module docstring); SitlError when it cannot. `keep`: a
    folder to keep the mission file, the recording and every console in (default: a temporary one,
    removed)."""
    why = scenario.unavailable()
    if why is not None:
        raise Unavailable(why)
    grid = scenario.grid if scenario.grid is not None else GeoGrid.load(GRID)
    ac = [c for c in scenario.crafts if c.kind == ARDUCOPTER]
    px = [c for c in scenario.crafts if c.kind == PX4]
    with contextlib.ExitStack() as stack:
        if keep is None:
            folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix=f"swarmctl-sitl-{scenario.name}-")))
        else:
            folder = keep
            folder.mkdir(parents=True, exist_ok=True)
        grid_file = GRID if scenario.grid is None else scenario.grid.save(folder / "grid.npz")
        numbers_ac, numbers_px4 = stack.enter_context(POOL.hold(len(ac), len(px), stopping))
        sims: dict[str, Any] = {}
        if ac:
            copters = stack.enter_context(
                arducopter_sitl(
                    len(ac),
                    homes=homes(grid, ac),
                    speedup=scenario.arducopter_speedup,
                    instances=numbers_ac,
                    params={
                        "BATT_CAPACITY": BATTERY_MAH,
                        **ARDUCOPTER_FAILSAFE,
                        "FS_GCS_TIMEOUT": min(120.0, GCS_TIMEOUT_S * scenario.arducopter_speedup),
                    },
                )
            )
            sims.update({c.name: s for c, s in zip(ac, copters)})
        if px:
            vehicles = stack.enter_context(
                px4_sitl(
                    len(px), homes=homes(grid, px), instances=numbers_px4, speed=scenario.px4_speed, params=PX4_FAILSAFE
                )
            )
            sims.update({c.name: s for c, s in zip(px, vehicles)})
        flight = Flight(scenario, folder, stopping)
        flight.instances = sims
        flight.mission_file.write_text(mission_text(scenario, sims, grid_file))
        procs = stack.enter_context(_stopped_first())
        for index, craft in enumerate(scenario.crafts):
            if craft.detector:
                if craft.kind != ARDUCOPTER:
                    raise SitlError(f"{scenario.name}: the detector tool reads ArduCopter SERIAL1, not {craft.kind}")
                detector = detector_process(scenario, craft, index, sims[craft.name], folder, grid_file)
                flight.detectors.append(detector.start())
                procs.append(flight.detectors[-1])
        entry = ["-m", "swarmctl.cli"] if scenario.fault is None else [str(FAULT_ENTRY), scenario.fault, "0"]
        argv = [sys.executable, *entry, "fly", "--yes", "--no-live", "--out", str(flight.recording)]
        flight.fly = SimProcess("swarmctl fly", argv + [str(flight.mission_file)], folder / "fly").start()
        procs.append(flight.fly)
        if scenario.during is not None:
            scenario.during(flight)
        rc = flight.wait_exit(max(1.0, scenario.deadline - flight.elapsed()))
        wall = flight.elapsed()
        landings = {c.name: landing(c, sims[c.name]) for c in scenario.crafts if c.name not in flight.killed}
        summary = flight.summary()
        if summary is None:
            raise SitlError(f"{scenario.name}: fly exited with {rc}, no summary.json:\n{flight.fly.console_tail(3000)}")
        knowledge_file = flight.recording / "knowledge.jsonl"
        knowledge = [json.loads(x) for x in knowledge_file.read_text().splitlines()] if knowledge_file.is_file() else []
        return FlightResult(
            scenario,
            rc,
            flight.fly.console(),
            summary,
            flight.events(),
            knowledge,
            landings,
            sorted(flight.killed),
            flight.marks,
            round(wall, 1),
            grid,
        )
    raise AssertionError("unreachable")  # pragma: no cover


@contextlib.contextmanager
def _stopped_first() -> Iterator[list[SimProcess]]:
    """The processes of a flight (fly, detectors), stopped on the way out before the instances are."""
    procs: list[SimProcess] = []
    try:
        yield procs
    finally:
        stop_all(procs, grace=10.0)


# --- several at once ------------------------------------------------------------------------------------------


class Flights:
    """Scenarios flown at once, each in a thread of its own (they wait for instance numbers as needed)."""

    def __init__(self, scenarios: Sequence[Scenario], keep: Path | None = None):
        names = [s.name for s in scenarios]
        if len(set(names)) != len(names):
            raise ValueError(f"scenario names repeat: {names}")
        self.scenarios = {s.name: s for s in scenarios}
        self.keep = keep
        self.stopping = threading.Event()
        self.futures: dict[str, Future] = {}
        self.threads: list[threading.Thread] = []
        self.started = 0.0

    def __enter__(self) -> Flights:
        self.started = time.monotonic()
        for name, scenario in self.scenarios.items():
            future: Future = Future()
            self.futures[name] = future
            thread = threading.Thread(target=self._run, args=(scenario, future), name=f"sitl {name}", daemon=True)
            self.threads.append(thread)
            thread.start()
        return self

    def _run(self, scenario: Scenario, future: Future) -> None:
        started = time.monotonic()
        try:
            result = fly_scenario(scenario, self.stopping, None if self.keep is None else self.keep / scenario.name)
        except BaseException as exc:  # handed to whoever waits for this scenario
            future.set_exception(exc)
        else:
            result.marks["scenario_s"] = round(time.monotonic() - started, 1)
            result.marks["done_after_s"] = round(time.monotonic() - self.started, 1)
            future.set_result(result)

    def result(self, name: str, timeout: float | None = None) -> FlightResult:
        """The scenario's result once it has flown (its exception if it could not)."""
        return self.futures[name].result(timeout)

    def timing(self, name: str) -> str:
        """One line: how long the scenario flew and when it was done, or why it did not fly."""
        future = self.futures[name]
        if not future.done():
            return "not done"
        if future.exception() is not None:
            return f"did not fly ({future.exception()})".splitlines()[0]
        result = future.result()
        return f"{result.marks['scenario_s']} s (fly {result.wall_s} s), done {result.marks['done_after_s']} s in"

    def __exit__(self, *exc: object) -> None:
        self.stopping.set()  # scenarios still waiting give up; flights in progress are stopped
        for thread in self.threads:
            thread.join()


LANDED_ALT_M = 2.0  # PX4 SIH read 1.1 m above home disarmed on the ground (its altitude estimate drifts)


def within(metres: float, landing: Landing | None) -> bool:
    """The vehicle is on the ground (disarmed, within LANDED_ALT_M of its home's altitude), within
    `metres` of its home."""
    if landing is None or landing.armed:
        return False
    return abs(landing.rel_alt) < LANDED_ALT_M and landing.from_home_m <= metres


def cells_apart(a: tuple[int, int], b: tuple[int, int]) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])
