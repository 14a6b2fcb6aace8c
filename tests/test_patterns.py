"""Search patterns from a last known point: coverage, the .plan files, vehicles kept apart, bad input."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Point

from swarmctl.cli import main
from swarmctl.errors import InputError
from swarmctl.geo.areas import Area
from swarmctl.geo.cli import PATTERNS
from swarmctl.geo.grid import GeoGrid, make_grid
from swarmctl.geo.patterns import (
    DEFAULT_FOV,
    INSIDE_M,
    MERGE_M,
    STACK_CEILING_M,
    Frame,
    clip,
    default_spacing,
    expanding_square_legs,
    free_region,
    plan_pattern,
    sector_legs,
)
from swarmctl.geo.plan_io import read_plan, read_waypoints
from tests.geo_helpers import PROJ, feature, to_lonlat, write_geojson

# An L of 400 x 300 m with a no-fly square in its lower arm; the LKP in the lower arm.
L_SHAPE = shapely.Polygon([(0, 0), (400, 0), (400, 300), (200, 300), (200, 150), (0, 150)])
NOFLY = shapely.box(300, 50, 330, 80)
LKP_M = (100.0, 100.0)
SLACK = 1e-3  # of the footprint radius: shapely's buffer is a polygon, a little inside the true circle


def lkp_latlon(xy=LKP_M) -> tuple[float, float]:
    point = to_lonlat(Point(xy))
    return point.y, point.x


def lkp_text(xy=LKP_M) -> str:
    lat, lon = lkp_latlon(xy)
    return f"{lat!r},{lon!r}"


@pytest.fixture(scope="module")
def l_grid() -> GeoGrid:
    area = Area(to_lonlat(L_SHAPE), nofly=[to_lonlat(NOFLY)], name="l")
    return make_grid(area)[0]


@pytest.fixture
def l_file(tmp_path):
    return write_geojson(tmp_path / "l.geojson", feature(to_lonlat(L_SHAPE)), feature(to_lonlat(NOFLY), nofly=True))


def run(capsys, *args):
    rc = main(["plan", *map(str, args)])
    out, err = capsys.readouterr()
    return rc, out, err


def local(grid: GeoGrid, waypoints) -> np.ndarray:
    lat, lon = np.array(waypoints, dtype=float).reshape(-1, 2).T
    u, v = Frame(grid).from_latlon(lat, lon)
    return np.column_stack([u, v])


def track(xy: np.ndarray):
    return LineString(xy) if len(xy) > 1 else Point(xy[0])


def uncovered(grid: GeoGrid, tracks: list, cells: np.ndarray, radius: float) -> list[tuple[int, int]]:
    """The cells whose centre no leg's buffer by the footprint radius holds (each leg buffered alone: GEOS
    can lose area buffering a whole track that runs over itself, as a sector search does)."""
    legs = [leg for t in tracks for leg in [LineString(p) for p in zip(t.coords[:-1], t.coords[1:])] or [t]]
    swept = shapely.union_all([leg.buffer(radius * (1 + SLACK), quad_segs=64) for leg in legs])
    centres = (cells + 0.5) * grid.cell
    inside = shapely.covers(swept, shapely.points(centres))
    return [tuple(map(int, c)) for c in cells[~inside]]


def meeting(tracks: list, altitudes: list[float]) -> list[tuple[int, int]]:
    return [
        (a, b)
        for a in range(len(tracks))
        for b in range(a + 1, len(tracks))
        if altitudes[a] == altitudes[b] and tracks[a].intersects(tracks[b])
    ]


def check_plan(grid: GeoGrid, planned, uavs: int) -> None:
    """Coverage, a waypoint on every leg that reaches the free area, waypoints and tracks inside it, no
    meeting."""
    frame = Frame(grid)
    region = free_region(grid, frame)
    area = frame.geometry(shapely.from_wkt(grid.area_wkt))
    assert len(planned.routes) == uavs and all(r.waypoints for r in planned.routes)
    paths = [local(grid, r.waypoints) for r in planned.routes]
    for xy, route in zip(paths, planned.routes):
        assert np.allclose(xy, np.array(route.local), atol=1e-6)  # lat/lon and back
        assert max(region.distance(Point(p)) for p in xy) < 1e-6
        assert max(area.distance(Point(p)) for p in xy) < 1e-6
    tracks = [track(xy) for xy in paths]
    if planned.straight == 0:  # every way from one waypoint to the next stays in the free area
        assert [t for t in tracks if t.difference(region.buffer(INSIDE_M)).length > 0] == []
    assert uncovered(grid, tracks, planned.cells, planned.spacing / 2) == []
    everything = np.vstack(paths)
    for leg in planned.legs:
        if clip(leg, region):
            assert min(leg.distance(Point(p)) for p in everything) < MERGE_M, leg
    assert meeting(tracks, [r.altitude for r in planned.routes]) == []


# --- the geometry --------------------------------------------------------------------------------------


def test_expanding_square_legs_grow_by_one_spacing_every_second_leg():
    legs = expanding_square_legs((0.0, 0.0), 10.0, 25.0)
    lengths = [round(leg.length, 9) for leg in legs]
    assert lengths[:8] == [10, 10, 20, 20, 30, 30, 40, 40]
    assert lengths == [10.0 * (i // 2 + 1) for i in range(len(legs))] and len(legs) % 4 == 0
    ends = [leg.coords[-1] for leg in legs[:4]]
    assert np.allclose(ends, [(0, 10), (10, 10), (10, -10), (-10, -10)])  # north, then right turns
    for a, b in zip(legs, legs[1:]):
        assert a.coords[-1] == b.coords[0]


def test_sector_pattern_is_three_equilateral_triangles_through_the_lkp():
    legs = sector_legs((0.0, 0.0), 100.0, 0.0)
    assert len(legs) == 9 and all(math.isclose(leg.length, 100.0) for leg in legs)
    assert np.allclose(legs[0].coords[-1], (0, 100))  # out along grid north
    far = [leg.coords[-1] if leg.coords[0] == (0.0, 0.0) else leg.coords[0] for leg in legs if (0.0, 0.0) in leg.coords]
    bearings = sorted(round(math.degrees(math.atan2(*p)) % 360) for p in far)
    assert bearings == [0, 60, 120, 180, 240, 300]  # six legs from the LKP, 60 degrees apart
    turned = sector_legs((0.0, 0.0), 100.0, 30.0)
    assert np.allclose(turned[0].coords[-1], (50, 100 * math.cos(math.radians(30))))


def test_default_spacing_is_the_footprint_diameter(l_grid):
    assert DEFAULT_FOV == 3.0
    assert default_spacing(l_grid) == 2 * 3.0 * 10.0
    assert plan_pattern(l_grid, "parallel", lkp_latlon(), 2).spacing == 60.0


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("uavs", [1, 3])
def test_every_pattern_covers_its_cells_and_keeps_vehicles_apart(l_grid, pattern, uavs):
    planned = plan_pattern(l_grid, pattern, lkp_latlon(), uavs)
    assert planned.straight == 0  # the L is one piece: every way between waypoints stays in it
    check_plan(l_grid, planned, uavs)
    free = int((~l_grid.blocked).sum())
    if pattern != "sector":
        assert len(planned.cells) == free
    else:  # the radius reaches the farthest free cell unless that needs over 60 patterns
        assert 0 < len(planned.cells) <= free and planned.radius > 0


def test_parallel_lanes_are_blocks_at_one_altitude_and_start_near_the_lkp(l_grid):
    planned = plan_pattern(l_grid, "parallel", lkp_latlon(), 3)
    assert {r.altitude for r in planned.routes} == {l_grid.altitude}
    assert "separate blocks of lanes" in planned.split
    first = planned.routes[0].local[0]
    assert first[1] == pytest.approx(30.0, abs=0.1)  # the lane nearest the LKP: S / 2 in from the south side
    across = [sorted({round(p[1], 6) for p in r.local}) for r in planned.routes]
    for low, high in zip(across, across[1:]):
        assert max(low) < min(high)  # contiguous blocks, in order away from the LKP


@pytest.mark.parametrize("pattern", ["expanding-square", "sector"])
def test_square_and_sector_stack_the_vehicles(l_grid, pattern):
    planned = plan_pattern(l_grid, pattern, lkp_latlon(), 3)
    assert [r.altitude for r in planned.routes] == [40.0, 50.0, 60.0]
    assert "stacked altitudes 40..60 m, 10 m apart" in planned.split
    start = np.ravel(Frame(l_grid).from_latlon(*lkp_latlon()))
    if pattern == "expanding-square":
        assert np.allclose(planned.routes[0].local[0], start, atol=1e-6)  # the first vehicle starts at the LKP
    else:
        assert all(np.allclose(r.local[0], start, atol=1e-6) for r in planned.routes)


def test_obstacles_are_kept_clear_of(tmp_path):
    area = Area(to_lonlat(shapely.box(0, 0, 300, 300)), nofly=[to_lonlat(shapely.box(120, 120, 180, 180))], name="a")
    grid = make_grid(area)[0]
    for pattern in PATTERNS:
        planned = plan_pattern(grid, pattern, lkp_latlon((60.0, 60.0)), 2)
        check_plan(grid, planned, 2)
        for route in planned.routes:
            x, y = grid.latlon_to_cells(*np.array(route.waypoints).T)
            inner = [(a, b) for a, b, (u, v) in zip(x, y, route.local) if 121 < u < 179 and 121 < v < 179]
            assert inner == []


corners = st.tuples(st.floats(0, 60), st.floats(0, 60), st.floats(140, 400), st.floats(100, 300))


@settings(max_examples=12)
@given(
    box=corners,
    tilt=st.floats(-30, 30),
    at=st.floats(0.05, 0.95),
    pattern=st.sampled_from(PATTERNS),
    uavs=st.integers(1, 3),
    spacing=st.sampled_from([None, 35.0, 80.0]),
)
def test_property_any_quadrilateral_any_lkp(box, tilt, at, pattern, uavs, spacing):
    x0, y0, x1, y1 = box
    shape = shapely.affinity.rotate(shapely.box(x0, y0, x1, y1), tilt)
    shape = shapely.affinity.skew(shape, xs=10)
    corner, centre = shape.exterior.coords[0], shape.centroid  # the LKP: from a corner towards the centre
    xy = (corner[0] + at * (centre.x - corner[0]), corner[1] + at * (centre.y - corner[1]))
    grid = make_grid(Area(to_lonlat(shape), name="q"))[0]
    try:
        planned = plan_pattern(grid, pattern, lkp_latlon(xy), uavs, spacing)
    except InputError as exc:  # only a pattern with fewer legs than vehicles may be refused
        assert "fewer than --uavs" in str(exc)
        return
    check_plan(grid, planned, uavs)


# --- the command and its files -------------------------------------------------------------------------


@pytest.mark.parametrize("pattern", PATTERNS)
def test_plan_writes_one_qgc_plan_per_vehicle(tmp_path, l_file, capsys, pattern):
    out = tmp_path / "out"
    rc, stdout, err = run(capsys, l_file, "--pattern", pattern, "--lkp", lkp_text(), "--uavs", 3, "--out", out)
    assert rc == 0, err
    assert re.search(rf"pattern: {pattern} from 45\.\d+,4\.\d+, track spacing 60 m, \d+ free cells covered; ", stdout)
    grid = GeoGrid.load(out / "grid.npz")
    tracks, altitudes = [], []
    for k in (1, 2, 3):
        line = re.search(rf"^uav{k}: (\d+) waypoints, ([\d,]+) m, altitude (\d+) m$", stdout, re.MULTILINE)
        assert line, stdout
        path = out / f"uav{k}.plan"
        plan = json.loads(path.read_text())
        assert plan["fileType"] == "Plan" and plan["version"] == 1
        items = plan["mission"]["items"]
        assert len(items) == int(line[1]) >= 1
        for i, item in enumerate(items):
            assert item["type"] == "SimpleItem" and item["command"] == 16 and item["frame"] == 3
            assert item["autoContinue"] is True and item["doJumpId"] == i + 1
            assert item["params"][:4] == [0, 0, 0, None] and item["params"][6] == float(line[3])
        assert plan["mission"]["plannedHomePosition"] == [*items[0]["params"][4:6], 0]
        points = read_waypoints(path)  # the project's own reader
        assert [(p.lat, p.lon, p.alt) for p in points] == [tuple(item["params"][4:7]) for item in items]
        assert {(p.command, p.frame) for p in points} == {(16, 3)}
        area = read_plan(path)  # the fences are the area's: the plan is a valid search area too
        assert len(area.polygons) == 1 and len(area.nofly) == 1
        xy = local(grid, [(p.lat, p.lon) for p in points])
        assert LineString(xy).length == pytest.approx(float(line[2].replace(",", "")), abs=1.0)
        tracks.append(track(xy))
        altitudes.append(points[0].alt)
    assert meeting(tracks, altitudes) == []
    if pattern != "sector":
        assert uncovered(grid, tracks, np.argwhere(~grid.blocked), 30.0) == []


def test_plan_without_a_pattern_writes_no_vehicle_plans(tmp_path, l_file, capsys):
    rc, stdout, _ = run(capsys, l_file, "--out", tmp_path / "out")
    assert rc == 0 and "pattern:" not in stdout and not list((tmp_path / "out").glob("uav*.plan"))


@pytest.mark.parametrize(
    "args, message",
    [
        (["--lkp", lkp_text((100.0, 250.0))], "outside the area"),
        (["--uavs", "0"], r"--uavs.*0"),
        (["--uavs", "51"], r"--uavs.*51"),
        (["--lkp", "nan,4.85"], "latitude must lie in"),
        (["--lkp", "45.77,inf"], "latitude must lie in"),
        (["--lkp", "45.77"], "not two numbers"),
        (["--lkp", "45.77;4.85"], "not two numbers"),
        (["--lkp", "4.85,45.77"], "outside the area"),
        (["--spacing", "nan"], "--spacing"),
        (["--spacing", "0"], "--spacing"),
    ],
)
def test_bad_pattern_input_is_one_line_and_exit_2(tmp_path, l_file, capsys, args, message):
    base = {"--pattern": "sector", "--lkp": lkp_text(), "--uavs": "3"}
    for key, value in zip(args[::2], args[1::2]):
        base[key] = value
    flat = [x for kv in base.items() for x in kv]
    rc, _, err = run(capsys, l_file, *flat, "--out", tmp_path / "out")
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("swarmctl: error: ") and "Traceback" not in err
    assert re.search(message, lines[0]), lines[0]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("args", [["--pattern", "sector"], ["--lkp", "45.7,4.8"]])
def test_pattern_and_lkp_go_together(tmp_path, l_file, capsys, args):
    rc, _, err = run(capsys, l_file, *args, "--out", tmp_path / "out")
    assert rc == 2 and "--pattern and --lkp go together" in err and len(err.strip().splitlines()) == 1


def test_too_many_vehicles_for_the_lanes_is_refused(tmp_path, l_file, capsys):
    rc, _, err = run(
        capsys, l_file, "--pattern", "parallel", "--lkp", lkp_text(), "--uavs", 9, "--out", tmp_path / "out"
    )
    assert rc == 2 and "fewer than --uavs 9" in err and not (tmp_path / "out").exists()


def test_waypoint_reader_refuses_bad_items(tmp_path, l_file, capsys):
    out = tmp_path / "out"
    assert run(capsys, l_file, "--pattern", "parallel", "--lkp", lkp_text(), "--uavs", 1, "--out", out)[0] == 0
    plan = json.loads((out / "uav1.plan").read_text())
    for change, message in (
        (lambda item: item.update(command="16"), r"items\[0\]\.command"),
        (lambda item: item["params"].__setitem__(4, "45.7"), r"items\[0\]\.params\[4\]"),
        (lambda item: item["params"].__setitem__(5, float("nan")), r"items\[0\]\.params\[5\]"),
        (lambda item: item.update(params=[0, 0]), "7 values"),
    ):
        bad = json.loads(json.dumps(plan))
        change(bad["mission"]["items"][0])
        path = tmp_path / "bad.plan"
        path.write_text(json.dumps(bad))
        with pytest.raises(InputError, match=message):
            read_waypoints(path)


def test_lkp_helper_is_inside_the_l():
    lat, lon = lkp_latlon()
    e, n = PROJ.to_metres(lon, lat)
    assert L_SHAPE.contains(Point(float(e), float(n)))


def test_parts_no_free_cells_join_are_flown_straight_with_a_warning(tmp_path, capsys):
    two = write_geojson(
        tmp_path / "two.geojson",
        feature(to_lonlat(shapely.box(0, 0, 150, 200))),
        feature(to_lonlat(shapely.box(250, 0, 400, 200))),
    )
    out = tmp_path / "out"
    rc, stdout, err = run(
        capsys, two, "--pattern", "parallel", "--lkp", lkp_text((50.0, 50.0)), "--uavs", 1, "--out", out
    )
    assert rc == 0, err
    assert "join parts of the area that no free cells connect; they are flown straight" in err
    grid = GeoGrid.load(out / "grid.npz")
    xy = local(grid, [(p.lat, p.lon) for p in read_waypoints(out / "uav1.plan")])
    assert uncovered(grid, [track(xy)], np.argwhere(~grid.blocked), 30.0) == []


def test_stacked_altitudes_above_the_ceiling_are_refused(l_grid):
    """40 m + 10 m a vehicle: 9 vehicles reach 120 m; a tenth would fly above it."""
    planned = plan_pattern(l_grid, "expanding-square", lkp_latlon(), 9)
    assert max(r.altitude for r in planned.routes) == STACK_CEILING_M
    with pytest.raises(InputError, match="above 120 m; use fewer --uavs"):
        plan_pattern(l_grid, "expanding-square", lkp_latlon(), 10)
