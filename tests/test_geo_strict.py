"""Strict area readers: JSON types are checked, never coerced, and degenerate areas are refused.

Every refusal is an `InputError` naming the file and the JSON path of the bad value (or, for a degenerate
area, its measured size and the fix); through the CLI it is one line on stderr with exit status 2.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from swarmctl.cli import main
from swarmctl.errors import InputError
from swarmctl.geo.grid import make_grid
from swarmctl.geo.load import load_area
from swarmctl.geo.readers import lonlat_ring
from tests.geo_helpers import PROJ, blocked_cells, feature, to_lonlat, write_geojson

LON, LAT = -87.632, 41.876  # the Chicago Loop
RING = [[LON, LAT], [LON + 0.002, LAT], [LON + 0.002, LAT + 0.002], [LON, LAT + 0.002], [LON, LAT]]
INNER = [[LON + 0.0005, LAT + 0.0005], [LON + 0.0015, LAT + 0.0005], [LON + 0.0015, LAT + 0.0015]]

# JSON values that are not numbers (bools are not numbers, though Python's bool is an int).
NOT_NUMBERS = st.one_of(
    st.text(max_size=12),
    st.booleans(),
    st.none(),
    st.lists(st.floats(-10, 10), max_size=3),
    st.dictionaries(st.text(max_size=4), st.integers(), max_size=2),
)


def latlon(ring: list) -> list:
    return [[lat, lon] for lon, lat in ring]


def fence(*polygons: dict, circles: list | None = None) -> dict:
    return {
        "fileType": "Plan",
        "version": 1,
        "geoFence": {"version": 2, "polygons": list(polygons), "circles": circles or []},
    }


def write(path: Path, obj: object) -> Path:
    path.write_text(json.dumps(obj))
    return path


def refused(path: Path, message: str) -> str:
    """load_area(path) raises an InputError naming the file and matching `message` (a literal string)."""
    with pytest.raises(InputError) as info:
        load_area(path)
    text = str(info.value)
    assert text.startswith(f"{path}: ") and message in text, text
    return text


def cli(capsys, *args) -> tuple[int, str]:
    rc = main(["plan", *map(str, args)])
    _, err = capsys.readouterr()
    return rc, err


# --- 1. .plan "inclusion" must be a JSON boolean ------------------------------------------------------


@pytest.mark.parametrize("value", ["false", "true", "yes", 0, 1, 0.0, None, [], {}])
def test_plan_polygon_inclusion_must_be_a_boolean(tmp_path, value):
    plan = fence(
        {"inclusion": True, "polygon": latlon(RING[:-1]), "version": 1},
        {"inclusion": value, "polygon": latlon(INNER), "version": 1},
    )
    text = refused(write(tmp_path / "bad.plan", plan), "geoFence.polygons[1].inclusion is ")
    assert "not true or false" in text and '"inclusion": true (search area) or false (no-fly zone)' in text


@pytest.mark.parametrize("value", ["false", 0, 1, None])
def test_plan_circle_inclusion_must_be_a_boolean(tmp_path, value):
    circle = {"circle": {"center": [LAT, LON], "radius": 100}, "inclusion": value, "version": 1}
    refused(write(tmp_path / "bad.plan", fence(circles=[circle])), "geoFence.circles[0].inclusion is ")


def test_plan_inclusion_left_out_is_refused_not_guessed(tmp_path):
    plan = fence({"inclusion": True, "polygon": latlon(RING[:-1])}, {"polygon": latlon(INNER)})
    refused(write(tmp_path / "bad.plan", plan), "geoFence.polygons[1].inclusion is missing")


def test_plan_booleans_still_choose_area_and_no_fly(tmp_path):
    circle = {"circle": {"center": [LAT + 0.001, LON + 0.001], "radius": 20}, "inclusion": False}
    plan = fence(
        {"inclusion": True, "polygon": latlon(RING[:-1])},
        {"inclusion": False, "polygon": latlon(INNER)},
        circles=[circle],
    )
    area = load_area(write(tmp_path / "ok.plan", plan))
    assert area.sources == {"inclusion fence(s)": 1} and len(area.nofly) == 1 and len(area.nofly_circles) == 1


def test_cli_no_fly_written_as_the_string_false_exits_2_naming_the_field(tmp_path, capsys):
    plan = fence({"inclusion": True, "polygon": latlon(RING[:-1])}, {"inclusion": "false", "polygon": latlon(INNER)})
    path = write(tmp_path / "inclfalse.plan", plan)
    rc, err = cli(capsys, path, "--out", tmp_path / "out")
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert "inclfalse.plan" in lines[0] and 'geoFence.polygons[1].inclusion is "false" (a string)' in lines[0]
    assert not (tmp_path / "out").exists()


# --- 2. .plan numbers must be JSON numbers --------------------------------------------------------------


@pytest.mark.parametrize(
    "circle, field",
    [
        ({"center": [LAT, LON], "radius": "100"}, 'geoFence.circles[0].circle.radius is "100" (a string)'),
        ({"center": [LAT, LON], "radius": True}, "geoFence.circles[0].circle.radius is true (a boolean)"),
        ({"center": [LAT, LON], "radius": None}, "geoFence.circles[0].circle.radius is null, not a number"),
        ({"center": [LAT, LON], "radius": [100]}, "geoFence.circles[0].circle.radius is [100] (an array)"),
        ({"center": [str(LAT), LON], "radius": 100}, 'geoFence.circles[0].circle.center[0] is "41.876"'),
        ({"center": [LAT, False], "radius": 100}, "geoFence.circles[0].circle.center[1] is false (a boolean)"),
        ({"center": "x", "radius": 100}, 'geoFence.circles[0].circle.center is "x" (a string), not [lat, lon]'),
        ({"center": [LAT], "radius": 100}, "geoFence.circles[0].circle.center is [41.876]"),
        ({"center": [LAT, LON]}, 'geoFence.circles[0] needs "circle"'),
    ],
)
def test_plan_circle_numbers_must_be_json_numbers(tmp_path, circle, field):
    plan = fence(circles=[{"circle": circle, "inclusion": True}])
    refused(write(tmp_path / "bad.plan", plan), field)


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity", "1" + "0" * 400])
def test_plan_radius_must_be_finite(tmp_path, literal):
    path = tmp_path / "bad.plan"
    text = json.dumps(fence(circles=[{"circle": {"center": [LAT, LON], "radius": 12345.5}, "inclusion": True}]))
    path.write_text(text.replace("12345.5", literal))
    refused(path, "geoFence.circles[0].circle.radius is ")


def test_plan_radius_may_be_an_integer(tmp_path):
    plan = fence(circles=[{"circle": {"center": [LAT, LON], "radius": 100}, "inclusion": True}])
    assert load_area(write(tmp_path / "ok.plan", plan)).sources == {"inclusion circle(s)": 1}


def test_cli_radius_as_a_string_exits_2(tmp_path, capsys):
    plan = fence(circles=[{"circle": {"center": [LAT, LON], "radius": "100"}, "inclusion": True}])
    rc, err = cli(capsys, write(tmp_path / "strradius.plan", plan), "--out", tmp_path / "out")
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert "strradius.plan" in lines[0] and "geoFence.circles[0].circle.radius" in lines[0]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(k=st.integers(0, 3), c=st.integers(0, 1), value=NOT_NUMBERS)
def test_any_non_number_in_a_plan_polygon_is_refused_with_its_path(tmp_path, k, c, value):
    ring = latlon(RING[:-1])
    ring[k][c] = value
    path = write(tmp_path / "bad.plan", fence({"inclusion": True, "polygon": ring}))
    refused(path, f"geoFence.polygons[0].polygon[{k}][{c}] is ")


# --- 3. GeoJSON coordinates must be JSON numbers ---------------------------------------------------------


@pytest.mark.parametrize(
    "obj, field",
    [
        ({"type": "Polygon", "coordinates": [[[str(LON), LAT], *RING[1:]]]}, 'coordinates[0][0][0] is "-87.632"'),
        ({"type": "Polygon", "coordinates": [[[True, LAT], *RING[1:]]]}, "coordinates[0][0][0] is true (a boolean)"),
        ({"type": "Polygon", "coordinates": [[*RING[:3], [LON, None], RING[4]]]}, "coordinates[0][3][1] is null"),
        ({"type": "Polygon", "coordinates": [[*RING[:2], [LON, LAT, "10"], *RING[3:]]]}, "coordinates[0][2][2]"),
        ({"type": "Polygon", "coordinates": [[*RING[:2], "12", *RING[3:]]]}, 'coordinates[0][2] is "12" (a string)'),
        ({"type": "Polygon", "coordinates": [[*RING[:2], [LON], *RING[3:]]]}, "coordinates[0][2] is [-87.632]"),
        ({"type": "Polygon", "coordinates": ["abc"]}, 'coordinates[0] is "abc" (a string)'),
        ({"type": "MultiPolygon", "coordinates": [[RING], [[*RING[:4], [LON, {}]]]]}, "coordinates[1][0][4][1] is {}"),
        (
            {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [RING, [["x", 1]]]}},
            "geometry.coordinates[1][0][0]",
        ),
        (
            {
                "type": "FeatureCollection",
                "features": [
                    feature(shapely.Polygon(RING)),
                    {"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [[*RING[:3], [LON, "41.8"]]]}},
                ],
            },
            "features[1].geometry.coordinates[0][3][1]",
        ),
        (
            {"type": "GeometryCollection", "geometries": [{"type": "Polygon", "coordinates": [[[False, LAT]]]}]},
            "geometries[0].coordinates[0][0][0] is false",
        ),
        ({"type": "GeometryCollection", "geometries": "abc"}, 'geometries is "abc" (a string)'),
    ],
)
def test_geojson_coordinates_must_be_json_numbers(tmp_path, obj, field):
    refused(write(tmp_path / "bad.geojson", obj), field)


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity", "1e999", "1" + "0" * 400])
def test_geojson_coordinates_must_be_finite(tmp_path, literal):
    path = tmp_path / "bad.geojson"
    path.write_text(
        json.dumps({"type": "Polygon", "coordinates": [[[12345.5, LAT], *RING[1:]]]}).replace("12345.5", literal)
    )
    text = refused(path, "coordinates[0][0][0] is ")
    assert "NaN or infinity" in text


@pytest.mark.parametrize(
    "position, message",
    [
        ([-180.5, LAT], "longitude -180.5 (at coordinates[0][1]) is beyond +-180"),
        ([LON, 90.5], "latitude 90.5 (at coordinates[0][1]) is beyond +-90"),
    ],
)
def test_geojson_ranges_name_the_position(tmp_path, position, message):
    refused(
        write(tmp_path / "bad.geojson", {"type": "Polygon", "coordinates": [[RING[0], position, *RING[2:]]]}), message
    )


def test_integer_coordinates_and_altitudes_are_numbers(tmp_path):
    ring = [[4, 45, 0], [5, 45, 10], [5, 46, 0.5], [4, 45, 0]]
    assert lonlat_ring(ring, Path("a.geojson"), "g").tolist() == [[4.0, 45.0], [5.0, 45.0], [5.0, 46.0], [4.0, 45.0]]


def test_cli_string_coordinates_exit_2_naming_the_value(tmp_path, capsys):
    path = write(tmp_path / "strnum.geojson", {"type": "Polygon", "coordinates": [[[str(v) for v in p] for p in RING]]})
    rc, err = cli(capsys, path, "--out", tmp_path / "out")
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert "strnum.geojson" in lines[0] and 'coordinates[0][0][0] is "-87.632" (a string)' in lines[0]
    assert "without quotes" in lines[0]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(k=st.integers(0, 4), c=st.integers(0, 1), value=NOT_NUMBERS, buildings=st.booleans())
def test_any_non_number_in_a_coordinate_position_is_refused_with_its_path(tmp_path, k, c, value, buildings):
    ring = [list(p) for p in RING]
    ring[k][c] = value
    path = write_geojson(
        tmp_path / "bad.geojson",
        feature(to_lonlat(shapely.box(0, 0, 50, 50))),
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [ring]}},
    )
    field = f"features[1].geometry.coordinates[0][{k}][{c}] is "
    if buildings:  # building footprints go through the same reader
        from swarmctl.geo.buildings import load_buildings

        with pytest.raises(InputError, match="bad.geojson: .*" + re.escape(field)):
            load_buildings(path)
    else:
        refused(path, field)


@settings(max_examples=60, deadline=None)
@given(
    lon=st.one_of(st.integers(-179, 178), st.floats(-179.0, 178.0)),
    lat=st.one_of(st.integers(-84, 83), st.floats(-84.0, 83.0)),
)
def test_any_finite_int_or_float_in_range_is_accepted(lon, lat):
    ring = [[lon, lat], [lon + 1, lat], [lon + 1, lat + 1], [lon, lat]]
    assert lonlat_ring(ring, Path("a.geojson"), "g", json_path="coordinates[0]").shape == (4, 2)


# --- no-fly flags in GeoJSON properties --------------------------------------------------------------------


@pytest.mark.parametrize(
    "value, nofly", [(True, 1), (1, 1), ("yes", 1), ("TRUE", 1), (False, 0), (0, 0), ("no", 0), (None, 0)]
)
def test_geojson_nofly_flags_read(tmp_path, value, nofly):
    path = write_geojson(
        tmp_path / "a.geojson",
        feature(to_lonlat(shapely.box(0, 0, 60, 60))),
        feature(to_lonlat(shapely.box(20, 20, 40, 40)), nofly=value),
    )
    area = load_area(path)
    assert len(area.nofly) == nofly and len(area.polygons) == 1


@pytest.mark.parametrize("value", ["maybe", 2, 0.5, [], {"a": 1}])
def test_geojson_nofly_flag_that_is_not_a_boolean_is_refused(tmp_path, value):
    path = write_geojson(
        tmp_path / "bad.geojson",
        feature(to_lonlat(shapely.box(0, 0, 60, 60))),
        feature(to_lonlat(shapely.box(20, 20, 40, 40)), nofly=value),
    )
    refused(path, 'features[1].properties["nofly"] is ')


# --- 4. degenerate areas -------------------------------------------------------------------------------------


def area_of(tmp_path, geom_metres) -> Path:
    return write_geojson(tmp_path / "thin.geojson", feature(to_lonlat(geom_metres)))


@pytest.mark.parametrize(
    "box, cell, message",
    [
        ((0, 0, 0.0001, 0.0001), 10.0, "0.1 mm x 0.1 mm"),  # 0.1 mm across
        ((0, 0, 8000, 0.0011), 10.0, "8 km x "),  # the audit's sliver (416 "free" cells before)
        ((0, 0, 9, 100), 10.0, "9 m x 100 m"),
        ((0, 0, 100, 9.5), 10.0, "100 m x 9.5 m"),
    ],
)
def test_an_area_narrower_than_a_cell_is_refused(tmp_path, box, cell, message):
    area = load_area(area_of(tmp_path, shapely.box(*box)))
    for rotate in (False, True):
        with pytest.raises(InputError, match=f"thin.geojson: the area measures {message}.*smaller than one 10 m cell"):
            make_grid(area, cell=cell, rotate=rotate)


def test_the_message_proposes_a_cell_that_fits(tmp_path):
    area = load_area(area_of(tmp_path, shapely.box(0, 0, 9, 100)))
    with pytest.raises(InputError, match=r"a larger area \(check its coordinates\) or a --cell of at most (8\.99|9)\b"):
        make_grid(area, cell=10.0)
    grid, _ = make_grid(area, cell=4.5)
    assert (grid.width, grid.height) == (2, 23) and not grid.blocked.all()


def test_an_area_smaller_than_a_cell_is_refused_even_when_spread_out(tmp_path):
    specks = shapely.MultiPolygon([shapely.box(0, 0, 3, 3), shapely.box(500, 500, 503, 503)])  # 18 m2 over 500 m
    with pytest.raises(InputError, match=r"\(18 square metres\), smaller than one 10 m cell \(100 square metres\)"):
        make_grid(load_area(area_of(tmp_path, specks)), cell=10.0)


def test_a_diagonal_sliver_is_refused_by_its_area(tmp_path):
    sliver = shapely.LineString([(0, 0), (5000, 5000)]).buffer(0.0005, cap_style="flat")
    with pytest.raises(InputError, match="smaller than one 10 m cell"):
        make_grid(load_area(area_of(tmp_path, sliver)), cell=10.0)


def test_an_area_of_exactly_one_cell_still_plans(tmp_path):
    grid, _ = make_grid(load_area(area_of(tmp_path, shapely.box(0, 0, 10, 10))), cell=10.0)
    assert (grid.width, grid.height) == (1, 1) and not grid.blocked.any()


def test_cli_sliver_exits_2_with_the_size_and_the_fix(tmp_path, capsys):
    path = write(
        tmp_path / "sliver.geojson",
        {"type": "Polygon", "coordinates": [[[LON, LAT], [LON + 0.1, LAT], [LON + 0.1, LAT + 1e-8], [LON, LAT]]]},
    )
    rc, err = cli(capsys, path, "--out", tmp_path / "out")
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert "sliver.geojson: the area measures 8.3 km x 1.11 mm" in lines[0] and "give a larger area" in lines[0]
    assert not (tmp_path / "out").exists()


def test_cli_tiny_circle_exits_2(tmp_path, capsys):
    plan = fence(circles=[{"circle": {"center": [LAT, LON], "radius": 0.001}, "inclusion": True}])
    rc, err = cli(capsys, write(tmp_path / "tinycircle.plan", plan), "--out", tmp_path / "out")
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "2 mm x 2 mm" in err, err


@settings(max_examples=40, deadline=None)
@example(w=400.0, h=291.0, cell=5.0)  # the turned box holds one column more than an upright one would
@given(w=st.floats(0.001, 400.0), h=st.floats(0.001, 400.0), cell=st.sampled_from([1.0, 5.0, 10.0, 25.0]))
def test_a_box_plans_iff_it_is_a_cell_a_side_and_then_it_has_a_free_cell(w, h, cell):
    assume(abs(min(w, h) / cell - 1.0) > 0.01)  # clear of the rounding tolerance
    from swarmctl.geo.areas import Area

    area = Area(to_lonlat(shapely.box(0, 0, w, h)), name="box")
    if min(w, h) < cell:
        with pytest.raises(InputError, match="box: the area measures .* smaller than one"):
            make_grid(area, cell=cell)
        return
    grid, _ = make_grid(area, cell=cell)
    free = grid.width * grid.height - len(blocked_cells(grid))
    assert free >= 1
    # The grid's own projection turns the box a little, so free cells are lattice points in a turned
    # rectangle: at most area + perimeter / 2 + 1 of them, in cells (Nosarzewska's bound for convex sets).
    assert free <= (w / cell + 1) * (h / cell + 1)
    # Each free cell's centre lies inside the box.
    xs, ys = np.nonzero(~grid.blocked)
    lat, lon = grid.cells_to_latlon(xs, ys)
    e, n = PROJ.to_metres(lon, lat)
    assert np.all((e >= -1e-6) & (e <= w + 1e-6) & (n >= -1e-6) & (n <= h + 1e-6))


def test_a_dollar_in_an_area_file_name_is_drawn_as_written(tmp_path, capsys):
    path = area_of(tmp_path, shapely.box(0, 0, 100, 100))
    odd = path.rename(tmp_path / "park $\\undefinedcmd{x}$.geojson")  # mathtext matplotlib cannot parse
    rc, err = cli(capsys, odd, "--out", tmp_path / "out")
    assert rc == 0, err
    assert (tmp_path / "out" / "preview.png").stat().st_size > 0


def test_a_kml_placemark_name_is_quoted_short_and_printable_in_a_warning(tmp_path, capsys):
    name = "evil\u202e" * 2000  # right-to-left overrides, 10,000 characters
    ring = [(LON, LAT), (LON + 0.01, LAT + 0.01), (LON + 0.01, LAT), (LON, LAT + 0.01), (LON, LAT)]  # a bow tie
    coords = " ".join(f"{x},{y}" for x, y in ring)
    kml = tmp_path / "bowtie.kml"
    kml.write_text(
        '<kml xmlns="http://www.opengis.net/kml/2.2"><Placemark>'
        f"<name>{name}</name><Polygon><outerBoundaryIs><LinearRing><coordinates>{coords}</coordinates>"
        "</LinearRing></outerBoundaryIs></Polygon></Placemark></kml>",
        encoding="utf-8",
    )
    rc, err = cli(capsys, kml, "--out", tmp_path / "out")
    warning = [line for line in err.splitlines() if "invalid polygon" in line]
    assert rc == 0 and len(warning) == 1, err
    assert warning[0].isprintable() and "\u202e" not in warning[0] and len(warning[0]) < 600, warning[0]
    assert "Placemark 0 (evil\\u202eevil" in warning[0]
