"""A search area from any file swarmctl reads one from, the reader picked by the file's suffix.

    area = load_area("field.kml")   # .geojson/.json, .kml or QGroundControl .plan

GeoJSON and KML are read by swarmctl.geo.areas, .plan files by swarmctl.geo.plan_io (which builds on
areas), so the choice between them lives here, above both.
"""

from __future__ import annotations

from pathlib import Path

from swarmctl.errors import InputError
from swarmctl.geo.areas import Area, read_geojson_area, read_kml
from swarmctl.geo.plan_io import read_plan

AREA_SUFFIXES = (".geojson", ".json", ".kml", ".plan")


def load_area(path: str | Path) -> Area:
    """Read a search area from a .geojson/.json, .kml or QGroundControl .plan file."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in AREA_SUFFIXES:
        raise InputError(
            f"{path}: unknown file type {suffix or '(no extension)'!r}; give a " + ", ".join(AREA_SUFFIXES) + " file"
        )
    if suffix == ".kml":
        return read_kml(path)
    if suffix == ".plan":
        return read_plan(path)
    return read_geojson_area(path)
