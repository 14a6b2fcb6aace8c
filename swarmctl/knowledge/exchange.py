"""One vehicle's side of the knowledge sharing: a Knowledge, where its messages go, and the protocol.

    ex = KnowledgeExchange(Knowledge(50, 50, vehicle_id=2), mission_id=7, peer=radio.address)   # UDP
    ex = KnowledgeExchange(Knowledge(50, 50, vehicle_id=2), mission_id=7, bus=bus, outlet=write)  # in-process
    ex.step(step, cell, on_target, cells, phi, obstacle)   # sense, then publish the delta (+ digest)
    ex.poll(timeout=0.0)                                   # merge what arrived, answer requests

Two ways the messages travel, one protocol:
- a UDP socket sending to `peer` (a MAVLink router, telemetry mesh or the loopback radio) and reading
  what it forwards: agents in separate processes (`swarmctl agent`, the onboard mode);
- a `swarmctl.knowledge.bus.KnowledgeBus`: the agents of one process (ground mode). Each frame is
  written once to `outlet` (the agent's own vehicle link: for the recording and any onboard agent)
  and its message delivered through the bus to the other agents of the process.

Protocol (payload layouts in swarmctl/knowledge/codec.py, docs/knowledge.md):
- every step the vehicle broadcasts a DELTA with the cells it explored itself since the last one
  (no relaying, like the simulator) and its position; a delta that does not fit is chunked;
- a vehicle that finds targets broadcasts a DETECTION at once; every `digest_every` steps it
  broadcasts its DIGEST (explored bitmap) and the targets it found itself again, each DETECTION with
  the step and cell it saw them from (a vehicle vouches only for what was in its own footprint, which
  is what receivers check: swarmctl.knowledge.trust);
- a vehicle that receives a digest showing cells it lacks sends a REQUEST (bitmap of the missing
  cells; at most one per digest chunk per `digest_every` steps) to the digest's sender, which
  answers with repair DELTAs of those cells (anything it knows, its own or received), broadcast so
  every vehicle missing them benefits; with `push` (default) a vehicle that receives a digest
  lacking cells it already knew before the digest's step also sends them at once (only the
  `push_fanout` vehicles following the digest's sender in id order do; cells learnt this step may
  still be in flight, so they are not pushed), which shortens convergence under loss
  (docs/knowledge.md). Steps are the swarm's common mission step.
Every message carries the sender's position; positions merge newest-step-wins.

Trust (docs/security.md): with `signing_key` every frame is MAVLink 2 signed and only frames signed
with the key are read; every message passes `KnowledgeTrust.admit` (mission members only, with their
system ids; steps not far ahead of its own; positions no faster than a vehicle flies; detections and
delta cells where the sender can have sensed them) before
it is merged, and answers to digests and requests are bounded per peer (swarmctl.knowledge.budget).

Concurrency: none of its own. The owner calls `poll` (from its loop, or, on UDP, when `fileno()` is
readable, e.g. asyncio's loop.add_reader); sends happen in the caller's thread. Messages from this
vehicle's own id (echoes) are ignored. Bad bytes are counted in `codec.rejected`, never raised.
"""

from __future__ import annotations

import logging
import select
import socket
from collections import Counter, deque
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt

from swarmctl.errors import InputError
from swarmctl.knowledge.budget import AnswerBudget
from swarmctl.knowledge.codec import BitmapChunk, KnowledgeCodec, Message, chunk_mask
from swarmctl.knowledge.model import Delta, Detection, Knowledge
from swarmctl.knowledge.trust import KnowledgeTrust

if TYPE_CHECKING:
    from swarmctl.knowledge.bus import KnowledgeBus

log = logging.getLogger("swarmctl.knowledge")

Address = tuple[str, int]


class DatagramSocket(Protocol):
    """What an exchange uses of its UDP socket: a socket.socket, or a wrapper (the recorder's tap)."""

    def sendto(self, data: bytes, address: Address, /) -> int: ...

    def recvfrom(self, bufsize: int, /) -> tuple[bytes, Any]: ...

    def fileno(self) -> int: ...

    def close(self) -> None: ...


NEVER = np.iinfo(np.int64).max
RECEIVE_BUFFER = 1 << 20  # bytes: room for a burst of a few thousand frames
# what one poll reads at most (the rest waits in the socket for the next poll, as the vehicle links'
# drains do: swarmctl.mavlink.inbox), so a flood cannot hold up the caller's loop
# What one poll reads: an onboard agent polls once a round and must keep up with a big swarm (40 agents
# send about 80 datagrams a round), so the bound is in bytes, each datagram counted as at least
# DATAGRAM_MIN (a flood of empty ones costs its recvfrom calls): at most 1,024 datagrams a poll.
DATAGRAM_PARSE = 8192  # bytes parsed of one datagram (a knowledge frame is at most 160); the rest dropped
DATAGRAM_MIN = 256  # bytes a datagram counts for at least
POLL_BYTES = 262144  # bytes parsed in all


class KnowledgeExchange:
    """Knowledge + where its messages go: a UDP socket on `host` that sends to `peer` (a radio or a
    MAVLink router), or a KnowledgeBus with an optional `outlet` (a callable taking each frame's bytes,
    e.g. a writer onto the vehicle's MAVLink link). `members` (vehicle index -> system id of every
    vehicle of the mission) and `fov` (sensor radius, cells) feed the trust checks; `signing_key` (32
    bytes) signs every frame and reads only frames signed with it."""

    def __init__(
        self,
        knowledge: Knowledge,
        mission_id: int,
        peer: Address | None = None,
        *,
        bus: KnowledgeBus | None = None,
        outlet: Callable[[bytes], bool] | None = None,
        system_id: int | None = None,
        digest_every: int = 5,
        push: bool = True,
        push_fanout: int = 2,
        host: str = "127.0.0.1",
        port: int = 0,
        members: Mapping[int, int] | None = None,
        fov: float | None = None,
        signing_key: bytes | None = None,
    ):
        if (peer is None) == (bus is None):
            raise ValueError("a KnowledgeExchange sends either to a UDP peer or on a bus: give one of them")
        self.knowledge = knowledge
        self.vehicle_id = knowledge.vehicle_id
        self.peer = peer
        self.bus = bus
        self.outlet = outlet
        self.digest_every = int(digest_every)
        self.push = push
        self.push_fanout = int(push_fanout)
        self._now = 0  # the latest step given to `step`/`publish`
        self._requested_at: dict[int, int] = {}  # digest chunk -> step of our last request for it
        # when each cell became known (push rule): views of the knowledge's stack row, so the agents of
        # one stack can be stepped at once (swarmctl.knowledge.stepping)
        stack, row = knowledge._stack, knowledge._row
        self._learned_at = stack.learned_at[row]
        self._noted = stack.noted[row]  # _learned_at != NEVER
        self._learned_at[...] = NEVER
        self._noted[...] = False
        self.system_id = knowledge.vehicle_id + 1 if system_id is None else int(system_id)
        self.codec = KnowledgeCodec(
            mission_id, knowledge.width, knowledge.height, system_id=self.system_id, signing_key=signing_key
        )
        self.trust = KnowledgeTrust(members, fov)
        self.budget = AnswerBudget(signed=signing_key is not None)
        self._found: dict[tuple[int, int], tuple[int, tuple[int, int] | None]] = {}  # own finds: (step, seen from)
        self.stats: Counter[str] = Counter()  # sent/received packets and bytes, requests, repairs
        self._inbox: deque[tuple[Message, str, int]] = deque()  # bus deliveries: (message, kind, frame bytes)
        self.sock: DatagramSocket | None = None  # UDP only
        self.address: Address | None = None
        if bus is not None:
            bus.join(self)
            return
        sock = self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)
            sock.bind((host, port))
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            raise InputError(
                f"knowledge link: cannot open UDP {host}:{port} ({exc.strerror}); "
                "check the address and that the port is free"
            ) from None
        self.address = sock.getsockname()

    # ----- life cycle -------------------------------------------------------------------------------
    def fileno(self) -> int:
        """The UDP socket's descriptor (-1 on a bus: nothing to wait for, deliveries are in memory)."""
        return self.sock.fileno() if self.sock is not None else -1

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
        if self.bus is not None:
            self.bus.leave(self)

    def __enter__(self) -> KnowledgeExchange:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----- sending ----------------------------------------------------------------------------------
    def _send(self, message: Message, repair: bool = False, answering: int | None = None) -> None:
        """Encode once; each frame goes out once: to the UDP peer, or to the outlet and the bus. An
        answer to vehicle `answering`'s digest or request goes out only as far as its budget allows."""
        for payload_type, payload, part in self.codec.encode_parts(message, repair):
            frame = self.codec.frame(payload_type, payload)
            if answering is not None and not self.budget.spend(answering, len(frame)):
                self.stats["withheld"] += 1  # the rest of the answer waits for the next period
                break
            if self.bus is not None:
                if self.outlet is not None and self.outlet(frame):
                    self.stats["link_packets"] += 1  # on the vehicle's own MAVLink link
                self.bus.publish(self, payload_type, payload, len(frame), part)
            else:
                assert self.sock is not None and self.peer is not None  # UDP: made with a peer, no bus
                try:
                    self.sock.sendto(frame, self.peer)
                except OSError as exc:  # a full buffer or an unreachable peer: counted, the mission goes on
                    if not self.stats["send_errors"]:
                        log.warning(
                            "knowledge: cannot send to %s (%s); further failures are only counted", self.peer, exc
                        )
                    self.stats["send_errors"] += 1
                    continue
            self.stats["sent_packets"] += 1
            self.stats["sent_bytes"] += len(frame)
            if answering is not None:
                self.stats["answer_packets"] += 1
                self.stats["answer_bytes"] += len(frame)

    def step(
        self,
        step: int,
        cell: tuple[int, int],
        on_target: bool = False,
        cells: npt.ArrayLike | None = None,
        phi: npt.ArrayLike | None = None,
        obstacle: npt.ArrayLike | None = None,
        targets: np.ndarray | None = None,
    ) -> None:
        """One decision step: record the own position, sense `cells` (with their phi and obstacle
        flags), note target cells found, and publish."""
        self.knowledge.set_position(step, cell, on_target)
        if cells is not None:
            assert phi is not None and obstacle is not None, "sensed cells come with their phi and obstacle flags"
            self.knowledge.sense(cells, phi, obstacle)
        self._note_learned(step)
        self.publish(step)
        if targets is not None and len(targets):
            self.report_targets(targets, step)

    def report_targets(self, cells: np.ndarray, step: int, seen_from: tuple[int, int] | None = None) -> None:
        """Record target cells this vehicle saw at `step` from `seen_from` (default: its own cell now)
        and broadcast a DETECTION at once, with that step and cell; repeated with every digest."""
        self.knowledge.add_targets(cells, step)
        pos = self.knowledge.own_position
        cell = seen_from if seen_from is not None else (pos.cell if pos else None)
        on_target = bool(pos and pos.on_target and pos.cell == cell and pos.step == step)
        for t in np.asarray(cells, dtype=np.int64).reshape(-1, 2):
            self._found.setdefault((int(t[0]), int(t[1])), (int(step), cell))
        self._send(Detection(self.vehicle_id, step, cell, on_target, cells))

    def publish(self, step: int) -> None:
        """Broadcast the delta; on this vehicle's digest steps also the digest and the known targets.
        Digests are staggered: vehicle v sends them when (step + v) % digest_every == 0."""
        self._publish(step, self.knowledge.take_delta())

    def _publish(self, step: int, delta: Delta) -> None:
        """`publish` with the delta taken already (swarmctl.knowledge.stepping takes all agents' at once)."""
        self._now = max(self._now, int(step))
        self.trust.own(self.vehicle_id, delta.step, delta.cell)  # the receiver's step and track (trust)
        self.budget.period(self._now // max(self.digest_every, 1))
        self._send(delta)
        self.stats["deltas"] += 1
        if self.digest_every > 0 and step > 0 and (step + self.vehicle_id) % self.digest_every == 0:
            self.publish_digest()

    def _note_learned(self, step: int) -> None:
        """Remember when each cell became known (for the push rule)."""
        fresh = self.knowledge.explored > self._noted  # explored, not noted yet
        if fresh.any():
            self._learned_at[fresh] = step
            self._noted |= fresh

    def publish_digest(self) -> None:
        """Broadcast the explored-cell digest now (all chunks) and, if any, the targets this vehicle
        found, each DETECTION with the step and cell they were seen from (targets learnt from others
        are theirs to repeat: a receiver takes a target only from the footprint of its finder)."""
        kn = self.knowledge
        pos = kn.own_position
        step, cell, on_target = (pos.step, pos.cell, pos.on_target) if pos else (0, None, False)
        for chunk in self.codec.digest(self.vehicle_id, step, cell, on_target, kn.explored):
            self._send(chunk)
        self.stats["digests"] += 1
        seen: dict[tuple[int, tuple[int, int] | None], list[tuple[int, int]]] = {}
        for target, where in sorted(self._found.items()):
            seen.setdefault(where, []).append(target)
        for (found_at, seen_from), targets in seen.items():
            self._send(Detection(self.vehicle_id, found_at, seen_from, False, np.array(targets)))

    # ----- receiving --------------------------------------------------------------------------------
    def deliver(self, message: Message, kind: str, size: int) -> None:
        """A message from another member of the bus (`kind` as in KIND_NAMES, its frame `size` bytes);
        handled at the next poll."""
        self._inbox.append((message, kind, size))

    def poll(self, timeout: float = 0.0) -> int:
        """Handle the datagrams (UDP) or deliveries (bus) waiting, waiting on UDP up to `timeout` s for the
        first. Returns how many. On UDP at most POLL_BYTES parsed (DATAGRAM_PARSE of each: the rest of a
        longer datagram is dropped, counted as `datagram`; each counted as at least DATAGRAM_MIN); the rest
        waits for the next poll."""
        if self.bus is not None:
            return self._poll_bus()
        sock = self.sock
        assert sock is not None  # UDP: no bus
        handled = 0
        parsed = 0
        wait = timeout
        while parsed < POLL_BYTES:
            if wait > 0:
                ready, _, _ = select.select([sock], [], [], wait)
                if not ready:
                    return handled
            try:
                data, _addr = sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return handled
            except ConnectionError:  # an ICMP error report from an earlier send: nothing to read
                continue
            wait = 0.0
            handled += 1
            self.stats["received_packets"] += 1
            self.stats["received_bytes"] += len(data)
            if len(data) > DATAGRAM_PARSE:
                self.codec._reject(
                    "datagram", f"{len(data)} bytes: the {len(data) - DATAGRAM_PARSE} past {DATAGRAM_PARSE}"
                )
                data = data[:DATAGRAM_PARSE]
            parsed += max(len(data), DATAGRAM_MIN)
            for message, sysid, size in self.codec.parse_frames(data):
                if message.sender == self.vehicle_id:
                    self.stats["own_echo"] += 1
                elif self.trust.admit(message, sysid):
                    self._handle(message, size)
        return handled

    def _poll_bus(self) -> int:
        assert self.bus is not None
        handled = self.bus.collect(self)  # a stacked ideal bus merges every member's deliveries at once
        while self._inbox:
            message, kind, size = self._inbox.popleft()
            handled += 1
            self.stats["received_packets"] += 1
            self.stats["received_bytes"] += size
            self.codec.accepted[kind] += 1  # what the codec would have counted had it decoded the frame
            self._handle(message, size)
        return handled

    def _handle(self, message: Message, size: int) -> None:
        """Merge an admitted message (`size`: its frame's bytes, credited to its sender's answer budget)
        and answer it when it is a digest or a request to us."""
        kn = self.knowledge
        if message.sender == self.vehicle_id:
            self.stats["own_echo"] += 1
            return
        sender = message.sender
        self.budget.received(sender, size)
        if isinstance(message, (Delta, Detection)):
            kn.merge(message)
            return
        assert isinstance(message, BitmapChunk)
        kn.merge_position(sender, message.position)
        theirs = chunk_mask(message, kn.width, kn.height)
        if message.target is None:  # a digest: ask for what they have and we lack ...
            missing = theirs & ~kn.explored
            last = self._requested_at.get(message.index)
            if missing.any() and (last is None or self._now - last >= max(self.digest_every, 1)):
                self._requested_at[message.index] = self._now
                self._request(sender, missing, message.index)
            # ... and offer what they lack and we knew (once per chunk and period, however many digests)
            if self.push and self._pushes_to(sender) and self.budget.first("push", sender, message.index):
                self._note_learned(self._now)
                region = chunk_mask(
                    BitmapChunk(0, 0, None, index=message.index, bits=np.ones_like(message.bits)), kn.width, kn.height
                )
                answer = kn.cells_delta(region & ~theirs & (self._learned_at < message.step))
                if len(answer):
                    self._send(answer, repair=True, answering=sender)
                    self.stats["pushes"] += 1
        elif message.target == self.vehicle_id and self.budget.first("repair", sender, message.index):
            answer = kn.cells_delta(theirs)  # a request to us: send what we know of it
            if len(answer):
                self._send(answer, repair=True, answering=sender)
                self.stats["repairs"] += 1

    def _pushes_to(self, sender: int) -> bool:
        """Whether this vehicle is one of the `push_fanout` vehicles after `sender` in the cyclic order
        of the ids it knows (so a digest draws a few pushes, not one from every vehicle)."""
        ids = sorted({*self.knowledge.positions, self.vehicle_id, sender})
        start = ids.index(sender)
        after = [ids[(start + k) % len(ids)] for k in range(1, len(ids))]
        return self.vehicle_id in after[: self.push_fanout]

    def _request(self, target: int, missing: np.ndarray, index: int) -> None:
        kn = self.knowledge
        pos = kn.own_position
        step, cell, on_target = (pos.step, pos.cell, pos.on_target) if pos else (0, None, False)
        chunk = self.codec.digest(self.vehicle_id, step, cell, on_target, missing, target=target)[index]
        self._send(chunk, answering=target)
        self.stats["requests"] += 1

    # ----- counters ---------------------------------------------------------------------------------
    def merged(self) -> int:
        """Knowledge messages taken so far: decoded and admitted by the trust checks."""
        return sum(self.codec.accepted.values()) - sum(self.trust.rejected.values())

    def rejections(self) -> dict[str, int]:
        """Messages dropped so far, by reason: the codec's (bad bytes, `signature`) and the trust
        checks' (`member`, `sysid`, `step`, `speed`, `footprint`)."""
        out = Counter(self.codec.rejected)
        out.update(self.trust.rejected)
        return dict(out)

    def counters(self) -> dict[str, int]:
        """sent/received packets and bytes, deltas, digests, requests, repairs, pushes, answers to
        digests and requests sent (`answer_packets`, `answer_bytes`) and withheld by the budget
        (`withheld`), accepted per kind (decoded), rejected per reason (prefixed 'rejected_': the
        codec's and the trust checks'), and `rejected` in all."""
        out = dict(self.stats)
        out.update({f"accepted_{k}": v for k, v in self.codec.accepted.items()})
        rejected = self.rejections()
        out.update({f"rejected_{k}": v for k, v in rejected.items()})
        out["rejected"] = sum(rejected.values())
        return out
