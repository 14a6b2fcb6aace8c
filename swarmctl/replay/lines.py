"""Reading a recording's JSON-lines files (events.jsonl, knowledge.jsonl) back, line by line.

Every line is checked against the event schema (swarmctl.mission.events). A line that is not JSON
(a recording cut while a line was being written leaves a broken last line), or that breaks the schema,
is skipped and kept as a `Damage` with its byte offset; lines of kinds the schema does not name are
counted and skipped.

A line that follows the schema but holds what no recorder writes is damage too (`implausible`): a time
`t` outside 2001..2128 (the tlog's own range), a step over MAX_STEP, more than MAX_VEHICLES names or
records in one list (a mission file allows 250 vehicles), a grid over the grid files' limits, a cell
outside them, or a whole number beyond 2**53. Each of those would otherwise cost the replay time or
memory without end (a step of 10**12 asks for 10**12 frames).
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from swarmctl.bounds import GIB, read_limited
from swarmctl.geo.defaults import MAX_GRID_CELLS, MAX_GRID_SIDE
from swarmctl.mission.events import EventError, check_event
from swarmctl.replay.tlog import MAX_STAMP_US, MIN_STAMP_US, Damage

LINES_MAX_BYTES = GIB  # a 50-vehicle, 200-step demo writes about 30 MB of events
MAX_STEP = 1_000_000  # decision rounds: a day's time limit (86,400 s) at more than 10 rounds a second
MAX_VEHICLES = 250  # a mission file's [[vehicles]] limit (swarmctl.mission.spec)
MAX_WHOLE = 2**53  # whole numbers beyond it are not exact as JSON numbers, and no field needs them
T_MIN, T_MAX = MIN_STAMP_US / 1e6, MAX_STAMP_US / 1e6  # 2001 .. 2128, as a tlog's timestamps
_LISTS = ("vehicles", "others", "held", "since", "map", "maps")  # one entry per vehicle (at most)
_CELLS = ("cell", "last_cell", "proposed")


def implausible(obj: dict) -> str | None:
    """Why a line that follows the schema cannot be a recorder's (None: it can)."""
    t = obj["t"]
    if not T_MIN <= t <= T_MAX:
        return f"time t {t!r} is not in 2001..2128 (seconds since 1970)"
    step = obj.get("step")
    if isinstance(step, int) and not 0 <= step <= MAX_STEP:
        return f"step {step} is not in 0..{MAX_STEP:,}"
    for key in _LISTS:
        value = obj.get(key)
        if isinstance(value, list) and len(value) > MAX_VEHICLES:
            return f"{key} has {len(value):,} entries, over the {MAX_VEHICLES} vehicles a mission may have"
    grid = obj.get("grid") if obj["event"] == "mission" else None
    if grid is not None and (min(grid) < 1 or max(grid) > MAX_GRID_SIDE or grid[0] * grid[1] > MAX_GRID_CELLS):
        return f"grid {grid} is over the limits of {MAX_GRID_SIDE:,} cells a side and {MAX_GRID_CELLS:,} in all"
    return _beyond(obj)


def _beyond(value: object, key: str = "") -> str | None:
    """A number or a cell in `value` (a parsed line) that no recording holds."""
    if isinstance(value, dict):
        return next((why for k, v in value.items() if (why := _beyond(v, k)) is not None), None)
    if isinstance(value, list):
        if key in _CELLS or key == "cells":
            flat = [value] if key in _CELLS else value
            if any(isinstance(c, list) and any(isinstance(v, int) and abs(v) > MAX_GRID_SIDE for v in c) for c in flat):
                return f"{key} holds a cell beyond {MAX_GRID_SIDE:,}, outside any grid"
        return next((why for v in value if (why := _beyond(v, key)) is not None), None)
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > MAX_WHOLE:
        return f"{key or 'a field'} holds {value}, beyond 2**53"
    return None


@dataclass
class Lines:
    """The valid lines of one file, what was skipped, and the kinds not in the schema."""

    path: Path
    events: list[dict] = field(default_factory=list)
    damage: list[Damage] = field(default_factory=list)
    unknown: Counter = field(default_factory=Counter)

    def of(self, kind: str) -> list[dict]:
        """The lines of one kind, in file order."""
        return [e for e in self.events if e["event"] == kind]


def read_lines(path: str | Path) -> Lines:
    """Read and check every line; InputError only when the file cannot be read at all."""
    path = Path(path)
    raw = read_limited(path, "recording's JSON-lines file", LINES_MAX_BYTES)
    out = Lines(path)
    offset = 0
    for number, line in enumerate(raw.split(b"\n"), start=1):
        at, offset = offset, offset + len(line) + 1
        if not line.strip():
            continue
        try:
            obj = json.loads(line)
        except (json.JSONDecodeError, UnicodeDecodeError):
            last = offset >= len(raw)
            why = f"line {number} is not JSON" + (" (cut short at the end of the file)" if last else "")
            out.damage.append(Damage(at, len(line), why))
            continue
        except RecursionError:  # the parser's own depth guard: no line the recorder writes nests so deep
            out.damage.append(Damage(at, len(line), f"line {number} is JSON nested too deeply"))
            continue
        try:
            kind = check_event(obj)
        except EventError as exc:
            out.damage.append(Damage(at, len(line), f"line {number}: {exc}"))
            continue
        if kind is None:
            out.unknown[str(obj["event"])] += 1
            continue
        odd = implausible(obj)
        if odd is not None:
            out.damage.append(Damage(at, len(line), f"line {number}: {kind}: {odd}"))
            continue
        out.events.append(obj)
    return out
