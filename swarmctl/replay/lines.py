"""Reading a recording's JSON-lines files (events.jsonl, knowledge.jsonl) back, line by line.

Every line is checked against the event schema (swarmctl.mission.events). A line that is not JSON
(a recording cut while a line was being written leaves a broken last line), or that breaks the schema,
is skipped and kept as a `Damage` with its byte offset; lines of kinds the schema does not name are
counted and skipped.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from swarmctl.bounds import GIB, read_limited
from swarmctl.mission.events import EventError, check_event
from swarmctl.replay.tlog import Damage

LINES_MAX_BYTES = GIB  # a 50-vehicle, 200-step demo writes about 30 MB of events


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
        out.events.append(obj)
    return out
