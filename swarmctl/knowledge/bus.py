"""Knowledge between the agents of one process (ground mode): an in-process bus, no hub to run.

    bus = KnowledgeBus()                                    # ideal: every message reaches every agent
    bus = KnowledgeBus(Channel("model", cell_size=10.0), seed=0)   # the simulator's losses (demo, tests)
    ex = KnowledgeExchange(Knowledge(50, 50, vehicle_id=0), mission_id=7, bus=bus, outlet=link_writer)

When one process flies every vehicle (`swarmctl fly`, `swarmctl demo`) its agents share what they know
here, in memory. An agent's exchange encodes each message once into its MAVLink 2 TUNNEL frames, hands
the frames to its `outlet` (the agent's own vehicle link, so the recording and any onboard agent see
them) and publishes each frame's payload on the bus with the message it carries (what decoding the
payload gives: KnowledgeCodec.encode_parts, pinned by the codec's tests; a payload published alone is
decoded here), and the bus delivers that message to every other member once (nothing is relayed, as on
a radio). The message a receiver merges is exactly what the frame carries (quantised phi, chunks), so
ground mode and the UDP knowledge channel of the onboard mode (`swarmctl agent`) feed the same merges.

Losses: with a `swarmctl.world.channel.Channel` (`"model"`, `"fixed"`, `"none"`) each frame from s to r
is lost with `channel.loss_probability(distance in cells)`, the sender's cell taken from the frame's
header and the receiver's from its own knowledge (an unknown cell counts as distance 0), as the
loopback radio (swarmctl.sim.radio) does over UDP. Randomness: one generator per (seed, sender system
id, receiver system id) link, like the radio's, so a run repeats whatever order the agents publish in.

What travels: on a lossy bus, everything (deltas, detections, digests, requests, repairs, pushes): the
digest protocol recovers what was lost, as over the radio. On an ideal bus every delta and detection
reaches every member at once and nothing is ever missing, so digests and requests carry nothing new
between members: they are still sent (the vehicle links and the recording get them) but not delivered
(counted in `skipped`), which keeps the cost of a big swarm down to the deltas.

Trust: each published message passes the mission's trust checks once, here, before any member gets
it (`KnowledgeTrust.admit`, the function the UDP exchange calls for what it reads: members only, their
system ids, positions no faster than a vehicle flies, detections inside the sender's footprint;
swarmctl.knowledge.trust), with the member list and fov of the first member to join. Frames are signed
when the members have a signing key (the outlet's copies: the recording and the vehicle links).

With a `swarmctl.knowledge.stack.KnowledgeStack` (`KnowledgeBus(stack=...)`, every member's Knowledge a
row of it, as `swarmctl.mission.sharing` builds them) an ideal bus does not queue each delta and
detection in every receiver's inbox: it keeps the decoded message once and, at the first poll of any
member, merges everything waiting into every receiver's row in one vectorised operation
(KnowledgeStack.merge_batch) and counts it in each receiver's counters. Deltas and detections merge
as a join (the order does not matter) and their handling sends nothing, so every agent ends each
round with exactly the knowledge and counters it would have had merging its inbox message by message.
A lossy bus delivers to each receiver's inbox as above (what each one got differs, and its digests
and requests answer).

Concurrency: none of its own; publish and poll from one thread (the controller's event loop).
Deliveries wait in each receiver's inbox (a stacked ideal bus: in the bus) until it polls
(KnowledgeExchange.poll), i.e. until the next decision round, as messages from the radio do.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any, Protocol

import numpy as np

from swarmctl.knowledge.codec import KIND_NAMES, PT_DELTA, PT_DETECTION, KnowledgeCodec, Message
from swarmctl.knowledge.model import Delta, Detection, Knowledge
from swarmctl.knowledge.stack import KnowledgeStack
from swarmctl.knowledge.trust import KnowledgeTrust
from swarmctl.world.channel import Channel

IDEAL_KINDS = frozenset({PT_DELTA, PT_DETECTION})  # what an ideal bus delivers (see the module docstring)


class Member(Protocol):
    """What the bus uses of a member: a swarmctl.knowledge.exchange.KnowledgeExchange (described here, not
    imported: that module imports this one)."""

    knowledge: Knowledge
    codec: KnowledgeCodec
    trust: KnowledgeTrust
    stats: Counter[str]
    vehicle_id: int
    system_id: int
    _now: int  # the member's latest step

    def deliver(self, message: Message, kind: str, size: int) -> None: ...

    def poll(self, timeout: float = 0.0) -> int: ...


class KnowledgeBus:
    """Delivers each member's messages to every other member once (see the module docstring)."""

    def __init__(self, channel: Channel | None = None, seed: int = 0, stack: KnowledgeStack | None = None):
        self.channel = channel or Channel("ideal")
        self.seed = int(seed)
        self.stack = stack
        self.members: list[Member] = []
        self._batch = _Batch(stack) if stack is not None else None
        self._codec: KnowledgeCodec | None = None
        self.trust = KnowledgeTrust()  # replaced by the first member's settings (join)
        self._rngs: dict[tuple[int, int], np.random.Generator] = {}
        self.published = 0  # frames published by members
        self.delivered = 0  # frames delivered on some link (sender -> receiver)
        self.lost = 0  # frames lost on some link (the channel model)
        self.skipped = 0  # frames an ideal bus does not deliver (digests, requests)

    @property
    def ideal(self) -> bool:
        return self.channel.kind == "ideal"

    def join(self, member: Member) -> None:
        """Add an exchange (its codec names the mission and grid every member must share)."""
        codec = member.codec
        if self._codec is None:
            self._codec = KnowledgeCodec(codec.mission_id, codec.width, codec.height)
            self.trust = KnowledgeTrust(member.trust.members, member.trust.fov)
        elif (codec.mission_id, codec.width, codec.height) != (
            self._codec.mission_id,
            self._codec.width,
            self._codec.height,
        ):
            raise ValueError("every member of a knowledge bus flies the same mission on the same grid")
        if any(m.vehicle_id == member.vehicle_id for m in self.members):
            raise ValueError(f"vehicle {member.vehicle_id} is on the bus already")
        self.members.append(member)
        if self._batch is not None:
            self._batch.joined(self.members)

    def leave(self, member: Member) -> None:
        if member in self.members:
            self.members.remove(member)
            if self._batch is not None:
                self._batch.joined(self.members)

    def collect(self, member: Member) -> int:
        """Merge what the bus holds for all members (a stacked ideal bus; see the module docstring) and
        return how many messages `member` received since its last collect (0 without a stack)."""
        if self._batch is None:
            return 0
        self._batch.flush()
        return self._batch.handled.pop(member, 0)

    def publish(
        self, sender: Member, payload_type: int, payload: bytes, size: int, message: Message | None = None
    ) -> int:
        """One TUNNEL payload of `sender` (its frame `size` bytes long) to every other member, lost as the
        channel says; returns how many members it reached. `message`: what the payload decodes to, when
        the sender has it (KnowledgeCodec.encode_parts); None: the payload is decoded here."""
        self.published += 1
        if self.ideal and payload_type not in IDEAL_KINDS:
            self.skipped += 1
            return 0
        assert self._codec is not None, "publish before join"
        if message is None:
            message = self._codec.decode(payload_type, payload)
        if message is None:  # never for a member's own encoding; counted in the bus codec's rejections
            return 0
        self.trust.advance(sender._now)  # the publisher's step: the bus's own (ground mode: lock-step)
        if not self.trust.admit(message, sender.system_id):  # counted in trust.rejected, delivered to no one
            return 0
        kind = KIND_NAMES[payload_type]
        # (an ideal bus carries deltas and detections only: IDEAL_KINDS)
        if self.ideal and self._batch is not None and self._batch.stacked and isinstance(message, (Delta, Detection)):
            reached = self._batch.add(sender, message, kind, size)
            self.delivered += reached
            return reached
        reached = 0
        for receiver in self.members:
            if receiver is sender:
                continue
            if self._lost(sender, receiver, message.cell):
                self.lost += 1
                continue
            receiver.deliver(message, kind, size)
            self.delivered += 1
            reached += 1
        return reached

    def _lost(self, tx: Member, rx: Member, tx_cell: tuple[int, int] | None) -> bool:
        if self.ideal:
            return False
        own = rx.knowledge.own_position
        rx_cell = own.cell if own is not None else None
        d = 0.0 if tx_cell is None or rx_cell is None else math.hypot(tx_cell[0] - rx_cell[0], tx_cell[1] - rx_cell[1])
        p = float(self.channel.loss_probability(np.array(d)))
        key = (tx.system_id, rx.system_id)
        rng = self._rngs.get(key)
        if rng is None:
            rng = self._rngs[key] = np.random.default_rng([self.seed, *key])
        return bool(rng.random() < p)

    def settle(self, limit: int = 1000) -> int:
        """Poll every member until no delivery is waiting (answers to digests included); returns the
        messages handled. For lock-step tests and tools; the controller polls once per round."""
        handled = 0
        for _ in range(limit):
            n = sum(m.poll(0.0) for m in list(self.members))
            handled += n
            if not n:
                return handled
        raise RuntimeError(f"knowledge bus not quiet after {limit} rounds of polling")

    def counters(self) -> dict[str, Any]:
        """published, delivered, lost and skipped frames, the channel kind, and the messages the trust
        checks dropped, by reason."""
        return dict(
            channel=self.channel.kind,
            published=self.published,
            delivered=self.delivered,
            lost=self.lost,
            skipped=self.skipped,
            rejected={k: v for k, v in self.trust.rejected.items() if v},
        )


class _Batch:
    """What a stacked ideal bus holds until the next poll: each message once, with its receivers."""

    def __init__(self, stack: KnowledgeStack):
        self.stack = stack
        self.stacked = True  # every member's knowledge is a row of the stack
        self.rows: dict[Member, int] = {}
        self.mask = np.zeros(stack.rows, dtype=bool)  # the members' rows (a new array at each change)
        self.messages: list[Delta | Detection] = []
        self.masks: list[np.ndarray] = []
        self.senders: list[int] = []  # the senders' rows
        self.kinds: list[str] = []
        self.sizes: list[int] = []
        self.handled: dict[Member, int] = {}

    def joined(self, members: list[Member]) -> None:
        """The membership changed: what was published before goes to the members of then."""
        self.stacked = all(m.knowledge._stack is self.stack for m in members)
        self.rows = {m: m.knowledge._row for m in members if m.knowledge._stack is self.stack}
        self.mask = np.zeros(self.stack.rows, dtype=bool)
        self.mask[list(self.rows.values())] = True

    def add(self, sender: Member, message: Delta | Detection, kind: str, size: int) -> int:
        self.messages.append(message)
        self.masks.append(self.mask)
        self.senders.append(sender.knowledge._row)
        self.kinds.append(kind)
        self.sizes.append(size)
        return int(self.mask.sum()) - 1

    def flush(self) -> None:
        """Merge every message held into its receivers' rows and count it in their counters."""
        if not self.messages:
            return
        messages, masks, senders = self.messages, self.masks, self.senders
        kinds, sizes = self.kinds, self.sizes
        self.messages, self.masks, self.senders, self.kinds, self.sizes = [], [], [], [], []
        receivers = np.stack(masks)
        receivers[np.arange(len(messages)), senders] = False
        self.stack.merge_batch(messages, receivers)
        # each member's counters: all messages of the batch but its own (one mask in the common case)
        packets = receivers.sum(axis=0)
        size = np.asarray(sizes, dtype=np.int64) @ receivers
        kind_of = np.array(kinds)
        by_kind = {kind: receivers[kind_of == kind].sum(axis=0) for kind in sorted(set(kinds))}
        for member, row in self.rows.items():
            n = int(packets[row])
            if not n:
                continue
            self.handled[member] = self.handled.get(member, 0) + n
            member.stats["received_packets"] += n
            member.stats["received_bytes"] += int(size[row])
            for kind, counts in by_kind.items():
                if counts[row]:
                    member.codec.accepted[kind] += int(counts[row])
