"""Building footprints and the rule that turns them into obstacle cells.

Footprints come from GeoJSON (WGS84 lon/lat). A building's height, in metres, is read from

1. ``height`` (also ``building:height``, ``HEIGHT``): a number (metres) or a string with a unit:
   "45", "45 m", "150 ft", "150 feet", "150'", "12'6\"", "12 levels", with thousands separators
   ("1,000 ft" is 304.8 m; "12,5 m" is a decimal comma); then, failing that,
2. a level count, ``building:levels`` (also ``levels``, ``stories``, ``STORIES``, ``NO_STORIES``),
   plus ``roof:levels`` when present, times `METRES_PER_LEVEL` = 4.0 m. The paper equates 10 stories
   with about 40 m; 4.0 m is also above the usual 3-3.5 m storey, so heights are overestimated,
   which errs on the safe side.

Missing values, words for unknown ("unknown", "n/a", ...) and zero or negative values count as unknown
(the Chicago building footprints use 0 stories for "unknown"). Anything else that cannot be read (a
unit not listed, text, NaN, infinity, more than `MAX_HEIGHT_M`) is refused: an InputError names the
file, the feature, the key and the value. A building blocks when ``height >= altitude - margin``; a
building of unknown height blocks under ``unknown="block"`` (the default: an unknown building may be
a tower) and is ignored under ``unknown="ignore"``. Heights are above ground and altitudes relative
to the take-off point, so the rule assumes flat ground.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import shapely
from shapely.geometry import MultiPolygon, Polygon

from swarmctl.bounds import BUILDINGS_MAX_BYTES
from swarmctl.errors import InputError
from swarmctl.geo.defaults import DEFAULT_ALTITUDE, DEFAULT_MARGIN, METRES_PER_LEVEL, UNKNOWN_RULES
from swarmctl.geo.readers import geojson_polygons, polygonal_part, read_json

FEET = 0.3048
MAX_HEIGHT_M = 1000.0  # no building is taller; a larger value is a unit or data error
HEIGHT_KEYS = ("height", "building:height", "HEIGHT")
LEVEL_KEYS = ("building:levels", "levels", "stories", "STORIES", "NO_STORIES")
ROOF_LEVEL_KEYS = ("roof:levels",)
UNKNOWN_WORDS = ("", "unknown", "n/a", "na", "none", "null", "?", "-", "no data")

# A number: thousands separated by commas ("1,000", "12,500.5"), else a decimal point or comma ("12,5").
_NUMBER = r"[-+]?(?:\d{1,3}(?:,\d{3})+(?:\.\d+)?|\d+(?:[.,]\d+)?|[.,]\d+)"
_THOUSANDS = re.compile(r"[-+]?\d{1,3}(?:,\d{3})+(?:\.\d+)?")
_UNITS = {
    "": 1.0,
    "m": 1.0,
    "metre": 1.0,
    "metres": 1.0,
    "meter": 1.0,
    "meters": 1.0,
    "ft": FEET,
    "feet": FEET,
    "foot": FEET,
    "'": FEET,
    "level": METRES_PER_LEVEL,
    "levels": METRES_PER_LEVEL,
    "storey": METRES_PER_LEVEL,
    "storeys": METRES_PER_LEVEL,
    "story": METRES_PER_LEVEL,
    "stories": METRES_PER_LEVEL,
    "floor": METRES_PER_LEVEL,
    "floors": METRES_PER_LEVEL,
}
_HEIGHT = re.compile(rf"^\s*({_NUMBER})\s*([a-z']*)\.?\s*(?:({_NUMBER})\s*(?:\"|in|inch|inches))?\s*$", re.I)
HEIGHT_FORMS = '"45", "45 m", "150 ft", "1,000 ft", "12\'6"" or "12 levels"'


class HeightError(ValueError):
    """A height or level count that cannot be read; the message says why."""


def _number(text: str) -> float:
    """A number as written in building data: "1,000" is a thousand, "12,5" twelve and a half."""
    if _THOUSANDS.fullmatch(text):
        return float(text.replace(",", ""))
    return float(text.replace(",", "."))


def _unknown(value: object) -> bool:
    return value is None or (isinstance(value, str) and value.strip().lower() in UNKNOWN_WORDS)


def _checked(metres: float, value: object) -> float | None:
    """Zero and below count as unknown (data sets use 0 and -1 for it); NaN, infinity and heights over
    MAX_HEIGHT_M are errors."""
    if not math.isfinite(metres):
        raise HeightError(f"{value!r} is not a finite number")
    if metres > MAX_HEIGHT_M:
        raise HeightError(
            f"{value!r} is {metres:,.0f} m, taller than any building ({MAX_HEIGHT_M:g} m); check the unit"
        )
    return metres if metres > 0 else None


def parse_height(value: object) -> float | None:
    """A height in metres from a number (metres) or a string with a unit: m, ft, feet, ', 12'6",
    levels (x METRES_PER_LEVEL); "1,000 ft" is 304.8 m.

    Returns None for missing or unknown values ("", "unknown", "n/a", ...) and for zero or negative
    ones; raises HeightError for anything else it cannot read."""
    if _unknown(value):
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return _checked(float(value), value)
    m = _HEIGHT.match(value) if isinstance(value, str) else None
    if m is None or m.group(2).lower() not in _UNITS:
        raise HeightError(f"{value!r} is not a height; write it as {HEIGHT_FORMS}")
    unit = _UNITS[m.group(2).lower()]
    if m.group(3) and unit != FEET:
        raise HeightError(f"{value!r}: inches follow feet only, as in 12'6\"")
    h = _number(m.group(1)) + (_number(m.group(3)) / 12.0 if m.group(3) else 0.0)
    return _checked(h * unit, value)


def parse_levels(value: object) -> float | None:
    """A level count from a number or a string ("12", "3.5", "3;4" -> the largest); None if unknown
    (missing, "unknown", zero); HeightError if unreadable."""
    if _unknown(value):
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        n = float(value)
    elif isinstance(value, str) and re.fullmatch(rf"\s*{_NUMBER}\s*(?:[;,/]\s*{_NUMBER}\s*)*", value):
        n = max(_number(t) for t in re.findall(_NUMBER, value))
    else:
        raise HeightError(f'{value!r} is not a number of levels; write it as "12" (or "3;4")')
    metres = _checked(n * METRES_PER_LEVEL, value)
    return None if metres is None else n


def building_height(props: dict) -> tuple[float | None, str | None]:
    """(height in metres, where it came from: "height" or "levels") or (None, None) if unknown;
    HeightError (naming the key and the value) for a value that cannot be read."""

    def read(key: str, parse) -> float | None:
        try:
            return parse(props.get(key))
        except HeightError as exc:
            raise HeightError(f"{key} {exc}") from None

    for key in HEIGHT_KEYS:
        h = read(key, parse_height)
        if h is not None:
            return h, "height"
    for key in LEVEL_KEYS:
        n = read(key, parse_levels)
        if n is not None:
            roof = next((r for r in (read(k, parse_levels) for k in ROOF_LEVEL_KEYS) if r), 0.0)
            return _checked((n + roof) * METRES_PER_LEVEL, f"{n:g} + {roof:g} levels"), "levels"
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
    obj = read_json(path, "GeoJSON", BUILDINGS_MAX_BYTES)
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
    for index, (props, *parts) in grouped.items():
        geom = shapely.union_all(parts) if len(parts) > 1 else parts[0]
        if not geom.is_valid:
            repaired += 1
            geom = polygonal_part(shapely.make_valid(geom))
        if geom.is_empty:
            continue
        try:
            height, source = building_height(props)
        except HeightError as exc:
            raise InputError(f"{path}: feature {index}: {exc}; fix the value or remove it") from None
        name = str(props.get("name") or props.get("BLDG_NAME1") or "")
        buildings.append(Building(geom, height, source, name))
    warnings = []
    if repaired:
        warnings.append(f"{path}: {repaired} invalid footprint(s) repaired with make_valid")
    return BuildingSet(buildings, path.name, max(0, n_features - len(grouped)), warnings)
