"""Missions over links that lose, delay, duplicate and reorder (swarmctl.sim.relay), against the same
missions over clean links. Not a test: it measures.

1. Coverage: missions/chicago-loop/mission.toml with `time_limit = 90.0` (a copy in a temporary folder),
   flown by `swarmctl fly` against three `swarmctl mock-vehicle --speedup 10` processes (system ids and
   homes from the file's comments), each sending to a LossyRelay that forwards to the mission's port for
   it (14551-14553). Cells: the distinct `cell` of each vehicle in the recording's `step` records
   (searching and not), summed over the vehicles. Once with the faults, once through relays without any.
2. The demo's mission with detectors (what `swarmctl demo` flies: 3 mock vehicles, their hidden targets,
   the coordinated planner, speed-up 10, 300 s), every vehicle's link through a relay with the faults
   (SimSwarm(link_faults=...)), for each seed: does it complete?

    python tools/lossy_links.py [--part coverage|demo|both] [--seeds 0-4] [--loss 0.2] [--delay-ms 30]
        [--jitter-ms 20] [--duplicate 0.02] [--runs-dir DIR] [--json FILE]

A progress line every few seconds on stderr (steps and cells so far), a table at the end, and with
--json the figures, with what each recording says went wrong (link losses, step timeouts, states).
Ports 14551-14553 must be free (the mission file listens there).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import tempfile
import time
import tomllib
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmctl.sim.relay import LinkFaults, LossyRelay  # noqa: E402

MISSION = ROOT / "missions/chicago-loop/mission.toml"
GRID = ROOT / "missions/chicago-loop/grid.npz"
PROGRESS_S = 10.0  # seconds between progress lines
FLY_LIMIT_S = 420.0  # a mission run longer than this has hung: stopped, and said so
DEMO_TIME_LIMIT = 300.0  # what `swarmctl demo` gives its search (DEMO_SETTINGS)
CLEAN = LinkFaults()


# --- reading a recording -------------------------------------------------------------------------------


def events(folder: Path) -> list[dict[str, Any]]:
    """The recording's events (a line cut short by a run still writing is left out)."""
    path = folder / "events.jsonl"
    if not path.is_file():
        return []
    out = []
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return out


def cells_per_vehicle(records: list[dict[str, Any]]) -> dict[str, int]:
    """Distinct cells of each vehicle in the `step` records."""
    seen: dict[str, set[tuple[int, int]]] = {}
    for e in records:
        if e.get("event") != "step":
            continue
        for v in [*e.get("vehicles", []), *e.get("others", [])]:
            if v.get("cell") is not None:
                seen.setdefault(v["vehicle"], set()).add(tuple(v["cell"]))
    return {name: len(cells) for name, cells in sorted(seen.items())}


def what_happened(records: list[dict[str, Any]]) -> dict[str, Any]:
    """What the recording says about the search: steps, round times, link events, states entered,
    step timeouts, detector reports missed."""
    steps = [e for e in records if e.get("event") == "step"]
    times = [e["t"] for e in steps]
    rounds = [b - a for a, b in zip(times, times[1:])]
    kinds = Counter(e.get("event") for e in records)
    states = Counter(f"{e['vehicle']}:{e['state']}" for e in records if e.get("event") == "state")
    links = Counter(f"{e['sysid']}:{e['change']}" for e in records if e.get("event") == "link")
    return {
        "steps": len(steps),
        "round_mean_s": round(sum(rounds) / len(rounds), 3) if rounds else None,
        "rounds_over_1_5_s": sum(r > 1.5 for r in rounds),
        "step_timeouts": kinds.get("step_timeout", 0),
        "no_report": kinds.get("no_report", 0),
        "off_course": sum(1 for e in records if e.get("event") == "off_course"),
        "link_events": dict(links),
        "states": {k: n for k, n in states.items() if not k.endswith((":connect", ":preflight", ":takeoff"))},
    }


def summary(folder: Path) -> dict[str, Any]:
    path = folder / "summary.json"
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return {}


# --- running and watching ------------------------------------------------------------------------------


def watch(proc: subprocess.Popen, folder: Path, label: str, limit: float) -> int:
    """Wait for the run, printing a progress line every PROGRESS_S; stopped (SIGINT, then killed) past
    `limit` seconds. Its exit status."""
    started = time.monotonic()
    while True:
        try:
            return proc.wait(timeout=PROGRESS_S)
        except subprocess.TimeoutExpired:
            pass
        took = time.monotonic() - started
        records = events(folder)
        steps = sum(1 for e in records if e.get("event") == "step")
        cells = sum(cells_per_vehicle(records).values())
        print(f"  {label}: {took:4.0f} s, {steps} steps, {cells} cells", file=sys.stderr, flush=True)
        if took > limit:
            print(f"  {label}: still running after {limit:g} s, stopping it", file=sys.stderr, flush=True)
            stop(proc)
            return proc.returncode


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def swarmctl(*args: str) -> list[str]:
    return [sys.executable, "-m", "swarmctl.cli", *args]


def port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


# --- 1. coverage ---------------------------------------------------------------------------------------


def mock_commands(text: str) -> list[dict[str, str]]:
    """The `swarmctl mock-vehicle` lines of the mission file's comments, as option -> value."""
    out = []
    for line in text.splitlines():
        m = re.match(r"#\s*swarmctl mock-vehicle (.*)$", line.strip())
        if m:
            words = shlex.split(m.group(1))
            out.append(dict(zip(words[::2], words[1::2])))
    if not out:
        raise SystemExit(f"{MISSION}: no `swarmctl mock-vehicle` lines in its comments")
    return out


def mission_copy(folder: Path, time_limit: float) -> tuple[Path, list[dict[str, str]]]:
    """The mission file with `time_limit` and the grid's absolute path, in `folder`; and its mocks."""
    text = MISSION.read_text(encoding="utf-8")
    changed, n = re.subn(r"(?m)^time_limit\s*=\s*[0-9.]+", f"time_limit = {time_limit!r}", text)
    changed, g = re.subn(r'(?m)^grid\s*=\s*"grid.npz"', f"grid = {json.dumps(str(GRID))}", changed)
    if n != 1 or g != 1:
        raise SystemExit(f"{MISSION}: expected one time_limit and one grid line to change ({n}, {g})")
    spec = tomllib.loads(changed)
    assert spec["timing"]["time_limit"] == time_limit and Path(spec["mission"]["grid"]).is_file()
    path = folder / "mission.toml"
    path.write_text(changed, encoding="utf-8")
    return path, mock_commands(text)


def run_coverage(faults: LinkFaults, seed: int, time_limit: float, out: Path, label: str) -> dict[str, Any]:
    """One `swarmctl fly` of the chicago-loop mission against three mock-vehicle processes, each
    through a relay with `faults` each way."""
    folder = out / label
    with tempfile.TemporaryDirectory(prefix="lossy-links-") as tmp:
        mission, mocks = mission_copy(Path(tmp), time_limit)
        relays: list[LossyRelay] = []
        procs: list[subprocess.Popen] = []
        try:
            for m in mocks:
                port = int(m["--connect"].rsplit(":", 1)[1])
                if not port_free(port):
                    raise SystemExit(f"port {port} is in use: the mission listens there; stop what holds it")
                relay = LossyRelay(("127.0.0.1", port), faults, seed=seed * 100 + int(m["--sysid"]))
                relays.append(relay)
                relay.start()
                args = {**m, "--connect": f"udpout:127.0.0.1:{relay.port}"}
                argv = [word for pair in args.items() for word in pair]
                procs.append(subprocess.Popen(swarmctl("mock-vehicle", *argv), cwd=ROOT, stderr=subprocess.DEVNULL))
            with open(out / f"{label}.log", "w") as log:
                fly = subprocess.Popen(
                    swarmctl("fly", "--yes", "--no-live", "--out", str(folder), str(mission)),
                    cwd=ROOT,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                )
                code = watch(fly, folder, label, FLY_LIMIT_S)
        finally:
            for p in procs:
                stop(p)
            counts = [r.counts() for r in relays]
            for r in relays:
                r.stop()
    records = events(folder)
    per = cells_per_vehicle(records)
    return {
        "label": label,
        "faults": faults.describe(),
        "exit": code,
        "outcome": summary(folder).get("outcome"),
        "cells": sum(per.values()),
        "cells_per_vehicle": per,
        "recording": str(folder),
        **what_happened(records),
        "relays": [
            {"forward": vars(c.forward), "back": vars(c.back), "clients": c.clients, "refused": c.refused}
            for c in counts
        ],
    }


# --- 2. the demo with detectors ------------------------------------------------------------------------


def demo_run(seed: int, faults: LinkFaults, folder: Path) -> int:
    """What `swarmctl demo --seed SEED --no-live --out FOLDER` flies, every link through a relay (run in
    a process of its own by `run_demo`). Its exit status: 0 complete."""
    from swarmctl.geo.grid import GeoGrid
    from swarmctl.mission.cli import default_policy
    from swarmctl.mission.service import LiveView, run_controller
    from swarmctl.sim.swarm import SimSwarm
    from swarmctl.world.channel import Channel

    grid = GeoGrid.load(GRID)
    policy, _ = default_policy(seed)
    swarm = SimSwarm(
        grid, uavs=3, seed=seed, speedup=10.0, channel=Channel("ideal", cell_size=grid.cell), link_faults=faults
    )
    with swarm:
        plan = swarm.plan(policy, end_action="rtl", time_limit=DEMO_TIME_LIMIT, grid=GRID)
        code, result = run_controller(
            plan,
            folder,
            LiveView(live=False, quiet=True),
            extra_summary=lambda _c: {
                "relays": [
                    {"forward": vars(c.forward), "back": vars(c.back)} for c in (r.counts() for r in swarm.relays)
                ],
                "seed": seed,
            },
        )
    return code


def run_demo(seed: int, faults: LinkFaults, out: Path, label: str) -> dict[str, Any]:
    folder = out / label
    argv = [sys.executable, str(Path(__file__).resolve()), "--demo-run", str(seed), "--demo-out", str(folder)]
    argv += fault_args(faults)
    with open(out / f"{label}.log", "w") as log:
        proc = subprocess.Popen(argv, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
        code = watch(proc, folder, label, FLY_LIMIT_S)
    records = events(folder)
    result = summary(folder)
    return {
        "label": label,
        "seed": seed,
        "faults": faults.describe(),
        "exit": code,
        "outcome": result.get("outcome"),
        "complete": result.get("outcome") == "complete",
        "targets_found": len(result.get("targets_found", [])),
        "search_time_s": result.get("search_time_s"),
        "cells": sum(cells_per_vehicle(records).values()),
        "recording": str(folder),
        **what_happened(records),
        "relays": result.get("relays"),
    }


# --- the command line ----------------------------------------------------------------------------------


def fault_args(faults: LinkFaults) -> list[str]:
    return [
        "--loss",
        repr(faults.loss),
        "--delay-ms",
        repr(faults.delay * 1000),
        "--jitter-ms",
        repr(faults.jitter * 1000),
        "--duplicate",
        repr(faults.duplicate),
    ]


def seeds(text: str) -> list[int]:
    """ "0-4" or "0,2,5"."""
    try:
        if re.fullmatch(r"\d+-\d+", text):
            lo, hi = (int(x) for x in text.split("-"))
            if lo > hi:
                raise ValueError
            return list(range(lo, hi + 1))
        return [int(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give seeds as 0-4 or 0,2,5") from None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--part", choices=["coverage", "demo", "both"], default="both")
    ap.add_argument("--seeds", type=seeds, default=seeds("0-4"), help="demo seeds (default 0-4)")
    ap.add_argument("--loss", type=float, default=0.2, help="loss probability per datagram, each way")
    ap.add_argument("--delay-ms", type=float, default=30.0)
    ap.add_argument("--jitter-ms", type=float, default=20.0)
    ap.add_argument("--duplicate", type=float, default=0.02)
    ap.add_argument("--time-limit", type=float, default=90.0, help="coverage: the search's time limit, s")
    ap.add_argument("--no-clean", action="store_true", help="skip the runs over clean links")
    ap.add_argument("--runs-dir", type=Path, default=None, help="where the recordings go (default: a new folder)")
    ap.add_argument("--json", type=Path, default=None, help="write the figures here")
    ap.add_argument("--demo-run", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--demo-out", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    try:
        faults = LinkFaults(args.loss, args.delay_ms / 1000, args.jitter_ms / 1000, args.duplicate)
    except ValueError as exc:
        ap.error(str(exc))
    if not 1.0 <= args.time_limit <= 3600.0:
        ap.error("--time-limit: give seconds from 1 to 3600")
    if args.demo_run is not None:
        return demo_run(args.demo_run, faults, args.demo_out)
    out = args.runs_dir or Path(tempfile.mkdtemp(prefix="lossy-links-", dir=ROOT / "runs"))
    out.mkdir(parents=True, exist_ok=True)
    print(f"lossy links: {faults.describe()}, each way; recordings in {out}", file=sys.stderr, flush=True)
    results: dict[str, Any] = {"faults": faults.describe(), "coverage": [], "demo": []}
    if args.part in ("coverage", "both"):
        for f, label in [(faults, "coverage-lossy")] + ([] if args.no_clean else [(CLEAN, "coverage-clean")]):
            results["coverage"].append(run_coverage(f, 0, args.time_limit, out, label))
            write(results, args.json)
    if args.part in ("demo", "both"):
        for seed in args.seeds:
            kind = "clean" if faults == CLEAN else "lossy"
            results["demo"].append(run_demo(seed, faults, out, f"demo-seed{seed}-{kind}"))
            write(results, args.json)
    report(results)
    return 0


def write(results: dict[str, Any], path: Path | None) -> None:
    if path is not None:
        path.write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")


def report(results: dict[str, Any]) -> None:
    cov = {r["label"]: r for r in results["coverage"]}
    for r in results["coverage"]:
        print(
            f"{r['label']}: {r['cells']} cells {r['cells_per_vehicle']} in {r['steps']} steps "
            f"(round {r['round_mean_s']} s), outcome {r['outcome']}, step timeouts {r['step_timeouts']}, "
            f"links {r['link_events']}, states {r['states']}"
        )
    if "coverage-lossy" in cov and "coverage-clean" in cov and cov["coverage-clean"]["cells"]:
        ratio = cov["coverage-lossy"]["cells"] / cov["coverage-clean"]["cells"]
        print(f"coverage under loss: {ratio:.0%} of the clean run's")
    for r in results["demo"]:
        print(
            f"{r['label']}: {r['outcome']} ({r['targets_found']} targets, {r['search_time_s']} s, {r['steps']} steps), "
            f"step timeouts {r['step_timeouts']}, no_report {r['no_report']}, links {r['link_events']}, "
            f"states {r['states']}"
        )


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
