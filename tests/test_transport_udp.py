"""UDP transports own their ports: no two sockets share one, a listening port taken is named."""

from __future__ import annotations

import pytest

from swarmctl.errors import InputError
from swarmctl.mavlink.codec import parse_connection
from swarmctl.mavlink.transport import UdpTransport


def test_a_udpout_never_gets_the_port_of_an_open_udpin():
    """With SO_REUSEADDR a bind to port 0 could be given a port another such socket held (about one bind
    in 28 000 per socket held): a udpout on a udpin's port made that link answer itself."""
    held = [UdpTransport(parse_connection("udpin:127.0.0.1:0")) for _ in range(100)]
    try:
        ports = {t.local_port for t in held}
        assert len(ports) == len(held)
        for _ in range(1500):  # with the option, ~5 of these would land on a held port
            out = UdpTransport(parse_connection(f"udpout:127.0.0.1:{held[0].local_port}"))
            try:
                assert out.local_port not in ports
            finally:
                out.close()
    finally:
        for t in held:
            t.close()


def test_a_udpin_port_in_use_is_refused_with_the_port_named_and_free_again_once_closed():
    first = UdpTransport(parse_connection("udpin:127.0.0.1:0"))
    port = first.local_port
    with pytest.raises(InputError) as err:
        UdpTransport(parse_connection(f"udpin:127.0.0.1:{port}"))
    assert f"udpin:127.0.0.1:{port}" in str(err.value) and "port is free" in str(err.value)
    first.close()
    again = UdpTransport(parse_connection(f"udpin:127.0.0.1:{port}"))  # no TIME_WAIT for UDP
    again.close()
