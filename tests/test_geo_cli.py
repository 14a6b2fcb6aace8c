"""`swarmctl plan`: outputs, summary, and every bad input as one line on stderr with exit status 2."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import numpy as np
import pytest
import shapely

from swarmctl.cli import main
from swarmctl.geo.grid import GeoGrid
from swarmctl.geo.plan_io import read_plan
from tests.geo_helpers import REPO, feature, to_lonlat, write_geojson

SQUARE = shapely.box(0, 0, 200, 100)


@pytest.fixture
def area_file(tmp_path):
    return write_geojson(tmp_path / "area.geojson", feature(to_lonlat(SQUARE)))


def plan(capsys, *args):
    rc = main(["plan", *map(str, args)])
    out, err = capsys.readouterr()
    return rc, out, err


def test_plan_writes_grid_geojson_plan_and_preview(tmp_path, area_file, capsys):
    tower = to_lonlat(shapely.box(52, 52, 58, 58))
    shed = to_lonlat(shapely.box(112, 12, 118, 18))
    far = to_lonlat(shapely.box(1000, 1000, 1010, 1010))
    buildings = write_geojson(
        tmp_path / "b.geojson",
        feature(tower, height="60 m"),
        feature(shed, **{"building:levels": "2"}),
        feature(far, height=99),
    )
    out_dir = tmp_path / "out"
    rc, out, err = plan(capsys, area_file, "--buildings", buildings, "--out", out_dir)
    assert rc == 0, err
    assert "grid: 20 x 10 = 200 cells of 10 m" in out
    assert "blocked: 1 cells (0.5 %)" in out
    assert (
        "3 in file, 2 in the area: 1 >= 40 m (obstacles), 1 below 40 m, 0 of unknown height (obstacles); "
        "1 outside the area ignored" in out
    )
    assert "largest connected free region: 199 cells" in out
    assert err == ""
    grid = GeoGrid.load(out_dir / "grid.npz")
    assert (grid.width, grid.height) == (20, 10) and grid.blocked[5, 5] and grid.blocked.sum() == 1
    cells = json.loads((out_dir / "grid.geojson").read_text())["features"]
    assert len(cells) == 200
    blocked = [c["properties"] for c in cells if c["properties"]["blocked"]]
    assert blocked == [{"x": 5, "y": 5, "blocked": True}]
    ring = np.array(cells[0]["geometry"]["coordinates"][0])
    assert ring.shape == (5, 2) and 4 < ring[0, 0] < 5 and 45 < ring[0, 1] < 46  # lon, lat
    assert len(read_plan(out_dir / "area.plan").polygons) == 1
    assert (out_dir / "preview.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_unreachable_free_cells_are_warned(tmp_path, capsys):
    wall = to_lonlat(shapely.box(50, 0, 60, 100))
    path = write_geojson(tmp_path / "walled.geojson", feature(to_lonlat(SQUARE)), feature(wall, nofly=True))
    rc, out, err = plan(capsys, path, "--out", tmp_path / "out")
    assert rc == 0
    assert "largest connected free region: 140 cells" in out and "2 free region(s)" in out
    assert "warning: 50 free cell(s)" in err and "cannot be reached" in err


def test_self_intersecting_polygon_is_repaired_with_a_warning(tmp_path, capsys):
    bowtie = {
        "type": "Polygon",
        "coordinates": [
            [
                list(map(float, p))
                for p in to_lonlat(shapely.LineString([(0, 0), (100, 100), (100, 0), (0, 100), (0, 0)])).coords
            ]
        ],
    }
    path = tmp_path / "bowtie.geojson"
    path.write_text(json.dumps(bowtie))
    rc, out, err = plan(capsys, path, "--out", tmp_path / "out")
    assert rc == 0
    assert "bowtie.geojson" in err and "Self-intersection" in err and "make_valid" in err
    assert "grid: 10 x 10" in out


def test_plan_help_lists_the_options(capsys):
    assert main(["plan", "--help"]) == 0
    out = capsys.readouterr().out
    for option in (
        "--buildings",
        "--cell",
        "--altitude",
        "--margin",
        "--rotate",
        "--unknown-height",
        "--max-cells",
        "--out",
    ):
        assert option in out


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


def _lonlat_square():
    return [[list(map(float, p)) for p in to_lonlat(SQUARE).exterior.coords]]


BAD_AREAS = {
    "malformed JSON": ("broken.geojson", '{"type": "FeatureCollection", "features": [', "not valid JSON"),
    "malformed KML": ("broken.kml", "<kml><Document><Placemark>", "not valid KML/XML"),
    "malformed plan": ("broken.plan", "{fileType: Plan}", "not valid JSON"),
    "no polygon": (
        "points.geojson",
        json.dumps({"type": "Point", "coordinates": [4.85, 45.77]}),
        "contains no area polygon",
    ),
    "empty collection": ("empty.geojson", '{"type": "FeatureCollection", "features": []}', "contains no area polygon"),
    "not GeoJSON": ("list.json", "[1, 2, 3]", "not a GeoJSON object"),
    "lat/lon swapped": (
        "swapped.geojson",
        json.dumps(
            {
                "type": "Polygon",
                "coordinates": [[[-35.363, 149.165], [-35.363, 149.166], [-35.362, 149.166], [-35.363, 149.165]]],
            }
        ),
        "latitude 149.16.* is beyond \\+-90.*swap",
    ),
    "non-WGS84 crs": (
        "feet.geojson",
        json.dumps(
            {
                "type": "FeatureCollection",
                "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::3435"}},
                "features": [],
            }
        ),
        "EPSG::3435.*must be WGS84.*reproject",
    ),
    "ring too short": (
        "short.geojson",
        json.dumps({"type": "Polygon", "coordinates": [[[4.8, 45.7], [4.9, 45.7]]]}),
        "not a polygon",
    ),
    "text coordinates": (
        "text.geojson",
        json.dumps({"type": "Polygon", "coordinates": [[["a", "b"]]]}),
        "not lists of numbers",
    ),
    "unknown extension": ("area.shp", "whatever", "unknown file type '.shp'"),
}


@pytest.mark.parametrize("case", BAD_AREAS, ids=list(BAD_AREAS))
def test_bad_area_files(tmp_path, capsys, case):
    name, text, message = BAD_AREAS[case]
    path = _write(tmp_path, name, text)
    rc, out, err = plan(capsys, path, "--out", tmp_path / "out")
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("swarmctl: error: ") and name in lines[0]
    assert re.search(message, lines[0]), lines[0]
    assert "Traceback" not in err and not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--cell", "0"], "'--cell': 0.0 is not in the range 0.01<=x<=10000"),
        (["--cell", "-5"], "'--cell': -5.0 is not in the range"),
        (["--cell", "nan"], "'--cell': 'nan' is not a finite number"),
        (
            ["--cell", "0.1", "--max-cells", "1000"],
            "area.geojson: the grid would be 200\\d x 100\\d = 2,00\\d,\\d+ cells of 0.1 m.*--max-cells",
        ),
        (["--max-cells", "100"], "20 x 10 = 200 cells of 10 m.*over the limit of 100"),
        (["--altitude", "0"], "'--altitude': 0.0 is not in the range"),
        (["--margin", "-1"], "'--margin': -1.0 is not in the range"),
        (["--margin", "40"], "--margin 40: the safety margin must be below --altitude"),
    ],
)
def test_bad_numbers(tmp_path, area_file, capsys, args, message):
    rc, out, err = plan(capsys, area_file, *args, "--out", tmp_path / "out")
    assert rc == 2
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert re.search(message, err), err


def test_missing_files(tmp_path, area_file, capsys):
    rc, _, err = plan(capsys, tmp_path / "nowhere.geojson", "--out", tmp_path / "out")
    assert rc == 2 and "nowhere.geojson: file not found" in err and len(err.strip().splitlines()) == 1
    rc, _, err = plan(capsys, area_file, "--buildings", tmp_path / "nobuildings.geojson", "--out", tmp_path / "o")
    assert rc == 2 and "nobuildings.geojson: file not found" in err


def test_every_cell_blocked_is_an_error(tmp_path, area_file, capsys):
    cover = write_geojson(tmp_path / "cover.geojson", feature(to_lonlat(shapely.box(-5, -5, 205, 105))))
    rc, _, err = plan(capsys, area_file, "--buildings", cover, "--out", tmp_path / "out")
    assert rc == 2 and "every cell" in err and "--unknown-height ignore" in err


def test_bad_buildings_file_swapped(tmp_path, area_file, capsys):
    path = _write(tmp_path, "bswap.geojson", BAD_AREAS["lat/lon swapped"][1])
    rc, _, err = plan(capsys, area_file, "--buildings", path, "--out", tmp_path / "out")
    assert rc == 2 and "bswap.geojson" in err and "swap" in err


def test_subprocess_exit_status_and_single_line(tmp_path):
    path = _write(tmp_path, "broken.kml", "<kml><Placemark>")
    proc = subprocess.run(
        [sys.executable, "-m", "swarmctl.cli", "plan", str(path), "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "broken.kml: not valid KML/XML" in proc.stderr
    assert "Traceback" not in proc.stderr and proc.stdout == ""
