"""Soak: 50 mock vehicles flying a search for 30 minutes of mock time; is the controller's memory flat, the
recording's write latency steady, and are there step timeouts of the controller's own making?

The set-up is tools/controller_overhead.py's: the mock vehicles in a child process (SimSwarm over
loopback UDP, all in one thread), one controller in this process flying every vehicle in ground mode with
the demo's settings, recording as fly and demo do (the running summary.json included). Mock time runs
`--speedup` times faster than the wall clock, so the search's time limit is 30 minutes / speed-up of wall
time; the vehicles' link timing (heartbeats, telemetry, failsafes) stays in wall-clock seconds.

So that every vehicle flies to the end, fewer targets are hidden than there are vehicles (no vehicle
parks: the hover rule waits for as many targets as vehicles) and the mocks' batteries drain at
`--drain` % per mock second (the mock's default, 0.08, would send them home after 18 minutes).

While it flies, once a second (wall clock): the process's resident memory (RSS, /proc) and the Python
allocator's blocks in use (sys.getallocatedblocks), the controller's rounds so far and their mean own
time (Controller.overhead_ms), and its step timeouts. Every write of the recording is timed where it is
made (swarmctl.mission.recorder._write, the one function every byte goes through). The search is cut into
thirds; the table gives each third's figures and the verdict:

- memory flat: the median RSS of the last third within 10 % of the first third's;
- no growth in the write latency: the median events.jsonl write of the last third at most 1.5 times the
  first third's, or at most 20 us more;
- no step timeouts: the mocks are healthy and nothing is injected, so any step timeout is the
  controller's (or its machine's) own.

    python tools/soak.py [--vehicles 50] [--mock-minutes 30] [--speedup 10] [--policy random] [--out results/]

Exit status 0 when every verdict holds, 1 otherwise.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing as mp
import os
import statistics
import sys
import tempfile
import time
from array import array
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import swarmctl.mission.recorder as recorder_module  # noqa: E402
from swarmctl.bench import cpu_model  # noqa: E402
from swarmctl.geo.grid import GeoGrid  # noqa: E402
from swarmctl.mission.controller import Controller  # noqa: E402
from swarmctl.mission.recorder import Recorder  # noqa: E402
from swarmctl.mission.service import keep_summary  # noqa: E402
from swarmctl.sim.swarm import SimSwarm, hide_targets, sim_plan, start_cells  # noqa: E402
from tools.controller_overhead import machine_reference_ms  # noqa: E402

GRID = ROOT / "missions/chicago-loop/grid.npz"
MEMORY_TOLERANCE = 0.10
LATENCY_RATIO, LATENCY_SLACK_US = 1.5, 20.0
RECORDING = ("events.jsonl", "mission.tlog", "knowledge.jsonl", "inputs.jsonl")  # open for the whole flight


def _host_mocks(size: int, targets: int, speedup: float, seed: int, drain: float, pipe) -> None:
    """Child process: the mock vehicles, with `targets` hidden, until the parent says stop."""
    grid = GeoGrid.load(GRID)
    hidden = hide_targets(grid, targets, seed, start_cells(grid, size))
    with SimSwarm(grid, uavs=size, seed=seed, speedup=speedup, targets=hidden) as swarm:
        for mock in swarm.mocks:
            mock.battery_drain = drain
        pipe.send(swarm.specs)
        pipe.recv()


def rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


class WriteTimer:
    """Times every write of the recording (µs), by file and by third of the search."""

    def __init__(self, thirds: int = 3):
        self.names: dict[int, str] = {}  # fd -> name, for the files open for the whole flight only
        self.times: dict[str, list[array]] = {}
        self.third: int | None = None  # set by the sampler once the search is on: the launch is not timed
        self.thirds = thirds
        self._write = recorder_module._write

    def install(self) -> None:
        recorder_module._write = self.write

    def uninstall(self) -> None:
        recorder_module._write = self._write

    def name(self, fd: int) -> str:
        name = self.names.get(fd)
        if name is None:
            try:
                name = os.path.basename(os.readlink(f"/proc/self/fd/{fd}"))
            except OSError:
                name = "?"
            if name in RECORDING:  # a temporary file's number is used again by the next one
                self.names[fd] = name
            else:
                name = "summary.json" if "summary.json" in name else name
        return name

    def write(self, fd: int, data) -> int:
        started = time.perf_counter_ns()
        n = self._write(fd, data)
        took = (time.perf_counter_ns() - started) / 1000.0
        if self.third is None:
            return n
        series = self.times.get(self.name(fd))
        if series is None:
            series = self.times[self.name(fd)] = [array("d") for _ in range(self.thirds)]
        series[self.third].append(took)
        return n


async def sample(controller: Controller, timer: WriteTimer, limit: float, samples: list[dict]) -> None:
    """Once a second, from the search's start to its end."""
    while controller.search_started is None:
        await asyncio.sleep(0.1)
    while controller.outcome is None:
        elapsed = time.monotonic() - controller.search_started
        timer.third = min(2, int(3 * elapsed / limit))
        overhead = controller.overhead_ms()
        samples.append(
            dict(
                t=round(elapsed, 2),
                third=timer.third,
                step=controller.step,
                rss=rss_bytes(),
                blocks=sys.getallocatedblocks(),
                rounds=overhead.get("rounds", 0),
                controller_mean=overhead.get("controller_mean"),
                step_timeouts=sum(a.timeouts for a in controller.agents),
            )
        )
        await asyncio.sleep(1.0)
    timer.third = None  # the end actions are not the search's


def fly(args: argparse.Namespace) -> dict:
    limit = args.mock_minutes * 60.0 / args.speedup
    parent, child_end = mp.Pipe()
    child = mp.get_context("spawn").Process(
        target=_host_mocks, args=(args.vehicles, args.targets, args.speedup, args.seed, args.drain, child_end)
    )
    child.start()
    specs = parent.recv()
    grid = GeoGrid.load(GRID)
    kw = dict(end_action="land", time_limit=limit, takeoff_at_once=max(1, args.vehicles // 4), end_timeout=120.0)
    plan = sim_plan(grid, specs, args.policy, seed=args.seed, name="soak", **kw)
    samples: list[dict] = []
    timer = WriteTimer()
    with tempfile.TemporaryDirectory() as tmp:
        rec = Recorder(tmp)
        controller = Controller(plan, rec)

        async def main() -> str:
            side = [
                asyncio.ensure_future(keep_summary(controller, rec)),
                asyncio.ensure_future(sample(controller, timer, limit, samples)),
            ]
            try:
                return await controller.run()
            finally:
                for task in side:
                    task.cancel()
                await asyncio.gather(*side, return_exceptions=True)

        started = time.monotonic()
        timer.install()
        try:
            outcome = asyncio.run(main())
            summary = controller.summary()
            rec.write_summary(summary)
        finally:
            timer.uninstall()
            rec.close()
            parent.send("stop")
            child.join(30)
        wall = time.monotonic() - started
        with open(Path(tmp) / "events.jsonl") as f:
            timeouts = [json.loads(line) for line in f if '"event":"step_timeout"' in line]
        sizes = {name: (Path(tmp) / name).stat().st_size for name in RECORDING if (Path(tmp) / name).exists()}
    searched_from = time.time() - (time.monotonic() - controller.search_started)  # events.jsonl's clock
    timeout_thirds = [0, 0, 0]
    for e in timeouts:
        timeout_thirds[max(0, min(2, int(3 * (e["t"] - searched_from) / limit)))] += 1
    return dict(
        outcome=outcome,
        limit_s=limit,
        wall_s=wall,
        summary=summary,
        samples=samples,
        writes=timer.times,
        step_timeouts=sum(v["step_timeouts"] for v in summary["vehicles"]),
        timeout_thirds=timeout_thirds,
        sizes=sizes,
    )


def percentile(values, q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def own_ms(first: dict, last: dict) -> float:
    """The controller's mean own time per round (ms) between two samples, from the running means
    Controller.overhead_ms gives at each."""
    rounds = last["rounds"] - first["rounds"]
    if not rounds or last["controller_mean"] is None:
        return float("nan")
    return (last["controller_mean"] * last["rounds"] - (first["controller_mean"] or 0.0) * first["rounds"]) / rounds


def thirds(run: dict) -> list[dict]:
    rows = []
    samples = run["samples"]
    for k in range(3):
        mine = [s for s in samples if s["third"] == k]
        before = [s for s in samples if s["third"] < k]
        events = list(run["writes"].get("events.jsonl", [array("d")] * 3)[k])
        everything = [x for series in run["writes"].values() for x in series[k]]
        row = dict(third=k + 1, samples=len(mine))
        if mine:
            first, last = (before[-1] if before else dict(rounds=0, controller_mean=0.0)), mine[-1]
            rounds = last["rounds"] - first["rounds"]
            row.update(
                start_s=mine[0]["t"],
                end_s=last["t"],
                rounds=rounds,
                controller_ms=own_ms(first, last),
                rss_median_mb=statistics.median(s["rss"] for s in mine) / 2**20,
                rss_max_mb=max(s["rss"] for s in mine) / 2**20,
                blocks_k=statistics.median(s["blocks"] for s in mine) / 1000,
            )
        row.update(
            writes=len(events),
            events_us_median=statistics.median(events) if events else float("nan"),
            events_us_p95=percentile(events, 0.95),
            events_us_max=max(events, default=float("nan")),
            all_us_max=max(everything, default=float("nan")),
            step_timeouts=run["timeout_thirds"][k],
        )
        rows.append(row)
    return rows


def verdicts(rows: list[dict], run: dict) -> list[tuple[str, bool, str]]:
    first, last = rows[0], rows[-1]
    growth = last["rss_median_mb"] / first["rss_median_mb"] - 1.0
    a, b = first["events_us_median"], last["events_us_median"]
    latency_ok = b <= max(a * LATENCY_RATIO, a + LATENCY_SLACK_US)
    flew = run["outcome"] == "time limit"
    return [
        (
            "flew the whole time",
            flew,
            f"outcome {run['outcome']}, {run['summary']['search_time_s']:.0f} of {run['limit_s']:.0f} s searched",
        ),
        (
            "memory flat",
            abs(growth) <= MEMORY_TOLERANCE,
            f"RSS median {first['rss_median_mb']:.1f} MB (first third) -> {last['rss_median_mb']:.1f} MB (last): "
            f"{100 * growth:+.1f} % (limit {100 * MEMORY_TOLERANCE:.0f} %)",
        ),
        (
            "no growth in write latency",
            latency_ok,
            f"events.jsonl write median {a:.1f} us -> {b:.1f} us "
            f"(limit: {LATENCY_RATIO:g} x, or {LATENCY_SLACK_US:g} us more)",
        ),
        (
            "no step timeouts from the controller",
            run["step_timeouts"] == 0,
            f"{run['step_timeouts']} step timeouts (summary.json, every vehicle)",
        ),
    ]


def report(args: argparse.Namespace, run: dict, reference: float, loads: tuple) -> tuple[str, bool]:
    rows = thirds(run)
    overhead = run["summary"]["overhead_ms"]
    lines = [
        f"soak: {args.vehicles} mock vehicles, {args.mock_minutes:g} min of mock time at speed-up {args.speedup:g} "
        f"({run['limit_s']:.0f} s of search), policy {args.policy}, {args.targets} targets hidden, "
        f"battery drain {args.drain:g} %/mock s",
        f"machine: {os.cpu_count()} CPUs ({len(os.sched_getaffinity(0))} usable), {cpu_model()}; "
        f"load average {loads[0][0]:.2f} {loads[0][1]:.2f} {loads[0][2]:.2f} before, "
        f"{loads[1][0]:.2f} {loads[1][1]:.2f} {loads[1][2]:.2f} after; machine reference {reference:.1f} ms",
        f"wall time {run['wall_s']:.0f} s (take-off, search, landing); outcome {run['outcome']}; "
        f"{run['summary']['steps']} steps; recording "
        + ", ".join(f"{k} {v / 2**20:.1f} MB" for k, v in run["sizes"].items()),
        f"controller per round (whole search): own {overhead.get('controller_mean', float('nan')):.1f} ms mean, "
        f"{overhead.get('controller_p95', float('nan')):.1f} ms p95; policy {overhead.get('decide_mean', 0):.1f} ms; "
        f"round {overhead.get('round_mean', 0):.1f} ms",
        "",
        "| third | search s | rounds | controller ms/round | RSS MB (median / max) | Python blocks (k) "
        "| events.jsonl writes | write us (median / p95 / max) | any file max us | step timeouts |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if "rounds" not in r:
            lines.append(f"| {r['third']} | - | - | - | - | - | {r['writes']} | - | - | {r['step_timeouts']} |")
            continue
        lines.append(
            f"| {r['third']} | {r['start_s']:.0f}-{r['end_s']:.0f} | {r['rounds']} | {r['controller_ms']:.1f} "
            f"| {r['rss_median_mb']:.1f} / {r['rss_max_mb']:.1f} | {r['blocks_k']:.0f} | {r['writes']} "
            f"| {r['events_us_median']:.1f} / {r['events_us_p95']:.1f} / {r['events_us_max']:.0f} "
            f"| {r['all_us_max']:.0f} | {r['step_timeouts']} |"
        )
    later = [s for s in run["samples"] if s["third"] > 0]
    if len(later) >= 2 and later[-1]["rounds"] > later[0]["rounds"]:
        slope = float(np.polyfit([s["rounds"] for s in later], [s["rss"] for s in later], 1)[0])
        lines.append("")
        lines.append(
            f"RSS trend over the last two thirds (least squares on rounds): {slope / 1024:+.1f} KB per round "
            f"({slope * 1000 / 2**20:+.1f} MB per 1000 rounds)"
        )
    lines.append("")
    ok = True
    if any("rounds" not in r for r in rows):
        lines.append("verdict: not judged, the search did not reach its last third")
        return "\n".join(lines), False
    for name, holds, why in verdicts(rows, run):
        ok &= holds
        lines.append(f"{'PASS' if holds else 'FAIL'}  {name}: {why}")
    return "\n".join(lines), ok


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=50)
    ap.add_argument("--mock-minutes", type=float, default=30.0, help="minutes of mock time to search")
    ap.add_argument("--speedup", type=float, default=10.0, help="mock seconds per wall-clock second")
    ap.add_argument("--policy", default="random", help="random keeps every vehicle moving to the end")
    ap.add_argument("--targets", type=int, default=10, help="targets hidden (fewer than the vehicles)")
    ap.add_argument("--drain", type=float, default=0.03, help="the mocks' battery drain, %% per mock second")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="folder for soak.json and soak.txt")
    args = ap.parse_args()
    if not 1 <= args.targets < args.vehicles:
        ap.error("--targets must be at least 1 and fewer than --vehicles, or vehicles would park")
    reference = machine_reference_ms()
    before = os.getloadavg()
    run = fly(args)
    text, ok = report(args, run, reference, (before, os.getloadavg()))
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        keep = {k: v for k, v in run.items() if k not in ("writes", "summary")}
        keep["thirds"] = thirds(run)
        keep["overhead_ms"] = run["summary"]["overhead_ms"]
        (args.out / "soak.json").write_text(json.dumps(keep, indent=1) + "\n")
        (args.out / "soak.txt").write_text(text + "\n")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
