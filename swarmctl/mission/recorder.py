"""The mission recording: one folder per mission.

mission.tlog     every MAVLink packet the controller sent or received (vehicle links and the
                 knowledge channel), in the standard telemetry-log format: for each packet an
                 8-byte big-endian timestamp (microseconds since 1970) then the raw packet, as
                 MAVProxy and QGroundControl write it (pymavlink's mavlogdump.py reads it)
events.jsonl     one JSON object per line: state changes, link events, guard refusals and one
                 "step" record per decision step (each vehicle's cell, observation digest,
                 Q-values, chosen and guarded move, knowledge received)
knowledge.jsonl  one "knowledge" line per vehicle and step: the cells it has explored and the
                 targets it knows of after the round (only when they changed since its last line)
inputs.jsonl     one "inputs" line per decision round: the beliefs the deciding vehicles had and the
                 guard's view, for `swarmctl replay --verify` (swarmctl.mission.inputs)
mission.toml     a copy of the mission file (when there is one)
grid.npz         a copy of the grid
summary.json     targets found, time, steps per vehicle, distance flown, messages sent/lost

Every line's fields, types and units: swarmctl.mission.events (docs/recording.md).

A crash at any moment leaves every file readable up to that moment: each line of events.jsonl,
knowledge.jsonl and inputs.jsonl is handed to the operating system as it is written (a step's refusals,
and its knowledge lines, in one write each; a SIGKILL loses at most the write in progress, never a line
already written), the tlog at least every TLOG_FLUSH_S, and summary.json is
replaced whole (written beside, then renamed over), so it is always one complete summary. The files
are flushed to the operating system, not synced to the disk: a crash of the machine itself may lose more.
"""

from __future__ import annotations

import base64
import functools
import json
import os
import shutil
import struct
import threading
import time
import zlib
from collections.abc import Iterable
from pathlib import Path
from typing import IO, Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.knowledge.model import stacked_field
from swarmctl.knowledge.stack import NEVER
from swarmctl.mission.inputs import InputsEncoder

_TS = struct.Struct(">Q")
TLOG_FLUSH_S = 0.5  # the tlog is flushed this often (at least once a second, so a crash loses under a second)
# Event kinds that change what summary.json says: a running summary is rewritten after each of them.
CHANGE_KINDS = frozenset({"mission", "state", "link", "targets", "find", "end", "end_action", "end_action_failed"})


_SEPARATORS = (",", ":")  # compact JSON lines
_PLAIN = frozenset({str, int, bool, type(None)})  # written as they are


@functools.lru_cache(maxsize=4096)
def _quoted(name: str) -> str:
    """A string as JSON writes it (the vehicle names, encoded once each)."""
    return json.dumps(name)


def _jsonable(value: Any) -> Any:
    """A JSON-ready copy of `value`: floats rounded to 6 places, tuples and arrays as lists, numpy
    scalars as Python values, paths as strings (dict keys as strings)."""
    kind = type(value)
    if kind is float:
        return round(value, 6)
    if kind in _PLAIN:
        return value
    if kind is list or kind is tuple:  # the common containers without a call per plain item
        return [round(v, 6) if type(v) is float else v if type(v) in _PLAIN else _jsonable(v) for v in value]
    if kind is dict:
        return {str(k): v if type(v) in _PLAIN else _jsonable(v) for k, v in value.items()}
    return _jsonable_other(value)


def _jsonable_other(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float):
        return round(value, 6)
    if isinstance(value, Path):
        return str(value)
    return value


def summary_text(value: Any, depth: int = 2, indent: str = "") -> str:
    """`value` (JSON-ready) as JSON text for people: the outer `depth` levels of objects and arrays one
    item a line, indented by two spaces a level, everything deeper on the item's line (so a vehicle of
    summary.json is one line). The deep parts go through json's C encoder: `indent=` would send the
    whole text through its pure-Python one (2.6 ms against 1.2 for 50 vehicles' summary)."""
    if depth <= 0 or not isinstance(value, (dict, list)) or not value:
        return json.dumps(value)
    inner = indent + "  "
    if isinstance(value, dict):
        items = [f"{inner}{json.dumps(k)}: {summary_text(v, depth - 1, inner)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}"
    items = [inner + summary_text(v, depth - 1, inner) for v in value]
    return "[\n" + ",\n".join(items) + "\n" + indent + "]"


def _copy(source: Path, target: Path) -> None:
    if not (target.exists() and os.path.samefile(source, target)):
        shutil.copyfile(source, target)


class Recorder:
    """Writes the mission folder; every method is safe to call from the loop and from link threads."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._tlog = (self.folder / "mission.tlog").open("wb")
        self._events = (self.folder / "events.jsonl").open("w", encoding="utf-8")
        self._knowledge: IO[str] | None = None  # knowledge.jsonl, opened with the first snapshot
        self._known: dict[str, tuple[int, int]] = {}  # vehicle -> (cells, targets) of its last snapshot
        self._inputs: IO[str] | None = None  # inputs.jsonl, opened with the first decision round
        self._encoder = InputsEncoder()
        self._parser = mavlink2.MAVLink(None)
        self._parser.robust_parsing = True
        self.packets = 0
        self.events = 0
        self.changes = 0  # events of CHANGE_KINDS written so far
        self.closed = False
        self._closing = threading.Event()
        self._flusher = threading.Thread(target=self._flush_tlog, name="recorder-tlog-flush", daemon=True)
        self._flusher.start()

    def _flush_tlog(self) -> None:
        while not self._closing.wait(TLOG_FLUSH_S):
            with self._lock:
                if not self.closed:
                    self._tlog.flush()

    # --- MAVLink ---------------------------------------------------------------------------------------
    def packet(self, data: bytes, when: float | None = None) -> None:
        """One raw MAVLink packet (a single frame)."""
        stamp = int((time.time() if when is None else when) * 1e6)
        with self._lock:
            if self.closed:
                return
            self._tlog.write(_TS.pack(stamp) + data)  # bytes + any bytes-like: one new bytes
            self.packets += 1

    def frames(self, msgs: list) -> None:
        """Parsed MAVLink messages, each logged as its own packet (its frame as received), all with one
        timestamp: what a link handed over at once."""
        if not msgs:
            return
        stamp = _TS.pack(int(time.time() * 1e6))
        data = stamp + stamp.join([m.get_msgbuf() for m in msgs])  # stamp, frame, stamp, frame, ...
        with self._lock:
            if self.closed:
                return
            self._tlog.write(data)
            self.packets += len(msgs)

    def datagram(self, data: bytes) -> None:
        """A datagram that may hold several frames: each frame is logged as its own packet."""
        with self._lock:
            try:
                msgs = self._parser.parse_buffer(bytes(data)) or []
            except Exception:
                msgs = []
            if self._parser.buf_len():
                self._parser.buf, self._parser.buf_index = bytearray(), 0
                self._parser.expected_length = mavlink2.HEADER_LEN_V1 + 2
        for m in msgs:
            if m.get_type() != "BAD_DATA":
                self.packet(m.get_msgbuf())

    def tap_link(self, link: Any) -> None:
        """Record every packet a MavlinkLink receives (a batch listener) and sends (its writer)."""
        link.add_batch_listener(self.frames)
        mav = link.mav
        inner = mav.file
        recorder = self

        class _Tee:
            def write(self, data: bytes) -> None:
                inner.write(data)
                recorder.packet(data)

        mav.file = _Tee()

    # --- events ----------------------------------------------------------------------------------------
    def event(self, kind: str, **fields: Any) -> None:
        """One line of events.jsonl, flushed at once."""
        self.events_at_once([(kind, fields)])

    def plain_event(self, kind: str, **fields: Any) -> None:
        """`event` for fields that are JSON already, floats rounded as wanted (the step record, the
        longest line of a round): written without the copy `_jsonable` makes, unless json refuses them."""
        record = {"t": time.time(), "event": kind, **fields}
        try:
            line = json.dumps(record, separators=_SEPARATORS) + "\n"
        except (TypeError, ValueError):  # a numpy value after all
            line = json.dumps(_jsonable(record), separators=_SEPARATORS) + "\n"
        self._write_events([line], kind in CHANGE_KINDS)

    def events_at_once(self, events: list[tuple[str, dict]]) -> None:
        """Lines of events.jsonl, (kind, fields) each, in one write, flushed at once (one step's refusals)."""
        if not events:
            return
        lines = [
            json.dumps(_jsonable({"t": time.time(), "event": kind, **fields}), separators=_SEPARATORS) + "\n"
            for kind, fields in events
        ]
        self._write_events(lines, sum(kind in CHANGE_KINDS for kind, _ in events))

    def _write_events(self, lines: list[str], changes: int) -> None:
        with self._lock:
            if self.closed:
                return
            self._events.write(lines[0] if len(lines) == 1 else "".join(lines))
            self._events.flush()
            self.events += len(lines)
            self.changes += changes

    def knowledge(self, step: int, views: Iterable[tuple[str, Any]]) -> int:
        """One "knowledge" line per (vehicle name, Knowledge) whose explored cells or known targets changed
        since its last line (knowledge only grows, so the counts tell); returns how many were written.

        The vehicles' maps are counted and packed as one stacked array, and the vehicles that know the
        same cells and targets (with ideal sharing, nearly all) share one compressed map and one encoded
        tail of the line."""
        views = list(views)
        if not views:
            return 0
        knowledges = [kn for _, kn in views]
        explored = stacked_field(knowledges, "explored").reshape(len(views), -1)
        counts = np.count_nonzero(explored, axis=1).tolist()
        known_targets = (stacked_field(knowledges, "target_step") != NEVER).reshape(len(views), -1)
        n_targets = np.count_nonzero(known_targets, axis=1).tolist()
        changed = []
        with self._lock:
            known = self._known
            for u, (name, _) in enumerate(views):
                seen = (counts[u], n_targets[u])
                if known.get(name) != seen:
                    known[name] = seen
                    changed.append(u)
        if not changed:
            return 0
        packed = np.packbits(explored[changed], axis=1)
        tails: dict[tuple[bytes, tuple], str] = {}  # (packed map, targets) -> the line's encoded tail
        lines = []
        height = views[0][1].height
        for row, u in zip(packed, changed):
            name = views[u][0]
            flat = np.flatnonzero(known_targets[u])  # ascending: the cells sorted by x, then y
            targets = list(zip((flat // height).tolist(), (flat % height).tolist()))
            key = (row.tobytes(), tuple(targets))
            tail = tails.get(key)
            if tail is None:
                tail = tails[key] = json.dumps(
                    {
                        "explored": base64.b64encode(zlib.compress(key[0], 6)).decode("ascii"),
                        "cells": counts[u],
                        "targets": [[int(x), int(y)] for x, y in targets],
                    },
                    separators=_SEPARATORS,
                )
            # the text json.dumps writes for {"t", "event", "step", "vehicle", then the tail's items}
            lines.append(
                f'{{"t":{time.time()!r},"event":"knowledge","step":{int(step)},"vehicle":{_quoted(name)},{tail[1:]}\n'
            )
        with self._lock:
            if self.closed:
                return 0
            if self._knowledge is None:
                self._knowledge = (self.folder / "knowledge.jsonl").open("w", encoding="utf-8")
            self._knowledge.write("".join(lines))
            self._knowledge.flush()
        return len(lines)

    def inputs(self, step: int, names: list[str], beliefs: Any, held: list[tuple[int, tuple[int, int]]]) -> None:
        """Round `step`'s "inputs" line: the Beliefs the policy decided on for the vehicles `names` (in
        the batch's order) and the guard's other vehicles `held` as (mission index, or -1 for another
        process's vehicle, cell), in the guard's order."""
        fields = self._encoder.line(step, names, beliefs, held)
        line = json.dumps({"t": time.time(), "event": "inputs", **fields}, separators=(",", ":")) + "\n"
        with self._lock:
            if self.closed:
                return
            if self._inputs is None:
                self._inputs = (self.folder / "inputs.jsonl").open("w", encoding="utf-8")
            self._inputs.write(line)
            self._inputs.flush()

    def flush(self) -> None:
        with self._lock:
            if not self.closed:
                self._tlog.flush()
                self._events.flush()
                for f in (self._knowledge, self._inputs):
                    if f is not None:
                        f.flush()

    # --- files -----------------------------------------------------------------------------------------
    def copy_inputs(self, mission_file: Path | None, grid_file: Path | None, grid: Any = None) -> None:
        """The mission file and the grid beside the recording (a file already in its place, as when the
        recording folder is the mission's own, is left as it is)."""
        if mission_file is not None and Path(mission_file).is_file():
            _copy(Path(mission_file), self.folder / "mission.toml")
        if grid_file is not None and Path(grid_file).is_file():
            _copy(Path(grid_file), self.folder / "grid.npz")
        elif grid is not None:
            grid.save(self.folder / "grid.npz")

    def write_summary(self, summary: dict, running: bool = False) -> Path:
        """Replace summary.json whole (written beside it, then renamed over it), with `running`: true while
        the mission goes on, false for the final one."""
        path = self.folder / "summary.json"
        text = summary_text(_jsonable({**summary, "running": running})) + "\n"
        with self._lock:  # one writer at a time: the running summary and the final one share the name
            partial = path.with_name(f".{path.name}.partial")
            partial.write_text(text, encoding="utf-8")
            os.replace(partial, path)
        return path

    def close(self) -> None:
        self._closing.set()
        if self._flusher is not threading.current_thread():
            self._flusher.join()
        with self._lock:
            if self.closed:
                return
            self.closed = True
            self._tlog.close()
            self._events.close()
            for f in (self._knowledge, self._inputs):
                if f is not None:
                    f.close()
