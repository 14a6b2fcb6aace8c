"""How the mission spec speaks: a pydantic error as one line (the key, the value, the rule, the fix),
and the table of keys for docs/mission.md.

Both work over a root model whose fields are the file's tables (a list field is an array of tables,
[[name]]), reading what each field declares: its type, range (ge, le), unit, meaning (description)
and, in json_schema_extra, `example`, `span` (the forms a value takes) and `default_text` (a default
worked out later).
"""

from __future__ import annotations

import json
import math
import typing
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel
from pydantic.fields import FieldInfo

from swarmctl.mavlink.codec import Endpoint


class SpecError(ValueError):
    """A rule a value breaks and the fix, raised inside validation; `key` continues the error's
    location (for checks over several keys), `value` is the value to show (else pydantic's input),
    `example` a good value to give on a command line."""

    def __init__(self, rule: str, fix: str, key: tuple = (), value: Any = None, example: str | None = None):
        super().__init__(f"{rule}; {fix}")
        self.rule, self.fix, self.key, self.value, self.example = rule, fix, key, value, example


def tables(root: type[BaseModel]) -> dict[str, type[BaseModel]]:
    """The file's tables: name -> the model of one table (of one entry, for an array of tables)."""
    return {name: t for name, info in root.model_fields.items() if (t := _table_of(info)) is not None}


def heading(root: type[BaseModel], name: str) -> str:
    """[name], or [[name]] for an array of tables."""
    return f"[[{name}]]" if typing.get_origin(root.model_fields[name].annotation) is list else f"[{name}]"


def table_of_key(root: type[BaseModel]) -> dict[str, str]:
    """Each key of the (non-array) tables -> its table."""
    return {
        key: name for name, model in tables(root).items() if heading(root, name)[1] != "[" for key in model.model_fields
    }


def explain(error: Any, root: type[BaseModel]) -> str:
    """One pydantic error as `key = value: rule; fix` (or `key is missing ...`, `key is not a key ...`)."""
    loc = tuple(error["loc"])
    cause = (error.get("ctx") or {}).get("error")
    if isinstance(cause, SpecError):
        loc += cause.key
    else:
        cause = None
    parts, info, owner = _walk(root, loc)
    key = _key(parts)
    if error["type"] == "extra_forbidden":
        return _unknown(root, parts, owner)
    top = heading(root, parts[0]) if len(parts) == 1 and parts[0] in root.model_fields else None
    if error["type"] in ("missing", "too_short") and top:
        return f"{top} is {'missing' if error['type'] == 'missing' else 'empty'}; add {info.description}"
    if error["type"] == "too_long" and top:
        most = (error.get("ctx") or {}).get("max_length")
        return f"{top}: {len(error.get('input') or ())} of them, more than the {most} a mission may have; fly fewer"
    if error["type"] == "missing":
        return f"{key} is missing ({info.description if info else 'needed'}); {_fix(parts, info)}"
    if cause is None and info is not None and _table_of(info) is not None:
        if top and top.startswith("[["):
            return f"{parts[0]} must be an array of tables; write {top} on a line of its own before each one's keys"
        if top:
            return f"{top} must be a table; write {top} on a line of its own, then its keys"
        return f"{key} must be a table; write one {heading(root, parts[0])} block each"
    value = cause.value if cause is not None and cause.value is not None else error.get("input")
    if cause is not None:
        return f"{key} = {_value(value)}: {cause.rule}; {cause.fix}"
    return f"{key} = {_value(value)}: {_rule(info)}; {_fix(parts, info)}"


def _walk(root: type[BaseModel], loc: tuple) -> tuple[list, Any, type[BaseModel]]:
    """Along an error's location: the key path in the file, the field it ends on (None for an
    unknown key) and the table that holds it."""
    model: type[BaseModel] | None = root
    owner: type[BaseModel] = root
    parts: list = []
    info = None
    for part in loc:
        if isinstance(part, int):
            if len(parts) == 1:  # the index into an array of tables
                parts.append(part)
            continue
        if model is None:  # past a value (pydantic's tags inside a type)
            break
        parts.append(part)
        owner = model
        info = model.model_fields.get(part)
        if info is None:  # an unknown key
            break
        model = _table_of(info)
    return parts, info, owner


def _table_of(info: FieldInfo) -> type[BaseModel] | None:
    for t in (info.annotation, *typing.get_args(info.annotation)):
        if isinstance(t, type) and issubclass(t, BaseModel):
            return t
    return None


def _key(parts: list) -> str:
    out = ""
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


def _unknown(root: type[BaseModel], parts: list, owner: type[BaseModel]) -> str:
    key, name, homes = _key(parts), parts[-1], table_of_key(root)
    if len(parts) == 1:
        if name in homes:
            return f"{name} belongs in [{homes[name]}]; write it below that table's heading"
        known = ", ".join(heading(root, t) for t in tables(root))
        return f"[{name}] is not a known table; use one of {known}"
    table = heading(root, parts[0])
    if homes.get(name, parts[0]) != parts[0] and parts[0] in homes.values():
        return f"{key} belongs in [{homes[name]}], not {table}; move it there"
    return f"{key} is not a key of {table}; use one of {', '.join(sorted(owner.model_fields))}"


def bounds(info: FieldInfo) -> tuple[float | None, float | None]:
    """A number field's range (ge, le); (None, None) for other fields."""
    lo = next((m.ge for m in info.metadata if hasattr(m, "ge")), None)
    hi = next((m.le for m in info.metadata if hasattr(m, "le")), None)
    return lo, hi


def _base_type(info: FieldInfo) -> Any:
    """The field's type without None and without Annotated metadata (Literal kept whole)."""
    t = info.annotation
    args = [a for a in typing.get_args(t) if a is not type(None)]
    if typing.get_origin(t) is not Literal and type(None) in typing.get_args(t):
        t = args[0]
    if typing.get_origin(t) is Annotated:
        t = typing.get_args(t)[0]
    return t


def _choices(info: FieldInfo) -> tuple[str, ...] | None:
    t = _base_type(info)
    return typing.get_args(t) if typing.get_origin(t) is Literal else None


def _extra(info: FieldInfo) -> dict[str, Any]:
    """A field's json_schema_extra: the dict setting() gives it (none: empty)."""
    extra = info.json_schema_extra
    return extra if isinstance(extra, dict) else {}


def _kind(info: FieldInfo) -> str:
    t = _base_type(info)
    if _choices(info):
        return "choice"
    names = {float: "number", int: "integer", bool: "true/false", str: "string", Path: "file path"}
    if typing.get_origin(t) is list:
        return "array"
    return names.get(t, "connection" if t is Endpoint or Endpoint in typing.get_args(t) else "table")


def _unit(info: FieldInfo) -> str:
    unit = _extra(info).get("unit", "")
    return f" ({unit})" if unit and unit != "%" else (" %" if unit else "")


def _rule(info: FieldInfo) -> str:
    if info is None:
        return "is not valid"
    kind, (lo, hi) = _kind(info), bounds(info)
    if kind == "number":
        return f"must be a finite number from {lo:g} to {hi:g}{_unit(info)}"
    if kind == "integer":
        return f"must be a whole number from {lo} to {hi}{_unit(info)}"
    if kind == "true/false":
        return "must be true or false"
    if kind == "choice":
        return f"must be one of {', '.join(_choices(info) or ())}"
    if kind == "array":
        span = _extra(info).get("span")
        return f"must be an array of numbers{f', {span}' if span else ''}"
    if info.metadata and any(hasattr(m, "pattern") for m in info.metadata):
        return "must be a name of letters, digits, '.', '_' or '-' (at most 64, starting with a letter or digit)"
    return "must be a non-empty string"


def _example(info: FieldInfo) -> Any:
    extra = _extra(info)
    if "example" in extra:
        return extra["example"]
    choices = _choices(info)
    if choices:
        return info.default if info.default is not None else choices[0]
    return info.default


def _fix(parts: list, info: FieldInfo | None) -> str:
    if info is None:
        return "see docs/mission.md"
    return f"write for example {parts[-1]} = {_value(_example(info))}"


def _value(value: Any) -> str:
    """A value as it would be written in TOML, shortened to fit one line."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, (str, Path, Endpoint)):
        text = json.dumps(str(value))
    elif isinstance(value, dict):
        text = "{" + ", ".join(f"{k} = {_value(v)}" for k, v in value.items()) + "}"
    elif isinstance(value, list):
        text = "[" + ", ".join(_value(v) for v in value) + "]"
    else:
        text = json.dumps(str(value))
    return text if len(text) <= 60 else text[:57] + "..."


def markdown_table(root: type[BaseModel]) -> str:
    """Every key of the file: table, key, type, default, range, meaning."""
    rows = ["| table | key | type | default | range | meaning |", "|---|---|---|---|---|---|"]
    for table, model in tables(root).items():
        name = heading(root, table)
        for key, info in model.model_fields.items():
            extra = _extra(info)
            if "default_text" in extra:
                default = extra["default_text"]
            elif info.is_required():
                default = "required"
            elif info.default is None:
                default = "none"
            else:
                default = f"`{_value(info.default)}`"
            lo, hi = bounds(info)
            unit = extra.get("unit", "")
            if lo is not None:
                span = f"{lo:g} to {hi:g} {unit}".strip()
            elif choices := _choices(info):
                span = ", ".join(choices)
            else:
                span = extra.get("span", "")
            meaning = (info.description or "").replace("|", "\\|")
            rows.append(f"| {name} | `{key}` | {_kind(info)} | {default} | {span} | {meaning} |")
    return "\n".join(rows)


def replace_between(path: Path, begin: str, end: str, text: str) -> bool:
    """Put `text` between the markers `begin` and `end` in the file; True when it changed."""
    old = path.read_text()
    head, found_begin, rest = old.partition(begin)
    _, found_end, tail = rest.partition(end)
    if not found_begin or not found_end:
        raise SystemExit(f"{path}: no {begin} ... {end} markers")
    new = f"{head}{begin}\n{text}\n{end}{tail}"
    path.write_text(new)
    return new != old
