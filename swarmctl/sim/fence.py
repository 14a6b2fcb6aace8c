"""The mock autopilot's geofence: the vehicle side of the mission protocol for mission_type FENCE, the
stored inclusion polygons, and the checks the autopilots make with them.

Upload, as ArduPilot runs it (libraries/GCS_MAVLink/MissionItemProtocol): MISSION_COUNT starts a
transfer (a second COUNT from the same sender restarts it; one from another sender while a transfer
runs is DENIED; more than `max_items` is NO_SPACE); the vehicle asks for each item in turn with
MISSION_REQUEST_INT, asks again every second while nothing comes and cancels the transfer after 5 s
of silence (OPERATION_CANCELLED); an item out of turn gets INVALID_SEQUENCE and the transfer goes on;
after the last item it answers MISSION_ACK ACCEPTED, or an error when the polygons do not add up. The
last item sent again after the transfer is acknowledged again (its ACK was lost). MISSION_CLEAR_ALL
removes the fence, MISSION_REQUEST_LIST / MISSION_REQUEST_INT download it. Only inclusion polygon
vertices (MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION) are taken; other fence items are UNSUPPORTED.

The stored fence survives reboots, like the autopilots' own storage. It is enforced when the mock's
personality (personality.py) says it is on: ArduPilot after MAV_CMD_DO_FENCE_ENABLE (param1 1 on, 0
off; not saved, so off again after a reboot); PX4 as soon as one is uploaded (its GF_ACTION parameter
is not 0). With several inclusion polygons ArduPilot keeps the vehicle inside all of them (its default
FENCE_OPTIONS) and PX4 inside any one of them; points on the boundary count as inside.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import shapely
from pymavlink.dialects.v20 import ardupilotmega as MAV

from swarmctl.mavlink.codec import from_deg_e7

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.sim.autopilot import MockAutopilot

FENCE = MAV.MAV_MISSION_TYPE_FENCE
MAX_ITEMS = 100  # the mock's storage; ArduPilot's depends on its board (84 points on a Pixhawk)
REQUEST_AGAIN = 1.0  # wall seconds without the requested item before asking again
UPLOAD_TIMEOUT = 5.0  # wall seconds without any item before the transfer is cancelled
_GLOBAL_FRAMES = {
    MAV.MAV_FRAME_GLOBAL,
    MAV.MAV_FRAME_GLOBAL_INT,
    MAV.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    MAV.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
}


def fence_polygons(items: list[Any]) -> list[list[tuple[float, float]]]:
    """The inclusion polygons of a fence's MISSION_ITEM_INTs, as (lat, lon) vertices: consecutive
    items form one polygon of param1 vertices. ValueError when the vertex counts do not add up."""
    polygons, i = [], 0
    while i < len(items):
        n = items[i].param1
        if n != int(n) or int(n) < 3:
            raise ValueError(f"item {i}: param1 {n!r} is not a polygon's vertex count (3 or more)")
        group = items[i : i + int(n)]
        if len(group) < n or any(item.param1 != n for item in group):
            raise ValueError(f"items {i}..: a polygon of {int(n)} vertices has {len(group)} items with that count")
        polygons.append([(from_deg_e7(item.x), from_deg_e7(item.y)) for item in group])
        i += int(n)
    return polygons


@dataclass
class _Upload:
    sender: tuple[int, int]  # (system, component) of the ground station uploading
    count: int
    items: list[Any] = field(default_factory=list)
    asked: float = 0.0  # when the next item was last requested (wall)
    heard: float = field(default_factory=time.monotonic)  # when the sender was last heard (wall)


class MockFence:
    """One mock vehicle's geofence (the mock calls it with its lock held, from the thread it runs in)."""

    def __init__(self, mock: MockAutopilot):
        self.mock = mock
        self.max_items = MAX_ITEMS
        self.items: list[Any] = []
        self.polygons: list[list[tuple[float, float]]] = []
        self.enabled = False  # the DO_FENCE_ENABLE switch (ArduPilot's; PX4 has none)
        self.refused = 0  # position targets refused because they lie outside the fence
        self.breaches = 0  # times the vehicle was found outside it in flight
        self.breached = False
        self._shapes: list[Any] = []
        self._upload: _Upload | None = None
        self._acked: tuple[tuple[int, int], int] | None = None  # (sender, seq) of the last item acked

    # --- checks ---------------------------------------------------------------------------------------

    @property
    def active(self) -> bool:
        """The fence is being enforced."""
        if not self.polygons:
            return False
        return self.mock.personality.fence_enforced(self.enabled, self.mock.params)

    def allows(self, lat: float, lon: float) -> bool:
        """True unless an enforced fence keeps the vehicle from (lat, lon)."""
        if not self.active:
            return True
        inside = [bool(shapely.intersects_xy(s, lon, lat)) for s in self._shapes]
        return all(inside) if self.mock.personality.fence_inside_all else any(inside)

    def enable(self, param1: float) -> int:
        """MAV_CMD_DO_FENCE_ENABLE (ArduPilot): 1 on, 0 off, 2 (floor only off) leaves it as it is."""
        if int(param1) not in (0, 1, 2):
            return MAV.MAV_RESULT_DENIED
        if int(param1) != 2:
            self.enabled = int(param1) == 1
            self.mock.statustext("Fence enabled" if self.enabled else "Fence disabled")
        return MAV.MAV_RESULT_ACCEPTED

    # --- the mission protocol -------------------------------------------------------------------------

    def handle(self, msg: Any) -> None:
        """A mission-protocol message with mission_type FENCE."""
        mtype = msg.get_type()
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        if mtype == "MISSION_COUNT":
            self._count(msg, sender)
        elif mtype == "MISSION_ITEM_INT":
            self._item(msg, sender)
        elif mtype == "MISSION_ITEM":
            self._ack(sender, MAV.MAV_MISSION_UNSUPPORTED)  # the mock takes MISSION_ITEM_INT only
        elif mtype in ("MISSION_REQUEST_LIST", "MISSION_REQUEST_INT", "MISSION_REQUEST"):
            self._download(msg, sender)
        elif mtype == "MISSION_CLEAR_ALL":
            if self._upload is not None:
                self._ack(sender, MAV.MAV_MISSION_ERROR)
                return
            self._store([], [])
            self._ack(sender, MAV.MAV_MISSION_ACCEPTED)

    def tick(self, now: float) -> None:
        """Ask again for an item that did not come; give up on a silent transfer."""
        up = self._upload
        if up is None:
            return
        if now - up.heard > UPLOAD_TIMEOUT:
            self._upload = None
            self._ack(up.sender, MAV.MAV_MISSION_OPERATION_CANCELLED)
        elif now - up.asked > REQUEST_AGAIN:
            self._request(up)

    def _count(self, msg: Any, sender: tuple[int, int]) -> None:
        if self._upload is not None and self._upload.sender != sender:
            self._ack(sender, MAV.MAV_MISSION_DENIED)  # someone else is uploading
            return
        self._upload = None
        if msg.count > self.max_items:
            self._ack(sender, MAV.MAV_MISSION_NO_SPACE)
            self.mock.statustext(f"Only {self.max_items} items are supported", MAV.MAV_SEVERITY_WARNING)
            return
        if msg.count == 0:
            self._store([], [])
            self._ack(sender, MAV.MAV_MISSION_ACCEPTED)
            return
        self._upload = _Upload(sender, msg.count)
        self._request(self._upload)

    def _item(self, msg: Any, sender: tuple[int, int]) -> None:
        up = self._upload
        if up is None:
            if self._acked == (sender, msg.seq):
                self._ack(sender, MAV.MAV_MISSION_ACCEPTED)  # the last item again: its ACK was lost
            return
        if sender != up.sender:
            self._ack(sender, MAV.MAV_MISSION_DENIED)
            return
        if msg.seq != len(up.items):
            self._ack(sender, MAV.MAV_MISSION_INVALID_SEQUENCE)  # and the transfer goes on
            return
        problem = None
        if msg.command != MAV.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION:
            problem = MAV.MAV_MISSION_UNSUPPORTED
        elif msg.frame not in _GLOBAL_FRAMES:
            problem = MAV.MAV_MISSION_UNSUPPORTED_FRAME
        if problem is not None:
            self._upload = None
            self._ack(sender, problem)
            return
        up.items.append(msg)
        up.heard = time.monotonic()
        if len(up.items) < up.count:
            self._request(up)
            return
        self._upload = None
        try:
            polygons = fence_polygons(up.items)
        except ValueError as exc:
            self.mock.statustext(f"Fence: {exc}"[:50], MAV.MAV_SEVERITY_WARNING)
            self._ack(sender, MAV.MAV_MISSION_INVALID_PARAM1)
            return
        self._store(up.items, polygons)
        self._acked = (sender, msg.seq)
        self._ack(sender, MAV.MAV_MISSION_ACCEPTED)

    def _download(self, msg: Any, sender: tuple[int, int]) -> None:
        mav = self.mock.mav
        if self._upload is not None:
            self._ack(sender, MAV.MAV_MISSION_DENIED)
        elif msg.get_type() == "MISSION_REQUEST_LIST":
            self.mock.send_message(mav.mission_count_encode(*sender, len(self.items), FENCE))
        elif msg.seq >= len(self.items):
            self._ack(sender, MAV.MAV_MISSION_INVALID_SEQUENCE)
        else:
            i = self.items[msg.seq]
            self.mock.send_message(
                mav.mission_item_int_encode(
                    *sender,
                    i.seq,
                    i.frame,
                    i.command,
                    0,
                    0,
                    i.param1,
                    i.param2,
                    i.param3,
                    i.param4,
                    i.x,
                    i.y,
                    i.z,
                    FENCE,
                )
            )

    def _store(self, items: list[Any], polygons: list[list[tuple[float, float]]]) -> None:
        self.items, self.polygons = list(items), polygons
        self._shapes = [shapely.Polygon([(lon, lat) for lat, lon in p]) for p in polygons]
        for s in self._shapes:
            shapely.prepare(s)
        self.breached = False

    def _request(self, up: _Upload) -> None:
        up.asked = time.monotonic()
        self.mock.send_message(self.mock.mav.mission_request_int_encode(*up.sender, len(up.items), FENCE))

    def _ack(self, sender: tuple[int, int], result: int) -> None:
        self.mock.send_message(self.mock.mav.mission_ack_encode(*sender, result, FENCE))
