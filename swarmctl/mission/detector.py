"""Sensing for the controller: what a vehicle's field of view covers, as MAVLink TUNNEL payloads.

The controller never reads the truth, and explores cells from the vehicle's position whether or not
it has a detector (swarmctl.mission.sensing). A detector (simulated: swarmctl.sim.detector; onboard
software on a real vehicle) adds what it sees from the cell the vehicle hovers over: the target
cells, and optionally the cells of its field of view with their value phi and obstacle flag. It uses
two of the knowledge codec's payload kinds (swarmctl/knowledge/codec.py), sent by the vehicle:

    DETECTION (TUNNEL.payload_type 32803)  the target cells in view (only sent when there are some)
    DELTA     (TUNNEL.payload_type 32800)  the cells in view: cell index, obstacle bit, phi * 255

with the knowledge header's sender = the vehicle's index in the mission (0-based order of
[[vehicles]]), sender x, y = the cell the report is for, step = a report counter, and the mission id
and grid size of the mission (reports for another mission or grid are rejected). DETECTION comes
first, so when the DELTA arrives the report for that cell is complete (a DELTA with no cells says
"seen from here, nothing more").

Two ways in (the vehicle's `detector` key), both read by `SensorFeed`:
- `detector = "mavlink"`: on the vehicle's own MAVLink link (ArduPilot: an onboard computer or camera
  component sending TUNNEL frames through the autopilot's routing); the feed accepts them only from
  that system id;
- `detector = "udp:127.0.0.1:14650"` (or `swarmctl agent --detector ...`): a local UDP socket, one
  MAVLink 2 TUNNEL frame or several per datagram, for a detector process running next to the agent
  (PX4 through MAVSDK has no way to hand TUNNEL messages to the controller, so PX4 vehicles use this).
With a detector the controller waits, after each cell reached, up to `[timing] sense_timeout` for its
report; a report that comes anyway (late, or from a vehicle given no detector) is used when it comes.

The simulated detector the mock vehicles carry (it writes these reports) is
swarmctl.sim.detector.SimDetector.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarmctl.knowledge.codec import PT_DELTA, PT_DETECTION, KnowledgeCodec
from swarmctl.knowledge.model import Delta, Detection, dequantise_phi

log = logging.getLogger(__name__)


@dataclass
class SensorReport:
    """What the detector saw from one cell."""

    cell: tuple[int, int]
    received: float  # time.monotonic() when the report was complete
    cells: np.ndarray  # (N, 2)
    phi: np.ndarray  # (N,) float32
    obstacle: np.ndarray  # (N,) bool
    targets: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))


NEW_REPORTS_KEPT = 256  # reports waiting for take_new (a detector repeats its report while the vehicle stays)
LATEST_CELLS_KEPT = 16  # cells whose latest report is kept for wait_report: the round waits for the newest
TARGETS_KEPT_S = 5.0  # a Detection counts for the Delta of its cell that comes within this long


class SensorFeed:
    """Collects one vehicle's detector reports (from its MAVLink link or a local socket): the latest
    report per cell (`wait_report`) and every report since the last `take_new`."""

    def __init__(self, vehicle_index: int, mission_id: int, width: int, height: int):
        self.vehicle_index = int(vehicle_index)
        self.codec = KnowledgeCodec(mission_id, width, height)
        self.latest: OrderedDict[tuple[int, int], SensorReport] = OrderedDict()  # the last cells reported
        self._new: deque[SensorReport] = deque(maxlen=NEW_REPORTS_KEPT)
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
            self._targets = {c: t for c, t in self._targets.items() if now - t[0] < TARGETS_KEPT_S}
            self._targets[message.cell] = (now, message.targets)
            return
        if not isinstance(message, Delta):
            return
        targets = np.zeros((0, 2), dtype=np.int64)
        seen = self._targets.get(message.cell)
        if seen is not None and now - seen[0] < TARGETS_KEPT_S:
            targets = seen[1]
        report = SensorReport(message.cell, now, message.cells, dequantise_phi(message.phi), message.obstacle, targets)
        self.latest[message.cell] = report  # bounded: a long mission reaches thousands of cells
        self.latest.move_to_end(message.cell)
        while len(self.latest) > LATEST_CELLS_KEPT:
            self.latest.popitem(last=False)
        self._new.append(report)
        self.reports += 1
        if self._changed is not None:
            self._changed.set()

    def listener(self, sysid: int):
        """A MavlinkLink listener taking the TUNNEL reports sent by system `sysid`."""

        def on_message(msg: Any) -> None:
            if msg.get_type() == "TUNNEL" and msg.get_srcSystem() == sysid:
                self.on_tunnel(msg.payload_type, bytes(msg.payload), msg.payload_length)

        return on_message

    def take_new(self) -> list[SensorReport]:
        """Every complete report received since the last call (oldest first), late ones included."""
        out = list(self._new)
        self._new.clear()
        return out

    # --- waiting ---------------------------------------------------------------------------------------
    async def wait_report(
        self, cell: tuple[int, int], since: float, timeout: float, abort: Callable[[], bool] | None = None
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
