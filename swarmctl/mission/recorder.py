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

A write that fails (a full disk, a read-only mount, an I/O error, a removed folder) never reaches the
flight: it is reported once (one line naming the file and the cause, per cause), the file is cut back
to its last whole line or packet, and the recording degrades: the bulky files (mission.tlog,
knowledge.jsonl, inputs.jsonl) stop at the first failure of any file, events.jsonl goes on while it
can, and the mission's end (its end lines in events.jsonl, the final summary.json) is written into
space reserved when the recording opened (`reserve` bytes, held by an unlinked file and released for
the end). `lost` says what stopped and why; the summary carries it (`recording_lost`) and the commands
exit with status 2.
"""

from __future__ import annotations

import base64
import errno
import functools
import json
import logging
import os
import shutil
import struct
import threading
import time
import zlib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.knowledge.model import stacked_field
from swarmctl.knowledge.stack import NEVER
from swarmctl.mission.inputs import InputsEncoder

log = logging.getLogger(__name__)

_TS = struct.Struct(">Q")
TLOG_FLUSH_S = 0.5  # the tlog is flushed this often (at least once a second, so a crash loses under a second)
TLOG_BUFFER = 65536  # bytes of tlog packets kept before they are written (and at least every TLOG_FLUSH_S)
# Space reserved when the recording opens, released for the mission's end: the end lines of events.jsonl
# (about 300 bytes a vehicle), the final summary.json beside the one it replaces (about 1 KB a vehicle),
# targets.geojson and targets.kml, each file rounded up to the disk's blocks.
RESERVE_BYTES = 128 * 1024
RESERVE_PER_VEHICLE = 4096
BULKY = ("mission.tlog", "knowledge.jsonl", "inputs.jsonl")  # stopped first when a write fails
_O_CLOEXEC = getattr(os, "O_CLOEXEC", 0)
# Event kinds that change what summary.json says: a running summary is rewritten after each of them.
CHANGE_KINDS = frozenset(
    {"mission", "state", "link", "targets", "find", "end", "end_action", "end_action_failed", "recording_lost"}
)


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


def reserve_for(vehicles: int) -> int:
    """The space a recording of `vehicles` vehicles reserves for its end (bytes)."""
    return RESERVE_BYTES + RESERVE_PER_VEHICLE * max(int(vehicles), 0)


def _write(fd: int, data: Any) -> int:
    """os.write: every byte of the recording goes out through here (tests put a full disk in its place)."""
    return os.write(fd, data)


def cause(exc: BaseException) -> str:
    """Why a write failed, in words: `No space left on device (ENOSPC)`."""
    if isinstance(exc, OSError) and exc.errno is not None:
        name = errno.errorcode.get(exc.errno)
        text = exc.strerror or os.strerror(exc.errno)
        return f"{text} ({name})" if name else text
    return f"{type(exc).__name__}: {exc}"


class _File:
    """One file of the recording, written with whole writes or none: a write that fails part-way is cut
    back to where the file ended before it, so every line and every packet in the file is whole."""

    def __init__(self, path: Path):
        self.path = path
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_APPEND | _O_CLOEXEC, 0o666)
        self.size = 0  # bytes written whole
        self.torn = False  # a failed write could not be cut back: the file ends in part of a line

    def write(self, data: bytes) -> None:
        total, done = len(data), 0
        with memoryview(data) as view:
            try:
                while done < total:
                    n = _write(self.fd, view[done:])
                    if n <= 0:
                        raise OSError(errno.EIO, os.strerror(errno.EIO))
                    done += n
            except OSError:
                if done:
                    try:
                        os.ftruncate(self.fd, self.size)
                    except OSError:
                        self.torn = True
                raise
        self.size += total

    def close(self) -> None:
        if self.fd >= 0:
            fd, self.fd = self.fd, -1
            os.close(fd)


def _write_file(path: Path, data: bytes) -> None:
    """`path` written whole with `data` (through _write), or removed."""
    out = _File(path)
    try:
        out.write(data)
    except OSError:
        out.close()
        try:
            path.unlink()
        except OSError:
            pass
        raise
    out.close()


class Recorder:
    """Writes the mission folder; every method is safe to call from the loop and from link threads.

    No write of the recording raises once it is open (the module's docstring: what degrades, the
    reserve); opening it does (OSError: the folder cannot be written, or `reserve` bytes do not fit),
    before anything flies."""

    def __init__(self, folder: str | Path, reserve: int = RESERVE_BYTES):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self.lost: dict[str, str] = {}  # file name -> why it stopped being written (empty: the recording is whole)
        self._stopped: set[str] = set()  # files not written any more
        self._reported: set[Any] = set()  # the causes reported (one line each)
        self._unnoted: list[dict] = []  # recording_lost lines events.jsonl has not taken yet
        self._ending = False  # the search is over: what comes now is the mission's end
        self._resumed = False  # events.jsonl, stopped by a failure, took up again for the end
        self._reserve: int | None = self._make_reserve(int(reserve))
        try:
            self._tlog = _File(self.folder / "mission.tlog")
            self._events = _File(self.folder / "events.jsonl")
        except OSError:
            self._release()
            raise
        self._tlog_buffer = bytearray()
        self._knowledge: _File | None = None  # knowledge.jsonl, opened with the first snapshot
        self._known: dict[str, tuple[int, int]] = {}  # vehicle -> (cells, targets) of its last snapshot
        self._inputs: _File | None = None  # inputs.jsonl, opened with the first decision round
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
                    self._tlog_out()

    # --- space and failures (each with the lock held) ----------------------------------------------------
    def _make_reserve(self, size: int) -> int | None:
        """An unlinked file holding `size` bytes of the disk until _release (None: no reserve)."""
        if size <= 0:
            return None
        path = self.folder / ".reserve"
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_TRUNC | _O_CLOEXEC, 0o600)
        try:
            os.unlink(path)  # nothing to see or leave behind: the space is held while the descriptor is open
            try:
                os.posix_fallocate(fd, 0, size)
            except (AttributeError, OSError) as exc:  # no fallocate here: the bytes written instead
                if isinstance(exc, OSError) and exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):
                    raise
                block, left = bytes(min(size, 65536)), size
                while left > 0:
                    left -= os.write(fd, block[: min(left, len(block))])
        except OSError as exc:
            os.close(fd)
            raise OSError(
                exc.errno,
                f"{exc.strerror or exc}: the {size // 1024} KiB kept for the end of the recording do not fit",
                str(self.folder),
            ) from None
        return fd

    def _release(self) -> None:
        """The reserved space, free for the mission's end."""
        if self._reserve is not None:
            fd, self._reserve = self._reserve, None
            os.close(fd)

    def _fail(self, name: str, exc: BaseException, keep: bool = False) -> None:
        """Writing `name` failed: it stops (unless `keep`), and with it every bulky file; the cause is
        reported once; at the mission's end the reserve is released."""
        now = round(time.time(), 6)
        why = cause(exc)
        for n in ([] if keep else [name]) + [b for b in BULKY if b != name]:
            if n in self._stopped:
                continue
            self._stopped.add(n)
            self.lost[n] = why if n == name else f"stopped when {name} could not be written"
            self._unnoted.append(dict(file=n, error=self.lost[n], since=now))
        if name == "mission.tlog":
            self._tlog_buffer.clear()
        if self._ending:
            self._release()
        key = exc.errno if isinstance(exc, OSError) and exc.errno is not None else type(exc).__name__
        if key in self._reported:
            return
        self._reported.add(key)
        if "events.jsonl" in self._stopped:
            what = "only the mission's end is written from here (its end lines and summary.json, into the space kept)"
        else:
            what = f"{', '.join(BULKY)} stop here; events.jsonl and summary.json go on"
            if name == "summary.json" and keep:
                what += " (summary.json at its next update)"
        log.error(
            "recording: cannot write %s: %s; %s; the flight goes on, exit status 2 at its end",
            self.folder / name,
            why,
            what,
        )

    def _events_write(self, data: bytes) -> bool:
        """`data` (whole lines, or b"") to events.jsonl after the recording_lost lines it has not taken
        yet; False when events.jsonl is stopped or this write failed. At the mission's end a failure
        releases the reserve and the write is made again (once)."""
        while "events.jsonl" not in self._stopped:
            out = self._events
            head = b"\n" if out.torn else b""  # a line cut short that could not be cut back: ended here
            if self._unnoted:
                head += "".join(
                    json.dumps({"t": time.time(), "event": "recording_lost", **d}, separators=_SEPARATORS) + "\n"
                    for d in self._unnoted
                ).encode()
            if not head and not data:
                return True
            try:
                out.write(head + data if head else data)
            except OSError as exc:
                if self._ending and self._reserve is not None:  # the end: into the space kept for it
                    self._fail("events.jsonl", exc, keep=True)
                    continue
                self._fail("events.jsonl", exc)
                return False
            out.torn = False
            if self._unnoted:
                self.events += len(self._unnoted)
                self.changes += len(self._unnoted)
                self._unnoted.clear()
            return True
        return False

    def _bulky(self, name: str, out: _File | None, data: bytes) -> bool:
        """`data` to a bulky file (mission.tlog, knowledge.jsonl, inputs.jsonl); False when it failed."""
        if out is None or name in self._stopped:
            return False
        try:
            out.write(data)
            return True
        except OSError as exc:
            self._fail(name, exc)
            self._events_write(b"")  # say so in events.jsonl while it can
            return False

    def _open_bulky(self, name: str) -> _File | None:
        if name in self._stopped:
            return None
        try:
            return _File(self.folder / name)
        except OSError as exc:
            self._fail(name, exc)
            self._events_write(b"")
            return None

    def _tlog_out(self) -> None:
        if self._tlog_buffer:
            data = bytes(self._tlog_buffer)  # a copy: nothing a failed write keeps holds the buffer
            self._tlog_buffer.clear()
            self._bulky("mission.tlog", self._tlog, data)

    def ending(self) -> None:
        """The search is over: from now on the mission's end is written (the end and end-action lines,
        the final summary). If part of the recording was lost by now, the reserve is released and
        events.jsonl (if it stopped) takes up again, for the end; if not, the reserve is kept until a
        write fails or the final summary."""
        with self._lock:
            self._ending = True
            if self.lost:
                self._release()
                if "events.jsonl" in self._stopped and not self._resumed and not self.closed:
                    self._resumed = True
                    self._stopped.discard("events.jsonl")
                    self._events_write(b"")

    def write_extra(self, name: str, make: Callable[..., object]) -> bool:
        """A file beside the recording made by make() (after the mission: the targets, the picture); a
        failure to write it is reported as the recording's are (its cause once) and counted in `lost`."""
        try:
            make()
            return True
        except OSError as exc:
            try:
                (self.folder / name).unlink(missing_ok=True)  # what it had written of it is no use
            except OSError:
                pass
            with self._lock:
                self._fail(name, exc)
            return False

    # --- MAVLink ---------------------------------------------------------------------------------------
    def packet(self, data: bytes, when: float | None = None) -> None:
        """One raw MAVLink packet (a single frame)."""
        stamp = int((time.time() if when is None else when) * 1e6)
        with self._lock:
            if self.closed or "mission.tlog" in self._stopped:
                return
            buffer = self._tlog_buffer
            buffer += _TS.pack(stamp)
            buffer += data
            self.packets += 1
            if len(buffer) >= TLOG_BUFFER:
                self._tlog_out()

    def frames(self, msgs: list) -> None:
        """Parsed MAVLink messages, each logged as its own packet (its frame as received), all with one
        timestamp: what a link handed over at once."""
        if not msgs:
            return
        stamp = _TS.pack(int(time.time() * 1e6))
        data = stamp + stamp.join([m.get_msgbuf() for m in msgs])  # stamp, frame, stamp, frame, ...
        with self._lock:
            if self.closed or "mission.tlog" in self._stopped:
                return
            buffer = self._tlog_buffer
            buffer += data
            self.packets += len(msgs)
            if len(buffer) >= TLOG_BUFFER:
                self._tlog_out()

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
                try:  # what is sent goes out whatever becomes of its record
                    recorder.packet(data)
                except Exception as exc:
                    with recorder._lock:
                        recorder._fail("mission.tlog", exc)

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
        data = (lines[0] if len(lines) == 1 else "".join(lines)).encode()
        with self._lock:
            if self.closed:
                return
            self.changes += changes  # the running summary follows the mission even when the lines are lost
            if self._events_write(data):
                self.events += len(lines)

    def knowledge(self, step: int, views: Iterable[tuple[str, Any]]) -> int:
        """One "knowledge" line per (vehicle name, Knowledge) whose explored cells or known targets changed
        since its last line (knowledge only grows, so the counts tell); returns how many were written.

        The vehicles' maps are counted and packed as one stacked array, and the vehicles that know the
        same cells and targets (with ideal sharing, nearly all) share one compressed map and one encoded
        tail of the line."""
        views = list(views)
        if not views or "knowledge.jsonl" in self._stopped:
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
                self._knowledge = self._open_bulky("knowledge.jsonl")
            if not self._bulky("knowledge.jsonl", self._knowledge, "".join(lines).encode()):
                return 0
        return len(lines)

    def inputs(self, step: int, names: list[str], beliefs: Any, held: list[tuple[int, tuple[int, int]]]) -> None:
        """Round `step`'s "inputs" line: the Beliefs the policy decided on for the vehicles `names` (in
        the batch's order) and the guard's other vehicles `held` as (mission index, or -1 for another
        process's vehicle, cell), in the guard's order."""
        if "inputs.jsonl" in self._stopped:
            return
        fields = self._encoder.line(step, names, beliefs, held)
        line = json.dumps({"t": time.time(), "event": "inputs", **fields}, separators=(",", ":")) + "\n"
        with self._lock:
            if self.closed:
                return
            if self._inputs is None:
                self._inputs = self._open_bulky("inputs.jsonl")
            self._bulky("inputs.jsonl", self._inputs, line.encode())

    def flush(self) -> None:
        """The tlog's packets out to the operating system (every other line is handed over as it is written)."""
        with self._lock:
            if not self.closed:
                self._tlog_out()

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

    def write_summary(self, summary: dict, running: bool = False) -> Path | None:
        """Replace summary.json whole (written beside it, then renamed over it), with `running`: true while
        the mission goes on, false for the final one (written into the reserved space). None when it
        could not be written (reported; a running one is tried again at the next call, and the one on
        disk stays the last whole one)."""
        path = self.folder / "summary.json"
        text = summary_text(_jsonable({**summary, "running": running})) + "\n"
        with self._lock:  # one writer at a time: the running summary and the final one share the name
            if not running:
                self._release()
            partial = path.with_name(f".{path.name}.partial")
            try:
                _write_file(partial, text.encode())
                os.replace(partial, path)
            except OSError as exc:
                self._fail("summary.json", exc, keep=running)
                self._events_write(b"")
                return None
        return path

    def close(self) -> None:
        self._closing.set()
        if self._flusher is not threading.current_thread():
            self._flusher.join()
        with self._lock:
            if self.closed:
                return
            self._tlog_out()
            self._release()
            self._events_write(b"")  # the losses events.jsonl has not told yet
            self.closed = True
            for f in (self._tlog, self._events, self._knowledge, self._inputs):
                if f is not None:
                    try:
                        f.close()
                    except OSError as exc:  # the last of an NFS file's writes may come back only here
                        self._fail(f.path.name, exc)
