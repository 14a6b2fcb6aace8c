"""Geofences: the polygon of a grid."""

from __future__ import annotations

import numpy as np
import shapely

from swarmctl.geo.areas import Area
from swarmctl.geo.fence import fence_contains, fence_polygon
from swarmctl.geo.grid import GeoGrid, make_grid
from tests.geo_helpers import REPO, to_lonlat
from tests.mission_support import small_grid

CHICAGO_GRID = REPO / "missions" / "chicago-loop" / "grid.npz"


def free_cell_centres(grid: GeoGrid):
    xs, ys = np.nonzero(~grid.blocked)
    return zip(*grid.cells_to_latlon(xs, ys))


# --- the polygon -----------------------------------------------------------------------------------

def test_the_chicago_grid_is_fenced_by_its_area_and_a_cell_of_margin():
    grid = GeoGrid.load(CHICAGO_GRID)
    fence = fence_polygon(grid)
    assert 3 <= len(fence) <= 60
    assert all(fence_contains(fence, lat, lon) for lat, lon in free_cell_centres(grid))
    outline = grid.projection.geometry_to_metres(shapely.Polygon([(lon, lat) for lat, lon in fence]))
    area = grid.projection.geometry_to_metres(shapely.from_wkt(grid.area_wkt))
    assert outline.contains(area.buffer(grid.cell * 0.99))  # one cell of margin all round
    assert not outline.contains(area.buffer(grid.cell * 1.5))


def test_a_grid_without_its_area_is_fenced_round_its_free_cells():
    grid = small_grid()  # no area_wkt: 10 x 10 cells, a blocked 2 x 2 block in the middle
    fence = fence_polygon(grid)
    assert len(fence) == 4  # the outline of the free cells; the blocked block is not cut out
    assert all(fence_contains(fence, lat, lon) for lat, lon in free_cell_centres(grid))
    blocked = grid.cell_to_latlon(4, 4)
    assert fence_contains(fence, *blocked)


def test_an_area_with_hundreds_of_vertices_is_simplified_without_cutting_into_it():
    angles = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    radius = np.where(np.arange(400) % 2, 300.0, 600.0)  # a 200-point star
    star = shapely.Polygon(np.column_stack([radius * np.cos(angles), radius * np.sin(angles)]))
    grid, _ = make_grid(Area(to_lonlat(star)), cell=10.0)
    fence = fence_polygon(grid, max_vertices=40)
    assert 3 <= len(fence) <= 40
    assert all(fence_contains(fence, lat, lon) for lat, lon in free_cell_centres(grid))
