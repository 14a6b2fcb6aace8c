"""Hand-built areas for the geo tests: shapes drawn in metres, turned into lon/lat."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import shapely

from swarmctl.geo.projection import LocalProjection

# A quiet spot (a park in Lyon) so that hand-built shapes do not look like real data.
LON0, LAT0 = 4.8522, 45.7772
PROJ = LocalProjection.centred_on((LON0, LAT0, LON0, LAT0))
REPO = Path(__file__).resolve().parent.parent
DATA = REPO / "missions" / "data"


def to_lonlat(geom_metres, proj: LocalProjection = PROJ):
    """A shapely geometry in metres around (LON0, LAT0) -> lon/lat."""
    return proj.geometry_to_lonlat(geom_metres)


def grid_box_lonlat(grid, x0, y0, x1, y1):
    """A box given in grid cell units (cell (x, y) spans [x, x+1]) as a lon/lat polygon."""
    box = shapely.box(x0, y0, x1, y1)
    return shapely.transform(
        box, lambda xy: np.column_stack(grid.projection.to_lonlat(*grid.grid_to_metres(xy[:, 0], xy[:, 1])))
    )


def feature(geom, **props) -> dict:
    """A GeoJSON Feature from a shapely geometry."""
    return {"type": "Feature", "properties": props, "geometry": shapely.geometry.mapping(geom)}


def write_geojson(path: Path, *features: dict, **members) -> Path:
    """Write a FeatureCollection (extra top-level members, e.g. crs, allowed)."""
    path.write_text(json.dumps({"type": "FeatureCollection", **members, "features": list(features)}))
    return path


def blocked_cells(grid) -> set[tuple[int, int]]:
    """The blocked cells as a set of (x, y)."""
    return {(int(x), int(y)) for x, y in zip(*np.nonzero(grid.blocked))}
