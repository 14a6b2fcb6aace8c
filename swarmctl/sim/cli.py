"""`swarmctl mock-vehicle`: run one mock autopilot as a real MAVLink endpoint until interrupted.
`swarmctl mock-relay`: a UDP relay that loses, delays, duplicates and reorders, in front of a port."""

from __future__ import annotations

import math
import socket
import time
from pathlib import Path

import click

from swarmctl.bounds import KEY_MAX_BYTES, SEED, read_limited, real, whole
from swarmctl.errors import InputError
from swarmctl.mavlink.codec import load_signing_key, parse_connection
from swarmctl.sim.relay import MAX_DELAY_S


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
    "--battery-drain",
    type=real(0, 100),
    default=0.08,
    show_default=True,
    help="Battery drain, % per simulated second while flying (a tenth of it armed on the ground).",
)
@click.option(
    "--swap-battery",
    type=real(0, 3600),
    default=0.0,
    help="Seconds after the vehicle has landed and disarmed with a used battery before a crew swaps it "
    "for a full one (it reboots on the new battery); 0: never.",
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
    battery_drain: float,
    swap_battery: float,
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
        battery_drain=battery_drain,
    )
    mock.start()
    try:
        click.echo(
            f"mock {autopilot} vehicle {sysid} on {connection}{' (signing)' if key else ''}; Ctrl-C to stop", err=True
        )
        end = time.monotonic() + duration if duration > 0 else math.inf
        down_since: float | None = None  # since when it has been landed and disarmed with a used battery
        while time.monotonic() < end:
            time.sleep(0.2)
            if swap_battery <= 0:
                continue
            if not mock.landed_disarmed or mock.battery >= 100.0:
                down_since = None
            elif down_since is None:
                down_since = time.monotonic()
            elif time.monotonic() - down_since >= swap_battery and mock.swap_battery():
                click.echo(f"mock vehicle {sysid}: battery swapped, rebooting on a full one", err=True)
                down_since = None
    finally:
        mock.stop()


def parse_host_port(text: str, option: str, lowest_port: int) -> tuple[str, int]:
    """HOST:PORT (a name or an IPv4 address, resolved here), or InputError naming the option."""
    fix = f"give HOST:PORT, e.g. {option} 127.0.0.1:14551"
    host, sep, port_text = text.strip().rpartition(":")
    if not sep or not host:
        raise InputError(f"{option} {text!r}: expected HOST:PORT; {fix}")
    if not port_text.isdigit() or not lowest_port <= int(port_text) <= 65535:
        raise InputError(f"{option} {text!r}: the port must be a number from {lowest_port} to 65535; {fix}")
    try:
        socket.gethostbyname(host)
    except (OSError, UnicodeError):
        raise InputError(f"{option} {text!r}: cannot resolve host {host!r}; {fix}") from None
    return host, int(port_text)


@click.command("mock-relay")
@click.option(
    "--to", "target", required=True, help="Where datagrams go: HOST:PORT (the controller's udpin port, or a vehicle's)."
)
@click.option(
    "--listen",
    default="127.0.0.1:0",
    show_default=True,
    help="Where senders send to: HOST:PORT (port 0: any free port, printed).",
)
@click.option(
    "--loss", type=real(0, 1), default=0.0, show_default=True, help="Loss probability per datagram, each way."
)
@click.option(
    "--delay-ms", type=real(0, MAX_DELAY_S * 1000), default=0.0, show_default=True, help="Mean one-way delay, ms."
)
@click.option(
    "--jitter-ms",
    type=real(0, MAX_DELAY_S * 1000),
    default=0.0,
    show_default=True,
    help="Delay spread, ms: each datagram waits delay +- jitter (uniform), so close ones are reordered.",
)
@click.option(
    "--duplicate", type=real(0, 1), default=0.0, show_default=True, help="Probability a datagram arrives twice."
)
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the faults' draws.")
@click.option(
    "--duration", type=real(0, 1e7), default=0.0, help="Stop after this many seconds (0: run until interrupted)."
)
def mock_relay_command(
    target: str,
    listen: str,
    loss: float,
    delay_ms: float,
    jitter_ms: float,
    duplicate: float,
    seed: int,
    duration: float,
) -> None:
    """Relay UDP datagrams to --to, losing, delaying, duplicating and reordering them each way.

    Point a vehicle (or a mock-vehicle's --connect udpout:) at the relay's --listen address instead of
    the controller's port; answers go back to whoever sent. Every sender gets its own socket towards
    --to, as each vehicle's radio would be its own address.
    """
    from swarmctl.sim.relay import LinkFaults, LossyRelay

    to = parse_host_port(target, "--to", 1)
    at = parse_host_port(listen, "--listen", 0)
    if jitter_ms > delay_ms:
        raise InputError(
            f"--jitter-ms {jitter_ms:g} is more than --delay-ms {delay_ms:g}: a delay cannot be negative; "
            "give a jitter of at most the delay"
        )
    faults = LinkFaults(loss, delay_ms / 1000, jitter_ms / 1000, duplicate)
    relay = LossyRelay(to, faults, seed=seed, listen=at)
    try:
        relay.start()
    except OSError as exc:
        why = exc.strerror or exc
        raise InputError(f"--listen {listen!r}: cannot listen there ({why}); pick another port") from None
    try:
        host, port = relay.address
        click.echo(
            f"relay {host}:{port} -> {to[0]}:{to[1]}: {faults.describe()}, each way (seed {seed}); Ctrl-C to stop",
            err=True,
        )
        end = time.monotonic() + duration if duration > 0 else math.inf
        while time.monotonic() < end:
            time.sleep(min(0.2, max(0.0, end - time.monotonic())))
    finally:
        relay.stop()
        c = relay.counts()
        click.echo(
            f"relay: {c.clients} sender(s); forward {c.forward.received} in, {c.forward.lost} lost, "
            f"{c.forward.duplicated} duplicated, {c.forward.sent} out; back {c.back.received} in, "
            f"{c.back.lost} lost, {c.back.duplicated} duplicated, {c.back.sent} out",
            err=True,
        )
