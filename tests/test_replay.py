"""`swarmctl replay` on a fresh demo recording: every output, the recording's schema, the options."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from swarmctl.cli import main
from swarmctl.mission.events import check_event
from swarmctl.replay.panels import ffmpeg_exe
from swarmctl.replay.recording import load
from swarmctl.replay.truth import load_truth
from tests.test_mission_cli import small_mission

KML = {"k": "http://www.opengis.net/kml/2.2", "gx": "http://www.google.com/kml/ext/2.2"}


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    """A complete demo mission on the 10 x 10 test grid (three vehicles, frontier, about 10 s)."""
    base = tmp_path_factory.mktemp("replay-demo")
    mission = small_mission(base)
    out = base / "run"
    argv = ["demo", "--mission", str(mission), "--uavs", "3", "--seed", "4", "--speedup", "30", "--out", str(out)]
    code = main(argv + ["--quiet", "--end-action", "hover", "--policy", "frontier"])
    assert code == 0
    return out


@pytest.fixture(scope="module")
def replayed(demo: Path) -> Path:
    out = demo.parent / "replay"
    assert main(["replay", str(demo), "--out", str(out), "--quiet", "--fps", "5"]) == 0
    return out


def test_a_demo_recording_validates_against_the_event_schema(demo):
    kinds = set()
    for name in ("events.jsonl", "knowledge.jsonl"):
        for line in (demo / name).read_text().splitlines():
            kinds.add(check_event(json.loads(line), strict=True))
    assert {"mission", "state", "step", "targets", "end", "knowledge"} <= kinds


def test_the_demo_writes_the_truth_beside_the_recording(demo):
    summary = json.loads((demo / "summary.json").read_text())
    truth = load_truth(demo / "truth.json", 10, 10)
    assert sorted(map(tuple, truth.targets.tolist())) == sorted(map(tuple, summary["hidden_targets"]))
    assert truth.seed == 4 and len(truth.starts) == 3


def test_snapshots_hold_each_vehicles_knowledge_and_agree_with_the_tunnel_frames(demo):
    replay = load(demo)
    assert replay.knowledge.source == "snapshots"
    steps = json.loads((demo / "summary.json").read_text())["steps"]
    assert replay.frames == steps + 1
    counts = replay.cells_explored()
    assert (np.diff(counts) >= 0).all() and counts[0] > 0
    # what the vehicles sent over TUNNEL is a part of what they knew
    from swarmctl.replay.knowledge import NEVER, from_tunnel

    tunnel = from_tunnel(replay.tlog, replay.frame_time)
    for k, v in enumerate(replay.vehicles):
        sent = tunnel.first[v.index] < NEVER
        known = replay.knowledge.first[k] < NEVER
        assert sent.any() and not (sent & ~known).any()
    # the vehicles' final knowledge together holds every cell each vehicle was at
    final = replay.knowledge.explored(replay.frames - 1)
    for v in replay.vehicles:
        cells = v.cells[v.cells[:, 0] >= 0]
        assert final[cells[:, 0], cells[:, 1]].all()


def test_replay_writes_the_page_the_panels_the_animation_tracks_plots_and_summary(demo, replayed):
    summary = json.loads((demo / "summary.json").read_text())
    steps = summary["steps"]
    for name in ("map.html", "animation.gif", "summary.txt", "explored.png", "targets.png", "distance.png"):
        assert (replayed / name).stat().st_size > 0, name
    for name in ("battery.png", "link.png", "modes.png"):
        assert (replayed / name).stat().st_size > 0, name
    # the three-panel pictures: the first and the last step by default, three panels (truth is there)
    first, last = Image.open(replayed / "panels-step-0.png"), Image.open(replayed / f"panels-step-{steps}.png")
    assert first.size == last.size and first.size[0] > 2.5 * first.size[1]
    with Image.open(replayed / "animation.gif") as gif:
        assert gif.n_frames == steps + 1
    if ffmpeg_exe() is not None:
        assert (replayed / "animation.mp4").stat().st_size > 1000
    text = (replayed / "summary.txt").read_text()
    assert f"{summary['outcome']}: {len(summary['targets_found'])} targets found, {steps} steps" in text
    assert "knowledge from snapshots" in text and "truth: 3 hidden targets, 3 found" in text


def test_tracks_are_one_timed_linestring_per_vehicle_and_the_targets_as_points(demo, replayed):
    summary = json.loads((demo / "summary.json").read_text())
    features = json.loads((replayed / "tracks.geojson").read_text())["features"]
    lines = [f for f in features if f["geometry"]["type"] == "LineString"]
    points = [f for f in features if f["geometry"]["type"] == "Point"]
    assert sorted(f["properties"]["vehicle"] for f in lines) == ["uav1", "uav2", "uav3"]
    for f in lines:
        coords, times = f["geometry"]["coordinates"], f["properties"]["coordTimes"]
        assert len(coords) == len(times) > 10 and times == sorted(times)
        assert f["properties"]["source"] == "telemetry"
        lon, lat = np.array(coords)[:, 0], np.array(coords)[:, 1]
        assert np.ptp(lat) < 0.002 and np.ptp(lon) < 0.002  # a 100 m grid
    got = sorted((p["geometry"]["coordinates"][1], p["geometry"]["coordinates"][0]) for p in points)
    want = sorted((t["lat"], t["lon"]) for t in summary["targets_found"])
    assert np.allclose(got, want, atol=1e-6, rtol=0)
    root = ET.parse(replayed / "tracks.kml").getroot()
    marks = root.findall(".//k:Placemark", KML)
    assert len(root.findall(".//k:Placemark/k:LineString", KML)) == 3
    tracks = root.findall(".//gx:Track", KML)
    assert len(tracks) == 3 and all(len(t.findall("k:when", KML)) == len(t.findall("gx:coord", KML)) for t in tracks)
    assert len(root.findall(".//k:Placemark/k:Point", KML)) == len(summary["targets_found"])
    assert len(marks) == 6 + len(summary["targets_found"])


def test_the_map_page_is_one_offline_file_with_every_vehicle(replayed):
    html = (replayed / "map.html").read_text()
    assert "http://" not in html.replace("http://www.w3.org", "") and "https://" not in html
    data = json.loads(html.split('id="replay-data">', 1)[1].split("</script>", 1)[0])
    assert [v["name"] for v in data["vehicles"]] == ["uav1", "uav2", "uav3"]
    assert data["knowledge"]["vehicles"] == 3 and len(data["targets"]) == 3 and len(data["hidden"]) == 3
    assert len(data["frameTimes"]) == len(data["vehicles"][0]["lat"]) == len(data["frameLabels"])


def test_vehicle_steps_and_frame_range_options(demo, tmp_path):
    out = tmp_path / "one"
    argv = ["replay", str(demo), "--out", str(out), "--quiet", "--vehicle", "uav2", "--steps", "0,5"]
    assert main(argv + ["--from-step", "2", "--to-step", "6"]) == 0
    features = json.loads((out / "tracks.geojson").read_text())["features"]
    lines = [f for f in features if f["geometry"]["type"] != "Point"]
    assert [f["properties"]["vehicle"] for f in lines] == ["uav2"]
    assert (out / "panels-step-0.png").is_file() and (out / "panels-step-5.png").is_file()
    with Image.open(out / "animation.gif") as gif:
        assert gif.n_frames == 5
    assert "vehicles shown: uav2 of 3" in (out / "summary.txt").read_text()
    # the known map of one vehicle is what it knew, not what the swarm knew
    alone, together = load(demo, ["uav2"]), load(demo)
    last = together.frames - 1
    assert alone.knowledge.explored(last).sum() <= together.knowledge.explored(last).sum()


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--vehicle", "zulu"], "--vehicle 'zulu'"),
        (["--steps", "0,x"], "--steps"),
        (["--steps", "9999"], "--steps 9999"),
        (["--from-step", "5", "--to-step", "2"], "--from-step 5"),
        (["--fps", "0"], "--fps"),
        (["--basemap", "https://tile.example/tile.png"], "--basemap"),
    ],
)
def test_bad_options_are_one_line_and_exit_2(demo, tmp_path, capsys, extra, needle):
    assert main(["replay", str(demo), "--out", str(tmp_path / "x"), "--quiet", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and needle in err and "Traceback" not in err


def test_a_recording_without_its_tlog_replays_from_the_events_alone(demo, tmp_path):
    """As for PX4 vehicles, whose own link belongs to MAVSDK and is not in the tlog."""
    import shutil

    rec = tmp_path / "rec"
    shutil.copytree(demo, rec, ignore=shutil.ignore_patterns("mission.tlog", "replay"))
    replay = load(rec)
    assert replay.tlog is None and replay.knowledge.source == "snapshots"
    assert all(v.track_source == "steps" and v.telemetry is None for v in replay.vehicles)
    out = tmp_path / "out"
    assert main(["replay", str(rec), "--out", str(out), "--quiet"]) == 0
    assert (out / "map.html").is_file() and (out / "explored.png").is_file() and not (out / "battery.png").exists()
    with_tlog = load(demo)
    for a, b in zip(replay.vehicles, with_tlog.vehicles):
        assert np.array_equal(a.cells, b.cells)  # the cells come from the step lines either way
