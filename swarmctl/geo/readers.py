"""Shared checks for the files swarmctl reads: JSON parsing, CRS, coordinates, polygon repair.

Every problem becomes an `InputError` whose message names the file, says what is wrong and how to
fix it. Repairs that keep going (a self-intersecting polygon fixed with shapely's ``make_valid``)
are returned as warning strings for the caller to print.
"""

from __future__ import annotations

import json
import math
import numbers
from pathlib import Path
from typing import TypeGuard

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon

from swarmctl.bounds import INPUT_MAX_BYTES, load_json
from swarmctl.errors import InputError

POLAR_LATITUDE = 85.0  # degrees: the local grid is not made for areas nearer a pole

# `crs` members that mean WGS84 longitude/latitude (RFC 7946 / the 2008 GeoJSON spec).
WGS84_CRS_NAMES = {
    "urn:ogc:def:crs:ogc:1.3:crs84",
    "urn:ogc:def:crs:ogc::crs84",
    "ogc:crs84",
    "crs84",
    "epsg:4326",
    "urn:ogc:def:crs:epsg::4326",
    "urn:ogc:def:crs:epsg:6.6:4326",
    "http://www.opengis.net/def/crs/ogc/1.3/crs84",
    "http://www.opengis.net/def/crs/epsg/0/4326",
}

# The geometry-level errors shapely and numpy raise on malformed coordinates.
GEOMETRY_ERRORS = (ValueError, TypeError, IndexError, KeyError, AttributeError, shapely.errors.GEOSException)


def require_file(path: Path) -> None:
    """Raise InputError unless `path` is an existing regular file."""
    if not path.exists():
        raise InputError(f"{path}: file not found; check the path")
    if not path.is_file():
        raise InputError(f"{path}: not a file; give the path of a GeoJSON, KML or .plan file")


def read_json(path: Path, kind: str, limit: int = INPUT_MAX_BYTES) -> object:
    """Parse a JSON file of at most `limit` bytes (and MAX_JSON_DEPTH levels, swarmctl.bounds); `kind`
    ("GeoJSON", "QGroundControl plan") is used in error messages."""
    require_file(path)
    return load_json(path, kind, limit, f"fix the file or export it again as {kind}")


def check_geojson_crs(obj: object, path: Path) -> None:
    """Refuse a GeoJSON whose `crs` member names anything but WGS84 lon/lat."""
    if not isinstance(obj, dict) or obj.get("crs") is None:
        return
    crs = obj["crs"]
    name = None
    if isinstance(crs, dict) and isinstance(crs.get("properties"), dict):
        name = crs["properties"].get("name") or crs["properties"].get("href")
    if isinstance(name, str) and name.strip().lower() in WGS84_CRS_NAMES:
        return
    raise InputError(
        f"{path}: declares the coordinate system {json.dumps(name if name else crs)}, but GeoJSON areas "
        "must be WGS84 longitude/latitude (RFC 7946); reproject the file, e.g. "
        "`ogr2ogr -t_srs EPSG:4326 out.geojson in.geojson`"
    )


def show_json(value: object) -> str:
    """A JSON value as a file spells it (cut to 40 characters), with its kind unless it is a number or null."""
    try:
        text = json.dumps(value)
    except (TypeError, ValueError):
        text = repr(value)
    if len(text) > 40:
        text = text[:37] + "..."
    if isinstance(value, bool) or isinstance(value, np.bool_):
        return f"{text} (a boolean)"
    kinds = ((str, "a string"), ((list, tuple, np.ndarray), "an array"), (dict, "an object"))
    kind = next((k for t, k in kinds if isinstance(value, t)), None)
    return f"{text} ({kind})" if kind else text


def is_number(value: object) -> TypeGuard[numbers.Real]:
    """Whether `value` is a JSON number: an int or a float (numpy's too), not a bool or a string."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def json_number(value: object, path: Path, field: str, fix: str) -> float:
    """`value` as a finite float; anything else (a string, a bool, null, NaN, infinity) is an InputError
    naming `field` (a JSON path such as geoFence.circles[0].circle.radius) and ending with `fix`."""
    if not is_number(value):
        raise InputError(f"{path}: {field} is {show_json(value)}, not a number; {fix}")
    try:
        number = float(value)
    except OverflowError:  # an integer of hundreds of digits
        number = math.inf
    if not math.isfinite(number):
        raise InputError(f"{path}: {field} is {show_json(value)}, not a finite number; {fix}")
    return number


def _positions(coords: object, path: Path, where: str, lat_first: bool, json_path: str | None) -> np.ndarray:
    """The positions of a ring as an (n, 2) float array, in the file's order; every value of every position
    must be a finite number (int or float, not a bool or a string), each position an array of at least two."""
    pair = "[lat, lon]" if lat_first else "[lon, lat]"
    fix = "fix the file's geometry"

    def loc(k: int, c: int | None = None) -> str:
        if json_path is None:
            return f"position {k}" + ("" if c is None else f" value {c}")
        return f"{json_path}[{k}]" + ("" if c is None else f"[{c}]")

    if not isinstance(coords, (list, tuple, np.ndarray)):
        what = json_path or "the ring"
        raise InputError(
            f"{path}: {where}: {what} is {show_json(coords)}: coordinates are not lists of numbers; "
            f"a ring is an array of positions {pair}; {fix}"
        )
    if len(coords) == 0:
        raise InputError(f"{path}: {where}: the ring has no positions; each position needs two numbers; {fix}")
    rows = []
    for k, pt in enumerate(coords):
        if not isinstance(pt, (list, tuple, np.ndarray)):
            raise InputError(
                f"{path}: {where}: {loc(k)} is {show_json(pt)}: coordinates are not lists of numbers; "
                f"a position is an array of numbers {pair}; {fix}"
            )
        if len(pt) < 2:
            raise InputError(
                f"{path}: {where}: {loc(k)} is {show_json(pt)}: each position needs two numbers {pair}; {fix}"
            )
        for c, v in enumerate(pt):
            if type(v) is not float and type(v) is not int and not is_number(v):  # bool's type is bool
                hint = " (write it without quotes)" if isinstance(v, str) and _numeric(v) else ""
                raise InputError(
                    f"{path}: {where}: {loc(k, c)} is {show_json(v)}: coordinates are not lists of numbers; "
                    f"each coordinate must be a JSON number{hint}; {fix}"
                )
            try:
                finite = math.isfinite(v)
            except OverflowError:  # an integer of hundreds of digits
                finite = False
            if not finite:
                raise InputError(
                    f"{path}: {where}: {loc(k, c)} is {show_json(v)}: coordinates contain NaN or infinity; {fix}"
                )
        rows.append(pt[:2])
    return np.array(rows, dtype=float)


def _numeric(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def lonlat_ring(
    coords: object,
    path: Path,
    where: str,
    lat_first: bool = False,
    fmt: str = "GeoJSON",
    json_path: str | None = None,
) -> np.ndarray:
    """Check one ring's coordinates and return them as an (n, 2) float array of lon, lat.

    `lat_first` is for QGroundControl plans, which store [lat, lon]; `fmt` names the format in errors;
    `json_path` (e.g. ``features[0].geometry.coordinates[0]``) is where the ring is in a JSON file, so that
    errors name the exact value (``...coordinates[0][3][1]``); without it they name "position k".
    Every value must be a finite number: an int or a float, not a bool, a string or null. Extra values
    (altitude) are checked the same way, then dropped. Latitudes beyond +-90, or within 5 degrees of a
    pole when the swapped reading is an ordinary place, are reported as swapped coordinates; longitudes
    beyond +-180, other polar rings, rings round a pole and rings across the antimeridian are refused.
    """
    arr = _positions(coords, path, where, lat_first, json_path)

    def at(k: int) -> str:
        return "" if json_path is None else f" (at {json_path}[{k}])"

    if lat_first:
        arr = arr[:, ::-1]
    lon, lat = arr[:, 0], arr[:, 1]
    stored, swapped = ("[lat, lon]", "[lon, lat]") if lat_first else ("[lon, lat]", "[lat, lon]")
    order = f"{fmt} stores {stored}" + (" (RFC 7946)" if fmt == "GeoJSON" else "")
    worst_at = int(np.argmax(np.abs(lat)))
    worst = float(lat[worst_at])
    if abs(worst) > 90:
        raise InputError(
            f"{path}: {where}: latitude {worst:g}{at(worst_at)} is beyond +-90, so the coordinates look like "
            f"{swapped}; {order}: swap the two values"
        )
    if np.any(np.abs(lon) > 180):
        far = int(np.argmax(np.abs(lon)))
        raise InputError(
            f"{path}: {where}: longitude {lon[far]:g}{at(far)} is beyond +-180; coordinates must be WGS84 degrees"
        )
    if abs(worst) > POLAR_LATITUDE:
        if np.all(np.abs(lon) <= POLAR_LATITUDE):  # read the other way round, it is an ordinary place
            raise InputError(
                f"{path}: {where}: latitude {worst:g} is within {90 - POLAR_LATITUDE:g} degrees of a pole, so the "
                f"coordinates look like {swapped}; {order}: swap the two values"
            )
        raise InputError(
            f"{path}: {where}: latitude {worst:g} is within {90 - POLAR_LATITUDE:g} degrees of a pole, where "
            "swarmctl's local grid does not hold; give an area between -85 and 85 degrees latitude"
        )
    _check_wrap(lon, lat, path, where)
    return arr


def _check_wrap(lon: np.ndarray, lat: np.ndarray, path: Path, where: str) -> None:
    """Refuse a ring that goes round a pole or across the antimeridian (an edge over 180 degrees of
    longitude, which a lon/lat polygon draws the long way round the Earth)."""
    if len(lon) < 2:
        return
    step = np.diff(lon)
    wrapped = (step + 180.0) % 360.0 - 180.0
    if abs(float(wrapped.sum() + ((lon[0] - lon[-1] + 180.0) % 360.0 - 180.0))) > 180.0:
        pole = "North" if float(lat.mean()) > 0 else "South"
        raise InputError(
            f"{path}: {where}: the ring goes round the {pole} Pole; swarmctl grids areas in a local projection "
            "that cannot hold a pole: give an area that does not contain one"
        )
    jump = np.flatnonzero(np.abs(step) > 180.0)
    if len(jump):
        i = int(jump[0])
        raise InputError(
            f"{path}: {where}: the ring crosses the antimeridian (from longitude {lon[i]:g} to {lon[i + 1]:g}), "
            "which swarmctl cannot grid; plan the parts east and west of 180 degrees as two areas"
        )


def make_polygon(shell: np.ndarray, holes: list[np.ndarray], path: Path, where: str) -> Polygon:
    """Build a shapely Polygon, turning shapely's complaints into an InputError."""
    try:
        return Polygon(shell, holes)
    except GEOMETRY_ERRORS as exc:
        raise InputError(
            f"{path}: {where}: not a polygon ({exc}); a ring needs at least 3 distinct positions"
        ) from None


def repair(polygons: list[tuple[Polygon, str]], path: Path, warnings: list[str]) -> list[Polygon]:
    """Make every polygon valid; repaired ones add a warning, empty ones are dropped with one.

    Self-intersecting rings are repaired with ``shapely.make_valid`` and only the polygonal part of
    the result is kept.
    """
    out: list[Polygon] = []
    for poly, where in polygons:
        if poly.is_valid and not poly.is_empty and poly.area > 0:
            out.append(poly)
            continue
        reason = shapely.is_valid_reason(poly)
        fixed = polygonal_part(shapely.make_valid(poly))
        if fixed.is_empty:
            warnings.append(f"{path}: {where}: has no area ({reason}); ignored")
            continue
        warnings.append(
            f"{path}: {where}: invalid polygon ({reason}); repaired with make_valid, "
            "check the result in preview.png or fix the file"
        )
        out.extend(shapely.get_parts(fixed))
    return out


def polygonal_part(geom) -> Polygon | MultiPolygon:
    """Keep only the polygons of a geometry (e.g. what make_valid returns), as one (Multi)Polygon."""
    parts = [g for g in shapely.get_parts(geom) if isinstance(g, (Polygon, MultiPolygon)) and not g.is_empty]
    if not parts:
        return Polygon()
    merged = shapely.union_all(parts)
    return merged if isinstance(merged, (Polygon, MultiPolygon)) else polygonal_part(merged)


def geojson_polygons(obj: object, path: Path) -> list[tuple[Polygon, dict, str, int]]:
    """Every polygon of a GeoJSON object as (polygon, feature properties, where-label, feature index).

    Accepts FeatureCollection, Feature, GeometryCollection, Polygon and MultiPolygon; other geometry
    types (points, lines) are skipped. Coordinates are checked with `lonlat_ring`.
    """
    if not isinstance(obj, dict) or "type" not in obj:
        raise InputError(f'{path}: not a GeoJSON object (no "type" member); export the data as GeoJSON')
    check_geojson_crs(obj, path)
    out: list[tuple[Polygon, dict, str, int]] = []

    def geometry(geom: object, props: dict, where: str, index: int = 0, at: str = "") -> None:
        # `at` is the JSON path of `geom` in the file ("" for the root), so errors can name the exact value.
        here = at or "the root"
        if geom is None:
            return
        if not isinstance(geom, dict):
            raise InputError(f"{path}: {where}: geometry {here} is {show_json(geom)}, not a JSON object; fix the file")
        kind = geom.get("type")
        if kind == "GeometryCollection":
            parts = geom.get("geometries")
            if parts is not None and not isinstance(parts, list):
                raise InputError(
                    f"{path}: {where}: {_member(at, 'geometries')} is {show_json(parts)}, not a list of geometries; "
                    "fix the file"
                )
            for i, g in enumerate(parts or []):
                geometry(g, props, f"{where} geometry {i}", index, f"{_member(at, 'geometries')}[{i}]")
            return
        if kind not in ("Polygon", "MultiPolygon"):
            return
        coords = geom.get("coordinates")
        field = _member(at, "coordinates")
        if not isinstance(coords, list):
            raise InputError(
                f"{path}: {where}: {field} is {show_json(coords)}: {kind} has no coordinate list; fix the file"
            )
        polys = [(coords, field)] if kind == "Polygon" else [(p, f"{field}[{j}]") for j, p in enumerate(coords)]
        for j, (rings, rings_at) in enumerate(polys):
            label = where if kind == "Polygon" else f"{where} part {j}"
            if not isinstance(rings, list) or not rings:
                raise InputError(
                    f"{path}: {label}: {rings_at} is {show_json(rings)}: polygon without rings; fix the file"
                )
            arrs = [lonlat_ring(r, path, label, json_path=f"{rings_at}[{k}]") for k, r in enumerate(rings)]
            out.append((make_polygon(arrs[0], arrs[1:], path, label), props, label, index))

    kind = obj.get("type")
    if kind == "FeatureCollection":
        feats = obj.get("features")
        if not isinstance(feats, list):
            raise InputError(f'{path}: FeatureCollection without a "features" list; fix the file')
        for i, f in enumerate(feats):
            if not isinstance(f, dict):
                raise InputError(
                    f"{path}: feature {i}: features[{i}] is {show_json(f)}, not a JSON object; fix the file"
                )
            p = f.get("properties")
            geometry(f.get("geometry"), p if isinstance(p, dict) else {}, f"feature {i}", i, f"features[{i}].geometry")
    elif kind == "Feature":
        p = obj.get("properties")
        geometry(obj.get("geometry"), p if isinstance(p, dict) else {}, "feature 0", 0, "geometry")
    else:
        geometry(obj, {}, "geometry")
    return out


def _member(at: str, key: str) -> str:
    """The JSON path of member `key` of the value at path `at` ("" is the root)."""
    return f"{at}.{key}" if at else key
