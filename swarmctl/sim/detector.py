"""The simulated detector a mock vehicle carries: the hidden truth, reported as a detector would.

A mock vehicle carries a hidden scenario (targets, the value map from swarmctl.world.scenario.value_map,
the grid's blocked cells) and, each time it hovers at the mission altitude within `tolerance` metres
of a cell centre, reports that cell (and repeats the report every `repeat` seconds while it stays),
in the TUNNEL payloads swarmctl.mission.detector describes.

With a probability of detection `pod` below 1 the detector misses: a target that enters the footprint
(at the first report of a cell the vehicle has just reached) is reported with probability pod, drawn
from `seed` and the vehicle's index; while it stays in the footprint, as the vehicle moves on or
stays, the detector keeps its verdict: the same look, as swarmctl.world.prior counts passes. pod 1
draws nothing.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from typing import TYPE_CHECKING

import numpy as np

from swarmctl.knowledge.codec import PAYLOAD_SIZE, KnowledgeCodec
from swarmctl.knowledge.model import Delta, Detection, disc_cells, quantise_phi
from swarmctl.mavlink.codec import distance_m
from swarmctl.world.prior import check_pod
from swarmctl.world.scenario import value_map

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.geo.grid import GeoGrid
    from swarmctl.sim.autopilot import MockAutopilot

log = logging.getLogger(__name__)

FOV_CELLS = 3.0  # the sensing disc radius (cells), as in the simulator
# Seconds between reports of the cell a vehicle stays at, as a detector reporting what its camera sees ten
# times a second would. The controller waits for the report of each cell reached: a report lost on the
# link costs it this long (on links losing 20 % each way, the demo's rounds took 0.8 s at 1 s, 0.39 s at
# 0.25 s, where one seed in five ran low on battery before the end, and 0.31-0.34 s at 0.1 s: tools/lossy_links.py).
REPORT_REPEAT_S = 0.1


class SimDetector:
    """The hidden scenario a mock vehicle carries, and the detector that reports its field of view.

    `attach(mock)` adds a step hook to a MockAutopilot; reports go out on the mock's own MAVLink link,
    or, with `udp=(host, port)`, as datagrams to a local detector socket (the PX4 path). Without a mock,
    `cell_to_report` and `report(None, cell)` (with `udp`) serve a detector fed a real vehicle's position."""

    def __init__(
        self,
        grid: GeoGrid,
        targets: np.ndarray,
        vehicle_index: int,
        mission_id: int,
        altitude: float,
        fov: float = FOV_CELLS,
        tolerance: float = 1.0,
        repeat: float = REPORT_REPEAT_S,
        udp: tuple[str, int] | None = None,
        pod: float = 1.0,
        seed: int = 0,
    ):
        self.grid = grid
        self.pod = check_pod(pod)
        self._rng = np.random.default_rng([int(seed), int(vehicle_index)])
        self._pass: tuple[tuple[int, int] | None, dict[tuple[int, int], bool]] = (None, {})  # cell, verdicts
        w, h = grid.width, grid.height
        self.targets = np.asarray(targets, dtype=np.int64).reshape(-1, 2)
        self.phi = value_map(self.targets, w, h)
        self.obstacle = np.asarray(grid.blocked, dtype=bool)
        self.target_mask = np.zeros((w, h), dtype=bool)
        if len(self.targets):
            self.target_mask[self.targets[:, 0], self.targets[:, 1]] = True
        self.vehicle_index, self.altitude, self.fov = int(vehicle_index), float(altitude), float(fov)
        self.tolerance, self.repeat = float(tolerance), float(repeat)
        self.codec = KnowledgeCodec(mission_id, w, h)
        self.udp = udp
        self._sock: socket.socket | None = None
        self._last: tuple[tuple[int, int] | None, float] = (None, 0.0)
        self._count = 0
        self._lock = threading.Lock()
        self.sent_reports = 0
        self._centres = grid.cells_to_latlon(*np.meshgrid(np.arange(w), np.arange(h), indexing="ij"))

    def attach(self, mock: MockAutopilot) -> SimDetector:
        mock.step_hooks.append(self._hook)
        return self

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _hook(self, mock: MockAutopilot, _dt: float) -> None:
        cell = self.cell_to_report(mock.armed, mock.lat, mock.lon, mock.rel_alt)
        if cell is not None:
            self.report(mock, cell)

    def cell_to_report(self, armed: bool, lat: float, lon: float, rel_alt: float) -> tuple[int, int] | None:
        """The cell to report for a vehicle at this position now (it hovers at the mission altitude within
        `tolerance` metres of that cell's centre, and the cell was not reported in the last `repeat`
        seconds), else None. For a detector fed another vehicle's telemetry (tools/sitl_detector.py)."""
        if not armed or abs(rel_alt - self.altitude) > max(1.0, self.tolerance):
            self._last = (None, 0.0)
            return None
        x, y = self.grid.latlon_to_cell(lat, lon)
        if not (0 <= x < self.grid.width and 0 <= y < self.grid.height):
            return None
        centre_lat, centre_lon = float(self._centres[0][x, y]), float(self._centres[1][x, y])
        if distance_m(lat, lon, centre_lat, centre_lon) > self.tolerance:
            self._last = (None, 0.0)
            return None
        now = time.monotonic()
        if self._last[0] == (x, y) and now - self._last[1] < self.repeat:
            return None
        self._last = ((x, y), now)
        return (x, y)

    def observe(self, cell: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(cells, phi, obstacle, targets) in the field of view from `cell`: the truth."""
        c = disc_cells(cell, self.grid.width, self.grid.height, self.fov)
        x, y = c[:, 0], c[:, 1]
        return c, self.phi[x, y], self.obstacle[x, y], c[self.target_mask[x, y]]

    def seen(self, cell: tuple[int, int], targets: np.ndarray) -> np.ndarray:
        """The targets in the footprint round `cell` this pass reports: each with probability pod, drawn
        once a pass (a report of another cell than the last starts a new one)."""
        if self.pod >= 1.0:
            return targets
        if self._pass[0] != cell:  # a new cell: a draw for each target entering the footprint
            before = self._pass[1]
            verdicts = {}
            for t in map(tuple, targets.tolist()):
                verdicts[t] = before[t] if t in before else bool(self._rng.random() < self.pod)
            self._pass = (cell, verdicts)
        seen = [self._pass[1].get(tuple(t), False) for t in targets.tolist()]
        return targets[np.asarray(seen, dtype=bool)] if len(targets) else targets

    def payloads(self, cell: tuple[int, int]) -> list[tuple[int, bytes]]:
        cells, phi, obstacle, targets = self.observe(cell)
        with self._lock:
            self._count += 1
            step = self._count
            targets = self.seen(cell, targets)
        out: list[tuple[int, bytes]] = []
        if len(targets):
            out += self.codec.encode(Detection(self.vehicle_index, step, cell, False, targets))
        out += self.codec.encode(Delta(self.vehicle_index, step, cell, False, cells, quantise_phi(phi), obstacle))
        return out

    def report(self, mock: MockAutopilot, cell: tuple[int, int]) -> None:
        payloads = self.payloads(cell)
        self.sent_reports += 1
        if self.udp is None:
            for ptype, payload in payloads:
                padded = list(payload) + [0] * (PAYLOAD_SIZE - len(payload))
                mock.send_message(mock.mav.tunnel_encode(0, 0, ptype, len(payload), padded))
            return
        if self._sock is None:
            self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for ptype, payload in payloads:
            try:
                self._sock.sendto(self.codec.frame(ptype, payload), self.udp)
            except OSError as exc:
                log.debug("detector: send failed: %s", exc)
