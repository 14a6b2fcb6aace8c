"""Pure helpers: angle codecs, local offsets, connection strings, key files, CLI input errors."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarmctl.cli import main
from swarmctl.errors import InputError
from swarmctl.mavlink.codec import (
    from_deg_e7,
    load_signing_key,
    ne_m,
    offset_m,
    parse_connection,
    to_deg_e7,
)

lat_st = st.floats(min_value=-89.0, max_value=89.0, allow_nan=False)
lon_st = st.floats(min_value=-180.0, max_value=180.0, allow_nan=False)


@given(lon_st)
def test_deg_e7_round_trip_within_half_a_unit(deg):
    e7 = to_deg_e7(deg)
    assert isinstance(e7, int) and abs(e7) <= 1_800_000_000 < 2**31
    assert abs(from_deg_e7(e7) - deg) <= 0.5e-7 + 1e-12


@given(st.integers(min_value=-1_800_000_000, max_value=1_800_000_000))
def test_deg_e7_integers_survive_the_float_trip(e7):
    assert to_deg_e7(from_deg_e7(e7)) == e7


@pytest.mark.parametrize("bad", [math.nan, math.inf, 180.0001, -500.0])
def test_deg_e7_rejects_non_angles(bad):
    with pytest.raises(ValueError):
        to_deg_e7(bad)


@given(lat_st, st.floats(-179, 179), st.floats(-2000, 2000), st.floats(-2000, 2000))
def test_local_offsets_invert(lat, lon, north, east):
    lat1, lon1 = offset_m(lat, lon, north, east)
    n, e = ne_m(lat, lon, lat1, lon1)
    assert abs(n - north) < 1e-6 and abs(e - east) < 1e-6 * max(1.0, 1 / math.cos(math.radians(lat)))


@pytest.mark.parametrize(
    "text, kind, host, port",
    [
        ("udpin:0.0.0.0:14550", "udpin", "0.0.0.0", 14550),
        ("udp:127.0.0.1:14550", "udpin", "127.0.0.1", 14550),
        ("udpout:10.0.0.2:14551", "udpout", "10.0.0.2", 14551),
        ("tcp:localhost:5760", "tcp", "localhost", 5760),
    ],
)
def test_connection_strings(text, kind, host, port):
    ep = parse_connection(text)
    assert (ep.kind, ep.host, ep.port) == (kind, host, port)


def test_serial_connection_and_mavsdk_urls():
    ep = parse_connection("/dev/ttyUSB0:57600")
    assert (ep.kind, ep.device, ep.baud) == ("serial", "/dev/ttyUSB0", 57600)
    assert ep.mavsdk_url() == "serial:///dev/ttyUSB0:57600"
    assert parse_connection("udpin:0.0.0.0:14540").mavsdk_url() == "udpin://0.0.0.0:14540"
    assert parse_connection("tcp:127.0.0.1:5760").mavsdk_url() == "tcpout://127.0.0.1:5760"


@pytest.mark.parametrize(
    "bad",
    ["", "udpin:14550", "udpout:host:port", "udpout:h:70000", "tcp:h:0", "http://x:80", "foo", "/dev/ttyUSB0:fast"],
)
def test_bad_connection_strings_name_the_field_and_the_fix(bad):
    with pytest.raises(InputError) as err:
        parse_connection(bad, "--connect")
    msg = str(err.value)
    assert msg.startswith("--connect") and "udpin:HOST:PORT" in msg and "\n" not in msg


def test_signing_key_files(tmp_path):
    raw = bytes(range(32))
    (tmp_path / "raw.key").write_bytes(raw)
    (tmp_path / "hex.key").write_text(raw.hex() + "\n")
    (tmp_path / "short.key").write_bytes(b"secret")
    assert load_signing_key(tmp_path / "raw.key") == raw
    assert load_signing_key(tmp_path / "hex.key") == raw
    for name in ("short.key", "missing.key"):
        with pytest.raises(InputError) as err:
            load_signing_key(tmp_path / name)
        assert "--signing-key" in str(err.value) and "32 raw bytes" in str(err.value)


@pytest.mark.parametrize(
    "args, words",
    [
        (["--connect", "udpout:127.0.0.1"], "--connect"),
        (["--home", "north,south,0"], "--home"),
        (["--sysid", "300"], "--sysid"),
        (["--signing-key", "/nonexistent/key"], "--signing-key"),
    ],
)
def test_cli_bad_input_is_one_line_and_exit_2(args, words, capsys):
    assert main(["mock-vehicle", *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("swarmctl: error: ") and words in err
