"""Cell <-> lat/lon round trips and the metric accuracy of the local projection."""

from __future__ import annotations

import functools

import numpy as np
import pyproj
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.geo.areas import Area
from swarmctl.geo.grid import make_grid
from swarmctl.geo.projection import LocalProjection

GEOD = pyproj.Geod(ellps="WGS84")
SIDE = 5000.0  # metres: anywhere in a 5 km area
# (lon, lat) centres: equator, Chicago, 60 N (Helsinki), southern hemisphere (Western Cape), 70 S.
CENTRES = [(0.0, 0.0), (-87.632384, 41.881895), (24.94, 60.17), (19.11, -34.11), (-60.0, -70.0)]
FAST = settings(max_examples=150, deadline=None)


@functools.cache
def square_grid(lon0: float, lat0: float, rotate_deg: float = 0.0):
    """A 5 km square (optionally rotated) at (lon0, lat0) gridded at 10 m."""
    proj = LocalProjection.centred_on((lon0, lat0, lon0, lat0))
    square = shapely.affinity.rotate(shapely.box(-SIDE / 2, -SIDE / 2, SIDE / 2, SIDE / 2), rotate_deg)
    area = Area(proj.geometry_to_lonlat(square), name="square")
    grid, _ = make_grid(area, cell=10.0, rotate=rotate_deg != 0.0, max_cells=10**6)
    return grid


centre = st.sampled_from(CENTRES)
offset = st.floats(-SIDE / 2, SIDE / 2, allow_nan=False)


@FAST
@given(centre, offset, offset)
def test_latlon_metres_latlon_error_below_half_a_metre(c, de, dn):
    grid = square_grid(*c)
    lon, lat = grid.projection.to_lonlat(de, dn)
    lon2, lat2 = grid.projection.to_lonlat(*grid.projection.to_metres(lon, lat))
    _, _, dist = GEOD.inv(lon, lat, lon2, lat2)
    assert dist < 0.5
    assert dist < 1e-6  # in practice the projection round trip is exact to the micrometre


@FAST
@given(centre, st.integers(0, 499), st.integers(0, 499), st.sampled_from([0.0, 27.0]))
def test_cell_latlon_cell_is_exact(c, x, y, rot):
    grid = square_grid(*c, rot)
    x, y = min(x, grid.width - 1), min(y, grid.height - 1)
    assert grid.latlon_to_cell(*grid.cell_to_latlon(x, y)) == (x, y)


@FAST
@given(centre, st.integers(0, 499), st.integers(0, 499), st.integers(0, 499), st.integers(0, 499))
def test_grid_distances_are_ground_distances(c, x1, y1, x2, y2):
    """Two cell centres are as far apart on the ellipsoid as on the grid (within 0.5 m over 5 km)."""
    grid = square_grid(*c)
    (la1, lo1), (la2, lo2) = grid.cell_to_latlon(x1, y1), grid.cell_to_latlon(x2, y2)
    _, _, ground = GEOD.inv(lo1, la1, lo2, la2)
    assert abs(ground - 10.0 * np.hypot(x2 - x1, y2 - y1)) < 0.5


@FAST
@given(centre, offset, offset)
def test_latlon_to_cell_lands_within_half_a_diagonal(c, de, dn):
    grid = square_grid(*c)
    lon, lat = grid.projection.to_lonlat(de * 0.999, dn * 0.999)
    x, y = grid.latlon_to_cell(lat, lon)
    assert grid.in_grid(x, y)
    la, lo = grid.cell_to_latlon(x, y)
    _, _, dist = GEOD.inv(lon, lat, lo, la)
    assert dist <= 10.0 * np.sqrt(2) / 2 + 1e-6


@pytest.mark.parametrize("c", CENTRES)
def test_five_km_square_is_500_by_500_cells_and_axes_point_east_and_north(c):
    grid = square_grid(*c)
    assert (grid.width, grid.height) == (500, 500)
    assert not grid.blocked.any()
    # Grid north is true north on the central meridian (the grid's middle); 2.5 km off it the two
    # differ by the meridian convergence, about 0.022 deg x tan(latitude).
    lat00, lon00 = grid.cell_to_latlon(249, 249)
    lat10, lon10 = grid.cell_to_latlon(250, 249)
    lat01, lon01 = grid.cell_to_latlon(249, 250)
    assert GEOD.inv(lon00, lat00, lon10, lat10)[0] == pytest.approx(90.0, abs=0.001)  # x: east
    assert GEOD.inv(lon00, lat00, lon01, lat01)[0] == pytest.approx(0.0, abs=0.001)  # y: north
    (sw_lat, sw_lon), (ne_lat, ne_lon) = grid.cell_to_latlon(0, 0), grid.cell_to_latlon(499, 499)
    assert sw_lat < ne_lat and sw_lon < ne_lon  # (0, 0) is the south-west cell


def test_vectorised_matches_scalar():
    grid = square_grid(*CENTRES[2])
    xs, ys = np.array([0, 17, 499, 250]), np.array([0, 400, 499, 3])
    lat, lon = grid.cells_to_latlon(xs, ys)
    for i in range(len(xs)):
        assert (lat[i], lon[i]) == grid.cell_to_latlon(xs[i], ys[i])
    bx, by = grid.latlon_to_cells(lat, lon)
    assert bx.tolist() == xs.tolist() and by.tolist() == ys.tolist()


def test_rotated_grid_follows_the_main_axis():
    grid = square_grid(CENTRES[1][0], CENTRES[1][1], 27.0)
    assert grid.rotation == pytest.approx(27.0, abs=1e-4)
    assert (grid.width, grid.height) == (500, 500)
    assert grid.blocked.mean() < 0.01  # the rotated square fills its rotated grid
