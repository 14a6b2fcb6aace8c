"""Sensing for the controller: what a vehicle's field of view covers, as MAVLink TUNNEL payloads.

The controller never reads the truth. A detector (simulated here, onboard software on a real
vehicle) reports, for the cell the vehicle hovers over, the cells its field of view covers with
their value phi and obstacle flag, and the target cells it sees. It uses two of the knowledge
codec's payload kinds (swarmctl/mavlink/knowledge_codec.py), sent by the vehicle:

    DETECTION (TUNNEL.payload_type 32803)  the target cells in view (only sent when there are some)
    DELTA     (TUNNEL.payload_type 32800)  the cells in view: cell index, obstacle bit, phi * 255

with the knowledge header's sender = the vehicle's index in the mission (0-based order of
[[vehicles]]), sender x, y = the cell the report is for, step = a report counter, and the mission id
and grid size of the mission (reports for another mission or grid are rejected). DETECTION comes
first, so when the DELTA arrives the report for that cell is complete.

Two ways in, both read by `SensorFeed`:
- on the vehicle's own MAVLink link (ArduPilot: an onboard computer or camera component sending
  TUNNEL frames through the autopilot's routing); the feed accepts them only from that system id;
- a local UDP socket (`swarmctl agent --detector udp:127.0.0.1:14650`), one MAVLink 2 TUNNEL frame
  or several per datagram, for a detector process running next to the agent (PX4 through MAVSDK has
  no way to hand TUNNEL messages to the controller, so PX4 vehicles use this path).

`SimDetector` is the simulated detector: a mock vehicle carries a hidden scenario (targets, the
value map from swarmctl.world.scenario.value_map, the grid's blocked cells) and, each time it
hovers at the mission altitude within `tolerance` metres of a cell centre, reports that cell (and
repeats the report every `repeat` seconds while it stays).
"""

from __future__ import annotations

import asyncio
import logging
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarmctl.mavlink.codec import distance_m
from swarmctl.mavlink.knowledge_codec import PAYLOAD_SIZE, PT_DELTA, PT_DETECTION, KnowledgeCodec
from swarmctl.world.knowledge import Delta, Detection, dequantise_phi, disc_cells, quantise_phi
from swarmctl.world.scenario import value_map

log = logging.getLogger(__name__)

FOV_CELLS = 3.0  # the sensing disc radius (cells), as in the simulator


@dataclass
class SensorReport:
    """What the detector saw from one cell."""

    cell: tuple[int, int]
    received: float  # time.monotonic() when the report was complete
    cells: np.ndarray  # (N, 2)
    phi: np.ndarray  # (N,) float32
    obstacle: np.ndarray  # (N,) bool
    targets: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))


class SensorFeed:
    """Collects one vehicle's detector reports (from its MAVLink link or a local socket)."""

    def __init__(self, vehicle_index: int, mission_id: int, width: int, height: int):
        self.vehicle_index = int(vehicle_index)
        self.codec = KnowledgeCodec(mission_id, width, height)
        self.latest: dict[tuple[int, int], SensorReport] = {}
        self._targets: dict[tuple[int, int], tuple[float, np.ndarray]] = {}
        self._changed: asyncio.Event | None = None
        self.reports = 0

    # --- input -----------------------------------------------------------------------------------------
    def on_tunnel(self, payload_type: int, payload: bytes, payload_length: int) -> None:
        if payload_type not in (PT_DELTA, PT_DETECTION):
            return
        self.take(self.codec.decode(payload_type, payload, payload_length))

    def on_datagram(self, data: bytes) -> None:
        for message in self.codec.parse_datagram(data):
            self.take(message)

    def take(self, message: Any) -> None:
        if message is None or message.sender != self.vehicle_index or message.cell is None:
            return
        now = time.monotonic()
        if isinstance(message, Detection):
            self._targets[message.cell] = (now, message.targets)
            return
        if not isinstance(message, Delta):
            return
        targets = np.zeros((0, 2), dtype=np.int64)
        seen = self._targets.get(message.cell)
        if seen is not None and now - seen[0] < 5.0:
            targets = seen[1]
        self.latest[message.cell] = SensorReport(
            message.cell, now, message.cells, dequantise_phi(message.phi), message.obstacle, targets
        )
        self.reports += 1
        if self._changed is not None:
            self._changed.set()

    def listener(self, sysid: int):
        """A MavlinkLink listener taking the TUNNEL reports sent by system `sysid`."""

        def on_message(msg: Any) -> None:
            if msg.get_type() == "TUNNEL" and msg.get_srcSystem() == sysid:
                self.on_tunnel(msg.payload_type, bytes(msg.payload), msg.payload_length)

        return on_message

    # --- waiting ---------------------------------------------------------------------------------------
    async def wait_report(
        self, cell: tuple[int, int], since: float, timeout: float, abort: Any = None
    ) -> SensorReport | None:
        """The report for `cell` received after `since` (monotonic), or None after `timeout` s (or as
        soon as `abort()` is true)."""
        if self._changed is None:
            self._changed = asyncio.Event()
        deadline = time.monotonic() + timeout
        while True:
            r = self.latest.get(cell)
            if r is not None and r.received >= since:
                return r
            left = deadline - time.monotonic()
            if left <= 0 or (abort is not None and abort()):
                return None
            self._changed.clear()
            try:
                await asyncio.wait_for(self._changed.wait(), min(left, 0.25))
            except TimeoutError:
                pass


class UdpSensorSource:
    """A local UDP socket an onboard detector writes its TUNNEL frames to; feeds a SensorFeed."""

    def __init__(self, feed: SensorFeed, host: str = "127.0.0.1", port: int = 14650):
        self.feed = feed
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((host, port))
        except OSError:
            self.sock.close()
            raise
        self.sock.setblocking(False)
        self.address = self.sock.getsockname()
        self._loop: asyncio.AbstractEventLoop | None = None

    def start(self) -> UdpSensorSource:
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(self.sock.fileno(), self._readable)
        return self

    def _readable(self) -> None:
        while True:
            try:
                data = self.sock.recv(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            self.feed.on_datagram(data)

    def close(self) -> None:
        if self._loop is not None:
            try:
                self._loop.remove_reader(self.sock.fileno())
            except (ValueError, RuntimeError):
                pass
        self.sock.close()


class SimDetector:
    """The hidden scenario a mock vehicle carries, and the detector that reports its field of view.

    `attach(mock)` adds a step hook to a MockAutopilot; reports go out on the mock's own MAVLink link,
    or, with `udp=(host, port)`, as datagrams to a local detector socket (the PX4 path)."""

    def __init__(
        self,
        grid: Any,
        targets: np.ndarray,
        vehicle_index: int,
        mission_id: int,
        altitude: float,
        fov: float = FOV_CELLS,
        tolerance: float = 1.0,
        repeat: float = 1.0,
        udp: tuple[str, int] | None = None,
    ):
        self.grid = grid
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

    def attach(self, mock: Any) -> SimDetector:
        mock.step_hooks.append(self._hook)
        return self

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _hook(self, mock: Any, _dt: float) -> None:
        if not mock.armed or abs(mock.rel_alt - self.altitude) > max(1.0, self.tolerance):
            self._last = (None, 0.0)
            return
        x, y = self.grid.latlon_to_cell(mock.lat, mock.lon)
        if not (0 <= x < self.grid.width and 0 <= y < self.grid.height):
            return
        lat, lon = float(self._centres[0][x, y]), float(self._centres[1][x, y])
        if distance_m(mock.lat, mock.lon, lat, lon) > self.tolerance:
            self._last = (None, 0.0)
            return
        now = time.monotonic()
        if self._last[0] == (x, y) and now - self._last[1] < self.repeat:
            return
        self._last = ((x, y), now)
        self.report(mock, (x, y))

    def observe(self, cell: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(cells, phi, obstacle, targets) in the field of view from `cell`: the truth."""
        c = disc_cells(cell, self.grid.width, self.grid.height, self.fov)
        x, y = c[:, 0], c[:, 1]
        return c, self.phi[x, y], self.obstacle[x, y], c[self.target_mask[x, y]]

    def payloads(self, cell: tuple[int, int]) -> list[tuple[int, bytes]]:
        cells, phi, obstacle, targets = self.observe(cell)
        with self._lock:
            self._count += 1
            step = self._count
        out: list[tuple[int, bytes]] = []
        if len(targets):
            out += self.codec.encode(Detection(self.vehicle_index, step, cell, False, targets))
        out += self.codec.encode(Delta(self.vehicle_index, step, cell, False, cells, quantise_phi(phi), obstacle))
        return out

    def report(self, mock: Any, cell: tuple[int, int]) -> None:
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
