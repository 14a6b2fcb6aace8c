"""Command-line options shared by the commands that build a world (eval, train, bench)."""

from __future__ import annotations

import click

from swarmctl.bounds import real, require_memory, whole
from swarmctl.errors import InputError
from swarmctl.world.config import (
    CHANNELS,
    MAX_CELL_SIZE,
    MAX_FOV,
    MAX_MAP,
    MAX_UAVS,
    MAX_WINDOW,
    SCENARIOS,
    WorldConfig,
)


def world_options(func):
    """Add the world's options (paper defaults) to a click command."""
    options = [
        click.option(
            "--scenario",
            type=click.Choice(SCENARIOS),
            default="cluster",
            show_default=True,
            help="Target placement rule.",
        ),
        click.option(
            "--clusters",
            type=whole(1),
            default=1,
            show_default=True,
            help="Clusters of targets (cluster scenario; > 1 is multi-cluster).",
        ),
        click.option(
            "--map", "map_size", type=whole(1, MAX_MAP), default=20, show_default=True, help="Map side M (cells)."
        ),
        click.option(
            "--uavs", "--vehicles", "uavs", type=whole(1, MAX_UAVS), default=2, show_default=True, help="Vehicles U."
        ),
        click.option("--targets", type=whole(1), default=4, show_default=True, help="Targets K."),
        click.option(
            "--obstacles",
            type=real(0, 0.4),
            default=0.0,
            show_default=True,
            help="Obstacle coverage fraction eta (0 .. 0.4).",
        ),
        click.option(
            "--channel",
            type=click.Choice(CHANNELS),
            default="ideal",
            show_default=True,
            help="Knowledge sharing: ideal, none, model (distance-based loss) or fixed (--loss).",
        ),
        click.option(
            "--loss",
            type=real(0, 1),
            default=0.0,
            show_default=True,
            help="Packet-loss probability for --channel fixed.",
        ),
        click.option(
            "--cell-size",
            type=real(0, MAX_CELL_SIZE, above=True),
            default=10.0,
            show_default=True,
            help="Metres per cell (channel model).",
        ),
        click.option(
            "--fov", type=real(0, MAX_FOV), default=3.0, show_default=True, help="Sensing radius zeta (cells)."
        ),
        click.option(
            "--window", type=whole(1, MAX_WINDOW), default=20, show_default=True, help="Observation window F."
        ),
        click.option(
            "--guard/--no-guard",
            default=False,
            show_default=True,
            help="Refuse moves into cells other vehicles hold or enter (the controller's guard).",
        ),
        click.option(
            "--remove-taken/--keep-taken",
            default=False,
            show_default=True,
            help="Observations: remove the targets other vehicles sit on from the value channel, "
            "as LA(n) does (--keep-taken is the paper's observation).",
        ),
    ]
    for option in reversed(options):
        func = option(func)
    return func


WORLD_KEYS = (
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


def world_config(kwargs: dict, **fields) -> WorldConfig:
    """Pop the world's options from a command's kwargs and build the validated config (options that
    only one setting of another reads are refused with the other, not ignored); `fields` are more
    WorldConfig fields a command sets itself (eval's finish line), validated together with them."""
    values = {k: kwargs.pop(k) for k in WORLD_KEYS}
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
