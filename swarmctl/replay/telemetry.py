"""What the vehicles said about themselves in a .tlog: positions, battery, flight modes, link.

Vehicles are the system ids that send autopilot HEARTBEATs (autopilot not MAV_AUTOPILOT_INVALID);
ground stations and companion computers are left out. Per vehicle:
- positions from GLOBAL_POSITION_INT (GPS_RAW_INT when a log has none): lat, lon, altitude above home,
  at most five a second (the first of each 0.2 s); a position outside -90..90 latitude or -180..180
  longitude (no receiver reports one) is skipped and counted (`bad_positions`), never projected;
- battery from SYS_STATUS.battery_remaining (BATTERY_STATUS when SYS_STATUS never gives it), in %;
- flight modes from the heartbeats (pymavlink's mode names: ArduPilot by vehicle type, PX4);
- link: "lost" from the moment heartbeats stop for LOST_AFTER_S (3 s, swarmctl's link watch's), "ok"
  again at the next heartbeat.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pyproj
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.mavlink.limits import AIRBORNE_M
from swarmctl.mavlink.network import LOST_AFTER_S
from swarmctl.replay.tlog import TlogIndex

MAV = mavlink2
GEOD = pyproj.Geod(ellps="WGS84")
POSITION_DT = 0.2  # positions kept: at most 5 per second per vehicle (enough for tracks and distance)


@dataclass
class VehicleTelemetry:
    """One system id's telemetry, as time series (seconds since 1970)."""

    sysid: int
    autopilot: str = "unknown"
    vehicle_type: str = "unknown"
    pos_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lat: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lon: np.ndarray = field(default_factory=lambda: np.zeros(0))
    alt: np.ndarray = field(default_factory=lambda: np.zeros(0))  # metres above home
    battery_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    battery: np.ndarray = field(default_factory=lambda: np.zeros(0))  # %
    modes: list[tuple[float, str]] = field(default_factory=list)  # (time, mode) at each change
    heartbeats: np.ndarray = field(default_factory=lambda: np.zeros(0))
    armed: list[tuple[float, bool]] = field(default_factory=list)  # at each change
    bad_positions: int = 0  # positions skipped: latitude or longitude out of range

    def link(self, end: float | None = None) -> list[tuple[float, str]]:
        """(time, "ok" | "lost") at each change of the link, from the heartbeat times."""
        hb = self.heartbeats
        if not hb.size:
            return []
        out = [(float(hb[0]), "ok")]
        gaps = np.flatnonzero(np.diff(hb) > LOST_AFTER_S)
        for g in gaps:
            out += [(float(hb[g]) + LOST_AFTER_S, "lost"), (float(hb[g + 1]), "ok")]
        if end is not None and end - hb[-1] > LOST_AFTER_S:
            out.append((float(hb[-1]) + LOST_AFTER_S, "lost"))
        return out

    def distance_m(self) -> float:
        """Horizontal distance flown, metres: the stretches with an end at least AIRBORNE_M above home,
        as the controller's odometer counts them (Vehicle.distance_flown_m, which adds the climbs)."""
        return path_m(self.lat, self.lon, self.alt >= AIRBORNE_M)

    def position_at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lat, lon, alt) of the last fix at or before each time (NaN before the first)."""
        t = np.asarray(t, dtype=float)
        if not self.pos_t.size:
            nan = np.full(t.shape, np.nan)
            return nan, nan.copy(), nan.copy()
        i = np.searchsorted(self.pos_t, t, side="right") - 1
        ok = i >= 0
        j = np.clip(i, 0, None)
        return (np.where(ok, self.lat[j], np.nan), np.where(ok, self.lon[j], np.nan), np.where(ok, self.alt[j], np.nan))


def path_m(lat: np.ndarray, lon: np.ndarray, airborne: np.ndarray | None = None) -> float:
    """Length in metres (on the WGS84 ellipsoid) of a path of points; with `airborne`, only the legs
    that start or end in the air count."""
    if lat.size < 2:
        return 0.0
    d = GEOD.inv(lon[:-1], lat[:-1], lon[1:], lat[1:])[2]
    if airborne is not None:
        d = np.where(airborne[1:] | airborne[:-1], d, 0.0)
    return float(np.sum(d))


def _enum_name(enum: str, value: int) -> str:
    entry = mavlink2.enums.get(enum, {}).get(value)
    return entry.name.removeprefix(enum + "_").lower() if entry is not None else str(value)


def read_telemetry(index: TlogIndex) -> dict[int, VehicleTelemetry]:
    """Per vehicle system id, its telemetry (see the module docstring)."""
    vehicles: dict[int, VehicleTelemetry] = {}
    beats: dict[int, list[float]] = {}
    for t, m in index.decode(index.select([MAV.MAVLINK_MSG_ID_HEARTBEAT])):
        if m.autopilot == MAV.MAV_AUTOPILOT_INVALID or m.type == MAV.MAV_TYPE_GCS:
            continue
        s = m.get_srcSystem()
        v = vehicles.get(s)
        if v is None:
            v = vehicles[s] = VehicleTelemetry(
                s, _enum_name("MAV_AUTOPILOT", m.autopilot), _enum_name("MAV_TYPE", m.type)
            )
        beats.setdefault(s, []).append(t)
        mode = mavutil.mode_string_v10(m)
        if not v.modes or v.modes[-1][1] != mode:
            v.modes.append((t, mode))
        armed = bool(m.base_mode & MAV.MAV_MODE_FLAG_SAFETY_ARMED)
        if not v.armed or v.armed[-1][1] != armed:
            v.armed.append((t, armed))
    for s, hb in beats.items():
        vehicles[s].heartbeats = np.asarray(hb)
    _positions(index, vehicles)
    _battery(index, vehicles)
    return vehicles


def _series(index: TlogIndex, msgid: int, sysids: set[int], fields, min_dt: float = 0.0) -> dict[int, np.ndarray]:
    """(N, 1 + len(fields)) arrays per system id: time and the fields' values; with min_dt, at most one
    message per system id in each min_dt seconds (the first) is decoded."""
    rows: dict[int, list] = {}
    pick = index.select([msgid])
    pick = pick[np.isin(index.sysid[pick], list(sysids))]
    if min_dt > 0 and pick.size:
        slot = np.floor(index.time[pick] / min_dt).astype(np.int64)
        key = index.sysid[pick] * (1 << 40) + (slot - slot.min())
        _, first = np.unique(key, return_index=True)
        pick = pick[np.sort(first)]
    for t, m in index.decode(pick):
        rows.setdefault(m.get_srcSystem(), []).append((t, *(f(m) for f in fields)))
    return {s: np.asarray(r, dtype=float) for s, r in rows.items()}


def _positions(index: TlogIndex, vehicles: dict[int, VehicleTelemetry]) -> None:
    fields = (lambda m: m.lat / 1e7, lambda m: m.lon / 1e7, lambda m: m.relative_alt / 1000.0)
    got = _series(index, MAV.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, set(vehicles), fields, POSITION_DT)
    missing = set(vehicles) - set(got)
    if missing:  # GPS_RAW_INT has no height above home: the first fix's altitude stands in for home
        raw = _series(
            index,
            MAV.MAVLINK_MSG_ID_GPS_RAW_INT,
            missing,
            (lambda m: m.lat / 1e7, lambda m: m.lon / 1e7, lambda m: m.alt / 1000.0),
        )
        for s, a in raw.items():
            a = a[(a[:, 1] != 0) | (a[:, 2] != 0)]
            if a.size:
                a[:, 3] -= a[0, 3]
                got[s] = a
    for s, a in got.items():
        a = a[(a[:, 1] != 0) | (a[:, 2] != 0)]  # (0, 0): no fix yet
        good = (np.abs(a[:, 1]) <= 90.0) & (np.abs(a[:, 2]) <= 180.0) & np.isfinite(a[:, 3])
        v = vehicles[s]
        v.bad_positions = int((~good).sum())
        a = a[good]
        a = a[np.argsort(a[:, 0], kind="stable")]
        v.pos_t, v.lat, v.lon, v.alt = a[:, 0], a[:, 1], a[:, 2], a[:, 3]


def _battery(index: TlogIndex, vehicles: dict[int, VehicleTelemetry]) -> None:
    got = _series(index, MAV.MAVLINK_MSG_ID_SYS_STATUS, set(vehicles), (lambda m: m.battery_remaining,))
    missing = {s for s in vehicles if s not in got or (got[s][:, 1] < 0).all()}
    if missing:
        got.update(_series(index, MAV.MAVLINK_MSG_ID_BATTERY_STATUS, missing, (lambda m: m.battery_remaining,)))
    for s, a in got.items():
        a = a[a[:, 1] >= 0]  # -1: not known
        vehicles[s].battery_t, vehicles[s].battery = a[:, 0], a[:, 1]
