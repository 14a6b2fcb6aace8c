"""The detector fed another vehicle's position (tools/sitl_detector.py, SimDetector without a mock): when
it reports, and that its datagrams are what a mission's `detector = "udp:HOST:PORT"` reads. Fast; the
tool against a real SITL copter is tests/test_sitl_fly.py's detector scenario."""

from __future__ import annotations

import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from swarmctl.mission.detector import SensorFeed
from swarmctl.sim.detector import SimDetector
from tests.mission_support import small_grid
from tests.sitl_support import ROOT


def centre(grid, x: int, y: int) -> tuple[float, float]:
    lat, lon = grid.cell_to_latlon(x, y)
    return float(lat), float(lon)


def test_a_report_only_when_armed_at_the_altitude_over_a_cell_centre_and_not_again_too_soon():
    grid = small_grid(12, 12)
    d = SimDetector(grid, np.array([[4, 4]]), 0, 7, 40.0, tolerance=1.0, repeat=60.0)
    lat, lon = centre(grid, 3, 3)
    assert d.cell_to_report(False, lat, lon, 40.0) is None  # on the ground, disarmed
    assert d.cell_to_report(True, lat, lon, 30.0) is None  # climbing
    assert d.cell_to_report(True, lat + 3e-5, lon, 40.0) is None  # 3.3 m off the centre
    assert d.cell_to_report(True, lat, lon, 40.4) == (3, 3)
    assert d.cell_to_report(True, lat, lon, 40.0) is None  # the same cell within `repeat` seconds
    assert d.cell_to_report(True, *centre(grid, 4, 3), 40.0) == (4, 3)
    assert d.cell_to_report(True, *centre(grid, -1, 3), 40.0) is None  # off the grid


def test_its_datagrams_are_what_the_missions_detector_socket_reads():
    grid = small_grid(12, 12)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(5.0)
        d = SimDetector(grid, np.array([[4, 4]]), 0, 7, 40.0, udp=sock.getsockname())
        d.report(None, (3, 3))
        d.close()
        feed = SensorFeed(0, 7, grid.width, grid.height)
        deadline = time.monotonic() + 5.0
        while (3, 3) not in feed.latest and time.monotonic() < deadline:
            feed.on_datagram(sock.recv(65535))
    report = feed.latest[(3, 3)]
    cells, phi, _obstacle, targets = d.observe((3, 3))
    assert {tuple(t) for t in report.targets} == {(4, 4)} == {tuple(t) for t in targets}
    assert {tuple(c) for c in report.cells} == {tuple(c) for c in cells}
    assert report.phi.max() == pytest.approx(phi.max(), abs=0.01)


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--target", "4-1"], "is not a cell X,Y"),
        (["--send", "tcp:127.0.0.1:1"], "is not udp:HOST:PORT"),
        (["--target", "99,1"], "is outside the 50 x 50 grid"),
    ],
)
def test_bad_arguments_are_refused_with_one_line(args, says):
    base = ["--telemetry", "tcp:127.0.0.1:1", "--sysid", "1", "--grid", str(ROOT / "missions/chicago-loop/grid.npz")]
    base += ["--mission-id", "7", "--altitude", "40", "--vehicle", "0", "--send", "udp:127.0.0.1:9"]
    run = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "sitl_detector.py"), *base, *args],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 2 and says in run.stderr and "Traceback" not in run.stderr
