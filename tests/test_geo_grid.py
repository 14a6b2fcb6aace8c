"""Which cells are blocked: area outline, holes, no-fly polygons and circles; the grid file."""

from __future__ import annotations

import json

import numpy as np
import pytest
import shapely

from swarmctl.errors import InputError
from swarmctl.geo.areas import Area, Circle
from swarmctl.geo.grid import GeoGrid, make_grid
from swarmctl.geo.load import load_area
from tests.geo_helpers import LAT0, LON0, PROJ, blocked_cells, feature, to_lonlat, write_geojson

SQUARE_60 = shapely.box(0, 0, 60, 60)  # metres: a 6 x 6 grid of 10 m cells


def grid_of(area: Area, **kw):
    grid, report = make_grid(area, cell=10.0, **kw)
    return grid, report


def test_plain_square_is_six_by_six_and_free():
    grid, _ = grid_of(Area(to_lonlat(SQUARE_60)))
    assert (grid.width, grid.height) == (6, 6)
    assert blocked_cells(grid) == set()


def test_cell_centre_outside_the_area_is_blocked():
    # An L: the square minus its north-east quarter (30..60 x 30..60).
    ell = SQUARE_60.difference(shapely.box(30, 30, 60, 60))
    grid, report = grid_of(Area(to_lonlat(ell)))
    assert blocked_cells(grid) == {(x, y) for x in (3, 4, 5) for y in (3, 4, 5)}
    assert report.outside == 9 and report.nofly == 0


def test_hole_is_no_fly():
    holed = shapely.Polygon(SQUARE_60.exterior, [shapely.box(20, 20, 40, 40).exterior])
    grid, report = grid_of(Area(to_lonlat(holed)))
    assert blocked_cells(grid) == {(2, 2), (2, 3), (3, 2), (3, 3)}
    assert report.nofly == 4 and report.outside == 0
    assert "POLYGON" in grid.nofly_wkt


def test_no_fly_feature_and_centre_rule(tmp_path):
    # A no-fly strip over the centres of column x = 1 (centres at x = 15 m), y from 0 to 32 m:
    # centres 5, 15, 25 are inside, 35 is not.
    path = write_geojson(
        tmp_path / "a.geojson",
        feature(to_lonlat(SQUARE_60)),
        feature(to_lonlat(shapely.box(12, 0, 18, 32)), nofly=True),
    )
    grid, _ = grid_of(load_area(path))
    assert blocked_cells(grid) == {(1, 0), (1, 1), (1, 2)}


def test_no_fly_zone_between_centres_blocks_nothing_and_warns():
    zone = to_lonlat(shapely.box(11, 11, 14, 14))  # inside cell (1, 1) but away from its centre
    grid, report = grid_of(Area(to_lonlat(SQUARE_60), nofly=[zone], name="a.geojson"))
    assert blocked_cells(grid) == set()
    assert any("cover no cell centre" in w for w in report.warnings)


def test_no_fly_circle_radius_is_in_metres():
    lon, lat = PROJ.to_lonlat(25.0, 25.0)  # the centre of cell (2, 2)
    area = Area(to_lonlat(SQUARE_60), nofly_circles=[Circle(float(lat), float(lon), 12.0)])
    grid, _ = grid_of(area)
    # Centres within 12 m: the cell itself and its 4 neighbours (10 m); diagonals are 14.1 m away.
    assert blocked_cells(grid) == {(2, 2), (1, 2), (3, 2), (2, 1), (2, 3)}


def test_multipolygon_with_gap_blocks_the_gap():
    two = shapely.MultiPolygon([shapely.box(0, 0, 20, 60), shapely.box(40, 0, 60, 60)])
    grid, _ = grid_of(Area(to_lonlat(two)))
    assert (grid.width, grid.height) == (6, 6)
    assert blocked_cells(grid) == {(x, y) for x in (2, 3) for y in range(6)}


def test_rectangular_grid_sizes_round_up():
    grid, _ = grid_of(Area(to_lonlat(shapely.box(0, 0, 95, 41))))
    assert (grid.width, grid.height) == (10, 5)


def test_rotate_aligns_a_tilted_strip():
    strip = shapely.affinity.rotate(shapely.box(0, 0, 200, 20), 30, origin=(0, 0))
    plain, _ = grid_of(Area(to_lonlat(strip)))
    rotated, _ = grid_of(Area(to_lonlat(strip)), rotate=True)
    assert rotated.rotation == pytest.approx(30.0, abs=1e-3)
    assert (rotated.width, rotated.height) == (20, 2)
    assert not rotated.blocked.any()
    assert plain.blocked.mean() > 0.5  # the unrotated grid wastes most of its cells


def test_rotation_keeps_x_closest_to_east():
    strip = shapely.affinity.rotate(shapely.box(0, 0, 200, 20), 80, origin=(0, 0))
    rotated, _ = grid_of(Area(to_lonlat(strip)), rotate=True)
    assert rotated.rotation == pytest.approx(-10.0, abs=1e-3)
    assert (rotated.width, rotated.height) == (2, 20)


def test_max_cells_and_cell_size_are_checked():
    area = Area(to_lonlat(SQUARE_60), name="a.geojson")
    with pytest.raises(InputError, match="a.geojson.*6 x 6 = 36 cells.*--max-cells"):
        make_grid(area, cell=10.0, max_cells=35)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(InputError, match="must be a number > 0"):
            make_grid(area, cell=bad)


def test_grid_file_round_trip(tmp_path):
    holed = shapely.Polygon(SQUARE_60.exterior, [shapely.box(20, 20, 40, 40).exterior])
    grid, _ = grid_of(Area(to_lonlat(holed), name="holed.geojson"), altitude=35.0)
    back = GeoGrid.load(grid.save(tmp_path / "grid.npz"))
    assert np.array_equal(back.blocked, grid.blocked)
    assert (back.proj, back.origin, back.rotation, back.cell, back.altitude) == (
        grid.proj,
        grid.origin,
        grid.rotation,
        grid.cell,
        grid.altitude,
    )
    assert back.area_name == "holed.geojson"
    assert back.cell_to_latlon(4, 1) == grid.cell_to_latlon(4, 1)
    assert shapely.from_wkt(back.area_wkt).equals(shapely.from_wkt(grid.area_wkt))


def test_bad_grid_files_raise_input_error(tmp_path):
    grid, _ = grid_of(Area(to_lonlat(SQUARE_60)))
    good = grid.save(tmp_path / "good.npz")
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip file")
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good.read_bytes()[:200])
    other = tmp_path / "other.npz"
    np.savez(other, blocked=np.zeros((2, 2), bool), meta=np.array('{"format": "something-else"}'))
    bad_shape = tmp_path / "bad_shape.npz"
    meta = dict(grid.meta(), width=7)
    np.savez(bad_shape, blocked=grid.blocked, meta=np.array(json.dumps(meta)))
    bad_cell = tmp_path / "bad_cell.npz"
    np.savez(bad_cell, blocked=grid.blocked, meta=np.array(json.dumps(dict(grid.meta(), cell_size_m=0))))
    bad_proj = tmp_path / "bad_proj.npz"
    np.savez(bad_proj, blocked=grid.blocked, meta=np.array(json.dumps(dict(grid.meta(), proj="+proj=nothing"))))
    for path in (tmp_path / "missing.npz", garbage, truncated, other, bad_shape, bad_cell, bad_proj):
        with pytest.raises(InputError, match=path.name):
            GeoGrid.load(path)


def test_connectivity_finds_the_largest_free_region():
    # A wall of no-fly along x = 2 cuts the 6 x 6 square into 12 and 18 free cells.
    area = Area(to_lonlat(SQUARE_60), nofly=[to_lonlat(shapely.box(20, 0, 30, 60))])
    grid, _ = grid_of(area)
    _, n = grid.free_regions()
    assert n == 2
    assert grid.largest_free_region().sum() == 18


def test_origin_is_south_west_corner():
    grid, _ = grid_of(Area(to_lonlat(SQUARE_60)))
    lat, lon = grid.corner_latlon()
    e, n = PROJ.to_metres(lon[0, 0], lat[0, 0])
    assert (e, n) == pytest.approx((0.0, 0.0), abs=1e-3)
    assert (LON0, LAT0) != (lon[0, 0], lat[0, 0])


def test_cell_centres_are_converted_once_and_match_the_conversion_of_each_cell():
    grid = GeoGrid(PROJ.proj, (-120.0, 35.0), 17.5, 12.0, np.zeros((7, 5), dtype=bool))  # rotated, off the origin
    for x in range(7):
        for y in range(5):
            lat, lon = grid.cells_to_latlon(x, y)
            assert grid.cell_to_latlon(x, y) == (float(lat), float(lon))  # bit for bit
    lat, lon = grid.cells_to_latlon(-1, 9)  # outside the grid: converted
    assert grid.cell_to_latlon(-1, 9) == (float(lat), float(lon))
    before = grid.cell_to_latlon(3, 3)
    grid.origin = (0.0, 0.0)  # the grid moved: its centres are converted again
    assert grid.cell_to_latlon(3, 3) != before
    assert grid.cell_to_latlon(3, 3) == tuple(float(v) for v in grid.cells_to_latlon(3, 3))
