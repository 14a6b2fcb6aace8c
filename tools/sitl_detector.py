"""A detector for a SITL vehicle: it reads the vehicle's real position on a MAVLink port of its own and
reports what a camera over the hidden targets would see, as a mission's `detector = "udp:HOST:PORT"`
expects it.

The controller flies the vehicle on one link (ArduCopter SITL's SERIAL0, tcp:127.0.0.1:5760+10N); this
tool listens to another (SERIAL1, tcp:127.0.0.1:5762+10N, or SERIAL2, +3), asks it for
GLOBAL_POSITION_INT from --sysid, maps each position to the mission's grid and, each time the vehicle
hovers at the mission altitude within
--tolerance metres of a cell centre, sends that cell's report (the targets in view, then the cells of
its field of view) to the controller's detector socket in MAVLink 2 TUNNEL frames, as
swarmctl.sim.detector.SimDetector does for the mock vehicles (swarmctl/mission/detector.py describes
the payloads). It runs until it is stopped (SIGTERM, Ctrl-C); each report is one line on stdout. Bad
arguments: one line on stderr, exit status 2.

    python tools/sitl_detector.py --telemetry tcp:127.0.0.1:5762 --sysid 1 --grid missions/chicago-loop/grid.npz \\
        --mission-id 7 --altitude 40 --vehicle 0 --target 4,1 --send udp:127.0.0.1:14650
"""

from __future__ import annotations

import argparse
import signal
import socket
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from pymavlink import mavutil  # noqa: E402

from swarmctl.geo.grid import GeoGrid  # noqa: E402
from swarmctl.sim.detector import FOV_CELLS, SimDetector  # noqa: E402

MAV = mavutil.mavlink
REQUEST_EVERY_S = 1.0  # the position request is repeated until positions come (a request can be lost at boot)


def cell(text: str) -> tuple[int, int]:
    x, _, y = text.partition(",")
    try:
        return int(x), int(y)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a cell X,Y (e.g. 4,1)") from None


def udp_address(text: str) -> tuple[str, int]:
    kind, _, rest = text.partition(":")
    host, _, port = rest.rpartition(":")
    if kind != "udp" or not host or not port.isdigit():
        raise argparse.ArgumentTypeError(f"{text!r} is not udp:HOST:PORT (e.g. udp:127.0.0.1:14650)")
    return host, int(port)


def connect(address: str, timeout: float):
    """A pymavlink connection to `address`, retried until it opens (SITL opens SERIAL1 and SERIAL2 only
    once it has booted, i.e. once the controller is connected to SERIAL0)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            conn = mavutil.mavlink_connection(address, source_system=254, source_component=191, dialect="ardupilotmega")
            conn.mav.robust_parsing = True
            return conn
        except (OSError, ConnectionError) as exc:
            if time.monotonic() > deadline:
                raise SystemExit(f"sitl_detector: cannot connect to {address} within {timeout:g} s ({exc})") from None
            time.sleep(0.2)


def run(args: argparse.Namespace) -> int:
    grid = GeoGrid.load(args.grid)
    for x, y in args.target:
        if not (0 <= x < grid.width and 0 <= y < grid.height):
            print(f"sitl_detector: --target {x},{y} is outside the {grid.width} x {grid.height} grid", file=sys.stderr)
            return 2
    detector = SimDetector(
        grid,
        np.array(args.target, dtype=np.int64).reshape(-1, 2),
        args.vehicle,
        args.mission_id,
        args.altitude,
        fov=args.fov,
        tolerance=args.tolerance,
        repeat=args.repeat,
        udp=args.send,
    )
    conn = connect(args.telemetry, args.connect_timeout)
    print(f"sitl_detector: listening to system {args.sysid} on {args.telemetry}, reports to {args.send}", flush=True)
    armed, asked, positions = False, 0.0, 0
    try:
        while True:
            now = time.monotonic()
            if positions == 0 and now - asked > REQUEST_EVERY_S:
                asked = now
                conn.mav.command_long_send(
                    args.sysid, 1, MAV.MAV_CMD_SET_MESSAGE_INTERVAL, 0, MAV.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                    1e6 / args.rate, 0, 0, 0, 0, 0,
                )  # fmt: skip
            msg = conn.recv_match(type=["HEARTBEAT", "GLOBAL_POSITION_INT"], blocking=True, timeout=0.5)
            if msg is None or msg.get_srcSystem() != args.sysid:
                continue
            if msg.get_type() == "HEARTBEAT":
                armed = bool(msg.base_mode & MAV.MAV_MODE_FLAG_SAFETY_ARMED)
                continue
            positions += 1
            lat, lon, rel_alt = msg.lat / 1e7, msg.lon / 1e7, msg.relative_alt / 1000.0
            if lat == 0 and lon == 0:
                continue  # no EKF origin yet
            seen = detector.cell_to_report(armed, lat, lon, rel_alt)
            if seen is not None:
                detector.report(None, seen)
                cells, _phi, _obstacle, targets = detector.observe(seen)
                print(
                    f"report {detector.sent_reports}: cell {seen[0]},{seen[1]}, {len(cells)} cells in view, "
                    f"targets {[tuple(int(v) for v in t) for t in targets]}",
                    flush=True,
                )
    finally:
        detector.close()
        conn.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--telemetry", required=True, help="the vehicle's second MAVLink port, e.g. tcp:127.0.0.1:5762")
    ap.add_argument("--sysid", type=int, required=True, help="the vehicle's system id")
    ap.add_argument("--grid", type=Path, required=True, help="the mission's grid (from `swarmctl plan`)")
    ap.add_argument("--mission-id", type=int, required=True, help="the mission's [mission] id")
    ap.add_argument("--altitude", type=float, required=True, help="the mission's altitude, metres above home")
    ap.add_argument("--vehicle", type=int, required=True, help="the vehicle's index in the mission's [[vehicles]]")
    ap.add_argument("--target", type=cell, action="append", default=[], help="a hidden target's cell X,Y; repeatable")
    ap.add_argument("--send", type=udp_address, required=True, help="the mission's detector socket, udp:HOST:PORT")
    ap.add_argument("--fov", type=float, default=FOV_CELLS, help="field of view, cells (the policy's fov)")
    ap.add_argument("--tolerance", type=float, default=1.0, help="metres from a cell centre that count as over it")
    ap.add_argument("--repeat", type=float, default=1.0, help="seconds between reports while the vehicle stays")
    ap.add_argument("--rate", type=float, default=10.0, help="GLOBAL_POSITION_INT rate asked for, Hz")
    ap.add_argument("--connect-timeout", type=float, default=60.0, help="seconds to wait for the port to open")
    args = ap.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        return run(args)
    except KeyboardInterrupt:
        return 0
    except socket.gaierror as exc:
        raise SystemExit(f"sitl_detector: {exc}") from None


if __name__ == "__main__":
    sys.exit(main())
