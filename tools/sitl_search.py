"""Measure a coverage search against real SITL: `swarmctl fly` with no detector and no [knowledge]
section, frontier, the Chicago Loop grid, and per vehicle the distinct cells flown, the knowledge
received, the end state and where its simulator says it landed.

    python tools/sitl_search.py                       # three ArduCopter copters, 90 s of search at x1
    python tools/sitl_search.py --swarm px4           # two PX4 vehicles
    python tools/sitl_search.py --swarm mixed         # one PX4 and two ArduCopter
    python tools/sitl_search.py --swarm arducopter-pair   # two ArduCopter from the PX4 pair's cells
    python tools/sitl_search.py --compare             # the PX4 pair, then the ArduCopter pair: cells compared
    python tools/sitl_search.py --speedup 5 --time-limit 20 --keep runs/sitl-search

It starts the instances itself (tests/sitl_fly.py's harness: ArduCopter -I 0-4 with --sysid N+1, PX4
-i 5-9; binaries from ARDUPILOT_SITL and PX4_SITL, defaults ../shared/sitl/arducopter and
../shared/px4/bin/px4) and stops every process at the end. Prints one line per vehicle, the decision
rounds' times (from one `step` record of events.jsonl to the next) and, with --json, the figures as JSON.
Exit status 0 when every vehicle flew at least --cells distinct cells, received knowledge and landed
within 3 m of home, else 1.

--compare flies two PX4 and then two ArduCopter vehicles (one swarm after the other, so that they do not
share the machine's cores) from the same cells, (0, 0) and (3, 0), the same search on the same grid, and
also fails unless the PX4 pair's distinct cells are at least --ratio (default 0.7) of the ArduCopter
pair's (per swarm: the mean over its vehicles).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.sitl_fly import ARDUCOPTER, MIXED, PX4_PAIR, TRIO, Craft, FlightResult, Flights, Scenario, within  # noqa: E402

# two ArduCopter vehicles from the PX4 pair's cells: the pace the PX4 pair is measured against
ARDUCOPTER_PAIR = [Craft("alpha", ARDUCOPTER, (0, 0)), Craft("bravo", ARDUCOPTER, (3, 0))]
SWARMS = {"arducopter": TRIO, "px4": PX4_PAIR, "mixed": MIXED, "arducopter-pair": ARDUCOPTER_PAIR}
COMPARED = ("px4", "arducopter-pair")
HOME_M = 3.0


def round_times(r: FlightResult) -> list[float]:
    """Seconds from each decision round's `step` record to the next one's."""
    times = [e["t"] for e in r.events if e["event"] == "step"]
    return [round(b - a, 1) for a, b in zip(times, times[1:])]


def fly_swarm(swarm: str, args: argparse.Namespace) -> tuple[dict, bool]:
    """Fly one swarm's search; its figures (printed as they come) and whether every vehicle passed."""
    scenario = Scenario(
        swarm,
        SWARMS[swarm],
        time_limit=args.time_limit,
        policy=args.policy,
        arducopter_speedup=args.speedup,
        px4_speed=args.px4_speed,
        deadline=args.time_limit + 900.0,
    )
    started = time.monotonic()
    with Flights([scenario], keep=args.keep) as flights:  # its files under KEEP/SWARM
        r = flights.result(swarm)
    rounds = round_times(r)
    figures = {
        "swarm": swarm,
        "time_limit_s": args.time_limit,
        "speedup": args.speedup,
        "px4_speed": args.px4_speed,
        "policy": args.policy,
        "rc": r.rc,
        "outcome": r.summary["outcome"],
        "search_time_s": r.summary["search_time_s"],
        "steps": r.summary["steps"],
        "round_s": rounds,
        "step_timeouts": sum(1 for e in r.events if e["event"] == "step_timeout"),
        "wall_s": round(time.monotonic() - started, 1),
        "vehicles": [],
    }
    ok = True
    for craft in scenario.crafts:
        v, landing = r.vehicle(craft.name), r.landings.get(craft.name)
        row = {
            "name": craft.name,
            "autopilot": v["autopilot"],
            "distinct_cells": len(r.cells(craft.name)),
            "steps": v["steps"],
            "knowledge_received": v["knowledge_received"],
            "knowledge_sent": v["knowledge_sent"],
            "end_state": v["end_state"],
            "landed_from_home_m": None if landing is None else round(landing.from_home_m, 2),
            "disarmed": None if landing is None else not landing.armed,
        }
        figures["vehicles"].append(row)
        ok &= row["distinct_cells"] >= args.cells and row["knowledge_received"] > 0 and within(HOME_M, landing)
        print(
            f"{craft.name} ({row['autopilot']}): {row['distinct_cells']} distinct cells in {row['steps']} steps, "
            f"knowledge received {row['knowledge_received']} (sent {row['knowledge_sent']}), {row['end_state']}, "
            f"landed {row['landed_from_home_m']} m from home, disarmed {row['disarmed']}"
        )
    spread = f"{min(rounds)}-{max(rounds)} s, median {statistics.median(rounds):.1f} s" if rounds else "none"
    print(
        f"{swarm}: {figures['outcome']} (exit {r.rc}), {figures['steps']} steps in {figures['search_time_s']} s "
        f"of search, rounds {spread}, {figures['step_timeouts']} step timeouts, {figures['wall_s']} s wall in all",
        flush=True,
    )
    return figures, ok


def mean_cells(figures: dict) -> float:
    return statistics.mean(v["distinct_cells"] for v in figures["vehicles"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--swarm", choices=sorted(SWARMS), default="arducopter", help="the vehicles (default arducopter)")
    ap.add_argument("--time-limit", type=float, default=90.0, help="seconds of search (default 90)")
    ap.add_argument("--speedup", type=float, default=1.0, help="ArduCopter SITL speed-up (default 1)")
    ap.add_argument("--px4-speed", type=float, default=1.0, help="PX4 SIH speed factor (default 1)")
    ap.add_argument("--policy", default="frontier", help="the mission's policy (default frontier)")
    ap.add_argument("--cells", type=int, default=8, help="distinct cells each vehicle must fly (default 8)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the mission, recording and consoles here")
    ap.add_argument("--json", type=Path, default=None, help="write the figures here as JSON")
    ap.add_argument(
        "--compare", action="store_true", help="fly the PX4 pair, then the ArduCopter pair, and compare their cells"
    )
    ap.add_argument("--ratio", type=float, default=0.7, help="--compare: PX4 cells / ArduCopter cells wanted (0.7)")
    args = ap.parse_args(argv)
    if not 1 <= args.time_limit <= 86400 or not 0 < args.speedup <= 100 or not 0 < args.px4_speed <= 100:
        ap.error("--time-limit must be 1 to 86400 s, --speedup and --px4-speed above 0 and at most 100")
    if not 0 < args.ratio <= 10:
        ap.error("--ratio must be above 0 and at most 10")
    if not args.compare:
        figures, ok = fly_swarm(args.swarm, args)
        if args.json is not None:
            args.json.write_text(json.dumps(figures, indent=2) + "\n")
        return 0 if ok else 1
    flown = [fly_swarm(swarm, args) for swarm in COMPARED]
    (px4, px4_ok), (copters, copters_ok) = flown
    ratio = mean_cells(px4) / max(mean_cells(copters), 1e-9)
    print(
        f"PX4 pair {mean_cells(px4):g} distinct cells per vehicle, ArduCopter pair {mean_cells(copters):g}: "
        f"{ratio:.0%} (wanted >= {args.ratio:.0%})"
    )
    if args.json is not None:
        both = {"swarms": [px4, copters], "cells_ratio": round(ratio, 3), "wanted_ratio": args.ratio}
        args.json.write_text(json.dumps(both, indent=2) + "\n")
    return 0 if px4_ok and copters_ok and ratio >= args.ratio else 1


if __name__ == "__main__":
    sys.exit(main())
