"""Building footprints and the rule that turns them into obstacle cells.

Footprints come from GeoJSON (WGS84 lon/lat). A building's height, in metres, is read from

1. ``height`` (also ``building:height``, ``HEIGHT``): a number or a string such as "45", "45 m",
   "150 ft" or "150'"; then, failing that,
2. a level count, ``building:levels`` (also ``levels``, ``stories``, ``STORIES``, ``NO_STORIES``),
   plus ``roof:levels`` when present, times `METRES_PER_LEVEL` = 4.0 m. The paper equates 10 stories
   with about 40 m; 4.0 m is also above the usual 3-3.5 m storey, so heights are overestimated,
   which errs on the safe side.

Zero, negative or unreadable values count as unknown (the Chicago building footprints use 0 stories
for "unknown"). A building blocks when ``height >= altitude - margin``; a building of unknown height
blocks under ``unknown="block"`` (the default: an unknown building may be a tower) and is ignored
under ``unknown="ignore"``. Heights are above ground and altitudes relative to the take-off point,
so the rule assumes flat ground.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon

from swarmctl.errors import InputError
from swarmctl.geo.defaults import DEFAULT_ALTITUDE, DEFAULT_MARGIN, METRES_PER_LEVEL, UNKNOWN_RULES
from swarmctl.geo.readers import geojson_polygons, polygonal_part, read_json

FEET = 0.3048
HEIGHT_KEYS = ("height", "building:height", "HEIGHT")
LEVEL_KEYS = ("building:levels", "levels", "stories", "STORIES", "NO_STORIES")
ROOF_LEVEL_KEYS = ("roof:levels",)

_NUMBER = r"[-+]?\d+(?:[.,]\d+)?"
_HEIGHT = re.compile(rf"^\s*({_NUMBER})\s*(m|metres?|meters?|ft|feet|'|)\s*(?:({_NUMBER})\s*(?:\"|in))?\s*$", re.I)


def _number(text: str) -> float:
    return float(text.replace(",", "."))


def parse_height(value: object) -> float | None:
    """A height in metres from a number or an OSM-style string ("45", "45 m", "150 ft", "12'6\\"").

    Returns None for missing, unreadable, zero or negative values.
    """
    if isinstance(value, bool) or value is None:
        return None
    if isinstance(value, (int, float)):
        h = float(value)
    elif isinstance(value, str):
        m = _HEIGHT.match(value)
        if not m:
            return None
        h = _number(m.group(1))
        if m.group(2).lower() in ("ft", "feet", "'"):
            h = (h + (_number(m.group(3)) / 12.0 if m.group(3) else 0.0)) * FEET
    else:
        return None
    return h if np.isfinite(h) and h > 0 else None


def parse_levels(value: object) -> float | None:
    """A level count from a number or a string ("12", "3.5", "3;4" -> the largest); None if unknown."""
    if isinstance(value, bool) or value is None:
        return None
    if isinstance(value, (int, float)):
        n = float(value)
    elif isinstance(value, str):
        found = [_number(t) for t in re.findall(_NUMBER, value)]
        if not found:
            return None
        n = max(found)
    else:
        return None
    return n if np.isfinite(n) and n > 0 else None


def building_height(props: dict) -> tuple[float | None, str | None]:
    """(height in metres, where it came from: "height" or "levels") or (None, None) if unknown."""
    for key in HEIGHT_KEYS:
        h = parse_height(props.get(key))
        if h is not None:
            return h, "height"
    for key in LEVEL_KEYS:
        n = parse_levels(props.get(key))
        if n is not None:
            roof = next((r for r in (parse_levels(props.get(k)) for k in ROOF_LEVEL_KEYS) if r), 0.0)
            return (n + roof) * METRES_PER_LEVEL, "levels"
    return None, None


@dataclass(frozen=True)
class BuildingRule:
    """When a building is an obstacle: ``height >= altitude - margin``; unknown heights per `unknown`."""

    altitude: float = DEFAULT_ALTITUDE
    margin: float = DEFAULT_MARGIN
    unknown: str = UNKNOWN_RULES[0]

    def __post_init__(self) -> None:
        if self.unknown not in UNKNOWN_RULES:
            raise ValueError(f"unknown-height rule {self.unknown!r}: use one of {UNKNOWN_RULES}")

    @property
    def threshold(self) -> float:
        """The lowest height (metres) that blocks."""
        return self.altitude - self.margin

    def blocks(self, height: float | None) -> bool:
        """Whether a building of this height (None = unknown) is an obstacle."""
        if height is None:
            return self.unknown == "block"
        return height >= self.threshold


@dataclass
class Building:
    """One footprint (lon/lat), its height in metres (None if unknown) and where that came from."""

    geometry: Polygon | MultiPolygon
    height: float | None
    height_source: str | None
    name: str = ""


@dataclass
class BuildingSet:
    """The footprints of one file, with what could not be used."""

    buildings: list[Building]
    name: str
    skipped: int = 0  # features without a polygon
    warnings: list[str] = field(default_factory=list)

    def unknown_height(self) -> int:
        """How many buildings have no usable height."""
        return sum(b.height is None for b in self.buildings)


def load_buildings(path: str | Path) -> BuildingSet:
    """Read building footprints (GeoJSON, WGS84 lon/lat) and their heights."""
    path = Path(path)
    if path.suffix.lower() not in (".geojson", ".json"):
        raise InputError(
            f"{path}: unknown file type {path.suffix or '(no extension)'!r} for buildings; "
            "give a GeoJSON (.geojson or .json) file of footprints"
        )
    obj = read_json(path, "GeoJSON")
    polys = geojson_polygons(obj, path)
    if not polys:
        raise InputError(
            f"{path}: contains no building footprint (Polygon or MultiPolygon); give a GeoJSON of footprints"
        )
    grouped: dict[int, list] = {}
    for poly, props, _, index in polys:
        grouped.setdefault(index, [props]).append(poly)
    n_features = len(obj.get("features") or []) if isinstance(obj, dict) else 0
    buildings, repaired = [], 0
    for props, *parts in grouped.values():
        geom = shapely.union_all(parts) if len(parts) > 1 else parts[0]
        if not geom.is_valid:
            repaired += 1
            geom = polygonal_part(shapely.make_valid(geom))
        if geom.is_empty:
            continue
        height, source = building_height(props)
        name = str(props.get("name") or props.get("BLDG_NAME1") or "")
        buildings.append(Building(geom, height, source, name))
    warnings = []
    if repaired:
        warnings.append(f"{path}: {repaired} invalid footprint(s) repaired with make_valid")
    return BuildingSet(buildings, path.name, max(0, n_features - len(grouped)), warnings)
