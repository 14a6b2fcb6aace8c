"""Area files: GeoJSON shapes, KML, QGroundControl .plan in and out."""

from __future__ import annotations

import json

import numpy as np
import pytest
import shapely

from swarmctl.errors import InputError
from swarmctl.geo.areas import Area, Circle
from swarmctl.geo.grid import make_grid
from swarmctl.geo.load import load_area
from swarmctl.geo.plan_io import plan_dict, read_plan, write_plan
from tests.geo_helpers import DATA, PROJ, blocked_cells, feature, to_lonlat, write_geojson

SQUARE_60 = shapely.box(0, 0, 60, 60)
HOLED = shapely.Polygon(SQUARE_60.exterior, [shapely.box(20, 20, 40, 40).exterior])


def _kml_coords(ring) -> str:
    return " ".join(f"{x!r},{y!r},0" for x, y in ring.coords)


def kml_text(polygons, nofly=()) -> str:
    """A KML document (with the usual namespace) of Placemarks."""

    def placemark(name, poly):
        inner = "".join(
            f"<innerBoundaryIs><LinearRing><coordinates>{_kml_coords(r)}</coordinates></LinearRing></innerBoundaryIs>"
            for r in poly.interiors
        )
        return (
            f"<Placemark><name>{name}</name><Polygon><outerBoundaryIs><LinearRing><coordinates>"
            f"{_kml_coords(poly.exterior)}</coordinates></LinearRing></outerBoundaryIs>{inner}</Polygon></Placemark>"
        )

    body = "".join(placemark(f"area {i}", p) for i, p in enumerate(polygons))
    body += "".join(placemark(f"No-fly {i}", p) for i, p in enumerate(nofly))
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n<kml xmlns="http://www.opengis.net/kml/2.2">'
        f"<Document><name>test</name>{body}</Document></kml>"
    )


def test_geojson_shapes_all_read(tmp_path):
    geom = shapely.geometry.mapping(to_lonlat(HOLED))
    multi = shapely.geometry.mapping(to_lonlat(shapely.MultiPolygon([HOLED])))
    for i, obj in enumerate(
        [
            geom,
            multi,
            {"type": "Feature", "properties": {}, "geometry": geom},
            {"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": geom}]},
            {"type": "GeometryCollection", "geometries": [geom]},
        ]
    ):
        path = tmp_path / f"a{i}.geojson"
        path.write_text(json.dumps(obj))
        area = load_area(path)
        assert len(area.polygons) == 1 and len(area.holes) == 1, obj["type"]
        assert blocked_cells(make_grid(area, cell=10.0)[0]) == {(2, 2), (2, 3), (3, 2), (3, 3)}


def test_wgs84_crs_members_are_accepted(tmp_path):
    for name in ("urn:ogc:def:crs:OGC:1.3:CRS84", "EPSG:4326", "urn:ogc:def:crs:EPSG::4326"):
        path = write_geojson(
            tmp_path / "a.geojson", feature(to_lonlat(SQUARE_60)), crs={"type": "name", "properties": {"name": name}}
        )
        assert len(load_area(path).polygons) == 1


def test_kml_outer_inner_boundaries_and_no_fly_placemark(tmp_path):
    path = tmp_path / "area.kml"
    path.write_text(kml_text([to_lonlat(HOLED)], nofly=[to_lonlat(shapely.box(42, 2, 48, 8))]))
    area = load_area(path)
    assert len(area.polygons) == 1 and len(area.holes) == 1 and len(area.nofly) == 1
    grid, _ = make_grid(area, cell=10.0)
    assert blocked_cells(grid) == {(2, 2), (2, 3), (3, 2), (3, 3), (4, 0)}


def test_kml_multigeometry_and_no_namespace(tmp_path):
    a, b = to_lonlat(shapely.box(0, 0, 20, 60)), to_lonlat(shapely.box(40, 0, 60, 60))
    path = tmp_path / "multi.kml"
    path.write_text(
        "<kml><Placemark><MultiGeometry>"
        + "".join(
            f"<Polygon><outerBoundaryIs><LinearRing><coordinates>{_kml_coords(p.exterior)}</coordinates>"
            "</LinearRing></outerBoundaryIs></Polygon>"
            for p in (a, b)
        )
        + "</MultiGeometry></Placemark></kml>"
    )
    area = load_area(path)
    assert len(area.polygons) == 2
    assert blocked_cells(make_grid(area, cell=10.0)[0]) == {(x, y) for x in (2, 3) for y in range(6)}


@pytest.mark.parametrize(
    "text, message",
    [
        ("<kml><Placemark><Polygon>", "not valid KML/XML"),
        (
            "<kml><Placemark><name>x</name><Point><coordinates>4.85,45.77</coordinates></Point></Placemark></kml>",
            "contains no area polygon",
        ),
        (
            "<kml><Polygon><outerBoundaryIs><LinearRing><coordinates>a,b c,d</coordinates></LinearRing>"
            "</outerBoundaryIs></Polygon></kml>",
            "must be 'lon,lat",
        ),
        (
            "<kml><Polygon><outerBoundaryIs><LinearRing><coordinates>45.7,4.8 45.8,4.8 45.8,94.9 45.7,4.8"
            "</coordinates></LinearRing></outerBoundaryIs></Polygon></kml>",
            "beyond \\+-90",
        ),
    ],
)
def test_kml_errors(tmp_path, text, message):
    path = tmp_path / "bad.kml"
    path.write_text(text)
    with pytest.raises(InputError, match=f"bad.kml.*{message}"):
        load_area(path)


def plan_area() -> Area:
    lon, lat = PROJ.to_lonlat(45.0, 45.0)
    return Area(
        to_lonlat(HOLED),
        nofly=[to_lonlat(shapely.box(2, 42, 8, 58))],
        nofly_circles=[Circle(float(lat), float(lon), 6.0)],
        name="holed",
    )


def test_plan_written_is_a_qgc_plan():
    plan = plan_dict(plan_area())
    assert (plan["fileType"], plan["version"], plan["groundStation"]) == ("Plan", 1, "QGroundControl")
    fence = plan["geoFence"]
    assert fence["version"] == 2
    assert [p["inclusion"] for p in fence["polygons"]] == [True, False, False]
    assert all(len(p["polygon"]) == 4 for p in fence["polygons"])  # rings stored open, as QGC does
    assert fence["circles"][0]["inclusion"] is False and fence["circles"][0]["circle"]["radius"] == 6.0
    assert plan["mission"]["items"] == [] and len(plan["mission"]["plannedHomePosition"]) == 3
    assert plan["rallyPoints"] == {"points": [], "version": 2}
    lat, lon = fence["polygons"][0]["polygon"][0]
    assert 45 < lat < 46 and 4 < lon < 5  # [lat, lon] order


def test_plan_round_trip(tmp_path):
    area = plan_area()
    back = read_plan(write_plan(area, tmp_path / "area.plan"))
    assert back.outline.equals_exact(area.outline, 1e-12)
    assert len(back.nofly) == 2 and back.nofly_circles == area.nofly_circles  # the hole became an exclusion
    assert shapely.union_all(back.nofly).equals(shapely.union_all(area.holes + area.nofly))
    grid_a, _ = make_grid(area, cell=10.0)
    grid_b, _ = make_grid(back, cell=10.0)
    assert np.array_equal(grid_a.blocked, grid_b.blocked)
    assert blocked_cells(grid_a) == {(2, 2), (2, 3), (3, 2), (3, 3), (0, 4), (0, 5), (4, 4)}
    # Writing what was read gives the same file again.
    again = write_plan(back, tmp_path / "again.plan")
    assert json.loads(again.read_text())["geoFence"] == json.loads((tmp_path / "area.plan").read_text())["geoFence"]


def test_real_qgc_geofence_plan():
    area = read_plan(DATA / "qgc_ce_geofence_outfield.plan")
    assert len(area.polygons) == 1 and len(area.nofly) == 1
    assert area.sources == {"inclusion fence(s)": 1}
    assert -77.5 < area.geometry.centroid.x < -77.49 and 38.75 < area.geometry.centroid.y < 38.76


def test_real_survey_plan_area_is_the_survey_polygon():
    area = read_plan(DATA / "mavsdk_qgc_sample_with_survey.plan")
    assert area.sources == {"survey polygon(s)": 1}
    assert len(area.geometry.exterior.coords) == 5
    assert 8.545 < area.geometry.centroid.x < 8.547 and 47.397 < area.geometry.centroid.y < 47.398


def test_plan_inclusion_circle_is_area(tmp_path):
    lon, lat = PROJ.to_lonlat(0.0, 0.0)
    plan = {
        "fileType": "Plan",
        "version": 1,
        "geoFence": {
            "polygons": [],
            "version": 2,
            "circles": [
                {"circle": {"center": [float(lat), float(lon)], "radius": 100.0}, "inclusion": True, "version": 1}
            ],
        },
    }
    path = tmp_path / "circle.plan"
    path.write_text(json.dumps(plan))
    area = read_plan(path)
    assert area.sources == {"inclusion circle(s)": 1}
    assert PROJ.geometry_to_metres(area.geometry).area == pytest.approx(np.pi * 100**2, rel=0.01)


@pytest.mark.parametrize(
    "plan, message",
    [
        ({"fileType": "Mission"}, "not a QGroundControl plan"),
        ({"fileType": "Plan", "geoFence": {"polygons": [], "circles": []}}, "contains no area polygon"),
        (
            {
                "fileType": "Plan",
                "geoFence": {
                    "polygons": [
                        {"inclusion": True, "polygon": [[149.165, -35.363], [149.166, -35.363], [149.166, -35.362]]}
                    ]
                },
            },
            "beyond \\+-90.*swap",
        ),
        ({"fileType": "Plan", "geoFence": {"circles": [{"circle": {"center": [38.7, -77.4]}}]}}, "radius"),
        (
            {"fileType": "Plan", "geoFence": {"circles": [{"circle": {"center": [38.7, -77.4], "radius": -1}}]}},
            "must be > 0",
        ),
        (
            {"fileType": "Plan", "geoFence": {"circles": [{"circle": {"center": [38.7, -77.4], "radius": 1e308}}]}},
            "below 1000 km",
        ),
        ({"fileType": "Plan", "geoFence": {"polygons": True}}, '"polygons" must be a list'),
        ({"fileType": "Plan", "mission": {"items": 3}}, '"items" must be a list'),
    ],
)
def test_plan_errors(tmp_path, plan, message):
    path = tmp_path / "bad.plan"
    path.write_text(json.dumps(plan))
    with pytest.raises(InputError, match=f"bad.plan.*{message}"):
        load_area(path)
