"""Measure a coverage search against real SITL: `swarmctl fly` with no detector and no [knowledge]
section, frontier, the Chicago Loop grid, and per vehicle the distinct cells flown, the knowledge
received, the end state and where its simulator says it landed.

    python tools/sitl_search.py                       # three ArduCopter copters, 90 s of search at x1
    python tools/sitl_search.py --swarm px4           # two PX4 vehicles
    python tools/sitl_search.py --swarm mixed         # one PX4 and two ArduCopter
    python tools/sitl_search.py --speedup 5 --time-limit 20 --keep runs/sitl-search

It starts the instances itself (tests/sitl_fly.py's harness: ArduCopter -I 0-4 with --sysid N+1, PX4
-i 5-9; binaries from ARDUPILOT_SITL and PX4_SITL, defaults ../shared/sitl/arducopter and
../shared/px4/bin/px4) and stops every process at the end. Prints one line per vehicle and, with
--json, the figures as JSON. Exit status 0 when every vehicle flew at least --cells distinct cells,
received knowledge and landed within 3 m of home, else 1.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.sitl_fly import MIXED, PX4_PAIR, TRIO, Flights, Scenario, within  # noqa: E402

SWARMS = {"arducopter": TRIO, "px4": PX4_PAIR, "mixed": MIXED}
HOME_M = 3.0


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
    args = ap.parse_args(argv)
    if not 1 <= args.time_limit <= 86400 or not 0 < args.speedup <= 100 or not 0 < args.px4_speed <= 100:
        ap.error("--time-limit must be 1 to 86400 s, --speedup and --px4-speed above 0 and at most 100")
    scenario = Scenario(
        args.swarm,
        SWARMS[args.swarm],
        time_limit=args.time_limit,
        policy=args.policy,
        arducopter_speedup=args.speedup,
        px4_speed=args.px4_speed,
        deadline=args.time_limit + 900.0,
    )
    started = time.monotonic()
    with Flights([scenario], keep=args.keep) as flights:
        r = flights.result(args.swarm)
    figures = {
        "swarm": args.swarm,
        "time_limit_s": args.time_limit,
        "speedup": args.speedup,
        "px4_speed": args.px4_speed,
        "policy": args.policy,
        "rc": r.rc,
        "outcome": r.summary["outcome"],
        "search_time_s": r.summary["search_time_s"],
        "steps": r.summary["steps"],
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
    print(
        f"{args.swarm}: {figures['outcome']} (exit {r.rc}), {figures['steps']} steps in {figures['search_time_s']} s "
        f"of search, {figures['wall_s']} s wall in all"
    )
    if args.json is not None:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
