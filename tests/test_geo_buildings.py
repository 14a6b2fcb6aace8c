"""The building rule: heights, levels, the threshold, the margin, unknown heights, coverage."""

from __future__ import annotations

import pytest
import shapely

from swarmctl.errors import InputError
from swarmctl.geo.areas import Area
from swarmctl.geo.buildings import (
    METRES_PER_LEVEL,
    BuildingRule,
    HeightError,
    building_height,
    load_buildings,
    parse_height,
    parse_levels,
)
from swarmctl.geo.grid import make_grid
from tests.geo_helpers import blocked_cells, feature, grid_box_lonlat, to_lonlat, write_geojson

SQUARE_60 = shapely.box(0, 0, 60, 60)


@pytest.mark.parametrize(
    "value, metres",
    [
        (45, 45.0),
        (45.5, 45.5),
        ("45", 45.0),
        ("45 m", 45.0),
        ("45m", 45.0),
        ("12,5 m", 12.5),
        ("150 ft", 45.72),
        ("150'", 45.72),
        ("12'6\"", 3.81),
        ("12.13 m", 12.13),
        ("1,000 ft", 304.8),
        ("1,250.5 feet", 381.1524),
        ("12 levels", 48.0),
        ("150 ft.", 45.72),
        (None, None),
        ("", None),
        ("unknown", None),
        ("0", None),
        (-3, None),
    ],
)
def test_parse_height(value, metres):
    got = parse_height(value)
    assert got == (None if metres is None else pytest.approx(metres, abs=1e-9))


@pytest.mark.parametrize(
    "value, reason",
    [
        ("tall", "not a height"),
        ("12 furlongs", "not a height"),
        ("3 m 6 in", "inches follow feet"),
        (True, "not a height"),
        ([40], "not a height"),
        ("nan", "not a height"),
        (float("nan"), "not a finite number"),
        (float("inf"), "not a finite number"),
        ("5,000 m", "taller than any building"),
    ],
)
def test_unreadable_heights_are_refused_with_the_value(value, reason):
    with pytest.raises(HeightError, match=reason):
        parse_height(value)


@pytest.mark.parametrize(
    "value, levels",
    [
        ("10", 10.0),
        (10, 10.0),
        ("3.5", 3.5),
        ("3;4", 4.0),
        (0, None),
        ("0", None),
        (None, None),
        ("n/a", None),
    ],
)
def test_parse_levels(value, levels):
    assert parse_levels(value) == levels


@pytest.mark.parametrize("value", ["many", "1,000", "ten"])
def test_unreadable_level_counts_are_refused(value):
    with pytest.raises(HeightError, match=repr(value)):
        parse_levels(value)


def test_height_wins_over_levels_and_levels_use_four_metres():
    assert METRES_PER_LEVEL == 4.0
    assert building_height({"height": "96", "building:levels": "26"}) == (96.0, "height")
    assert building_height({"height": None, "building:levels": "10"}) == (40.0, "levels")
    assert building_height({"stories": "9"}) == (36.0, "levels")
    assert building_height({"STORIES": 11}) == (44.0, "levels")
    assert building_height({"STORIES": 0, "NO_STORIES": 0}) == (None, None)  # 0 = unknown
    assert building_height({"building:levels": "9", "roof:levels": "1"}) == (40.0, "levels")
    assert building_height({"height": "unknown", "building:levels": "2"}) == (8.0, "levels")
    assert building_height({"name": "no height"}) == (None, None)


def test_threshold_is_inclusive_and_margin_lowers_it():
    rule = BuildingRule(altitude=40.0)
    assert rule.blocks(40.0) and rule.blocks(306.9) and not rule.blocks(39.99)
    margin = BuildingRule(altitude=40.0, margin=5.0)
    assert margin.blocks(35.0) and not margin.blocks(34.9)
    assert BuildingRule(unknown="block").blocks(None) and not BuildingRule(unknown="ignore").blocks(None)


@pytest.fixture
def tiny(tmp_path):
    """A 6 x 6 grid and a helper writing footprints (in cell units) with properties to a file."""
    area = Area(to_lonlat(SQUARE_60), name="square.geojson")
    grid, _ = make_grid(area, cell=10.0)

    def buildings(*items):
        feats = [feature(grid_box_lonlat(grid, *box), **props) for box, props in items]
        return load_buildings(write_geojson(tmp_path / "b.geojson", *feats))

    return area, buildings


def run(area, bset, **rule):
    rule = BuildingRule(**rule)
    return make_grid(area, cell=10.0, altitude=rule.altitude, buildings=bset, rule=rule)


def test_footprint_blocks_every_cell_it_overlaps(tiny):
    area, buildings = tiny
    bset = buildings(
        ((1.2, 1.2, 1.8, 1.8), {"height": "50"}),  # inside cell (1, 1) only
        ((3.0, 3.0, 5.0, 4.0), {"height": 41}),  # exactly on cell edges: (3, 3) and (4, 3), no neighbours
        ((0.9, 5.2, 1.1, 5.4), {"height": "45 m"}),  # straddles the x = 1 edge: (0, 5) and (1, 5)
    )
    grid, report = run(area, bset)
    assert blocked_cells(grid) == {(1, 1), (3, 3), (4, 3), (0, 5), (1, 5)}
    assert (report.buildings_used, report.buildings_blocking, report.buildings) == (3, 3, 5)


def test_low_buildings_do_not_block_and_levels_count(tiny):
    area, buildings = tiny
    bset = buildings(
        ((0.2, 0.2, 0.8, 0.8), {"height": "39.9"}),  # below 40 m
        ((2.2, 0.2, 2.8, 0.8), {"building:levels": "10"}),  # 10 x 4 m = 40 m: blocks
        ((4.2, 0.2, 4.8, 0.8), {"stories": 9}),  # 36 m
        ((4.2, 2.2, 4.8, 2.8), {"STORIES": 12}),  # 48 m
    )
    grid, report = run(area, bset)
    assert blocked_cells(grid) == {(2, 0), (4, 2)}
    assert (report.buildings_blocking, report.buildings_tall, report.buildings_low) == (2, 2, 2)


def test_margin_makes_lower_buildings_block(tiny):
    area, buildings = tiny
    bset = buildings(((0.2, 0.2, 0.8, 0.8), {"height": 36}), ((2.2, 0.2, 2.8, 0.8), {"height": 34}))
    assert blocked_cells(run(area, bset)[0]) == set()
    assert blocked_cells(run(area, bset, margin=5.0)[0]) == {(0, 0)}
    assert blocked_cells(run(area, bset, altitude=30.0)[0]) == {(0, 0), (2, 0)}


def test_unknown_height_rule(tiny):
    area, buildings = tiny
    bset = buildings(((1.2, 1.2, 1.8, 1.8), {"name": "no tags"}), ((3.2, 3.2, 3.8, 3.8), {"STORIES": 0}))
    grid, report = run(area, bset, unknown="block")
    assert blocked_cells(grid) == {(1, 1), (3, 3)}
    assert (report.unknown_height, report.buildings_blocking, report.buildings_tall) == (2, 2, 0)
    grid, report = run(area, bset, unknown="ignore")
    assert blocked_cells(grid) == set()
    assert report.unknown_height == 2 and report.buildings_blocking == 0


def test_buildings_outside_the_area_are_ignored_and_counted(tiny):
    area, buildings = tiny
    bset = buildings(
        ((1.2, 1.2, 1.8, 1.8), {"height": 90}),
        ((8.0, 8.0, 9.0, 9.0), {"height": 90}),
        ((-3.0, 2.0, -2.0, 3.0), {"height": 90}),
    )
    grid, report = run(area, bset)
    assert blocked_cells(grid) == {(1, 1)}
    assert (report.buildings_total, report.buildings_used, report.buildings_outside) == (3, 1, 2)


def test_multipolygon_building_is_one_building(tmp_path):
    area = Area(to_lonlat(SQUARE_60))
    two = shapely.MultiPolygon([shapely.box(2, 2, 8, 8), shapely.box(42, 42, 48, 48)])
    bset = load_buildings(write_geojson(tmp_path / "b.geojson", feature(to_lonlat(two), height=60)))
    assert len(bset.buildings) == 1
    grid, _ = make_grid(area, cell=10.0, buildings=bset)
    assert blocked_cells(grid) == {(0, 0), (4, 4)}


def test_building_file_problems(tmp_path):
    points = write_geojson(
        tmp_path / "points.geojson",
        {"type": "Feature", "properties": {}, "geometry": {"type": "Point", "coordinates": [4.8, 45.7]}},
    )
    with pytest.raises(InputError, match="points.geojson: contains no building footprint"):
        load_buildings(points)
    with pytest.raises(InputError, match="b.shp: unknown file type"):
        load_buildings(tmp_path / "b.shp")
    with pytest.raises(InputError, match="missing.geojson: file not found"):
        load_buildings(tmp_path / "missing.geojson")


def test_buildings_all_outside_the_area_warn(tiny):
    area, buildings = tiny
    _, report = run(area, buildings(((20.0, 20.0, 21.0, 21.0), {"height": 90})))
    assert report.buildings_used == 0
    assert any("none of its 1 buildings lies in the area" in w for w in report.warnings)
