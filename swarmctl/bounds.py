"""The limits on outside input, and the checks every boundary shares.

- Numbers on the command line: `real(lo, hi)` is click's FloatRange that also refuses NaN and
  infinity (click's own range lets NaN through: every comparison with it is false); `whole(lo, hi)`
  is click's IntRange. Seeds are whole numbers in 0..SEED_MAX.
- Files: `read_limited` refuses anything but a regular file, and a file over its size limit, before
  reading a byte; `load_json` also bounds the nesting depth before parsing (Python's parser would
  raise RecursionError a thousand levels down).
- Memory: `require_memory` refuses a job whose arrays would pass MEMORY_BUDGET before any exists.
- Output paths: `writable_folder` and `writable_file` probe an output place before the work begins,
  so a 10-minute run never ends on an unwritable path.

Every refusal is an InputError of one line naming the file or option, the value and the fix.
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
import tempfile
from pathlib import Path

import click
import numpy as np

from swarmctl.errors import InputError

MIB = 2**20
GIB = 2**30
MEMORY_BUDGET = 8 * GIB  # the largest array set one command may plan (the machines have 24 GiB)
SEED_MAX = 2**32 - 1
MAX_THREADS = 256  # --threads of every command (torch and onnxruntime CPU threads)
MAX_JSON_DEPTH = 64  # GeoJSON and QGroundControl plans nest about 8 deep
INPUT_MAX_BYTES = 64 * MIB  # an area, a no-fly set, a .plan, a KML file, a summary (a city outline is a few MB)
BUILDINGS_MAX_BYTES = 512 * MIB  # building footprints (a large city's OpenStreetMap export)
CHECKPOINT_MAX_BYTES = 256 * MIB  # a checkpoint of the paper's network is 0.3 MB
KEY_MAX_BYTES = 1024  # a MAVLink signing key file: 32 bytes, or 64 hex digits and a newline


# --- numbers --------------------------------------------------------------------------------------------


class FiniteRange(click.FloatRange):
    """click.FloatRange that refuses NaN and infinity too."""

    name = "number"

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number; give a number {self._describe_range()}", param, ctx)
        return number


def real(lo: float | None = None, hi: float | None = None, *, above: bool = False, below: bool = False) -> FiniteRange:
    """A finite float option in [lo, hi] (`above`: lo itself excluded; `below`: hi excluded)."""
    lo, hi = (int(v) if isinstance(v, float) and v.is_integer() else v for v in (lo, hi))  # "1<=x<=60" in errors
    return FiniteRange(lo, hi, min_open=above, max_open=below)


def whole(lo: int | None = None, hi: int | None = None) -> click.IntRange:
    """An integer option in [lo, hi]."""
    return click.IntRange(lo, hi)


SEED = whole(0, SEED_MAX)


def finite(value: object, lo: float, hi: float) -> bool:
    """Whether `value` is a real number (not a bool) in [lo, hi]."""
    return (
        isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and lo <= value <= hi
    )


# --- memory ---------------------------------------------------------------------------------------------


def size_text(nbytes: float) -> str:
    """A byte count for people: '1.5 GiB', '300 MiB', '12 kB'."""
    if nbytes >= GIB:
        return f"{nbytes / GIB:.1f} GiB"
    if nbytes >= MIB:
        return f"{nbytes / MIB:.0f} MiB"
    return f"{nbytes / 1000:.0f} kB"


def require_memory(nbytes: float, what: str, fix: str) -> None:
    """Refuse a job whose arrays (`what`, about `nbytes`) would pass MEMORY_BUDGET; `fix` says what to shrink."""
    if nbytes > MEMORY_BUDGET:
        raise InputError(
            f"{what} would need about {size_text(nbytes)}, over the {size_text(MEMORY_BUDGET)} limit; {fix}"
        )


# --- files ----------------------------------------------------------------------------------------------


def read_limited(path: Path, what: str, limit: int, field: str | None = None) -> bytes:
    """The bytes of `path`, a regular file of at most `limit` bytes (`what` names it in errors, `field`,
    e.g. "--signing-key", comes before the path)."""
    at = f"{field} {path}" if field else str(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise InputError(f"{at}: file not found; check the path") from None
    except OSError as exc:
        raise InputError(f"{at}: cannot be read ({exc.strerror}); check the path and its permissions") from None
    if not stat.S_ISREG(info.st_mode):
        kind = "a folder" if stat.S_ISDIR(info.st_mode) else "not a regular file"
        raise InputError(f"{at}: {kind}; give the path of {what}")
    if info.st_size > limit:
        raise InputError(
            f"{at}: {size_text(info.st_size)}, over the {size_text(limit)} a {what} may have; give a smaller file"
        )
    try:
        with path.open("rb") as fh:
            data = fh.read(limit + 1)
    except OSError as exc:
        raise InputError(f"{at}: cannot be read ({exc.strerror}); check the file's permissions") from None
    if len(data) > limit:  # it grew while we looked
        raise InputError(f"{at}: over the {size_text(limit)} a {what} may have; give a smaller file")
    return data


_JSON_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.S)
_OPENERS = np.zeros(256, dtype=np.int8)
_OPENERS[[ord("["), ord("{")]] = 1
_OPENERS[[ord("]"), ord("}")]] = -1
_CHUNK = 16 * MIB


def json_depth(data: bytes) -> int:
    """The deepest nesting of arrays and objects in JSON text (brackets inside strings do not count)."""
    bare = _JSON_STRING.sub(b'""', data)
    depth, deepest = 0, 0
    for start in range(0, len(bare), _CHUNK):
        steps = _OPENERS[np.frombuffer(bare, dtype=np.uint8, count=min(_CHUNK, len(bare) - start), offset=start)]
        if len(steps):
            running = depth + np.cumsum(steps, dtype=np.int64)
            deepest = max(deepest, int(running.max()))
            depth = int(running[-1])
    return deepest


def load_json(path: Path, what: str, limit: int = INPUT_MAX_BYTES, fix: str = "fix the file") -> object:
    """Parse a JSON file of at most `limit` bytes and MAX_JSON_DEPTH levels; `what` ("GeoJSON",
    "QGroundControl plan") names it in errors, `fix` ends the message of a file that does not parse."""
    data = read_limited(path, f"{what} file", limit)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a UTF-8 text file; export the data as {what}") from None
    depth = json_depth(data)
    if depth > MAX_JSON_DEPTH:
        raise InputError(
            f"{path}: JSON nested {depth} levels deep, over the {MAX_JSON_DEPTH} a {what} file may have; {fix}"
        )
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg}); {fix}") from None


# --- output paths ---------------------------------------------------------------------------------------


def writable_folder(folder: Path, option: str) -> Path:
    """Check, before any work, that `folder` is or can be made a folder files can be written in. Nothing
    is created: the nearest folder that exists is probed with a temporary file."""
    existing = folder
    try:
        while not existing.exists() and existing != existing.parent:
            existing = existing.parent
    except OSError as exc:  # a name too long, a loop of links
        raise InputError(f"{option} {folder}: {exc.strerror or exc}; give another folder") from None
    if not existing.is_dir():
        where = "" if existing == folder else f" ({existing} is a file)"
        raise InputError(f"{option} {folder}: a file is in the way{where}; give a folder")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as exc:
        raise InputError(
            f"{option} {folder}: cannot write in {existing} ({exc.strerror or exc}); give a writable folder"
        ) from None
    return folder


def writable_file(path: Path, option: str) -> Path:
    """Check, before any work, that the output file `path` can be written (nothing is created): a new
    file, or a regular file that may be overwritten (never a device or a pipe)."""
    try:
        if path.is_dir():
            raise InputError(f"{option} {path}: is a folder; give a file name in it")
        writable_folder(path.parent, option)
        if path.exists():
            if not path.is_file():
                raise InputError(f"{option} {path}: is not a regular file (a device or a pipe); give a file path")
            if not os.access(path, os.W_OK):
                raise InputError(f"{option} {path}: the file cannot be overwritten; give another path")
    except OSError as exc:  # a name too long, a loop of links
        raise InputError(f"{option} {path}: {exc.strerror or exc}; give another path") from None
    return path


RECORDING_MARK = "events.jsonl"  # every recording folder has it from its first moment


def new_recording_folder(folder: Path, option: str) -> Path:
    """`writable_folder`, and not a folder that already holds a recording (whose files would be
    overwritten)."""
    writable_folder(folder, option)
    if (folder / RECORDING_MARK).exists():
        raise InputError(
            f"{option} {folder}: already holds a recording ({RECORDING_MARK}); give another folder, or "
            "move that recording away first"
        )
    return folder
