"""Hostile recordings: what would cost the replay unbounded memory or time, or end it in a traceback, is
refused with one line (exit 2) or skipped as damage and listed (docs/recording.md, "Limits")."""

from __future__ import annotations

import base64
import json
import resource
import shutil
import subprocess
import sys
import tracemalloc
import zlib
from html import escape as html_escape
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.cli import main
from swarmctl.geo.grid import GeoGrid
from swarmctl.mission.inputs import InputsDecoder, InputsError
from swarmctl.replay import panels
from swarmctl.replay.knowledge import from_snapshots
from swarmctl.replay.page import page_data
from swarmctl.replay.recording import load
from swarmctl.replay.tlog import index_tlog
from swarmctl.world.beliefs import ObservationSettings
from tests.test_mission_cli import small_mission

LOGS = Path(__file__).resolve().parent / "data" / "logs"
COPTER = LOGS / "arducopter_sitl_guided_takeoff_120s.tlog"
CHICAGO_GRID = Path(__file__).resolve().parent.parent / "missions" / "chicago-loop" / "grid.npz"
SWARMCTL = Path(sys.executable).parent / "swarmctl"
BOMB_BYTES = 64 * 2**20  # zeros: 64 KB of zlib


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    """A one-vehicle frontier demo on the 10 x 10 test grid (about 7 s): events, knowledge, inputs, tlog."""
    base = tmp_path_factory.mktemp("hostile-demo")
    out = base / "run"
    argv = ["demo", "--mission", str(small_mission(base)), "--uavs", "1", "--seed", "4", "--speedup", "30"]
    assert main(argv + ["--out", str(out), "--quiet", "--end-action", "hover", "--policy", "frontier"]) == 0
    return out


def _copy(demo: Path, tmp_path: Path) -> Path:
    rec = tmp_path / "rec"
    shutil.copytree(demo, rec, ignore=shutil.ignore_patterns("replay"))
    return rec


def _rewrite(path: Path, change) -> None:
    """Rewrite a JSON-lines file, each line through change(index, obj) -> obj."""
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    path.write_text("".join(json.dumps(change(i, e)) + "\n" for i, e in enumerate(lines)))


def _bomb(prefix: bytes = b"", zeros: int = BOMB_BYTES) -> str:
    """base64 of zlib of `prefix` and then `zeros` zero bytes."""
    z = zlib.compressobj(9)
    parts = [z.compress(prefix)] + [z.compress(bytes(2**20)) for _ in range(zeros // 2**20)] + [z.flush()]
    return base64.b64encode(b"".join(parts)).decode("ascii")


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    return err


def _peak(fn) -> int:
    """Peak bytes Python and numpy allocated while fn ran."""
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


# --- 1. decompression bombs ------------------------------------------------------------------------------
def test_a_knowledge_bomb_is_skipped_and_listed_without_being_inflated(demo, tmp_path):
    line = {"step": 1, "vehicle": "uav1", "explored": _bomb(), "cells": 0, "targets": []}
    result = {}
    peak = _peak(lambda: result.update(out=from_snapshots([line], ["uav1"], 10, 10, {1: 1})))
    assert peak < 8 * 2**20  # the 64 MiB it inflates to were never made
    assert "longer than 13 bytes can compress to" in result["out"][2][0]
    # a whole mask followed by more: refused too (nothing may be left over after the W x H mask)
    mask = np.packbits(np.ones(100, dtype=bool)).tobytes()
    tail = {**line, "explored": base64.b64encode(zlib.compress(mask + bytes(3))).decode(), "cells": 100}
    _, _, problems = from_snapshots([tail], ["uav1"], 10, 10, {1: 1})
    assert problems and "more than the 13 bytes" in problems[0]
    whole = {**line, "explored": base64.b64encode(zlib.compress(mask)).decode(), "cells": 100}
    assert from_snapshots([whole], ["uav1"], 10, 10, {1: 1})[2] == []
    # through the CLI: the snapshot is skipped and named, the rest replayed
    rec = _copy(demo, tmp_path)
    _rewrite(rec / "knowledge.jsonl", lambda i, e: {**e, "explored": _bomb()} if i == 0 else e)
    out = tmp_path / "out"
    assert main(["replay", str(rec), "--out", str(out), "--quiet"]) == 0
    assert "knowledge.jsonl: skipped 1 snapshots" in (out / "summary.txt").read_text()


@pytest.mark.parametrize("field", ["maps", "positions"])
def test_an_inputs_bomb_is_refused_within_the_size_the_grid_allows(field):
    decoder = InputsDecoder(10, 10, 1)
    line = {"step": 1, "since": [0], "map": [-1], "maps": [], "positions": _bomb()}
    if field == "maps":
        line.update(map=[0], maps=[_bomb()])
    errors = []

    def decode():
        with pytest.raises(InputsError) as exc:
            decoder.beliefs(line, [0], ObservationSettings())
        errors.append(str(exc.value))

    assert _peak(decode) < 8 * 2**20
    assert "can compress to" in errors[0]
    from swarmctl.mission.inputs import inflate

    with pytest.raises(InputsError, match="decompresses to more than the 6 bytes"):
        inflate(base64.b64encode(zlib.compress(bytes(7))).decode(), 6, "positions")


# --- 2. tlogs: regular files of a bounded size --------------------------------------------------------------
def _limited(args: list[str]) -> subprocess.CompletedProcess:
    """swarmctl in a process of at most 3 GB of address space (a reader without a bound dies, not the box)."""

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30))

    return subprocess.run(
        [str(SWARMCTL), *args], capture_output=True, text=True, timeout=120, preexec_fn=limit, stdin=subprocess.DEVNULL
    )


def test_a_device_is_refused_before_a_byte_is_read(tmp_path):
    done = _limited(["replay", "/dev/zero", "--out", str(tmp_path / "out"), "--quiet"])
    assert done.returncode == 2, done.stderr[-2000:]
    assert done.stderr.strip() == (
        "swarmctl: error: /dev/zero: not a regular file (a device, a pipe or a socket); give a .tlog file or a "
        "recording folder"
    )


def test_a_tlog_over_the_cap_is_refused_before_it_is_read(tmp_path, capsys, monkeypatch):
    from swarmctl.replay import tlog

    big = tmp_path / "big.tlog"
    with big.open("wb") as fh:
        fh.truncate(3 * 2**20)  # sparse: no disk
    monkeypatch.setattr(tlog, "TLOG_MAX_BYTES", 2**20)
    read = []
    monkeypatch.setattr(tlog, "read_limited", lambda *a, **k: read.append(a) or b"")
    assert main(["replay", str(big), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert "3 MiB, over the 1 MiB a .tlog may have; replay a shorter log" in _error(capsys)
    assert not read


# --- 3. fields no recorder writes ----------------------------------------------------------------------------
def test_a_step_number_of_a_trillion_is_skipped_as_damage(demo, tmp_path):
    rec = _copy(demo, tmp_path)
    text = (rec / "events.jsonl").read_text()
    step = next(json.loads(x) for x in text.splitlines() if json.loads(x)["event"] == "step")
    (rec / "events.jsonl").write_text(text + json.dumps({**step, "step": 10**12}) + "\n")
    replay = load(rec)
    assert replay.frames < 100
    [damage] = replay.damage["events.jsonl"]
    assert "step 1000000000000 is not in 0..1,000,000" in damage.reason


def test_a_time_of_1e308_is_skipped_as_damage(demo, tmp_path):
    rec = _copy(demo, tmp_path)
    _rewrite(rec / "events.jsonl", lambda i, e: {**e, "t": 1e308} if e["event"] == "step" and e["step"] == 2 else e)
    replay = load(rec)
    page_data(replay)  # the page's clock: time.gmtime(1e308) overflowed
    [damage] = replay.damage["events.jsonl"]
    assert "time t 1e+308 is not in 2001..2128" in damage.reason


@pytest.mark.parametrize("vehicles", [["x", 1], "x", {"name": "uav1"}])
def test_a_summary_whose_vehicles_are_not_objects_is_replayed_without_it(demo, tmp_path, vehicles):
    rec = _copy(demo, tmp_path)
    summary = json.loads((rec / "summary.json").read_text())
    (rec / "summary.json").write_text(json.dumps({**summary, "vehicles": vehicles}))
    replay = load(rec)
    assert replay.vehicles[0].summary is None
    assert "summary.json: vehicles is not a list of objects; replayed without its figures" in replay.notes


def _copter_with_bad_positions(path: Path, every: int) -> int:
    """COPTER rewritten with every `every`-th GLOBAL_POSITION_INT at lat 2147483647, lon -2147483648."""
    index = index_tlog(COPTER)
    mav = mavlink2.MAVLink(None)
    out, bad, k = bytearray(), 0, 0
    for i in range(len(index)):
        raw = index.frame(i)
        if int(index.msgid[i]) == mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            k += 1
            if k % every == 0:
                m = mav.decode(bytearray(raw))
                m.lat, m.lon = 2147483647, -2147483648
                mav.srcSystem, mav.srcComponent, mav.seq = m.get_srcSystem(), m.get_srcComponent(), m.get_seq()
                raw = m.pack(mav)
                bad += 1
        out += int(round(index.time[i] * 1e6)).to_bytes(8, "big") + raw
    path.write_bytes(bytes(out))
    return bad


def test_positions_out_of_range_are_skipped_and_counted_not_projected(tmp_path, capsys):
    some = tmp_path / "some.tlog"
    bad = _copter_with_bad_positions(some, 3)
    replay = load(some)
    tel = replay.vehicles[0].telemetry
    assert tel.bad_positions > 0 and (np.abs(tel.lat) <= 90).all() and (np.abs(tel.lon) <= 180).all()
    assert any("positions outside -90..90 latitude" in n for n in replay.notes), replay.notes
    assert bad >= tel.bad_positions
    every = tmp_path / "every.tlog"
    _copter_with_bad_positions(every, 1)
    assert main(["replay", str(every), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert "positions out of range skipped); give --grid FILE" in _error(capsys)


# --- 4. --verify that checked nothing -------------------------------------------------------------------------
def test_verify_that_could_check_no_decision_fails_with_exit_2(demo, tmp_path, capsys):
    rec = _copy(demo, tmp_path)
    (rec / "inputs.jsonl").write_bytes(np.random.default_rng(0).bytes(5000))
    out = tmp_path / "out"
    assert main(["replay", str(rec), "--verify", "--out", str(out), "--quiet"]) == 2
    assert "recorded decisions could be checked" in _error(capsys)
    report = json.loads((out / "verify.json").read_text())
    assert report["checked"] == 0 and report["decisions"] > 0 and report["ok"] is False
    assert report["nothing_checked"] is True
    # the intact recording still verifies
    assert main(["replay", str(demo), "--verify", "--out", str(tmp_path / "ok"), "--quiet"]) == 0


# --- 5. more vehicles than a mission may have ---------------------------------------------------------------
def test_a_mission_line_of_2000_vehicles_is_skipped_as_damage(demo, tmp_path):
    rec = _copy(demo, tmp_path)
    names = ["uav1"] + [f"v{k}" for k in range(1999)]
    _rewrite(rec / "events.jsonl", lambda i, e: {**e, "vehicles": names} if e["event"] == "mission" else e)
    replay = load(rec)
    assert replay.all_vehicles == ["uav1"]
    [damage] = replay.damage["events.jsonl"]
    assert "vehicles has 2,000 entries, over the 250 vehicles a mission may have" in damage.reason


# --- 6. --fps and ffmpeg ------------------------------------------------------------------------------------
def test_an_fps_near_zero_is_refused(demo, tmp_path, capsys):
    assert main(["replay", str(demo), "--fps", "1e-9", "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert "--fps" in _error(capsys)


@pytest.mark.skipif(panels.ffmpeg_exe() is None, reason="no ffmpeg")
def test_an_ffmpeg_that_fails_costs_the_mp4_only(demo, tmp_path, monkeypatch, capsys):
    def broken(self, rgb):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(panels._Mp4, "add", broken)
    out = tmp_path / "out"
    assert main(["replay", str(demo), "--out", str(out), "--quiet", "--fps", "0.1"]) == 0
    assert (out / "animation.gif").is_file() and not (out / "animation.mp4").exists()
    assert "note: animation.mp4 not written: ffmpeg failed" in (out / "summary.txt").read_text()


# --- 7. --grid on a recording ---------------------------------------------------------------------------------
def test_grid_on_a_recording_names_the_option_not_the_truth_file(demo, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["replay", str(demo), "--grid", str(CHICAGO_GRID), "--out", str(out), "--quiet"]) == 2
    err = _error(capsys)
    assert "--grid" in err and "has its own grid" in err and "truth.json" not in err and "delete" not in err
    # without its grid.npz, a grid of another size is not the recording's
    rec = _copy(demo, tmp_path)
    (rec / "grid.npz").unlink()
    assert main(["replay", str(rec), "--grid", str(CHICAGO_GRID), "--out", str(out), "--quiet"]) == 2
    err = _error(capsys)
    assert "not the recording's: its mission flew 10 x 10 cells" in err and "truth.json" not in err
    # the recording's own grid, given again, is fine
    replay = load(demo, grid_file=demo / "grid.npz")
    own = GeoGrid.load(demo / "grid.npz")
    assert (replay.grid.width, replay.grid.height) == (own.width, own.height) == (10, 10)


def test_a_grid_of_another_place_is_said_to_hold_none_of_the_positions(tmp_path):
    out = tmp_path / "out"
    assert main(["replay", str(COPTER), "--grid", str(CHICAGO_GRID), "--out", str(out), "--quiet"]) == 0
    assert "sysid1: none of its positions lies in the grid" in (out / "summary.txt").read_text()
    fitted = tmp_path / "fitted"
    assert main(["replay", str(COPTER), "--out", str(fitted), "--quiet"]) == 0
    assert "none of its positions" not in (fitted / "summary.txt").read_text()


@pytest.mark.parametrize("text", ["</script><script>alert(1)</script>", "<!--<script>", "__DATA__ & __TITLE__"])
def test_recorded_text_cannot_end_or_change_the_page_data(demo, tmp_path, text):
    from swarmctl.replay.page import write_page

    replay = load(demo)
    replay.name = f"run {text}"
    replay.vehicles[0].name = text
    html = write_page(replay, tmp_path / "index.html").read_text()
    head, rest = html.split('<script type="application/json" id="replay-data">', 1)
    block = rest.split("</script>", 1)[0]
    assert "<" not in block  # nothing in the data can start a tag, a comment or an end tag
    data = json.loads(block)
    assert data["name"] == f"run {text}" and data["vehicles"][0]["name"] == text
    title = head.split("<title>", 1)[1].split("</title>", 1)[0]
    assert title == html_escape(f"run {text}: replay")  # the name as text; the data never lands in it


def test_a_dollar_in_recorded_names_is_drawn_as_written(demo, tmp_path, capsys):
    rec = _copy(demo, tmp_path)
    odd = json.dumps("$\\undefinedcmd{x}$")  # as matplotlib's mathtext, a formula it cannot parse
    for path in [*rec.glob("*.jsonl"), rec / "summary.json"]:  # the mission's name and the vehicle's
        path.write_text(path.read_text().replace('"small"', odd).replace('"uav1"', odd))
    assert load(rec).name == json.loads(odd) and load(rec).vehicles[0].name == json.loads(odd)
    out = tmp_path / "out"
    assert main(["replay", str(rec), "--out", str(out), "--quiet", "--to-step", "3"]) == 0, capsys.readouterr().err
    assert list(out.glob("panels-step-*.png"))


def test_control_characters_in_recorded_names_leave_the_kml_well_formed(demo, tmp_path):
    import xml.etree.ElementTree as ET

    from swarmctl.replay.tracks import write_tracks

    replay = load(demo)
    replay.name = "run\x00\x1b[2J"
    replay.vehicles[0].name = "uav\x01"
    kmls = {p.name: p for p in write_tracks(replay, tmp_path) if p.suffix == ".kml"}
    names = {f: [e.text for e in ET.parse(p).iter() if e.tag.endswith("name")] for f, p in kmls.items()}
    assert "run\\x00\\x1b[2J: tracks" in names["tracks.kml"] and "uav\\x01" in names["tracks.kml"]
    assert "run\\x00\\x1b[2J: targets found" in names["targets.kml"]  # XML 1.0 refuses raw controls
