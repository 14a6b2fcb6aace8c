"""Search areas from GeoJSON, KML and QGroundControl .plan files.

An `Area` is the polygon(s) to search, in WGS84 lon/lat, plus its no-fly zones. Sources:

- GeoJSON (RFC 7946, lon/lat): Polygon, MultiPolygon, Feature, FeatureCollection, GeometryCollection.
  Every polygon is part of the area, except features whose properties set ``"nofly": true``
  (also ``"no_fly"`` / ``"no-fly"``; 1, "true", "yes" and "1" count as true, false, 0, null, "false",
  "no", "0" and "" as false, any other value is refused), which are no-fly zones.
- KML: every ``<Polygon>`` (outer and inner boundaries), in ``<MultiGeometry>`` too. A Placemark
  whose ``<name>`` starts with "no-fly"/"nofly" (any case) is a no-fly zone.
- QGroundControl .plan: see `swarmctl.geo.plan_io.read_plan`.

`swarmctl.geo.load.load_area` reads any of them, the reader picked by the file's suffix.

Polygon holes are no-fly zones. Invalid (self-intersecting) polygons are repaired with
``shapely.make_valid`` and reported in `Area.warnings`.
"""

from __future__ import annotations

import functools
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import shapely
from shapely.geometry import MultiPolygon, Polygon

from swarmctl.bounds import INPUT_MAX_BYTES, read_limited
from swarmctl.errors import InputError
from swarmctl.geo.readers import (
    geojson_polygons,
    lonlat_ring,
    make_polygon,
    polygonal_part,
    read_json,
    repair,
    require_file,
    show_json,
)

NOFLY_KEYS = ("nofly", "no_fly", "no-fly")
BUILDING_KEYS = ("building", "height", "building:levels", "stories", "STORIES", "BLDG_ID")
_NOFLY_NAME = re.compile(r"^\s*no[-_ ]?fly", re.IGNORECASE)


@dataclass(frozen=True)
class Circle:
    """A circular zone: centre latitude/longitude in degrees, radius in metres."""

    lat: float
    lon: float
    radius: float


@dataclass
class Area:
    """A search area in WGS84 lon/lat.

    `geometry` is a Polygon or MultiPolygon (holes kept: they are no-fly); `nofly` holds the other
    no-fly polygons, `nofly_circles` the circular ones (radius in metres, so they are only turned
    into polygons in a metric frame). `name` is the source file name.
    """

    geometry: Polygon | MultiPolygon
    nofly: list[Polygon] = field(default_factory=list)
    nofly_circles: list[Circle] = field(default_factory=list)
    name: str = "area"
    sources: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    @property
    def polygons(self) -> list[Polygon]:
        """The area's polygons, holes included."""
        return list(shapely.get_parts(self.geometry))

    @property
    def holes(self) -> list[Polygon]:
        """The holes of the area's polygons, as polygons."""
        return [Polygon(ring) for p in self.polygons for ring in p.interiors]

    @functools.cached_property
    def outline(self) -> Polygon | MultiPolygon:
        """The area with its holes filled (holes are counted as no-fly instead)."""
        return shapely.union_all([Polygon(p.exterior) for p in self.polygons])

    def describe(self) -> str:
        """One line: what the area is made of."""
        parts = [f"{len(self.polygons)} polygon(s)"]
        for label, n in (
            ("hole(s)", len(self.holes)),
            ("no-fly polygon(s)", len(self.nofly)),
            ("no-fly circle(s)", len(self.nofly_circles)),
        ):
            if n:
                parts.append(f"{n} {label}")
        if self.sources:
            parts.append("from " + ", ".join(f"{n} {k}" for k, n in self.sources.items()))
        return ", ".join(parts)


def build_area(
    area_parts: list[tuple[Polygon, str]],
    nofly_parts: list[tuple[Polygon, str]],
    path: Path,
    circles: list[Circle] | None = None,
    sources: dict[str, int] | None = None,
) -> Area:
    """Repair the polygons read from `path` and assemble an Area; no polygon left -> InputError."""
    warnings: list[str] = []
    polys = repair(area_parts, path, warnings)
    if not polys:
        raise InputError(
            f"{path}: contains no area polygon; give a file with a Polygon or MultiPolygon "
            "(GeoJSON), a <Polygon> (KML) or an inclusion geofence or survey polygon (.plan)"
        )
    geometry = polygonal_part(shapely.union_all(polys))
    west, _, east, _ = geometry.bounds
    if east - west > 180.0:
        raise InputError(
            f"{path}: the area spans longitudes {west:g} to {east:g}: it lies across the antimeridian (or round "
            "the Earth), which swarmctl cannot grid; plan the parts east and west of 180 degrees as two areas"
        )
    nofly = repair(nofly_parts, path, warnings)
    return Area(geometry, nofly, list(circles or []), path.name, dict(sources or {}), warnings)


_NOFLY_TRUE = ("true", "yes", "1")
_NOFLY_FALSE = ("false", "no", "0", "")


def _is_nofly(props: dict, path: Path, at: str) -> bool:
    """Whether a feature's properties mark it no-fly. true, 1 and the strings "true", "yes", "1" (any case)
    do; false, 0, null, "false", "no", "0" and "" do not; any other value is refused, never guessed."""
    marked = False
    for key in NOFLY_KEYS:
        if key not in props:
            continue
        value = props[key]
        text = value.strip().lower() if isinstance(value, str) else None
        if value is True or (type(value) is int and value == 1) or text in _NOFLY_TRUE:
            marked = True
        elif not (value is None or value is False or (type(value) is int and value == 0) or text in _NOFLY_FALSE):
            raise InputError(
                f'{path}: {at}properties["{key}"] is {show_json(value)}, neither true nor false; '
                f'write "{key}": true for a no-fly zone or false (or leave it out) for search area'
            )
    return marked


def read_geojson_area(path: Path) -> Area:
    """Read an Area from GeoJSON (see the module docstring for no-fly features)."""
    obj = read_json(path, "GeoJSON")
    collection = isinstance(obj, dict) and obj.get("type") == "FeatureCollection"
    area: list[tuple[Polygon, str]] = []
    nofly: list[tuple[Polygon, str]] = []
    tagged = 0
    for poly, props, where, index in geojson_polygons(obj, path):
        at = f"features[{index}]." if collection else ""
        (nofly if _is_nofly(props, path, at) else area).append((poly, where))
        tagged += any(props.get(k) not in (None, "") for k in BUILDING_KEYS)
    result = build_area(area, nofly, path, sources={"GeoJSON polygon(s)": len(area)} if area else None)
    if len(area) > 1 and tagged > len(area) / 2:
        result.warnings.append(
            f"{path}: {tagged} of its {len(area)} polygons carry building tags, and the area is their union; "
            "to fly around buildings, give an area file and pass this one as --buildings"
        )
    return result


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _kml_ring(elem: ET.Element, path: Path, where: str):
    text = next((e.text for e in elem.iter() if _local(e.tag) == "coordinates"), None)
    if not text or not text.strip():
        raise InputError(f"{path}: {where}: boundary without <coordinates>; fix the KML")
    try:
        points = [tuple(float(v) for v in tok.split(",")) for tok in text.split()]
    except ValueError:
        raise InputError(
            f"{path}: {where}: <coordinates> must be 'lon,lat[,alt]' tuples separated by spaces; fix the KML"
        ) from None
    return lonlat_ring(points, path, where, fmt="KML")


NAME_SHOWN = 60  # characters of a Placemark's name quoted in a message


def _label(name: str) -> str:
    """A Placemark's name as messages quote it: at most NAME_SHOWN characters."""
    name = " ".join(name.split())
    return (name[:NAME_SHOWN] + "...") if len(name) > NAME_SHOWN else (name or "unnamed")


def read_kml(path: Path) -> Area:
    """Read an Area from a KML file (at most INPUT_MAX_BYTES): every <Polygon>, with outer and inner boundaries."""
    require_file(path)
    try:
        root = ET.fromstring(read_limited(path, "KML file", INPUT_MAX_BYTES))
    except ET.ParseError as exc:
        raise InputError(f"{path}: not valid KML/XML ({exc}); fix the file or export it again as KML") from None
    placemarks = [e for e in root.iter() if _local(e.tag) == "Placemark"] or [root]
    area: list[tuple[Polygon, str]] = []
    nofly: list[tuple[Polygon, str]] = []
    for pi, pm in enumerate(placemarks):
        name = next((e.text or "" for e in pm if _local(e.tag) == "name"), "")
        target = nofly if _NOFLY_NAME.match(name) else area
        for gi, poly in enumerate(e for e in pm.iter() if _local(e.tag) == "Polygon"):
            where = f"Placemark {pi} ({_label(name)}) polygon {gi}"
            outer = [e for e in poly if _local(e.tag) == "outerBoundaryIs"]
            if not outer:
                raise InputError(f"{path}: {where}: <Polygon> without <outerBoundaryIs>; fix the KML")
            shell = _kml_ring(outer[0], path, where)
            holes = [
                _kml_ring(ring, path, f"{where} inner boundary")
                for inner in poly
                if _local(inner.tag) == "innerBoundaryIs"
                for ring in inner.iter()
                if _local(ring.tag) == "LinearRing"
            ]
            target.append((make_polygon(shell, holes, path, where), where))
    return build_area(area, nofly, path, sources={"KML polygon(s)": len(area)} if area else None)
