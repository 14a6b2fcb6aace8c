"""Real logs replay: the ArduCopter and QuadPlane SITL tlogs (foreign), and a swarmctl recording flown
against real ArduCopter SITL, as a folder and as its bare tlog (tests/data/logs/SOURCES.md)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from swarmctl.cli import main
from swarmctl.replay.recording import load

LOGS = Path(__file__).resolve().parent / "data" / "logs"
COPTER = LOGS / "arducopter_sitl_guided_takeoff_120s.tlog"
PLANE = LOGS / "arduplane_quadplane_sitl_vtol.tlog"
SITL3 = LOGS / "sitl3-mission"
CMAC = (-35.3632, 149.1652)  # ArduPilot's default SITL home, Canberra


def _lines(out: Path) -> list[dict]:
    features = json.loads((out / "tracks.geojson").read_text())["features"]
    return [f for f in features if f["geometry"]["type"] == "LineString"]


@pytest.mark.parametrize(
    "log, modes", [(COPTER, {"STABILIZE", "GUIDED"}), (PLANE, {"QLOITER", "CIRCLE", "GUIDED", "QLAND"})]
)
def test_foreign_tlogs_replay_to_tracks_modes_plots_and_a_map_page(tmp_path, log, modes):
    out = tmp_path / "out"
    assert main(["replay", str(log), "--out", str(out), "--quiet"]) == 0
    replay = load(log)
    assert replay.kind == "tlog" and [v.name for v in replay.vehicles] == ["sysid1"]
    assert replay.knowledge is None and "fitted around the tracks" in replay.grid_note
    tel = replay.vehicles[0].telemetry
    assert modes == {m for _t, m in tel.modes}
    [track] = _lines(out)
    lon, lat = np.array(track["geometry"]["coordinates"])[:, :2].T
    assert abs(lat.mean() - CMAC[0]) < 0.01 and abs(lon.mean() - CMAC[1]) < 0.01
    for name in ("map.html", "distance.png", "link.png", "modes.png", "animation.gif", "summary.txt"):
        assert (out / name).stat().st_size > 0, name
    assert not (out / "explored.png").exists()  # no knowledge in a foreign log: no explored-cells plot
    g = replay.grid
    x, y = g.latlon_to_cells(tel.lat, tel.lon)
    assert g.in_grid(x, y).all()  # the fitted grid holds the whole track
    text = (out / "summary.txt").read_text()
    assert "knowledge: none" in text and "sysid1" in text


def test_the_copter_takes_off_and_the_plane_flies_far(tmp_path):
    copter, plane = load(COPTER).vehicles[0], load(PLANE).vehicles[0]
    assert copter.telemetry.alt.max() > 4.0 and copter.distance_m < 20
    assert plane.telemetry.alt.max() > 50 and plane.distance_m > 1000
    assert copter.hover  # it holds position at about 4.7 m
    assert [a for _t, a in copter.telemetry.armed] == [False, True]


def test_the_sitl_swarm_recording_replays_with_its_knowledge_from_the_tunnel_frames(tmp_path):
    out = tmp_path / "out"
    assert main(["replay", str(SITL3), "--out", str(out), "--quiet"]) == 0
    replay = load(SITL3)
    summary = json.loads((SITL3 / "summary.json").read_text())
    assert replay.frames == summary["steps"] + 1 and replay.knowledge.source == "tunnel"
    assert sorted(t.cell for t in replay.targets) == sorted(tuple(t["cell"]) for t in summary["targets_found"])
    assert [f["properties"]["vehicle"] for f in _lines(out)] == ["alpha", "bravo", "charlie"]
    for name in ("explored.png", "targets.png", "panels-step-0.png", f"panels-step-{summary['steps']}.png"):
        assert (out / name).is_file(), name
    # the vehicles' cells in the step lines are where their telemetry puts them at that step
    for v in replay.vehicles:
        ok = v.cells[:, 0] >= 0
        x, y = replay.grid.latlon_to_cells(v.lat[ok], v.lon[ok])
        assert np.mean((x == v.cells[ok, 0]) & (y == v.cells[ok, 1])) > 0.8


def test_a_bare_swarmctl_tlog_gets_its_grid_fitted_from_the_knowledge_messages(tmp_path):
    shutil.copy(SITL3 / "mission.tlog", tmp_path / "sitl3.tlog")
    bare = load(tmp_path / "sitl3.tlog")
    truth = load(SITL3)
    assert "fitted to the knowledge messages" in bare.grid_note
    assert (bare.grid.width, bare.grid.height) == (truth.grid.width, truth.grid.height)
    for cell in ((0, 0), (49, 49), (25, 10)):
        a, b = np.array(bare.grid.cell_to_latlon(*cell)), np.array(truth.grid.cell_to_latlon(*cell))
        assert np.abs(a - b).max() < 2e-5  # within about 2 m
    assert bare.knowledge is not None and sorted(t.cell for t in bare.targets) == sorted(t.cell for t in truth.targets)
    assert [v.name for v in load(tmp_path / "sitl3.tlog", ["2"]).vehicles] == ["sysid2"]


def test_buildings_given_to_the_replay_are_drawn_on_the_map_page(tmp_path, capsys):
    footprints = Path(__file__).resolve().parent.parent / "missions" / "data" / "chicago_loop_osm_sample10.geojson"
    out = tmp_path / "out"
    assert main(["replay", str(SITL3), "--out", str(out), "--quiet", "--buildings", str(footprints)]) == 0
    html = (out / "map.html").read_text()
    data = json.loads(html.split('id="replay-data">', 1)[1].split("</script>", 1)[0])
    assert len(data["buildings"]) == 10  # the sample's ten footprints overlap the Chicago grid
    assert main(["replay", str(SITL3), "--out", str(out), "--quiet", "--buildings", str(tmp_path / "no.geojson")]) == 2
    assert "--buildings" in capsys.readouterr().err
