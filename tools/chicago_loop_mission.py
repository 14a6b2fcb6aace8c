"""Rebuild missions/chicago-loop/: the paper's real-map step (500 m x 500 m of the Chicago Loop).

The square is centred on the bounding box of the OSM building sample
(missions/data/chicago_loop_osm_sample10.geojson, around Madison / LaSalle), because that sample
is the only Loop building data in the project. Run from the repository root:

    python tools/chicago_loop_mission.py
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import shapely

from swarmctl.cli import main
from swarmctl.geo.buildings import load_buildings
from swarmctl.geo.projection import LocalProjection

ROOT = Path(__file__).resolve().parent.parent
BUILDINGS = ROOT / "missions/data/chicago_loop_osm_sample10.geojson"
MISSION = ROOT / "missions/chicago-loop"
SIDE = 500.0


def square_geojson(lon: float, lat: float, side: float) -> dict:
    """A side x side metre square centred on (lon, lat), as a GeoJSON FeatureCollection."""
    proj = LocalProjection.centred_on((lon, lat, lon, lat))
    h = side / 2
    lons, lats = proj.to_lonlat(np.array([-h, h, h, -h, -h]), np.array([-h, -h, h, h, -h]))
    ring = [[round(float(a), 7), round(float(b), 7)] for a, b in zip(lons, lats)]
    props = {
        "name": "Chicago Loop, 500 m square centred on the OSM building sample",
        "centre_lon": lon,
        "centre_lat": lat,
        "side_m": side,
    }
    return {
        "type": "FeatureCollection",
        "features": [{"type": "Feature", "properties": props, "geometry": {"type": "Polygon", "coordinates": [ring]}}],
    }


def run() -> int:
    """Write the square and run `swarmctl plan` on it with the building sample."""
    bounds = shapely.union_all([b.geometry for b in load_buildings(BUILDINGS).buildings]).bounds
    lon, lat = round((bounds[0] + bounds[2]) / 2, 6), round((bounds[1] + bounds[3]) / 2, 6)
    MISSION.mkdir(parents=True, exist_ok=True)
    area = MISSION / "area.geojson"
    area.write_text(json.dumps(square_geojson(lon, lat, SIDE), indent=1) + "\n", encoding="utf-8")
    return main(
        [
            "plan",
            str(area.relative_to(ROOT)),
            "--buildings",
            str(BUILDINGS.relative_to(ROOT)),
            "--cell",
            "10",
            "--altitude",
            "40",
            "--out",
            str(MISSION.relative_to(ROOT)),
        ]
    )


if __name__ == "__main__":
    sys.exit(run())
