"""`swarmctl plan` on the real files: the copied ones always, the shared collection when present."""

from __future__ import annotations

import json

import numpy as np
import pytest

from swarmctl.cli import main
from swarmctl.geo.grid import GeoGrid
from tests.geo_helpers import DATA, REPO

SHARED = REPO.parent / "shared" / "data"
MISSION = REPO / "missions" / "chicago-loop"
SAMPLE = DATA / "chicago_loop_osm_sample10.geojson"


def plan(capsys, *args):
    rc = main(["plan", *map(str, args)])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return rc, out, err


def polygon_files(folder):
    return sorted(p for p in folder.rglob("*") if p.suffix in (".geojson", ".plan", ".kml"))


@pytest.mark.parametrize("name", [p.name for p in polygon_files(DATA)])
def test_plan_runs_on_every_copied_file(tmp_path, capsys, name):
    rc, out, err = plan(capsys, DATA / name, "--cell", "20", "--out", tmp_path)
    assert rc == 0, err
    grid = GeoGrid.load(tmp_path / "grid.npz")
    assert 0 < grid.blocked.sum() < grid.blocked.size or name.startswith("mavsdk")
    assert f"grid: {grid.width} x {grid.height}" in out
    assert (tmp_path / "preview.png").stat().st_size > 1000


def test_loop_with_building_sample(tmp_path, capsys):
    rc, out, err = plan(
        capsys,
        DATA / "chicago_loop_neighborhood.geojson",
        "--buildings",
        SAMPLE,
        "--cell",
        "20",
        "--rotate",
        "--out",
        tmp_path,
    )
    assert rc == 0, err
    assert "10 in file, 10 in the area: 7 >= 40 m (obstacles), 0 below 40 m, 3 of unknown height (obstacles)" in out
    rc, out, _ = plan(
        capsys,
        DATA / "chicago_loop_neighborhood.geojson",
        "--buildings",
        SAMPLE,
        "--cell",
        "20",
        "--unknown-height",
        "ignore",
        "--out",
        tmp_path / "ignore",
    )
    assert "7 >= 40 m (obstacles), 0 below 40 m, 3 of unknown height (ignored)" in out


def test_helsinki_levels_and_unknown_heights(tmp_path, capsys):
    square = tmp_path / "helsinki_square.geojson"
    square.write_text(
        json.dumps(
            {
                "type": "Polygon",
                "coordinates": [
                    [[24.9352, 60.1642], [24.9534, 60.1642], [24.9534, 60.1790], [24.9352, 60.1790], [24.9352, 60.1642]]
                ],
            }
        )
    )
    rc, out, err = plan(
        capsys,
        square,
        "--buildings",
        DATA / "helsinki_centre_osm_buildings.geojson",
        "--cell",
        "20",
        "--out",
        tmp_path / "block",
    )
    assert rc == 0, err
    # 154 footprints have a height or a level count, 292 neither.
    assert (
        "buildings: 446 in file, 446 in the area: 5 >= 40 m (obstacles), 149 below 40 m, 292 of unknown height" in out
    )
    rc, out, err = plan(
        capsys,
        square,
        "--buildings",
        DATA / "helsinki_centre_osm_buildings.geojson",
        "--cell",
        "20",
        "--unknown-height",
        "ignore",
        "--altitude",
        "30",
        "--out",
        tmp_path / "ign",
    )
    assert rc == 0, err
    blocking = int(out.split("in the area: ")[1].split(" >= 30 m")[0])
    assert blocking > 2  # at 30 m, the buildings of 8+ levels (4 m each) block too


def test_chicago_mission_is_committed_and_reproducible(tmp_path, capsys):
    grid = GeoGrid.load(MISSION / "grid.npz")
    assert (grid.width, grid.height, grid.cell, grid.altitude) == (50, 50, 10.0, 40.0)
    assert 0.05 < grid.blocked_fraction < 0.2
    for name in ("area.geojson", "grid.geojson", "area.plan", "preview.png", "README.md"):
        assert (MISSION / name).is_file(), name
    rc, out, err = plan(capsys, MISSION / "area.geojson", "--buildings", SAMPLE, "--out", tmp_path)
    assert rc == 0, err
    again = GeoGrid.load(tmp_path / "grid.npz")
    assert np.array_equal(again.blocked, grid.blocked) and again.origin == pytest.approx(grid.origin)
    assert f"{100 * grid.blocked_fraction:.1f} %" in (MISSION / "README.md").read_text()


@pytest.mark.skipif(not SHARED.is_dir(), reason="the shared data collection is not next to the repository")
@pytest.mark.parametrize("name", [str(p.relative_to(SHARED)) for p in polygon_files(SHARED)] if SHARED.is_dir() else [])
def test_plan_runs_on_every_shared_file(tmp_path, capsys, name):
    cell = "25" if "groenland" in name else "10"  # a 27 km2 area: 10 m cells exceed --max-cells
    rc, out, err = plan(capsys, SHARED / name, "--cell", cell, "--out", tmp_path)
    if name.startswith("logs/") and "targets" in name:  # a mission's found targets: points, no area
        assert rc == 2 and "contains no area polygon" in err, err
        return
    assert rc == 0, err
    assert GeoGrid.load(tmp_path / "grid.npz").width > 0
