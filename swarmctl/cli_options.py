"""Command-line options shared by the commands that build a world (eval, train, bench)."""

from __future__ import annotations

import click

from swarmctl.errors import InputError
from swarmctl.world.config import CHANNELS, SCENARIOS, WorldConfig


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
            type=int,
            default=1,
            show_default=True,
            help="Clusters of targets (cluster scenario; > 1 is multi-cluster).",
        ),
        click.option("--map", "map_size", type=int, default=20, show_default=True, help="Map side M (cells)."),
        click.option("--uavs", "--vehicles", "uavs", type=int, default=2, show_default=True, help="Vehicles U."),
        click.option("--targets", type=int, default=4, show_default=True, help="Targets K."),
        click.option(
            "--obstacles", type=float, default=0.0, show_default=True, help="Obstacle coverage fraction eta (0 .. 0.4)."
        ),
        click.option(
            "--channel",
            type=click.Choice(CHANNELS),
            default="ideal",
            show_default=True,
            help="Knowledge sharing: ideal, none, model (distance-based loss) or fixed (--loss).",
        ),
        click.option(
            "--loss", type=float, default=0.0, show_default=True, help="Packet-loss probability for --channel fixed."
        ),
        click.option(
            "--cell-size", type=float, default=10.0, show_default=True, help="Metres per cell (channel model)."
        ),
        click.option("--fov", type=float, default=3.0, show_default=True, help="Sensing radius zeta (cells)."),
        click.option("--window", type=int, default=20, show_default=True, help="Observation window F."),
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


def world_config(kwargs: dict) -> WorldConfig:
    """Pop the world's options from a command's kwargs and build the validated config."""
    return WorldConfig(**{k: kwargs.pop(k) for k in WORLD_KEYS})


def require(condition: bool, message: str) -> None:
    if not condition:
        raise InputError(message)
