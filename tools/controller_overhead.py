"""Controller overhead per decision step with 3, 12 and 50 mock vehicles at the Chicago Loop.

For each swarm size: start the mock vehicles (over loopback UDP), fly a search for --search seconds
with the given policy in ground mode (one controller flies every vehicle; the agents share knowledge
on the in-process bus, swarmctl.knowledge.bus, and write their TUNNEL frames on their own vehicle's
link), recording it as fly and demo do (the running summary.json included), and report per decision
round the policy time, the CPU time of the controller's loop thread and of its whole process (the loop
with any reader threads of stream links: with --same-process the mocks' thread too), the whole round,
and the controller's own part (the round minus the time spent waiting for vehicles to reach their cells
and for detector reports). The mocks run in a child process, all in one thread (swarmctl.sim.autopilot's
MockRunner), or, with --same-process, in that thread next to the controller, where it competes with the
controller for the interpreter lock; on a small machine they still compete for the CPU, so the numbers
are upper bounds. With --own-cpu the mocks' process runs on the last CPU and the controller on the
others, as real vehicles fly their own computers; their work then no longer shares a
core, and its caches, with the controller's.

    python tools/controller_overhead.py [--sizes 3 12 50] [--policy frontier] [--search 20] [--runs 3] [--own-cpu]
        [--out results/]

The header gives the machine's speed before the runs: a fixed workload of dict updates and small numpy
calls (what a round is mostly made of) timed alone, in CPU ms, so that tables from different days, or
machines, can be set side by side (a figure twice the reference's on a machine whose reference is
twice as long is the same code at the same cost).

Below the table, how the CPU grows with the swarm (`scaling`): the exponent of a least-squares fit of
log CPU on log vehicles over the sizes of 12 and more, and 50 vehicles' CPU over 3 vehicles'.

With --runs N each size is flown N times, back to back, and the table gives the minimum and the median
of the per-run means, with the machine's load average (1 min) before each run: on a shared machine
the minimum is the figure least disturbed by other work.

With --web each flight is flown twice, alternately without and with the live page (`--web`,
swarmctl.mission.web) served and open: a client in another process asks for it as the page does (the
page, its setup, every track once, then the state POLL_MS apart). A second table sets the two side by
side: the loop thread's CPU per round, and the controller process's CPU over the whole flight per
round (the page's answers between rounds included), each with the change the page makes.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import secrets
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmctl.bench import cpu_model  # noqa: E402
from swarmctl.geo.grid import GeoGrid  # noqa: E402
from swarmctl.mission.controller import Controller  # noqa: E402
from swarmctl.mission.recorder import Recorder  # noqa: E402
from swarmctl.mission.service import keep_summary, live_site  # noqa: E402
from swarmctl.mission.web_page import WebSetup  # noqa: E402
from swarmctl.sim.swarm import SimSwarm, sim_plan  # noqa: E402


def _host_mocks(size: int, speedup: float, seed: int, pipe, cpus: set[int] | None = None) -> None:
    """Child process: the mock vehicles (on `cpus`, when given), until the parent says stop."""
    if cpus is not None:
        os.sched_setaffinity(0, cpus)
    grid = GeoGrid.load(ROOT / "missions/chicago-loop/grid.npz")
    with SimSwarm(grid, uavs=size, seed=seed, speedup=speedup) as swarm:
        pipe.send(swarm.specs)
        pipe.recv()


def machine_reference_ms(rounds: int = 5) -> float:
    """CPU ms (min of `rounds`) of a fixed workload like a round's: 20,000 dict updates and 2,000
    small numpy calls."""
    import numpy as np

    a = np.random.default_rng(0).random(100)

    def work() -> None:
        counts: dict[int, int] = {}
        for i in range(20000):
            counts[i & 255] = counts.get(i & 255, 0) + 1
        for _ in range(2000):
            (a * 2.0).sum()

    times = []
    for _ in range(rounds):
        started = time.thread_time()
        work()
        times.append(time.thread_time() - started)
    return 1000 * min(times)


def split_cpus() -> tuple[set[int], set[int]]:
    """(the controller's CPUs, the mocks' CPU) for --own-cpu: the last CPU this process may use for
    the mocks, the others for the controller."""
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        raise SystemExit("--own-cpu needs at least 2 CPUs")
    return set(cpus[:-1]), {cpus[-1]}


def _open_page(url: str, stop) -> None:
    """Child process: the live page's requests, as an open page makes them, until `stop` is set."""
    import urllib.request

    from swarmctl.mission.web_page import POLL_MS

    base = url.split("#")[0]
    for path in ("", "draw.js", "live.js", "live/setup", "live/state?tracks=1"):
        urllib.request.urlopen(base + path, timeout=10).read()
    while not stop.wait(POLL_MS / 1000):
        try:
            urllib.request.urlopen(base + "live/state", timeout=10).read()
        except OSError:
            return  # the mission ended and its page with it


def measure(
    size: int,
    policy: str,
    search: float,
    speedup: float,
    seed: int,
    same_process: bool,
    own_cpu: bool = False,
    web: bool = False,
) -> dict:
    import multiprocessing as mp

    grid = GeoGrid.load(ROOT / "missions/chicago-loop/grid.npz")
    kw = dict(end_action="land", time_limit=search, takeoff_at_once=max(1, size // 4), end_timeout=120.0)
    with tempfile.TemporaryDirectory() as tmp:
        if same_process:
            swarm = SimSwarm(grid, uavs=size, seed=seed, speedup=speedup).start()
            plan = swarm.plan(policy, **kw)
            child = parent = None
        else:
            parent, child_end = mp.Pipe()
            mine, theirs = split_cpus() if own_cpu else (None, None)
            child = mp.get_context("spawn").Process(target=_host_mocks, args=(size, speedup, seed, child_end, theirs))
            child.start()
            if mine is not None:  # this thread's; the link threads started from it inherit it
                os.sched_setaffinity(0, mine)
            specs = parent.recv()
            plan = sim_plan(grid, specs, policy, seed=seed, name="overhead", **kw)
        rec = Recorder(tmp)
        controller = Controller(plan, rec)

        async def fly() -> str:  # with the running summary.json, as fly and demo keep it
            site = page = None
            stop = mp.get_context("spawn").Event()
            if web:
                site = live_site(controller, WebSetup("127.0.0.1", 0, secrets.token_urlsafe(24)))
                url = await site.start()
                page = mp.get_context("spawn").Process(target=_open_page, args=(url, stop))
                page.start()
            summaries = asyncio.ensure_future(keep_summary(controller, rec))
            try:
                return await controller.run()
            finally:
                summaries.cancel()
                await asyncio.gather(summaries, return_exceptions=True)
                if page is not None:
                    stop.set()
                    page.join(10)
                if site is not None:
                    await site.close()

        started = time.monotonic()
        cpu0 = time.process_time()
        try:
            outcome = asyncio.run(fly())
        finally:
            rec.close()
            if own_cpu and not same_process:
                os.sched_setaffinity(0, mine | theirs)
            if same_process:
                swarm.stop()
            else:
                parent.send("stop")
                child.join(30)
        took = time.monotonic() - started
        flight_cpu = time.process_time() - cpu0
        return dict(
            web=web,
            flight_cpu_per_round=round(1000 * flight_cpu / max(controller.step, 1), 3),
            vehicles=size,
            policy=policy,
            mocks="same process" if same_process else "child process" + (" on its own CPU" if own_cpu else ""),
            outcome=outcome,
            wall_s=round(took, 1),
            steps=controller.step,
            **controller.overhead_ms(),
        )


def summarise(runs: list[dict]) -> dict:
    """One size's runs: the first run's fields, with the min and median of the per-run means and the
    loads (a single run is returned as it is)."""
    if len(runs) == 1:
        return runs[0]
    import statistics

    out = dict(runs[0], runs=runs, loads=[round(r["load"], 2) for r in runs])
    out["rounds"] = min(r.get("rounds", 0) for r in runs)
    for key, name in (
        ("decide_mean", "decide"),
        ("cpu_mean", "cpu"),
        ("process_cpu_mean", "process_cpu"),
        ("round_mean", "round"),
    ):
        values = [r[key] for r in runs if key in r]
        out[f"{name}_min"] = min(values) if values else float("nan")
        out[f"{name}_median"] = statistics.median(values) if values else float("nan")
    return out


def scaling(rows: list[dict]) -> dict:
    """How the controller's CPU per step grows with the swarm, from each size's process CPU (the minimum
    over the runs; a single run's mean): `exponent`, the slope of a least-squares fit of log CPU on log
    vehicles over the sizes of 12 vehicles and more (the speed target's 12..200; None with fewer than two
    such sizes), the `sizes` it was fitted over, and `ratio_50_3`, 50 vehicles' CPU over 3 vehicles'
    (None without both)."""
    import numpy as np

    cpu = {r["vehicles"]: r.get("process_cpu_min", r.get("process_cpu_mean")) for r in rows}
    cpu = {n: c for n, c in cpu.items() if c is not None and c > 0}
    sizes = sorted(n for n in cpu if n >= 12)
    exponent = None
    if len(sizes) >= 2:
        exponent = float(np.polyfit(np.log(sizes), np.log([cpu[n] for n in sizes]), 1)[0])
    ratio = cpu[50] / cpu[3] if 50 in cpu and 3 in cpu else None
    return {"exponent": exponent, "sizes": sizes if exponent is not None else [], "ratio_50_3": ratio}


def web_table(paged: list[tuple[list[dict], list[dict]]]) -> list[str]:
    """The live page's cost: per size, over the alternated runs without and with the page, the minimum
    and the median of the loop thread's CPU per round and of the process's CPU over the flight per round,
    and the change of the minima (the figures least disturbed by other work)."""
    import statistics

    lines = [
        "",
        "with the live page open (--web; runs alternated): CPU per round, ms, min / median of the runs",
        "",
        "| vehicles | runs | loop CPU without | with | change (min) | flight CPU without | with | change (min) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for without, with_page in paged:
        cells = []
        for key in ("cpu_mean", "flight_cpu_per_round"):
            a = [r[key] for r in without if key in r]
            b = [r[key] for r in with_page if key in r]
            cells += [
                f"{min(a):.1f} / {statistics.median(a):.1f}",
                f"{min(b):.1f} / {statistics.median(b):.1f}",
                f"{100 * (min(b) - min(a)) / min(a):+.1f} %",
            ]
        lines.append(f"| {without[0]['vehicles']} | {len(without)} + {len(with_page)} | " + " | ".join(cells) + " |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[3, 12, 50])
    ap.add_argument("--policy", default="frontier")
    ap.add_argument("--search", type=float, default=20.0, help="seconds of search per size")
    ap.add_argument("--speedup", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--same-process",
        action="store_true",
        help="run the mocks in this process (they then compete for the interpreter lock)",
    )
    ap.add_argument("--out", type=Path, default=None, help="folder for controller_overhead.json/.txt")
    ap.add_argument("--runs", type=int, default=1, help="flights per size (min and median reported)")
    ap.add_argument(
        "--own-cpu",
        action="store_true",
        help="run the mocks on the last CPU and the controller on the others (not with --same-process)",
    )
    ap.add_argument(
        "--web",
        action="store_true",
        help="fly each run twice, alternately without and with the live page served and open, and compare",
    )
    args = ap.parse_args()
    if args.runs < 1:
        ap.error("--runs must be at least 1")
    if args.own_cpu and args.same_process:
        ap.error("--own-cpu keeps the mocks' process apart: not with --same-process")
    reference = machine_reference_ms()
    rows, paged = [], []
    for n in args.sizes:
        runs, with_page = [], []
        for _ in range(args.runs):
            for web in (False, True) if args.web else (False,):
                load = os.getloadavg()[0]
                how = (args.same_process, args.own_cpu, web)
                got = measure(n, args.policy, args.search, args.speedup, args.seed, *how)
                (with_page if web else runs).append({**got, "load": load})
        rows.append(summarise(runs))
        if with_page:
            paged.append((runs, with_page))
    lines = [
        f"controller overhead per decision step, policy {args.policy}, mock speed-up {args.speedup:g}x, "
        f"{os.cpu_count()} CPUs, {cpu_model()}, mocks in "
        f"{'the same' if args.same_process else 'a child'} process" + (" on their own CPU" if args.own_cpu else ""),
        f"machine reference (a fixed dict and small-numpy workload, alone, before the runs): {reference:.1f} ms",
        "",
        "| vehicles | rounds | policy ms | controller CPU ms | process CPU ms | controller wall ms (mean) | (p95) "
        "| whole round ms |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    if args.runs > 1:
        lines = lines[:3] + [
            f"min / median of {args.runs} runs per size; load: the 1-minute load average before each run",
            "",
            "| vehicles | rounds | policy ms (min / median) | controller CPU ms (min / median) | "
            "process CPU ms (min / median) | whole round ms (median) | load |",
            "|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for r in rows:
            lines.append(
                f"| {r['vehicles']} | {r.get('rounds', 0)} | {r['decide_min']:.1f} / {r['decide_median']:.1f} | "
                f"{r['cpu_min']:.1f} / {r['cpu_median']:.1f} | "
                f"{r['process_cpu_min']:.1f} / {r['process_cpu_median']:.1f} | {r['round_median']:.1f} | "
                f"{' '.join(f'{x:.1f}' for x in r['loads'])} |"
            )
    for r in rows if args.runs == 1 else []:
        lines.append(
            f"| {r['vehicles']} | {r.get('rounds', 0)} | {r.get('decide_mean', float('nan')):.1f} | "
            f"{r.get('cpu_mean', float('nan')):.1f} | {r.get('process_cpu_mean', float('nan')):.1f} | "
            f"{r.get('controller_mean', float('nan')):.1f} | {r.get('controller_p95', float('nan')):.1f} | "
            f"{r.get('round_mean', float('nan')):.1f} |"
        )
    growth = scaling(rows)
    if growth["exponent"] is not None or growth["ratio_50_3"] is not None:
        parts = []
        if growth["exponent"] is not None:
            parts.append(
                f"exponent {growth['exponent']:.2f} over {', '.join(map(str, growth['sizes']))} vehicles "
                "(least squares on log process CPU against log vehicles" + (", the minima)" if args.runs > 1 else ")")
            )
        if growth["ratio_50_3"] is not None:
            parts.append(f"50 vehicles / 3 vehicles {growth['ratio_50_3']:.2f}")
        lines += ["", "growth: " + "; ".join(parts)]
    if paged:
        lines += web_table(paged)
    text = "\n".join(lines)
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        for r in rows:
            r["machine_reference_ms"] = round(reference, 2)
        (args.out / "controller_overhead.json").write_text(json.dumps(rows, indent=2) + "\n")
        (args.out / "controller_overhead.txt").write_text(text + "\n")


if __name__ == "__main__":
    main()
