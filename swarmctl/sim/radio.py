"""A loopback "radio": forwards broadcast MAVLink between the agents of a test or demo swarm over real
UDP sockets on 127.0.0.1 and loses TUNNEL packets like the simulator's channel model.

    with Radio(Channel("model", cell_size=10.0), seed=0) as radio:
        ... agents send to radio.address; the radio forwards each datagram to every other agent ...

Every agent sends its datagrams to `radio.address`; the radio learns the agent's address from its
first datagram (or from `add_peer`) and forwards every MAVLink frame to every other known agent.
A TUNNEL frame from sender s to receiver r is dropped with probability
`channel.loss_probability(distance in cells between s and r)`, the function
swarmctl.world.channel.Channel uses in the simulator, so simulated and MAVLink-level runs compare:
`Channel("model", cell_size)` (distance-dependent), `Channel("fixed", loss=p)`, `Channel("ideal")`
(no loss). Positions come from the knowledge header (sender x, y) of the TUNNEL payloads each agent
sends, or from `set_position`; a vehicle whose position is not known yet counts as distance 0.
Other MAVLink traffic (and bytes that do not parse) is forwarded unchanged, or dropped like TUNNEL
frames when `lossy_other=True`.

Randomness: one numpy generator per (seed, sender system id, receiver system id) link, so a run is
reproducible whatever order the agents' datagrams interleave in. A receiver's system id is learnt
from its own frames or given to `add_peer`; until then its UDP port stands in (not reproducible).

Concurrency: one background thread owns the socket (select with a short timeout); `close()` (or the
context manager) stops it, joins it and closes the socket. Counters are read under a lock.
"""

from __future__ import annotations

import logging
import math
import select
import socket
import threading
import time
from collections import Counter
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.knowledge.codec import PAYLOAD_TYPE_BLOCK, frame_sender_cell
from swarmctl.world.channel import Channel

log = logging.getLogger("swarmctl.radio")

Address = tuple[str, int]


class Radio:
    """Loopback broadcast medium with the simulator's packet-loss model (see the module docstring)."""

    def __init__(
        self,
        channel: Channel | None = None,
        seed: int = 0,
        host: str = "127.0.0.1",
        lossy_other: bool = False,
        poll_interval: float = 0.05,
    ):
        self.channel = channel or Channel("ideal")
        self.seed = int(seed)
        self.lossy_other = lossy_other
        self._poll = poll_interval
        self._lock = threading.Lock()
        self._peers: list[Address] = []
        self._sysid: dict[Address, int] = {}
        self._cell: dict[Address, tuple[int, int]] = {}
        self._rngs: dict[tuple[int, int], np.random.Generator] = {}
        self.received = 0  # datagrams received from agents
        self.delivered: Counter[Address] = Counter()  # datagrams sent to each agent
        self.dropped = 0  # frames lost on some link
        self.forwarded = 0  # frames delivered on some link
        self.bytes_in = 0
        self.bytes_out = 0
        self._stop = threading.Event()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 21)
            self.sock.bind((host, 0))
            self.sock.setblocking(False)
        except OSError:
            self.sock.close()
            raise
        self.address: Address = self.sock.getsockname()
        self._parser = mavlink2.MAVLink(None)
        self._parser.robust_parsing = True
        self._thread = threading.Thread(target=self._run, name="knowledge-radio", daemon=True)
        self._thread.start()

    # ----- set-up -----------------------------------------------------------------------------------
    def add_peer(self, address: Address, system_id: int | None = None) -> None:
        """Forward to `address` from now on (agents are also learnt from their first datagram).
        `system_id` names its loss streams before it has sent anything."""
        with self._lock:
            if address not in self._peers:
                self._peers.append(address)
            if system_id is not None:
                self._sysid[address] = int(system_id)

    def set_position(self, address: Address, cell: tuple[int, int]) -> None:
        """Override the radio's idea of where the agent at `address` is (grid cell)."""
        with self._lock:
            self._cell[address] = (int(cell[0]), int(cell[1]))

    def counts(self) -> tuple[int, dict[Address, int]]:
        """(datagrams received, datagrams delivered per agent), read atomically."""
        with self._lock:
            return self.received, dict(self.delivered)

    # ----- shutdown ---------------------------------------------------------------------------------
    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout=5.0)
        self.sock.close()

    def __enter__(self) -> Radio:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ----- the forwarding loop ----------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self.sock], [], [], self._poll)
            except (OSError, ValueError):
                return
            if not ready:
                continue
            while True:
                try:
                    data, addr = self.sock.recvfrom(65535)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    return
                try:
                    self._handle(data, addr)
                except Exception:  # never let one datagram stop the radio
                    log.exception("radio: failed to forward a datagram from %s", addr)
                    with self._lock:
                        self.received += 1

    def _split(self, data: bytes) -> list[tuple[bytes, Any]]:
        """(frame bytes, parsed message or None) for each frame in the datagram; if anything in it
        does not parse, the whole datagram is one unparsed piece (forwarded as it is)."""
        try:
            msgs = self._parser.parse_buffer(data) or []
        except Exception:
            msgs = None
        leftover = self._parser.buf_len()
        if leftover:
            self._parser.buf, self._parser.buf_index = bytearray(), 0
            self._parser.expected_length = mavlink2.HEADER_LEN_V1 + 2
        if msgs is None or leftover or not msgs or any(isinstance(m, mavlink2.MAVLink_bad_data) for m in msgs):
            return [(data, None)]
        return [(bytes(m.get_msgbuf()), m) for m in msgs]

    def _handle(self, data: bytes, addr: Address) -> None:
        pieces = self._split(data)
        with self._lock:
            self.received += 1
            self.bytes_in += len(data)
            if addr not in self._peers:
                self._peers.append(addr)
            for _frame, m in pieces:
                if m is None:
                    continue
                self._sysid.setdefault(addr, m.get_srcSystem())
                if m.get_type() == "TUNNEL" and m.payload_type in PAYLOAD_TYPE_BLOCK:
                    head = frame_sender_cell(bytes(m.payload))
                    if head is not None and head[2] is not None:
                        self._cell[addr] = head[2]
            receivers = [p for p in self._peers if p != addr]
            outgoing: list[tuple[bytes, Address]] = []
            for rx in receivers:
                kept = []
                for frame, m in pieces:
                    lossy = self.lossy_other or (m is not None and m.get_type() == "TUNNEL")
                    if lossy and self._lost(addr, rx):
                        self.dropped += 1
                    else:
                        self.forwarded += 1
                        kept.append(frame)
                if kept:
                    outgoing.append((b"".join(kept), rx))
                    self.delivered[rx] += 1
                    self.bytes_out += sum(len(k) for k in kept)
        for payload, rx in outgoing:
            try:
                self.sock.sendto(payload, rx)
            except OSError as exc:  # an agent that went away; the count above still says it was sent
                log.debug("radio: send to %s failed: %s", rx, exc)

    def _lost(self, tx: Address, rx: Address) -> bool:
        if self.channel.kind == "ideal":
            return False
        a, b = self._cell.get(tx), self._cell.get(rx)
        distance = 0.0 if a is None or b is None else math.hypot(a[0] - b[0], a[1] - b[1])
        p = float(self.channel.loss_probability(np.array(distance)))
        key = (self._sysid.get(tx, tx[1]), self._sysid.get(rx, rx[1]))
        rng = self._rngs.get(key)
        if rng is None:
            rng = self._rngs[key] = np.random.default_rng([self.seed, *key])
        return bool(rng.random() < p)


def wait_quiet(radio: Radio, agents: list, timeout: float = 10.0) -> None:
    """Poll every agent (KnowledgeExchange) until the radio has handled every datagram they sent and
    each has read every datagram delivered to it, answers sent while polling included. Raises
    TimeoutError after `timeout` seconds. For tests and demos that step a swarm in lock-step."""
    deadline = time.monotonic() + timeout
    while True:
        for a in agents:
            a.poll(0.0)
        sent = sum(a.stats["sent_packets"] for a in agents)
        received, delivered = radio.counts()
        if received == sent and all(a.stats["received_packets"] == delivered.get(a.address, 0) for a in agents):
            # nothing in flight: one more poll round must not read or send anything new
            if sum(a.poll(0.0) for a in agents) == 0 and sum(a.stats["sent_packets"] for a in agents) == sent:
                return
        if time.monotonic() > deadline:
            raise TimeoutError(
                f"swarm not quiet after {timeout} s: radio got {received}/{sent} datagrams, "
                f"agents read {[a.stats['received_packets'] for a in agents]} of {delivered}"
            )
        if agents:
            agents[0].poll(0.002)
