"""What answering costs: bytes a vehicle sends in answer per byte a sender makes it receive, per message
kind, over real UDP on 127.0.0.1 (tools/knowledge_amplification.py prints the table; docs/security.md).

The vehicle (index 0) knows every cell of a W x H map and runs a step per round (its own deltas and
digests go out as usual and are not counted); the sender sends `per_step` messages of one kind each
round for `steps` rounds, at its worst for the vehicle:

    DELTA      a few cells round the sender's position (draws no answer)
    DETECTION  one target in the sender's footprint (draws no answer)
    DIGEST     an empty bitmap chunk (the sender "lacks" every cell of it: the vehicle pushes)
    REQUEST    a request to the vehicle for every cell of a chunk (the vehicle repairs)

as a mission member (index 1 with its system id: what an unsigned channel lets anyone pretend) or as
a stranger (index 7); with `signed`, the vehicle signs and reads only signed frames, and the sender
holds the key (a real member) or not (a forger). Counted: the vehicle's answer bytes (`answer_bytes`:
pushes, repairs, requests) over the bytes of the sender's datagrams it received.
"""

from __future__ import annotations

import socket
from dataclasses import dataclass

import numpy as np

from swarmctl.knowledge.codec import KnowledgeCodec
from swarmctl.knowledge.exchange import KnowledgeExchange
from swarmctl.knowledge.model import Delta, Detection, Knowledge

KINDS = ("DELTA", "DETECTION", "DIGEST", "REQUEST")
MISSION = 7
FOV = 3.0
KEY = bytes(range(32))


@dataclass
class Amplification:
    """One measurement: bytes the sender's datagrams carried, answer bytes the vehicle sent."""

    kind: str
    sender: str
    received: int
    answered: int

    @property
    def ratio(self) -> float:
        return self.answered / self.received if self.received else 0.0


def _messages(codec: KnowledgeCodec, kind: str, sender: int, step: int, n: int, size: int) -> list[bytes]:
    cell = (0, 0)
    if kind == "DELTA":
        cells = np.array([[0, 0], [0, 1], [1, 0]])
        message = Delta(sender, step, cell, False, cells, np.zeros(3, np.uint8), np.zeros(3, bool))
        return [f for _ in range(n) for f in codec.frames(message)]
    if kind == "DETECTION":
        return [f for _ in range(n) for f in codec.frames(Detection(sender, step, cell, False, np.array([[1, 1]])))]
    target = 0 if kind == "REQUEST" else None
    chunks = codec.digest(sender, step, cell, False, np.zeros((size, size), bool), target=target)
    if target is not None:
        chunks = [
            type(c)(c.sender, c.step, c.cell, False, c.index, c.count, np.ones_like(c.bits), target) for c in chunks
        ]
    return [f for i in range(n) for f in codec.frames(chunks[(step * n + i) % len(chunks)])]


def measure(
    kind: str,
    member: bool = True,
    size: int = 50,
    steps: int = 50,
    per_step: int = 1,
    signed: bool = False,
    sender_key: bool = False,
) -> Amplification:
    """Answer bytes per received byte for one kind (see the module docstring)."""
    sender, sysid = (1, 2) if member else (7, 8)
    key = KEY if signed else None
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sink:
        sink.bind(("127.0.0.1", 0))
        sink.setblocking(False)
        kn = Knowledge(size, size, vehicle_id=0)
        xs, ys = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
        every = np.stack([xs.ravel(), ys.ravel()], axis=1)
        kn.sense(every, np.full(len(every), 0.5), np.zeros(len(every), bool))
        vehicle = KnowledgeExchange(
            kn, MISSION, sink.getsockname(), system_id=1, members={0: 1, 1: 2}, fov=FOV, digest_every=5, signing_key=key
        )
        codec = KnowledgeCodec(MISSION, size, size, system_id=sysid, signing_key=key if sender_key else None)
        address = vehicle.address
        assert address is not None  # a UDP exchange
        try:
            for step in range(1, steps + 1):
                vehicle.step(step, (size - 1, size - 1))
                for frame in _messages(codec, kind, sender, step, per_step, size):
                    sink.sendto(frame, address)
                while vehicle.poll(0.05):
                    pass
                _drain(sink)
            who = ("member" if member else "stranger") + ("" if not signed else ", key" if sender_key else ", no key")
            return Amplification(kind, who, vehicle.stats["received_bytes"], vehicle.stats["answer_bytes"])
        finally:
            vehicle.close()


def _drain(sock: socket.socket) -> None:
    while True:
        try:
            sock.recv(65535)
        except BlockingIOError:
            return
