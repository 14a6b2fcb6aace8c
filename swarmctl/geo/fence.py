"""The inclusion geofence of a grid: the polygon the vehicles may fly in, for the autopilots to enforce.

The fence is the outer boundary of the search area (`GeoGrid.area_wkt`; for a grid without it, the
union of the free cells), pushed out by a margin of one cell (`margin` metres), with its holes left
out: holes, no-fly zones and blocked cells stay the safety guard's business, not the autopilot's.
The margin keeps every path the controller flies inside the fence: vehicles fly only between the
centres of neighbouring free cells, and every point of such a path lies within 0.71 cells of a free
cell centre, which is inside the area. It also keeps home off the fence line (ArduPilot refuses to
arm within FENCE_MARGIN of it).

An area of several parts becomes one polygon (their outline when the margin joins them, else their
convex hull), because the two autopilots read several inclusion polygons differently (ArduPilot: the
vehicle must be inside every one, unless FENCE_OPTIONS asks for their union; PX4: inside any one).

Autopilots hold a few dozen fence points at most, so the polygon is simplified to at most
`max_vertices` vertices, never cutting into the area grown by half the margin; when no simplification
keeps that, the convex hull and then the minimum rotated rectangle (4 vertices) are used.
"""

from __future__ import annotations

import numpy as np
import shapely
from pyproj import Geod
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient

from swarmctl.errors import InputError

MAX_FENCE_VERTICES = 60  # ArduPilot keeps 84 fence points on a Pixhawk (depends on the board's storage)


def fence_polygon(
    grid, margin: float | None = None, max_vertices: int = MAX_FENCE_VERTICES
) -> list[tuple[float, float]]:
    """The inclusion fence of `grid` as (lat, lon) vertices, open ring (the first is not repeated).

    `margin`: metres the fence lies outside the area (default: one cell side).
    """
    if max_vertices < 4:
        raise ValueError("a fence needs room for at least 4 vertices")
    margin = float(grid.cell if margin is None else margin)
    area = _area_metres(grid)
    fence = _outline(area.buffer(margin, join_style="mitre", mitre_limit=2.0))
    if _vertices(fence) > max_vertices:
        fence = _simplified(fence, area.buffer(margin / 2.0), margin / 2.0, max_vertices)
    ring = orient(fence, sign=1.0).exterior
    lon, lat = grid.projection.to_lonlat(*np.asarray(ring.coords)[:-1].T)
    return [(float(a), float(b)) for a, b in zip(np.atleast_1d(lat), np.atleast_1d(lon))]


def fence_contains(polygon: list[tuple[float, float]], lat: float, lon: float) -> bool:
    """Whether (lat, lon) lies inside (or on) the fence polygon given as (lat, lon) vertices."""
    return bool(shapely.intersects_xy(Polygon([(b, a) for a, b in polygon]), lon, lat))


def farthest_metres(polygon: list[tuple[float, float]], lat: float, lon: float) -> float:
    """The distance in metres (WGS84 geodesic) from (lat, lon) to the farthest point of the polygon:
    one of its vertices. How far a circle fence round home must reach to hold the whole polygon."""
    lats, lons = np.array(polygon, dtype=float).T
    _, _, dist = Geod(ellps="WGS84").inv(np.full_like(lons, lon), np.full_like(lats, lat), lons, lats)
    return float(np.max(dist))


def _area_metres(grid):
    """The area in the grid's projection metres, holes dropped (one Polygon or a MultiPolygon)."""
    if grid.area_wkt:
        area = grid.projection.geometry_to_metres(shapely.from_wkt(grid.area_wkt))
    else:
        xs, ys = np.nonzero(~grid.blocked)
        if len(xs) == 0:
            raise InputError(
                "the grid has no free cell, so there is no area to fence in; plan the grid again with `swarmctl plan`"
            )
        cells = shapely.box(xs, ys, xs + 1, ys + 1)
        area = shapely.transform(
            shapely.union_all(cells), lambda xy: np.column_stack(grid.grid_to_metres(xy[:, 0], xy[:, 1]))
        )
    parts = [Polygon(p.exterior) for p in getattr(area, "geoms", [area]) if isinstance(p, Polygon)]
    if not parts:
        raise InputError("the grid's area holds no polygon to fence in; plan the grid again with `swarmctl plan`")
    return shapely.union_all(parts)


def _outline(geom) -> Polygon:
    """One polygon without holes: the shape itself, or the convex hull of a shape in pieces."""
    if isinstance(geom, Polygon):
        return Polygon(geom.exterior)
    return geom.convex_hull


def _vertices(poly: Polygon) -> int:
    return len(poly.exterior.coords) - 1


def _simplified(fence: Polygon, must_hold, largest: float, max_vertices: int) -> Polygon:
    """`fence` with at most max_vertices vertices that still contains `must_hold`."""
    tolerance = largest / 64.0
    while tolerance <= largest:
        candidate = _outline(fence.simplify(tolerance, preserve_topology=True))
        if _vertices(candidate) <= max_vertices and candidate.contains(must_hold):
            return candidate
        tolerance *= 2.0
    hull = fence.convex_hull
    if _vertices(hull) <= max_vertices:
        return hull
    return hull.minimum_rotated_rectangle
