"""Forward the vehicles' MAVLink to a ground station, so QGroundControl or Mission Planner shows the
swarm while swarmctl flies it.

Only what the vehicles send is forwarded, byte for byte (signed packets stay signed): the ground
station watches; commands keep coming from swarmctl alone, so nothing it sends is relayed back.
"""

from __future__ import annotations

import logging
import socket
from typing import Any

log = logging.getLogger(__name__)


class GcsForwarder:
    """Send every packet handed to `forward` to (host, port) over UDP, best effort."""

    def __init__(self, host: str, port: int):
        self.address = (host, int(port))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.sent = 0
        self.dropped = 0

    def forward(self, msg: Any) -> None:
        """A MavlinkLink listener: forward the received message's bytes."""
        try:
            self.sock.sendto(bytes(msg.get_msgbuf()), self.address)
            self.sent += 1
        except OSError as exc:  # a ground station that is not there must not disturb the mission
            if not self.dropped:
                log.warning("forwarding to the ground station at %s:%d failed: %s", *self.address, exc)
            self.dropped += 1

    def close(self) -> None:
        self.sock.close()
