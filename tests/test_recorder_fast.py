"""The recorder's fast paths write what the plain encoding writes: knowledge lines (stacked maps,
one compressed map for the vehicles that know the same) and the rounds' batched events, line for line
the same text but for the time stamps."""

import base64
import json
import time
import zlib

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from swarmctl.knowledge.model import Knowledge
from swarmctl.mission.recorder import Recorder

W, H = 7, 5


def _reference_knowledge(known: dict, step: int, views) -> list[dict]:
    """The knowledge lines as the recorder first wrote them, one vehicle at a time."""
    out = []
    for name, kn in views:
        cells, targets = int(np.count_nonzero(kn.explored)), len(kn.targets)
        if known.get(name) == (cells, targets):
            continue
        known[name] = (cells, targets)
        packed = zlib.compress(np.packbits(np.asarray(kn.explored, dtype=bool).reshape(-1)).tobytes(), 6)
        out.append(
            {
                "t": 0,
                "event": "knowledge",
                "step": int(step),
                "vehicle": name,
                "explored": base64.b64encode(packed).decode("ascii"),
                "cells": cells,
                "targets": sorted([int(x), int(y)] for x, y in kn.targets),
            }
        )
    return out


maps = st.lists(st.booleans(), min_size=W * H, max_size=W * H).map(lambda b: np.array(b).reshape(W, H))
cells = st.tuples(st.integers(0, W - 1), st.integers(0, H - 1))
vehicle = st.tuples(maps, st.dictionaries(cells, st.integers(0, 9), max_size=3))
rounds = st.lists(st.lists(st.tuples(st.integers(0, 3), vehicle), max_size=5), min_size=1, max_size=4)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rounds)
def test_knowledge_lines_are_the_plain_ones(tmp_path, plan):
    folder = tmp_path / f"k{time.monotonic_ns()}"
    rec = Recorder(folder)
    kns = [Knowledge(W, H, i) for i in range(4)]
    known: dict = {}
    expected = []
    try:
        for step, changes in enumerate(plan, start=1):
            for i, (explored, targets) in changes:  # knowledge only grows: or-in the new cells and targets
                kns[i].explored |= explored
                table = kns[i].targets
                for c, s in targets.items():
                    table[c] = s
            # vehicles 2 and 3 often know the same as 0 and 1: the shared encoding must not mix them up
            views = [(f"uav-{i}", kns[i]) for i in (0, 1, 2, 3, 1)]
            assert rec.knowledge(step, views) == len(ref := _reference_knowledge(known, step, views))
            expected += ref
    finally:
        rec.close()
    path = folder / "knowledge.jsonl"
    text = path.read_text().splitlines() if path.exists() else []
    got = [json.loads(line) for line in text]
    for line, record in zip(text, got):
        assert line == json.dumps(record, separators=(",", ":"))  # compact, as json.dumps writes it
        assert isinstance(record.pop("t"), float)
    assert got == [{k: v for k, v in e.items() if k != "t"} for e in expected]


def test_events_at_once_write_the_lines_event_writes(tmp_path):
    one, many = Recorder(tmp_path / "one"), Recorder(tmp_path / "many")
    events = [
        ("refused", dict(vehicle=f"uav-{i}", step=3, cell=(i, 2), proposed=(i, 3), reason="collision"))
        for i in range(3)
    ] + [("state", dict(vehicle="uav-0", state="hover", cell=(1, 2)))]
    try:
        for kind, fields in events:
            one.event(kind, **fields)
        many.events_at_once(events)
        many.events_at_once([])
        assert (one.events, one.changes) == (many.events, many.changes) == (4, 1)
    finally:
        one.close()
        many.close()

    def lines(rec):
        return [{k: v for k, v in json.loads(x).items() if k != "t"} for x in (rec.folder / "events.jsonl").open()]

    assert lines(one) == lines(many)
    first = dict(event="refused", vehicle="uav-0", step=3, cell=[0, 2], proposed=[0, 3], reason="collision")
    assert lines(many)[0] == first


def test_tlog_holds_each_frame_after_its_time_stamp(tmp_path):
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=3)
    msgs = [mav.heartbeat_encode(2, 3, 0, i, 4) for i in range(3)]
    frames = [bytes(m.pack(mav)) for m in msgs]
    rec = Recorder(tmp_path)
    before = int(time.time() * 1e6)
    try:
        rec.frames(msgs[:2])
        rec.frames([])
        rec.packet(memoryview(frames[2]))
        rec.packet(bytearray(frames[0]))
        assert rec.packets == 4
    finally:
        rec.close()
    data = (tmp_path / "mission.tlog").read_bytes()
    got, at = [], 0
    for frame in frames[:2] + frames[2:] + frames[:1]:
        stamp = int.from_bytes(data[at : at + 8], "big")
        assert before <= stamp <= int(time.time() * 1e6)
        got.append(data[at + 8 : at + 8 + len(frame)])
        at += 8 + len(frame)
    assert at == len(data) and got == frames + frames[:1]


def test_a_plain_event_writes_what_event_writes_and_takes_numpy_values_too(tmp_path):
    rec = Recorder(tmp_path)
    ready = dict(step=3, vehicles=[dict(vehicle="a", cell=(1, 2), q=[0.5, -1.25], refused=None)], decide_ms=1.5)
    numpy = dict(step=np.int64(3), vehicles=[dict(vehicle="a", cell=np.array([1, 2]), q=[0.5, -1.25])])
    for fields in (ready, numpy):
        rec.event("step", **fields)
        rec.plain_event("step", **fields)
    rec.close()
    lines = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    for line in lines:
        line.pop("t")
    assert lines[0] == lines[1] and lines[2] == lines[3] and lines[0]["vehicles"][0]["cell"] == [1, 2]
    assert rec.events == 4


_JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=5), inner, max_size=4),
    max_leaves=30,
)


@settings(max_examples=200, deadline=None)
@given(_JSON)
def test_the_summary_text_reads_back_as_what_was_written(value):
    from swarmctl.mission.recorder import summary_text

    assert json.loads(summary_text(value)) == value


def test_the_summary_text_puts_each_vehicle_and_each_top_level_field_on_its_own_line(tmp_path):
    rec = Recorder(tmp_path)
    summary = {"outcome": "complete", "vehicles": [{"name": f"uav{i}", "cell": [i, 2]} for i in range(3)], "n": 1}
    rec.write_summary(summary, running=True)
    rec.close()
    lines = (tmp_path / "summary.json").read_text().splitlines()
    assert lines[0] == "{" and lines[-1] == "}"
    assert '    {"name": "uav1", "cell": [1, 2]},' in lines
    assert '  "running": true' in lines and '  "outcome": "complete",' in lines
    assert json.loads("\n".join(lines)) == {**summary, "running": True}
