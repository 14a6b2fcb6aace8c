"""Damaged and wrong input: what can be read is replayed and what was skipped is said; an empty or a
foreign file is one clear line and exit status 2."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from swarmctl.cli import main
from swarmctl.errors import InputError
from swarmctl.replay.lines import read_lines
from swarmctl.replay.recording import load
from swarmctl.replay.tlog import index_tlog

LOGS = Path(__file__).resolve().parent / "data" / "logs"
SITL3 = LOGS / "sitl3-mission"
TLOG = (SITL3 / "mission.tlog").read_bytes()
CLEAN = index_tlog(SITL3 / "mission.tlog")


def _records(index) -> list[tuple[float, bytes]]:
    return [(float(index.time[i]), index.frame(i)) for i in range(len(index))]


ALL = _records(CLEAN)


def _recording(tmp_path: Path) -> Path:
    folder = tmp_path / "rec"
    shutil.copytree(SITL3, folder)
    for f in folder.iterdir():
        f.chmod(0o644)
    return folder


def test_a_log_cut_mid_packet_replays_and_names_the_cut(tmp_path):
    rec = _recording(tmp_path)
    cut = len(TLOG) - 20  # inside the last record
    (rec / "mission.tlog").write_bytes(TLOG[:cut])
    index = index_tlog(rec / "mission.tlog")
    assert len(index) == len(CLEAN) - 1
    [damage] = index.damage
    assert damage.offset + damage.length == cut and "cut short at the end" in damage.reason
    out = tmp_path / "out"
    assert main(["replay", str(rec), "--out", str(out), "--quiet"]) == 0
    text = (out / "summary.txt").read_text()
    assert f"skipped in mission.tlog: 1 stretch, {damage.length} bytes" in text and f"at byte {damage.offset}" in text


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(at=st.integers(0, len(TLOG) - 1), garbage=st.binary(min_size=1, max_size=3000))
def test_garbage_inside_a_log_costs_at_most_the_records_it_lands_in(tmp_path, at, garbage):
    path = tmp_path / "garbage.tlog"
    path.write_bytes(TLOG[:at] + garbage + TLOG[at:])
    index = index_tlog(path)
    got = _records(index)
    assert set(got) <= set(ALL)  # nothing made up from the garbage
    assert len(got) >= len(ALL) - 2  # the record it was dropped into, and at most one more
    assert index.damage and sum(d.length for d in index.damage) >= len(garbage)
    assert all(d.offset <= at + len(garbage) and d.offset + d.length >= at for d in index.damage[:1])


def test_garbage_inside_a_recording_is_counted_with_its_offsets_in_the_summary(tmp_path):
    rec = _recording(tmp_path)
    at = int(CLEAN.start[len(CLEAN) // 2]) - 8  # on a record boundary
    junk = np.random.default_rng(0).integers(0, 256, 777, dtype=np.uint8).tobytes()
    (rec / "mission.tlog").write_bytes(TLOG[:at] + junk + TLOG[at:])
    replay = load(rec)
    [damage] = replay.damage["mission.tlog"]
    assert (damage.offset, damage.length) == (at, 777)
    assert len(replay.tlog) == len(CLEAN)


def test_an_events_file_with_a_broken_last_line_replays_the_rest(tmp_path):
    rec = _recording(tmp_path)
    text = (rec / "events.jsonl").read_bytes()
    broken = text + b'{"t":1796110800.1,"event":"step","step":26,"vehi'
    (rec / "events.jsonl").write_bytes(broken)
    lines = read_lines(rec / "events.jsonl")
    assert len(lines.events) == text.count(b"\n")
    [damage] = lines.damage
    assert damage.offset == len(text) and "cut short at the end of the file" in damage.reason
    out = tmp_path / "out"
    assert main(["replay", str(rec), "--out", str(out), "--quiet"]) == 0
    assert "skipped in events.jsonl: 1 stretch" in (out / "summary.txt").read_text()
    assert load(rec).frames == 26  # steps 0..25: the broken step 26 is not made up


def test_a_line_that_breaks_the_schema_is_skipped_and_named(tmp_path):
    rec = _recording(tmp_path)
    lines = (rec / "events.jsonl").read_text().splitlines()
    bad = json.loads(lines[20])
    bad["step"] = "twenty"
    lines[20] = json.dumps(bad)
    (rec / "events.jsonl").write_text("\n".join(lines) + "\n")
    [damage] = read_lines(rec / "events.jsonl").damage
    assert "line 21" in damage.reason and "'step'" in damage.reason
    assert load(rec).frames == 26  # the lost step is carried over from the one before


@pytest.mark.parametrize(
    "content, needle",
    [
        (b"", "the file is empty"),
        (b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 40, "no MAVLink telemetry found"),
        (b"\xa3\x95\x80\x80" + bytes(200), "dataflash"),
        (b"hello, this is a text file\n" * 50, "no MAVLink telemetry found"),
    ],
)
def test_empty_and_foreign_files_are_one_line_and_exit_2(tmp_path, capsys, content, needle):
    path = tmp_path / "input.tlog"
    path.write_bytes(content)
    with pytest.raises(InputError, match=needle):
        load(path)
    assert main(["replay", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("swarmctl: error: ") and err.count("\n") == 0 and needle in err


def test_a_folder_that_is_not_a_recording_and_a_missing_path_exit_2(tmp_path, capsys):
    assert main(["replay", str(tmp_path), "--quiet"]) == 2
    assert "not a recording" in capsys.readouterr().err
    assert main(["replay", str(tmp_path / "nowhere.tlog"), "--quiet"]) == 2
    assert "not found" in capsys.readouterr().err


def test_an_events_file_with_nothing_readable_and_no_tlog_exits_2(tmp_path, capsys):
    (tmp_path / "events.jsonl").write_text("not json\n{\n")
    assert main(["replay", str(tmp_path), "--quiet"]) == 2
    assert "no readable event" in capsys.readouterr().err


def test_a_tlog_of_a_ground_station_alone_has_no_vehicle_to_replay(tmp_path):
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    hb = mav.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(mav)
    path = tmp_path / "gcs.tlog"
    path.write_bytes(b"".join(int((1.8e9 + i) * 1e6).to_bytes(8, "big") + hb for i in range(10)))
    with pytest.raises(InputError, match="no vehicle in it"):
        load(path)
