"""Shared checks for the files swarmctl reads: JSON parsing, CRS, coordinates, polygon repair.

Every problem becomes an `InputError` whose message names the file, says what is wrong and how to
fix it. Repairs that keep going (a self-intersecting polygon fixed with shapely's ``make_valid``)
are returned as warning strings for the caller to print.
"""

from __future__ import annotations

import json
from pathlib import Path

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


def lonlat_ring(coords: object, path: Path, where: str, lat_first: bool = False, fmt: str = "GeoJSON") -> np.ndarray:
    """Check one ring's coordinates and return them as an (n, 2) float array of lon, lat.

    `lat_first` is for QGroundControl plans, which store [lat, lon]; `fmt` names the format in errors.
    Extra values (altitude) are dropped. Latitudes beyond +-90, or within 5 degrees of a pole when the
    swapped reading is an ordinary place, are reported as swapped coordinates; other polar rings, rings
    round a pole and rings across the antimeridian are refused.
    """
    try:
        arr = np.array([[float(v) for v in pt[:2]] for pt in coords], dtype=float)  # type: ignore[union-attr]
    except GEOMETRY_ERRORS:
        raise InputError(f"{path}: {where}: coordinates are not lists of numbers; fix the file's geometry") from None
    if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) == 0:
        raise InputError(f"{path}: {where}: each position needs two numbers; fix the file's geometry")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{path}: {where}: coordinates contain NaN or infinity; fix the file's geometry")
    if lat_first:
        arr = arr[:, ::-1]
    lon, lat = arr[:, 0], arr[:, 1]
    stored, swapped = ("[lat, lon]", "[lon, lat]") if lat_first else ("[lon, lat]", "[lat, lon]")
    order = f"{fmt} stores {stored}" + (" (RFC 7946)" if fmt == "GeoJSON" else "")
    worst = float(lat[np.argmax(np.abs(lat))])
    if abs(worst) > 90:
        raise InputError(
            f"{path}: {where}: latitude {worst:g} is beyond +-90, so the coordinates look like {swapped}; "
            f"{order}: swap the two values"
        )
    if np.any(np.abs(lon) > 180):
        raise InputError(
            f"{path}: {where}: longitude {lon[np.argmax(np.abs(lon))]:g} is beyond +-180; "
            "coordinates must be WGS84 degrees"
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

    def geometry(geom: object, props: dict, where: str, index: int = 0) -> None:
        if geom is None:
            return
        if not isinstance(geom, dict):
            raise InputError(f"{path}: {where}: geometry is not a JSON object; fix the file")
        kind = geom.get("type")
        if kind == "GeometryCollection":
            for i, g in enumerate(geom.get("geometries") or []):
                geometry(g, props, f"{where} geometry {i}", index)
            return
        if kind not in ("Polygon", "MultiPolygon"):
            return
        coords = geom.get("coordinates")
        polys = [coords] if kind == "Polygon" else coords
        if not isinstance(polys, list):
            raise InputError(f"{path}: {where}: {kind} has no coordinate list; fix the file")
        for j, rings in enumerate(polys):
            label = where if kind == "Polygon" else f"{where} part {j}"
            if not isinstance(rings, list) or not rings:
                raise InputError(f"{path}: {label}: polygon without rings; fix the file")
            arrs = [lonlat_ring(r, path, label) for r in rings]
            out.append((make_polygon(arrs[0], arrs[1:], path, label), props, label, index))

    kind = obj.get("type")
    if kind == "FeatureCollection":
        feats = obj.get("features")
        if not isinstance(feats, list):
            raise InputError(f'{path}: FeatureCollection without a "features" list; fix the file')
        for i, f in enumerate(feats):
            if not isinstance(f, dict):
                raise InputError(f"{path}: feature {i} is not a JSON object; fix the file")
            props = f.get("properties") if isinstance(f.get("properties"), dict) else {}
            geometry(f.get("geometry"), props, f"feature {i}", i)
    elif kind == "Feature":
        props = obj.get("properties") if isinstance(obj.get("properties"), dict) else {}
        geometry(obj.get("geometry"), props, "feature 0")
    else:
        geometry(obj, {}, "geometry")
    return out
