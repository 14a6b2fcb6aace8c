"""The recording's event schema: every kind of line in events.jsonl, knowledge.jsonl and inputs.jsonl,
every field, its type and unit, in one table.

The recorder writes these lines, `swarmctl replay` reads them back through `check_event`, and
docs/recording.md shows the tables `schema_markdown()` renders from this module (a test keeps the two
the same). Readers are lenient: fields this table does not name are allowed (a newer recorder may add
some) and kinds it does not name are skipped; `check_event(..., strict=True)` also refuses those, so
a test can hold a fresh recording to the table.

Field kinds: `int`, `number` (int or float), `str`, `bool`, `cell` ([x, y] grid indices, ints >= 0),
`cells` (a list of cells), `number rows` (a list of lists of numbers: a grid-sized array, x-major),
`xy` ([x, y] ints of any sign: a cell that may lie off the grid), `latlon`
([lat, lon] degrees), `latlons` (a list of them), `ints`, `numbers`, `strs`, and `records NAME` (a
list of objects following the record schema NAME below).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from swarmctl.mission.agent import State
from swarmctl.world.moves import MOVE_NAMES


@dataclass(frozen=True)
class Field:
    """One field of an event or record: name, kind (module docstring), unit, meaning."""

    name: str
    kind: str
    unit: str
    doc: str
    required: bool = True
    nullable: bool = False
    values: tuple[str, ...] | None = None  # the strings allowed, when the field is an enumeration


AGENT_STATES = tuple(s.value for s in State if s is not State.NEW)  # as the controller records them

_T = Field("t", "number", "s", "wall-clock time the line was written, seconds since 1970-01-01 UTC")
_VEHICLE = Field("vehicle", "str", "-", "the vehicle's name (mission file `[[vehicles]] name`)")
_SYSID = Field("sysid", "int", "-", "the vehicle's MAVLink system id")
_STEP = Field("step", "int", "steps", "decision round number: 1 for the first round; 0 before the first")

RECORDS: dict[str, tuple[str, tuple[Field, ...]]] = {
    "step vehicle": (
        "one searching vehicle in a `step` line",
        (
            _VEHICLE,
            _SYSID,
            Field("cell", "cell", "cells", "where the vehicle was when the round decided (before its move)"),
            Field(
                "obs",
                "str",
                "-",
                "observation digest: the first 16 hex digits of the sha1 of the 3 x F x F float32 observation "
                "(ddql policies; null for planners)",
                nullable=True,
            ),
            Field("q", "numbers", "-", "the network's Q-values of stay, north, east, south, west", nullable=True),
            Field("move", "str", "-", "the move the policy chose", values=MOVE_NAMES),
            Field("guarded", "str", "-", "the move flown after the safety guard", values=MOVE_NAMES),
            Field("refused", "str", "-", "why the guard refused the move (null: not refused)", nullable=True),
            Field("received", "int", "messages", "knowledge messages the vehicle's agent accepted since the last step"),
            Field(
                "by",
                "str",
                "-",
                "the planner that chose the move instead of the network (ddql straggler=frontier)",
                required=False,
            ),
        ),
    ),
    "step other": (
        "one vehicle that did not search this round (hovering, lost, rejoining, ended ...) in a `step` line",
        (
            _VEHICLE,
            _SYSID,
            Field("state", "str", "-", "its state at the end of the round", values=AGENT_STATES),
            Field("cell", "cell", "cells", "its cell at the end of the round (null: none held)", nullable=True),
            Field("received", "int", "messages", "knowledge messages its agent accepted since the last step"),
        ),
    ),
    "inputs held": (
        "one vehicle that did not search in an `inputs` line: the guard kept its cell free",
        (
            Field("index", "int", "-", "its mission index (the mission line's order); -1: another process's vehicle"),
            Field("cell", "cell", "cells", "the cell it held"),
        ),
    ),
}

EVENTS: dict[str, tuple[str, str, tuple[Field, ...]]] = {
    "mission": (
        "events.jsonl",
        "the first line: what is flown",
        (
            Field("name", "str", "-", "mission name"),
            Field("policy", "str", "-", "the policy spec (`ddql:PATH[:options]`, `frontier`, ...)"),
            Field("altitude", "number", "m", "flight altitude above home"),
            Field("end_action", "str", "-", "land, rtl or hover"),
            Field("grid", "cell", "cells", "grid width and height [W, H]"),
            Field("vehicles", "strs", "-", "vehicle names in mission order (the order is the vehicle index)"),
            Field(
                "fence",
                "latlons",
                "deg",
                "the geofence polygon uploaded to every vehicle (null: no fence)",
                nullable=True,
            ),
            Field(
                "finish",
                "str",
                "-",
                "the mission's finish line (`[mission] finish`; pos: `pos >= X`, X in the summary's `pos_goal`)",
                required=False,
                values=("held", "found", "covered", "pos"),
            ),
            Field(
                "expected_targets",
                "int",
                "targets",
                "the N the finish line counts (held: the vehicle count when the file leaves it out; null: unknown)",
                required=False,
                nullable=True,
            ),
            Field(
                "on_find",
                "str",
                "-",
                "what a vehicle does at a target it finds",
                required=False,
                values=("hold", "mark"),
            ),
            Field("seed", "int", "-", "the seed of the policy's random draws", required=False),
            Field(
                "weights_sha256",
                "str",
                "-",
                "ddql: the sha256 of the network's weights (the checkpoint's `weights_sha256`; null: a planner)",
                required=False,
                nullable=True,
            ),
            Field(
                "forward",
                "str",
                "-",
                "ddql: what ran the network (null: a planner)",
                required=False,
                nullable=True,
                values=("torch", "onnx", "onednn", "onnx+onednn", "torch+onednn"),
            ),
            Field(
                "hover",
                "str",
                "-",
                "the hover rule the vehicles parked by (left out: `first`, the rule before there were others)",
                required=False,
                values=("defer", "first", "no"),
            ),
            Field(
                "hold",
                "int",
                "targets",
                "the targets the hover rule waits for when fewer than the vehicles (null: one a vehicle)",
                required=False,
                nullable=True,
            ),
        ),
    ),
    "state": (
        "events.jsonl",
        "a vehicle's state changed (or the same state with new detail)",
        (
            _VEHICLE,
            _SYSID,
            Field("state", "str", "-", "the new state", values=AGENT_STATES),
            Field("cell", "cell", "cells", "the vehicle's cell then (null: none yet / none held)", nullable=True),
            Field("last_cell", "cell", "cells", "lost: the last cell it held", required=False, nullable=True),
            Field(
                "mode", "str", "-", "override: the flight mode the pilot chose; rejoin: the mode found", required=False
            ),
            Field(
                "armed",
                "bool",
                "-",
                "rejoin, or override after a link loss: armed when the link came back",
                required=False,
            ),
            Field(
                "position",
                "numbers",
                "deg, deg, m",
                "rejoin, or override after a link loss: latitude, longitude and metres above home when the link "
                "came back",
                required=False,
            ),
            Field(
                "lost_s",
                "number",
                "s",
                "rejoin, or override after a link loss: how long the link was lost",
                required=False,
            ),
            Field(
                "reason",
                "str",
                "-",
                "override: why (`pilot`: a pilot's mode; `not commanded`: off course for more than "
                "`[flight] off_course_rounds` rounds); low battery: `floor` (below `[battery] return_below`) or "
                "`energy` (below what its return takes plus `[battery] reserve`)",
                required=False,
                values=("pilot", "not commanded", "floor", "energy"),
            ),
            Field("off_m", "number", "m", "off course: metres from the path of its last step", required=False),
            Field("below_m", "number", "m", "off course: metres below the mission altitude", required=False),
            Field("rounds", "int", "rounds", "off course: rounds in a row off course", required=False),
            Field(
                "battery",
                "int",
                "%",
                "low battery: the charge left; rejoin after a battery swap: the new one",
                required=False,
            ),
            Field("distance_m", "number", "m", "low battery: its distance from home", required=False),
            Field("rate", "number", "%/s", "low battery: its consumption, measured (or the prior)", required=False),
            Field("seconds_home", "number", "s", "low battery: how long its return takes", required=False),
            Field("needed", "number", "%", "low battery: the charge its return takes plus the reserve", required=False),
            Field("relaunch", "bool", "-", "rejoin: true when it takes off again on a fresh battery", required=False),
            Field("error", "str", "-", "failed: why", required=False),
            Field(
                "rejoined",
                "bool",
                "-",
                "search: true when the vehicle came back after a link loss or a battery swap",
                required=False,
            ),
            Field(
                "end_state", "str", "-", "ended: how it ended (landed at home, hovering on target ...)", required=False
            ),
        ),
    ),
    "preflight": (
        "events.jsonl",
        "what a vehicle said (its STATUSTEXT) or still lacked (`waiting for ...`) while it got ready to arm; "
        "a text is not repeated within 10 s",
        (_VEHICLE, _SYSID, Field("text", "str", "-", "the text, e.g. `PreArm: Need Position Estimate`")),
    ),
    "limits": (
        "events.jsonl",
        "a vehicle's speeds, read at preflight, and the timeouts flown with (the mission's where it sets them)",
        (
            _VEHICLE,
            _SYSID,
            Field("read", "strs", "-", "the speed parameters read (empty: the firmware's defaults)"),
            Field("speed", "number", "m/s", "horizontal speed to a target"),
            Field("climb", "number", "m/s", "climb rate"),
            Field("descent", "number", "m/s", "descent rate"),
            Field("land_speed", "number", "m/s", "the landing's final descent rate"),
            Field("takeoff_timeout", "number", "s", "arming and climbing to the mission's altitude"),
            Field("step_timeout", "number", "s", "a step of one cell (the derived ones follow each move's distance)"),
            Field("end_timeout", "number", "s", "the end action's landing (derived: from the grid's far corner)"),
        ),
    ),
    "fence": (
        "events.jsonl",
        "a vehicle's fence upload (before take-off, and before a grounded vehicle rejoins)",
        (
            _VEHICLE,
            _SYSID,
            Field("uploaded", "bool", "-", "whether the vehicle took the fence"),
            Field("vertices", "int", "-", "uploaded: the polygon's vertex count", required=False),
            Field("error", "str", "-", "not uploaded: why", required=False),
        ),
    ),
    "link": (
        "events.jsonl",
        "a vehicle's link: first heartbeat, heartbeats stopped (3 s), heartbeats back",
        (_SYSID, Field("change", "str", "-", "what happened", values=("seen", "lost", "back"))),
    ),
    "targets": (
        "events.jsonl",
        "targets a vehicle's detector reported for the first time (within the footprint of a cell it reached)",
        (
            _VEHICLE,
            Field("cells", "cells", "cells", "the target cells"),
            _STEP,
            Field("latlon", "latlons", "deg", "the cells' centres, in the order of `cells`"),
        ),
    ),
    "find": (
        "events.jsonl",
        "a target entered the swarm's knowledge for the first time (swarmctl.mission.finish); with "
        '`on_find = "mark"` the finding vehicle also sent a STATUSTEXT saying so, and searches on',
        (
            Field(
                "vehicle",
                "str",
                "-",
                "the vehicle whose detector saw it (null: learnt from another process's vehicle over the knowledge "
                "channel)",
                nullable=True,
            ),
            Field("cell", "cell", "cells", "the target's cell"),
            Field("lat", "number", "deg", "the cell centre's latitude"),
            Field("lon", "number", "deg", "the cell centre's longitude"),
            _STEP,
            Field("time_s", "number", "s", "seconds since the search started (0: found during the launch)"),
        ),
    ),
    "refused": (
        "events.jsonl",
        "the safety guard refused a vehicle's move (it stays)",
        (
            _VEHICLE,
            _STEP,
            Field("cell", "cell", "cells", "where the vehicle was"),
            Field("proposed", "xy", "cells", "the cell the policy wanted (off the grid when the move left it)"),
            Field("reason", "str", "-", "why (outside, blocked, contested ...)"),
        ),
    ),
    "off_course": (
        "events.jsonl",
        "a vehicle is not where it was sent (`[flight] off_course_m` from the path of its last step, or "
        "`below_altitude_m` below the mission altitude) at the start of a round: its setpoint is sent again "
        "(swarmctl.mission.watch); `cleared`: it is back on course",
        (
            _VEHICLE,
            _SYSID,
            _STEP,
            Field("cell", "cell", "cells", "the cell it was sent to"),
            Field("off_m", "number", "m", "metres from the path of its last step", required=False),
            Field("below_m", "number", "m", "metres below the mission altitude (negative: above)", required=False),
            Field("rounds", "int", "rounds", "rounds in a row off course, this one included", required=False),
            Field("cleared", "bool", "-", "true: back on course", required=False),
        ),
    ),
    "step_timeout": (
        "events.jsonl",
        "a vehicle did not reach its cell within the step timeout (the cell stays claimed)",
        (_VEHICLE, _STEP, Field("cell", "cell", "cells", "the cell it was sent to")),
    ),
    "no_report": (
        "events.jsonl",
        "no report from the vehicle's detector arrived for a cell the vehicle reached (sense timeout); "
        "the cell's footprint is explored all the same, and a late report counts when it comes",
        (_VEHICLE, Field("cell", "cell", "cells", "the cell"), _STEP),
    ),
    "report_dropped": (
        "events.jsonl",
        "detector reports of a round named cells or targets outside the footprints of the cells the vehicle "
        "reached (or a cell it never reached): those were not used",
        (_VEHICLE, _STEP, Field("dropped", "int", "-", "cells and targets dropped this round")),
    ),
    "step": (
        "events.jsonl",
        "one decision round, written when its moves are flown and sensed",
        (
            _STEP,
            Field("vehicles", "records step vehicle", "-", "the vehicles that searched this round"),
            Field("others", "records step other", "-", "the other vehicles of this process"),
            Field("decide_ms", "number", "ms", "time the policy took for the round (every vehicle at once)"),
            Field(
                "pos",
                "number",
                "-",
                "the search's probability of success after the round, 4 decimals (swarmctl.mission.probability; "
                "left out by recorders before it)",
                required=False,
            ),
        ),
    ),
    "prior": (
        "events.jsonl",
        "where the person is likely to be, written once at the start of the search: what the step records' "
        "`pos` and the summary's `pos` are computed against (swarmctl.mission.probability)",
        (
            Field("pod", "number", "-", "the detector's probability of detection in one pass (`[sensing] pod`)"),
            Field(
                "weights",
                "number rows",
                "-",
                "the prior, normalised over the free cells: W lists of H numbers (x-major), 8 decimals",
            ),
            Field("source", "str", "-", "the `[mission] prior` file's name, or `uniform`"),
        ),
    ),
    "end": (
        "events.jsonl",
        "the search ended",
        (
            Field(
                "outcome",
                "str",
                "-",
                "how: complete (the finish line met), partial (the search could not go on short of it), time limit, "
                "failed, interrupted",
                values=("complete", "partial", "time limit", "failed", "interrupted"),
            ),
            Field("step", "int", "steps", "rounds flown"),
        ),
    ),
    "end_action": (
        "events.jsonl",
        "the end action a vehicle was given",
        (
            _VEHICLE,
            Field("action", "str", "-", "land, rtl, hover, or `none: link lost`"),
            Field("cell", "cell", "cells", "its cell then", required=False, nullable=True),
        ),
    ),
    "end_action_failed": (
        "events.jsonl",
        "a vehicle's end action failed",
        (_VEHICLE, Field("error", "str", "-", "why")),
    ),
    "fault": (
        "events.jsonl",
        "an unexpected error (a bug, or a reply nothing foresaw) in a part of the controller: in the live view "
        "it is reported and the view turned off; in the live page's server it is reported once (that request "
        "answered 500); anywhere else the search stops there, and every vehicle in the air is given its end "
        "action (the traceback is in fault.txt)",
        (
            Field(
                "part",
                "str",
                "-",
                "where: `live view`, `web page` (the live page's server: reported, and the search flies on), or "
                "`mission` (the launch, the rounds and what they call)",
            ),
            Field("where", "str", "-", "the innermost place in swarmctl it was raised: `file:line in function`"),
            Field("error", "str", "-", "the exception: `Type: message`"),
        ),
    ),
    "operator": (
        "events.jsonl",
        "an order the operator gave on the live page (`--web`, swarmctl.mission.web), as the controller took it: "
        "pause (the vehicles hold, no setpoint goes out, the clock and the time limit stop), resume, end (as "
        "Ctrl-C: every vehicle's end action), home (one vehicle sent home between rounds), confirm or reject a "
        "find (a rejected one is no target for this process's policy, hover rule and finish line any more)",
        (
            Field("action", "str", "-", "the order", values=("pause", "resume", "end", "home", "confirm", "reject")),
            Field("source", "str", "-", "where it came from", values=("web",)),
            _STEP,
            Field("vehicle", "str", "-", "home: the vehicle sent home", required=False),
            Field("cell", "cell", "cells", "confirm, reject: the find's cell", required=False),
        ),
    ),
    "recording_lost": (
        "events.jsonl",
        "a file of the recording stopped being written (a write failed: a full disk, a read-only mount, an I/O "
        "error); written as soon as events.jsonl can take it, at the latest with the mission's end",
        (
            Field("file", "str", "-", "the file (`mission.tlog`, `events.jsonl`, `summary.json`, ...)"),
            Field(
                "error",
                "str",
                "-",
                "why: the failure (`No space left on device (ENOSPC)`), or `stopped when FILE could not be written`",
            ),
            Field("since", "number", "s", "when it stopped (wall clock, seconds since 1970-01-01 UTC)"),
        ),
    ),
    "knowledge": (
        "knowledge.jsonl",
        "one vehicle's knowledge after a round, written when it changed since that vehicle's last line",
        (
            _STEP,
            _VEHICLE,
            Field(
                "explored",
                "str",
                "-",
                "the explored-cell mask: base64 of zlib of numpy.packbits (big bit order) of the (W, H) bool "
                "mask flattened x * H + y",
            ),
            Field("cells", "int", "cells", "how many cells the mask holds (a check on `explored`)"),
            Field("targets", "cells", "cells", "the target cells the vehicle knows of"),
        ),
    ),
    "inputs": (
        "inputs.jsonl",
        "one decision round's inputs: the beliefs of the vehicles that searched, as the policy was given them, "
        "and the guard's view (swarmctl.mission.inputs; the policy was given step `step` - 1)",
        (
            _STEP,
            Field("vehicles", "strs", "-", "the vehicles that searched, in the order the policy took them"),
            Field(
                "since",
                "ints",
                "steps",
                "per vehicle: the step of its previous line its map changes are counted from (0: from an empty map)",
            ),
            Field("map", "ints", "-", "per vehicle: its entry of `maps` (-1: its map did not change)"),
            Field(
                "maps",
                "strs",
                "-",
                "map changes: base64 of zlib of the changed cells' flat indices x * H + y (uint32 little-endian, "
                "each the difference to the one before) and their values (uint16 little-endian: phi_hat "
                "quantised to 0..255 where explored in bits 0-7, explored 256, known obstacle 512, known target 1024)",
            ),
            Field(
                "positions",
                "str",
                "-",
                "base64 of zlib of int16 little-endian (vehicles x N x 3): where each of them believes each of "
                "the N vehicles is (x, y; -1, -1: unknown) and whether it hovers on a target (1)",
            ),
            Field(
                "heard",
                "str",
                "steps",
                "base64 of zlib of int16 little-endian (vehicles x N): how many steps before the policy's step "
                "each of them last heard each of the N vehicles (negative: a report stamped later; -32768: never; "
                "clipped to +-32767); absent: all current",
                required=False,
            ),
            Field("held", "records inputs held", "-", "the guard's other vehicles, in the guard's order"),
        ),
    ),
}


class EventError(ValueError):
    """A line that does not follow the schema (the message names the field)."""


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return (_is_int(v) or isinstance(v, float)) and math.isfinite(v)


def _is_cell(v: Any) -> bool:
    return isinstance(v, list) and len(v) == 2 and all(_is_int(c) and c >= 0 for c in v)


def _is_latlon(v: Any) -> bool:
    return (
        isinstance(v, list)
        and len(v) == 2
        and all(_is_number(c) for c in v)
        and -90 <= v[0] <= 90
        and -180 <= v[1] <= 180
    )


_CHECKS = {
    "int": _is_int,
    "number": _is_number,
    "str": lambda v: isinstance(v, str),
    "bool": lambda v: isinstance(v, bool),
    "cell": _is_cell,
    "cells": lambda v: isinstance(v, list) and all(_is_cell(c) for c in v),
    "xy": lambda v: isinstance(v, list) and len(v) == 2 and all(_is_int(c) for c in v),
    "latlon": _is_latlon,
    "latlons": lambda v: isinstance(v, list) and all(_is_latlon(c) for c in v),
    "ints": lambda v: isinstance(v, list) and all(_is_int(c) for c in v),
    "numbers": lambda v: isinstance(v, list) and all(_is_number(c) for c in v),
    "number rows": lambda v: isinstance(v, list) and all(isinstance(r, list) and all(map(_is_number, r)) for r in v),
    "strs": lambda v: isinstance(v, list) and all(isinstance(c, str) for c in v),
}


def _check_fields(obj: dict, fields: tuple[Field, ...], where: str, strict: bool) -> None:
    for f in fields:
        if f.name not in obj:
            if f.required:
                raise EventError(f"{where}: field {f.name!r} is missing")
            continue
        value = obj[f.name]
        if value is None:
            if not f.nullable:
                raise EventError(f"{where}: field {f.name!r} is null")
            continue
        if f.kind.startswith("records "):
            sub = RECORDS[f.kind.removeprefix("records ")][1]
            if not isinstance(value, list):
                raise EventError(f"{where}: field {f.name!r} is not a list")
            for i, rec in enumerate(value):
                if not isinstance(rec, dict):
                    raise EventError(f"{where}: {f.name}[{i}] is not an object")
                _check_fields(rec, sub, f"{where}: {f.name}[{i}]", strict)
            continue
        if not _CHECKS[f.kind](value):
            raise EventError(f"{where}: field {f.name!r} is not a {f.kind}: {value!r:.60}")
        if f.values is not None and value not in f.values:
            raise EventError(f"{where}: field {f.name!r} = {value!r} is not one of {', '.join(f.values)}")
    if strict:
        extra = sorted(set(obj) - {f.name for f in fields} - {"t", "event"})
        if extra:
            raise EventError(f"{where}: field(s) {', '.join(extra)} not in the schema")


def check_event(obj: Any, strict: bool = False) -> str | None:
    """Check one parsed line against the schema. Returns its kind, or None for a kind the schema does not
    name (strict: EventError). Raises EventError naming the field when a known kind breaks the schema."""
    if not isinstance(obj, dict):
        raise EventError("the line is not a JSON object")
    kind = obj.get("event")
    if not isinstance(kind, str):
        raise EventError("field 'event' is missing or not a string")
    if not _is_number(obj.get("t")):
        raise EventError(f"{kind}: field 't' is missing or not a number")
    if kind not in EVENTS:
        if strict:
            raise EventError(f"event kind {kind!r} is not in the schema")
        return None
    _check_fields(obj, EVENTS[kind][2], kind, strict)
    return kind


def _table(fields: tuple[Field, ...]) -> list[str]:
    rows = ["| field | type | unit | meaning |", "|---|---|---|---|"]
    for f in fields:
        kind = f.kind + (" or null" if f.nullable else "") + ("" if f.required else ", optional")
        doc = f.doc + (f" (one of: {', '.join(f.values)})" if f.values else "")
        rows.append(f"| `{f.name}` | {kind} | {f.unit} | {doc} |")
    return rows


def schema_markdown() -> str:
    """The schema as Markdown tables (docs/recording.md holds this text between its schema markers)."""
    out = [f"Every line has `t` ({_T.unit}: {_T.doc}) and `event` (the kind, below).", ""]
    for kind, (file, doc, fields) in EVENTS.items():
        out += [f"#### `{kind}` ({file})", "", doc[0].upper() + doc[1:] + ".", "", *_table(fields), ""]
    for name, (doc, fields) in RECORDS.items():
        out += [f"#### record `{name}`", "", doc[0].upper() + doc[1:] + ".", "", *_table(fields), ""]
    return "\n".join(out).rstrip() + "\n"


DOC_START, DOC_END = "<!-- schema: start -->", "<!-- schema: end -->"


def with_schema(doc: str) -> str:
    """`doc` (docs/recording.md) with the text between its schema markers replaced by schema_markdown()."""
    head, rest = doc.split(DOC_START, 1)
    _old, tail = rest.split(DOC_END, 1)
    return f"{head}{DOC_START}\n{schema_markdown()}{DOC_END}{tail}"


if __name__ == "__main__":  # python -m swarmctl.mission.events docs/recording.md: refresh the tables
    import sys
    from pathlib import Path

    for name in sys.argv[1:]:
        path = Path(name)
        path.write_text(with_schema(path.read_text(encoding="utf-8")), encoding="utf-8")
