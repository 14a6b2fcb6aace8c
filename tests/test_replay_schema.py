"""The recording's event schema (swarmctl.mission.events) and the knowledge snapshot writer."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.knowledge.model import Knowledge
from swarmctl.mission.events import EVENTS, RECORDS, EventError, check_event, with_schema
from swarmctl.mission.recorder import Recorder
from swarmctl.replay.knowledge import NEVER, from_snapshots
from swarmctl.replay.lines import read_lines

DOC = Path(__file__).resolve().parent.parent / "docs" / "recording.md"

_cell = st.lists(st.integers(0, 300), min_size=2, max_size=2)
_number = st.one_of(st.integers(-(10**6), 10**6), st.floats(-1e6, 1e6, allow_nan=False))
_latlon = st.tuples(st.floats(-90, 90), st.floats(-180, 180)).map(list)
KINDS = {
    "int": st.integers(0, 10**6),
    "number": _number,
    "str": st.text(max_size=12),
    "bool": st.booleans(),
    "cell": _cell,
    "cells": st.lists(_cell, max_size=4),
    "xy": st.lists(st.integers(-300, 300), min_size=2, max_size=2),
    "latlon": _latlon,
    "latlons": st.lists(_latlon, max_size=4),
    "ints": st.lists(st.integers(-(10**6), 10**6), max_size=5),
    "numbers": st.lists(_number, max_size=5),
    "number rows": st.lists(st.lists(_number, max_size=3), max_size=3),
    "strs": st.lists(st.text(max_size=6), max_size=4),
}


def _value(f):
    if f.kind.startswith("records "):
        return st.lists(_record(RECORDS[f.kind.removeprefix("records ")][1]), max_size=3)
    base = st.sampled_from(f.values) if f.values else KINDS[f.kind]
    return st.one_of(base, st.none()) if f.nullable else base


def _record(fields):
    required = {f.name: _value(f) for f in fields if f.required}
    optional = {f.name: _value(f) for f in fields if not f.required}
    return st.fixed_dictionaries(required, optional=optional)


EVENT = st.sampled_from(sorted(EVENTS)).flatmap(
    lambda kind: _record(EVENTS[kind][2]).map(lambda body: {"t": 1.8e9, "event": kind, **body})
)


@settings(max_examples=300, deadline=None)
@given(EVENT)
def test_every_line_built_by_the_schema_passes_it_and_survives_json(event):
    assert check_event(json.loads(json.dumps(event)), strict=True) == event["event"]


@settings(max_examples=300, deadline=None)
@given(EVENT, st.data())
def test_a_missing_or_mistyped_field_is_refused_and_named(event, data):
    fields = [f for f in EVENTS[event["event"]][2] if f.required]
    f = data.draw(st.sampled_from(fields))
    broken = dict(event)
    if data.draw(st.booleans()):
        del broken[f.name]
    else:
        broken[f.name] = {"not": "this"}
    with pytest.raises(EventError, match=repr(f.name)):
        check_event(broken)


def test_lenient_reading_and_strict_checking():
    line = {"t": 1.0, "event": "end", "outcome": "complete", "step": 3, "new_field": 1}
    assert check_event(line) == "end"
    with pytest.raises(EventError, match="new_field"):
        check_event(line, strict=True)
    assert check_event({"t": 1.0, "event": "from_the_future"}) is None
    with pytest.raises(EventError, match="not in the schema"):
        check_event({"t": 1.0, "event": "from_the_future"}, strict=True)
    with pytest.raises(EventError, match="'outcome'.*one of"):
        check_event({"t": 1.0, "event": "end", "outcome": "won", "step": 3})
    with pytest.raises(EventError, match="'t'"):
        check_event({"event": "end", "outcome": "complete", "step": 3})


def test_docs_recording_holds_the_schema_tables():
    text = DOC.read_text(encoding="utf-8")
    assert with_schema(text) == text, "run: python -m swarmctl.mission.events docs/recording.md"
    for kind, (_file, _doc, fields) in EVENTS.items():
        assert f"#### `{kind}`" in text
        for f in fields:
            assert f"| `{f.name}` |" in text


@settings(max_examples=60, deadline=None)
@given(
    st.integers(1, 30),
    st.integers(1, 30),
    st.lists(st.tuples(st.integers(0, 2), st.integers(0, 10**9)), min_size=1, max_size=12),
)
def test_snapshots_read_back_as_written_and_only_changes_are_written(tmp_path_factory, w, h, updates):
    folder = tmp_path_factory.mktemp("snap")
    rec = Recorder(folder)
    views = [Knowledge(w, h, vehicle_id=i) for i in range(3)]
    names = ["a", "b", "c"]
    want = np.full((3, w, h), NEVER, dtype=np.int32)
    written = 0
    for step, (v, seed) in enumerate(updates, start=1):
        rng = np.random.default_rng(seed)
        views[v].explored |= rng.random((w, h)) < 0.2
        if rng.random() < 0.3:
            views[v].add_targets([(int(rng.integers(w)), int(rng.integers(h)))], step)
        written += rec.knowledge(step, list(zip(names, views)))
        for k in range(3):
            want[k][views[k].explored & (want[k] == NEVER)] = step
    rec.close()
    lines = read_lines(folder / "knowledge.jsonl") if written else None
    assert written == (len(lines.events) if lines else 0)
    if lines is None:
        return
    assert not lines.damage
    assert all(check_event(e, strict=True) == "knowledge" for e in lines.events)
    first, targets, problems = from_snapshots(lines.events, names, w, h, {s: s for s in range(len(updates) + 1)})
    assert problems == [] and np.array_equal(first, want)
    known = {c for kn in views for c in kn.targets}
    assert set(targets) == known


def test_a_snapshot_that_does_not_decode_is_skipped_and_named():
    good = {"t": 1.0, "event": "knowledge", "step": 1, "vehicle": "a", "cells": 1, "targets": []}
    import base64
    import zlib

    mask = np.zeros(4, dtype=bool)
    mask[2] = True
    ok = dict(good, explored=base64.b64encode(zlib.compress(np.packbits(mask).tobytes())).decode())
    lies = dict(ok, cells=2)
    junk = dict(good, explored="!!!")
    first, _t, problems = from_snapshots([ok, lies, junk], ["a"], 2, 2, {1: 1})
    assert first[0].tolist() == [[NEVER, NEVER], [1, NEVER]] and len(problems) == 2


def test_the_schema_names_every_state_the_controller_records():
    from swarmctl.mission.agent import TRANSITIONS, State
    from swarmctl.mission.events import AGENT_STATES

    entered = {s for targets in TRANSITIONS.values() for s in targets}  # every state an agent can move to
    assert set(AGENT_STATES) == {s.value for s in entered} == {s.value for s in State} - {"new"}


def test_a_refused_move_off_the_grid_keeps_its_proposed_cell():
    line = {"t": 1.0, "event": "refused", "vehicle": "a", "step": 1, "cell": [0, 0], "proposed": [-1, 0]}
    assert check_event({**line, "reason": "outside"}, strict=True) == "refused"
    with pytest.raises(EventError, match="proposed"):
        check_event({**line, "proposed": [-1], "reason": "outside"})
