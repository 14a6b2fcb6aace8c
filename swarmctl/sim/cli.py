"""`swarmctl mock-vehicle`: run one mock autopilot as a real MAVLink endpoint until interrupted."""

from __future__ import annotations

import math
import time
from pathlib import Path

import click

from swarmctl.bounds import KEY_MAX_BYTES, read_limited, real, whole
from swarmctl.errors import InputError
from swarmctl.mavlink.codec import load_signing_key, parse_connection


def parse_home(text: str) -> tuple[float, float, float]:
    parts = [p.strip() for p in text.split(",")]
    fix = "give LAT,LON,ALT in degrees and metres AMSL, e.g. --home -35.363262,149.165237,584"
    if len(parts) != 3:
        raise InputError(f"--home {text!r}: expected three comma-separated numbers; {fix}")
    try:
        lat, lon, alt = (float(p) for p in parts)
    except ValueError:
        raise InputError(f"--home {text!r}: not numbers; {fix}") from None
    if not (-90 <= lat <= 90 and -180 <= lon <= 180 and -500 <= alt <= 9000):
        raise InputError(
            f"--home {text!r}: latitude must be in -90..90, longitude in -180..180 and altitude in -500..9000 m; {fix}"
        )
    return lat, lon, alt


@click.command("mock-vehicle")
@click.option("--sysid", type=whole(1, 255), default=1, show_default=True, help="MAVLink system id (1..255).")
@click.option(
    "--connect",
    "connection",
    default="udpout:127.0.0.1:14550",
    show_default=True,
    help="Where the controller is: udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT.",
)
@click.option(
    "--home", default="-35.363262,149.165237,584", show_default=True, help="Home LAT,LON,ALT (degrees, metres AMSL)."
)
@click.option("--autopilot", type=click.Choice(["ardupilot", "px4"]), default="ardupilot", show_default=True)
@click.option("--speed", type=real(0, 100, above=True), default=5.0, show_default=True, help="Horizontal speed, m/s.")
@click.option(
    "--speedup",
    type=real(0, 100, above=True),
    default=1.0,
    show_default=True,
    help="Simulated seconds per wall-clock second (physics only; link timing stays real).",
)
@click.option(
    "--signing-key",
    type=str,
    default=None,
    help="File with a 32-byte MAVLink 2 signing key: sign everything, accept only signed.",
)
@click.option(
    "--ready-after",
    type=real(0, 3600),
    default=5.0,
    show_default=True,
    help="Simulated seconds after boot before the pre-arm checks pass.",
)
@click.option(
    "--gcs-failsafe",
    type=real(0, 3600),
    default=5.0,
    show_default=True,
    help="Seconds without a controller heartbeat before RTL (0 disables).",
)
@click.option(
    "--duration", type=real(0, 1e7), default=0.0, help="Stop after this many seconds (0: run until interrupted)."
)
def mock_vehicle_command(
    sysid: int,
    connection: str,
    home: str,
    autopilot: str,
    speed: float,
    speedup: float,
    signing_key: str | None,
    ready_after: float,
    gcs_failsafe: float,
    duration: float,
) -> None:
    """Run a mock ArduCopter or PX4 vehicle that speaks MAVLink over a real socket."""
    from swarmctl.sim.autopilot import MockAutopilot

    parse_connection(connection, "--connect")
    key = None
    if signing_key:
        read_limited(Path(signing_key), "signing key file", KEY_MAX_BYTES, "--signing-key")
        key = load_signing_key(signing_key)
    home_position = parse_home(home)
    mock = MockAutopilot(
        sysid,
        connection,
        home=home_position,
        autopilot=autopilot,
        speed=speed,
        speedup=speedup,
        signing_key=key,
        ready_after=ready_after,
        gcs_failsafe_timeout=gcs_failsafe if gcs_failsafe > 0 else None,
    )
    mock.start()
    try:
        click.echo(
            f"mock {autopilot} vehicle {sysid} on {connection}{' (signing)' if key else ''}; Ctrl-C to stop", err=True
        )
        end = time.monotonic() + duration if duration > 0 else math.inf
        while time.monotonic() < end:
            time.sleep(0.2)
    finally:
        mock.stop()
