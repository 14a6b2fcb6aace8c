"""Command-line options made from config dataclasses, and the world's options shared by the commands
that build a world (eval, train).

`options_from(cls, fields, overrides)` adds one click option per named field of a dataclass (WorldConfig,
TrainConfig), made from the field's metadata, so that each default is written once, in the dataclass:

- `help`: the option's help text; `unit`: said after it ("Map side M." and "cells": "Map side M (cells).");
- `option`: its name or names (default: --field-name); "--on/--off" for a bool field's pair of flags; a
  single name for a bool field is a flag that sets the opposite of the field's default (--plain-target);
- `lo`, `hi`, `above`, `below`: its bounds, as swarmctl.bounds.whole (an int field) or real (a float);
- `choices`: the values of a str field (click.Choice);
- `pair`, `metavar`: one option of two values that sets this field and the `pair` field (--temperature
  START END sets temperature_start and temperature_end).

Each option's parameter is named after its field; `values_from(cls, kwargs, fields)` pops the values
back out of a command's keyword arguments as {field: value}. `overrides` changes what a command needs
otherwise ({"keep_resume": {"default": None}}); the options are `FieldOption`s, which remember their
dataclass, their fields and whether the command gave a default of its own (tests/test_one_source.py).
"""

from __future__ import annotations

import dataclasses
import functools
import types
import typing
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import click

from swarmctl.bounds import real, require_memory, whole
from swarmctl.errors import InputError
from swarmctl.world.config import WorldConfig


class FieldOption(click.Option):
    """A click option made by options_from: `config` is its dataclass, `fields` the fields it sets (two
    for a pair), `own_default` whether the command gave it a default other than the dataclass's."""

    def __init__(self, *args, config: type, fields: tuple[str, ...], own_default: bool, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.config, self.fields, self.own_default = config, fields, own_default

    def field_default(self) -> Any:
        """The dataclass's default for the option's value (a pair's: both, as a tuple)."""
        values = tuple(field_default(self.config, name) for name in self.fields)
        return values if len(values) > 1 else values[0]


def field_default(cls: type, name: str) -> Any:
    """The default of a dataclass field."""
    f = _field(cls, name)
    if f.default is not dataclasses.MISSING:
        return f.default
    if not callable(f.default_factory):  # (MISSING: a field without a default)
        raise ValueError(f"{cls.__name__}.{name} has no default")
    return f.default_factory()


def field_help(cls: type, name: str) -> str | None:
    """The help text of a field's option (its metadata's help, with its unit)."""
    meta = _field(cls, name).metadata
    text, unit = meta.get("help"), meta.get("unit")
    if text is not None and unit is not None:
        text = f"{text.rstrip('.')} ({unit})."
    return text


def options_from(
    cls: type, fields: Sequence[str], overrides: Mapping[str, Mapping[str, Any]] | None = None
) -> Callable[[Callable], Callable]:
    """A decorator that adds to a click command one option per field of the dataclass `cls` named in
    `fields`, in that order, made from the fields' metadata (see the module's docstring); `overrides`
    maps a field to click.option arguments that replace the ones made."""
    overrides = dict(overrides or {})
    unknown = set(overrides) - set(fields)
    if unknown:
        raise ValueError(f"overrides for fields not among the options: {', '.join(sorted(unknown))}")
    options = [_option(cls, name, overrides.get(name, {})) for name in fields]

    def decorate(func: Callable) -> Callable:
        for option in reversed(options):
            func = option(func)
        return func

    return decorate


def values_from(cls: type, kwargs: dict, fields: Iterable[str]) -> dict[str, Any]:
    """Pop the values of the options options_from(cls, fields) made from a command's kwargs, as
    {field: value} (a pair's two values under their two fields)."""
    values = {}
    for name in fields:
        value = kwargs.pop(name)
        pair = _field(cls, name).metadata.get("pair")
        if pair is None:
            values[name] = value
        else:
            values[name], values[pair] = value
    return values


@functools.cache
def _fields(cls: type) -> dict[str, dataclasses.Field]:
    return {f.name: f for f in dataclasses.fields(cls)}


@functools.cache
def _kind(cls: type, name: str) -> type:
    """A field's type: int, float, str or bool (None left out of an optional one)."""
    kind = typing.get_type_hints(cls)[name]
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        kind = next(a for a in typing.get_args(kind) if a is not type(None))
    return kind


def _field(cls: type, name: str) -> dataclasses.Field:
    try:
        return _fields(cls)[name]
    except KeyError:
        raise ValueError(f"{cls.__name__} has no field {name!r}") from None


def _option(cls: type, name: str, override: Mapping[str, Any]) -> Callable:
    meta = _field(cls, name).metadata
    kind, default = _kind(cls, name), field_default(cls, name)
    decls = meta.get("option", "--" + name.replace("_", "-"))
    decls = (decls,) if isinstance(decls, str) else tuple(decls)
    attrs: dict[str, Any] = dict(default=default, show_default=True)
    if meta.get("help") is not None:
        attrs["help"] = field_help(cls, name)
    if "metavar" in meta:
        attrs["metavar"] = meta["metavar"]
    names: tuple[str, ...] = (name,)
    if "pair" in meta:
        names = (name, meta["pair"])
        attrs.update(nargs=2, default=(default, field_default(cls, meta["pair"])))
    if kind is bool:
        if len(decls) == 1 and "/" not in decls[0]:  # one flag: the opposite of the default
            attrs.update(is_flag=True, flag_value=not default, show_default=False)
    elif "choices" in meta:
        attrs["type"] = click.Choice(meta["choices"])
    elif kind is int:
        attrs["type"] = whole(meta.get("lo"), meta.get("hi"))
    elif kind is float:
        attrs["type"] = real(
            meta.get("lo"), meta.get("hi"), above=meta.get("above", False), below=meta.get("below", False)
        )
    elif kind is str:
        attrs["type"] = click.STRING
    else:
        raise ValueError(f"{cls.__name__}.{name}: no option for a {kind} field")
    attrs.update(override)
    return click.option(
        *decls, name, cls=FieldOption, config=cls, fields=names, own_default="default" in override, **attrs
    )


WORLD_KEYS = (  # the world's options, in the order of every command's help
    "scenario",
    "clusters",
    "map_size",
    "uavs",
    "targets",
    "obstacles",
    "channel",
    "loss",
    "cell_size",
    "fov",
    "window",
    "guard",
    "remove_taken",
)
world_options = options_from(WorldConfig, WORLD_KEYS)  # add the world's options (the paper's defaults) to a command


def world_config(kwargs: dict, **fields) -> WorldConfig:
    """Pop the world's options from a command's kwargs and build the validated config (options that
    only one setting of another reads are refused with the other, not ignored); `fields` are more
    WorldConfig fields a command sets itself (eval's finish line), validated together with them."""
    values = values_from(WorldConfig, kwargs, WORLD_KEYS)
    require(
        values["loss"] == 0 or values["channel"] == "fixed",
        f"--loss {values['loss']:g}: only --channel fixed reads it (the channel is {values['channel']}); "
        "add --channel fixed, or leave --loss out",
    )
    require(
        values["clusters"] == 1 or values["scenario"] == "cluster",
        f"--clusters {values['clusters']}: only --scenario cluster reads it (the scenario is "
        f"{values['scenario']}); leave --clusters out",
    )
    return WorldConfig(**values, **fields)


def require(condition: bool, message: str) -> None:
    """Raise InputError(message) unless the condition holds."""
    if not condition:
        raise InputError(message)


def require_world_memory(cfg: WorldConfig, batch: int, what: str, cells: int | None = None, extra: int = 0) -> None:
    """Refuse, before any array exists, `batch` episodes of `cfg` (plus `extra` bytes) that would not fit
    in memory (swarmctl.world.env.planned_bytes)."""
    from swarmctl.world.env import planned_bytes

    require_memory(
        planned_bytes(cfg, batch, cells) + extra,
        what,
        "use a smaller --map, fewer --uavs or a smaller --fov or --window",
    )
