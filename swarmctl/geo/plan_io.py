"""QGroundControl .plan files (JSON, fileType "Plan", version 1) in and out.

The versions are checked: the file's must be 1, its geoFence's and mission's 1 or 2 (what
QGroundControl writes and reads); a version left out is taken as the current one.

Reading (`read_plan`): geofence polygons with ``"inclusion": true`` and survey ComplexItem polygons
make up the area (their union); geofence polygons with ``"inclusion": false`` are no-fly zones;
geofence circles are no-fly zones when ``"inclusion": false`` and part of the area when true. Plans
store positions as [lat, lon(, alt)].

Values are checked as QGroundControl checks them: every fence needs ``"inclusion"`` as a JSON boolean
(0, 1, "false", null or a missing key are refused, never guessed), and coordinates and circle radii
must be finite JSON numbers (not strings, not booleans). Errors name the JSON path of the bad value,
e.g. ``geoFence.polygons[1].inclusion``.

Writing (`write_plan`): the area's outer rings become inclusion polygons, its holes and no-fly
polygons exclusion polygons, its no-fly circles exclusion circles, with an empty mission (home at
a point inside the area, altitudes relative to home) and no rally points, as QGroundControl
itself writes them. `write_mission_plan` writes the same fences with a mission of waypoints: SimpleItems
with command 16 (NAV_WAYPOINT) and frame 3 (altitude relative to home); `read_waypoints` reads a plan's
SimpleItems back, their command, frame and position checked.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import Polygon

from swarmctl.errors import InputError
from swarmctl.geo.areas import Area, Circle, build_area
from swarmctl.geo.defaults import CIRCLE_SEGMENTS
from swarmctl.geo.projection import LocalProjection
from swarmctl.geo.readers import json_number, lonlat_ring, make_polygon, read_json, show_json

MAX_RADIUS = 1e6  # metres
PLAN_VERSION = 1  # the file version QGroundControl writes (and the only one it reads)
PART_VERSIONS = (1, 2)  # the geoFence and mission versions QGroundControl reads
MAV_CMD_NAV_WAYPOINT = 16
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3  # altitude relative to home


def circle_polygon(circle: Circle) -> Polygon:
    """A circle (radius in metres) as a lon/lat polygon, built in a frame centred on it."""
    proj = LocalProjection.centred_on((circle.lon, circle.lat, circle.lon, circle.lat))
    disc = shapely.Point(*proj.to_metres(circle.lon, circle.lat)).buffer(circle.radius, CIRCLE_SEGMENTS)
    return proj.geometry_to_lonlat(disc)


def _ring(coords: object, path: Path, where: str, at: str) -> np.ndarray:
    if not isinstance(coords, list):
        raise InputError(
            f'{path}: {where}: {at} is {show_json(coords)}: "polygon" must be a list of [lat, lon] positions; '
            "fix the plan"
        )
    return lonlat_ring(coords, path, where, lat_first=True, fmt="a QGroundControl plan", json_path=at)


def _inclusion(item: dict, path: Path, at: str, zone: str) -> bool:
    """A fence's "inclusion": a JSON boolean, required, as QGroundControl itself requires (0, 1, "false" and
    null are refused: reading "false" as true would turn a no-fly zone into search area)."""
    fix = f'write "inclusion": true (search area) or false (no-fly zone) for this {zone}, as QGroundControl does'
    if "inclusion" not in item:
        raise InputError(f"{path}: {at}.inclusion is missing; {fix}")
    value = item["inclusion"]
    if not isinstance(value, bool):
        raise InputError(f"{path}: {at}.inclusion is {show_json(value)}, not true or false; {fix}")
    return value


def _items(parent: dict, key: str, path: Path, where: str) -> list:
    """parent[key] as a list (missing or null: empty); anything else is an InputError."""
    value = parent.get(key)
    if value is None:
        return []
    if not isinstance(value, list):
        raise InputError(f'{path}: {where} "{key}" must be a list; fix the plan')
    return value


def _plan_parts(path: Path) -> tuple[dict, dict]:
    """A .plan file's geoFence and mission objects, its fileType and versions checked."""
    obj = read_json(path, "QGroundControl plan")
    if not isinstance(obj, dict) or obj.get("fileType") != "Plan":
        raise InputError(
            f'{path}: not a QGroundControl plan (fileType is not "Plan"); save it from QGroundControl\'s Plan view'
        )
    fence = obj.get("geoFence") or {}
    mission = obj.get("mission") or {}
    if not isinstance(fence, dict) or not isinstance(mission, dict):
        raise InputError(f'{path}: "geoFence" and "mission" must be JSON objects; fix the plan')
    for where, part, known in (
        ("", obj, (PLAN_VERSION,)),
        ("geoFence ", fence, PART_VERSIONS),
        ("mission ", mission, PART_VERSIONS),
    ):
        version = part.get("version", known[-1])  # hand-written plans may leave it out
        if isinstance(version, bool) or version not in known:
            raise InputError(
                f"{path}: {where}version {version!r} is not one QGroundControl writes "
                f"({' or '.join(map(str, known))}); save the plan again from QGroundControl"
            )
    return fence, mission


def read_plan(path: str | Path) -> Area:
    """Read the area and no-fly zones of a QGroundControl .plan file (see the module docstring)."""
    path = Path(path)
    fence, mission = _plan_parts(path)
    area: list[tuple[Polygon, str]] = []
    nofly: list[tuple[Polygon, str]] = []
    circles: list[Circle] = []
    counts = {"inclusion fence(s)": 0, "survey polygon(s)": 0, "inclusion circle(s)": 0}
    for i, item in enumerate(_items(fence, "polygons", path, "geoFence")):
        where, at = f"geoFence polygon {i}", f"geoFence.polygons[{i}]"
        if not isinstance(item, dict):
            raise InputError(f"{path}: {where}: {at} is {show_json(item)}, not a JSON object; fix the plan")
        poly = make_polygon(_ring(item.get("polygon"), path, where, f"{at}.polygon"), [], path, where)
        if _inclusion(item, path, at, "polygon"):
            area.append((poly, where))
            counts["inclusion fence(s)"] += 1
        else:
            nofly.append((poly, where))
    for i, item in enumerate(_items(fence, "circles", path, "geoFence")):
        where, at = f"geoFence circle {i}", f"geoFence.circles[{i}]"
        shape = '"circle": {"center": [lat, lon], "radius": metres}'
        circle = item.get("circle") if isinstance(item, dict) else None
        if not isinstance(circle, dict) or "center" not in circle or "radius" not in circle:
            raise InputError(f"{path}: {where}: {at} needs {shape}; fix the plan")
        center = circle["center"]
        if not isinstance(center, list) or len(center) < 2:
            raise InputError(
                f"{path}: {where}: {at}.circle.center is {show_json(center)}, not [lat, lon]; "
                f"{at} needs {shape}; fix the plan"
            )
        fix = "write it as a JSON number in degrees, e.g. 41.876 (not a string or a boolean); fix the plan"
        lat, lon = (json_number(center[k], path, f"{at}.circle.center[{k}]", fix) for k in (0, 1))
        fix = "write the radius in metres as a JSON number, e.g. 100 (not a string or a boolean); fix the plan"
        radius = json_number(circle["radius"], path, f"{at}.circle.radius", fix)
        centre = f"{where}: {at}.circle.center"
        lonlat_ring([[lat, lon]], path, centre, lat_first=True, fmt="a QGroundControl plan")
        if not 0 < radius < MAX_RADIUS:
            raise InputError(
                f"{path}: {where}: {at}.circle.radius {radius:g} m must be > 0 and below 1000 km; fix the plan"
            )
        circle = Circle(lat, lon, radius)
        if _inclusion(item, path, at, "circle"):
            area.append((circle_polygon(circle), where))
            counts["inclusion circle(s)"] += 1
        else:
            circles.append(circle)
    for i, item in enumerate(_items(mission, "items", path, "mission")):
        if isinstance(item, dict) and item.get("complexItemType") == "survey":
            where = f"mission item {i} (survey)"
            ring = _ring(item.get("polygon"), path, where, f"mission.items[{i}].polygon")
            area.append((make_polygon(ring, [], path, where), where))
            counts["survey polygon(s)"] += 1
    return build_area(area, nofly, path, circles, {k: n for k, n in counts.items() if n})


def _latlon_list(ring) -> list[list[float]]:
    coords = list(ring.coords)[:-1]  # QGC stores rings open
    return [[float(lat), float(lon)] for lon, lat in coords]


def plan_dict(area: Area) -> dict:
    """The QGroundControl plan (as a dict) for an area: fences only, empty mission."""
    polygons = [{"inclusion": True, "polygon": _latlon_list(p.exterior), "version": 1} for p in area.polygons]
    polygons += [
        {"inclusion": False, "polygon": _latlon_list(p.exterior), "version": 1} for p in area.holes + area.nofly
    ]
    circles = [
        {"circle": {"center": [c.lat, c.lon], "radius": c.radius}, "inclusion": False, "version": 1}
        for c in area.nofly_circles
    ]
    home = area.geometry.representative_point()
    return {
        "fileType": "Plan",
        "geoFence": {"circles": circles, "polygons": polygons, "version": 2},
        "groundStation": "QGroundControl",
        "mission": {
            "cruiseSpeed": 15,
            "firmwareType": 0,
            "globalPlanAltitudeMode": 1,
            "hoverSpeed": 5,
            "items": [],
            "plannedHomePosition": [home.y, home.x, 0],
            "vehicleType": 2,
            "version": 2,
        },
        "rallyPoints": {"points": [], "version": 2},
        "version": 1,
    }


def write_plan(area: Area, path: str | Path) -> Path:
    """Write `area` as a QGroundControl .plan file (see the module docstring); returns the path."""
    path = Path(path)
    path.write_text(json.dumps(plan_dict(area), indent=4) + "\n", encoding="utf-8")
    return path


@dataclass(frozen=True)
class Waypoint:
    """A mission item of a .plan: a NAV_WAYPOINT at (lat, lon), `alt` metres in `frame`."""

    lat: float
    lon: float
    alt: float
    command: int = MAV_CMD_NAV_WAYPOINT
    frame: int = MAV_FRAME_GLOBAL_RELATIVE_ALT


def waypoint_item(point: Waypoint, jump_id: int) -> dict:
    """A QGroundControl SimpleItem for a waypoint, as QGroundControl writes it (altitude relative to home)."""
    return {
        "AMSLAltAboveTerrain": None,
        "Altitude": point.alt,
        "AltitudeMode": 1,
        "autoContinue": True,
        "command": point.command,
        "doJumpId": jump_id,
        "frame": point.frame,
        "params": [0, 0, 0, None, point.lat, point.lon, point.alt],
        "type": "SimpleItem",
    }


def mission_plan_dict(area: Area, waypoints: list[Waypoint]) -> dict:
    """The QGroundControl plan of `area`'s fences with `waypoints` as its mission; the planned home is
    the first waypoint's position on the ground (the vehicle's real home replaces it)."""
    plan = plan_dict(area)
    plan["mission"]["items"] = [waypoint_item(p, i + 1) for i, p in enumerate(waypoints)]
    if waypoints:
        plan["mission"]["plannedHomePosition"] = [waypoints[0].lat, waypoints[0].lon, 0]
    return plan


def write_mission_plan(area: Area, waypoints: list[Waypoint], path: str | Path) -> Path:
    """Write a .plan with `area`'s fences and a waypoint mission; returns the path."""
    path = Path(path)
    path.write_text(json.dumps(mission_plan_dict(area, waypoints), indent=4) + "\n", encoding="utf-8")
    return path


def _whole(value: object, path: Path, at: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise InputError(f"{path}: {at} is {show_json(value)}, not a whole number; fix the plan")
    return value


def read_waypoints(path: str | Path) -> list[Waypoint]:
    """The SimpleItem mission items of a .plan file, in order (complex items, such as surveys, skipped).
    Each needs a whole "command" and "frame" and "params" of seven values whose latitude, longitude and
    altitude (the last three) are finite JSON numbers."""
    path = Path(path)
    _, mission = _plan_parts(path)
    points = []
    for i, item in enumerate(_items(mission, "items", path, "mission")):
        at = f"mission.items[{i}]"
        if not isinstance(item, dict):
            raise InputError(f"{path}: {at} is {show_json(item)}, not a JSON object; fix the plan")
        if item.get("type") != "SimpleItem":
            continue
        command, frame = (_whole(item.get(key), path, f"{at}.{key}") for key in ("command", "frame"))
        params = item.get("params")
        if not isinstance(params, list) or len(params) != 7:
            raise InputError(f"{path}: {at}.params must be a list of 7 values; fix the plan")
        fix = "write it as a JSON number (not a string, a boolean or null); fix the plan"
        lat, lon, alt = (json_number(params[k], path, f"{at}.params[{k}]", fix) for k in (4, 5, 6))
        if not (-90 <= lat <= 90 and -180 <= lon <= 180):
            raise InputError(
                f"{path}: {at}.params [4], [5] = {lat:g}, {lon:g}: not a latitude and a longitude; fix the plan"
            )
        points.append(Waypoint(lat, lon, alt, command, frame))
    return points
