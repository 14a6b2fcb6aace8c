"""A TCP port the mock autopilot serves, as ArduPilot SITL serves SERIAL0: it waits for a client, boots
when the first one connects, prints its console text before MAVLink, and takes the next client once
one has gone (a controller that reconnects gets heartbeats again).

The mock uses it for ``connect="tcpin:HOST:PORT"`` (port 0: any free one, see `local_port`).
"""

from __future__ import annotations

import select
import socket
import threading
from collections.abc import Callable

from swarmctl.mavlink.transport import Transport

SCHEME = "tcpin:"


def parse_tcpin(connect: str) -> tuple[str, int]:
    """(host, port) of "tcpin:HOST:PORT"; ValueError otherwise."""
    host, sep, port = connect.removeprefix(SCHEME).rpartition(":")
    if not connect.startswith(SCHEME) or not sep or not host or not port.isdigit() or int(port) > 65535:
        raise ValueError(f"{connect!r} is not tcpin:HOST:PORT")
    return host, int(port)


class Serial0Server(Transport):
    """One client at a time on a listening TCP socket. `on_connect()` is called, from the thread that
    reads, when a client has connected (before anything is read from it)."""

    datagrams = False

    def __init__(self, host: str, port: int):
        self.server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.server.bind((host, port))
        self.server.listen(1)
        self.local_port = self.server.getsockname()[1]
        self.client: socket.socket | None = None
        self.clients = 0  # how many have connected so far
        self.on_connect: Callable[[], None] | None = None
        self._lock = threading.Lock()

    def read(self, timeout: float) -> bytes:
        client = self.client
        if client is None:
            ready, _, _ = select.select([self.server], [], [], timeout)
            if ready:
                accepted, _addr = self.server.accept()
                accepted.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                with self._lock:
                    self.client = accepted
                    self.clients += 1
                if self.on_connect is not None:
                    self.on_connect()
            return b""
        ready, _, _ = select.select([client], [], [], timeout)
        if not ready:
            return b""
        try:
            data = client.recv(65535)
        except OSError:
            data = b""
        if not data:  # the client went away: wait for the next one
            self._drop(client)
        return data

    def write(self, data: bytes) -> None:
        client = self.client
        if client is None:
            return  # nobody listening: SITL's output goes nowhere too
        try:
            client.sendall(data)
        except OSError:
            self._drop(client)

    def _drop(self, client: socket.socket) -> None:
        with self._lock:
            if self.client is client:
                self.client = None
        client.close()

    def close(self) -> None:
        if self.client is not None:
            self._drop(self.client)
        self.server.close()
