"""Knowledge between the agents of one process (ground mode): an in-process bus, no hub to run.

    bus = KnowledgeBus()                                    # ideal: every message reaches every agent
    bus = KnowledgeBus(Channel("model", cell_size=10.0), seed=0)   # the simulator's losses (demo, tests)
    ex = KnowledgeExchange(Knowledge(50, 50, vehicle_id=0), mission_id=7, bus=bus, outlet=link_writer)

When one process flies every vehicle (`swarmctl fly`, `swarmctl demo`) its agents share what they know
here, in memory. An agent's exchange encodes each message once into its MAVLink 2 TUNNEL frames, hands
the frames to its `outlet` (the agent's own vehicle link, so the recording and any onboard agent see
them) and publishes each frame's payload on the bus, which decodes it once and delivers the message to
every other member once (nothing is relayed, as on a radio). The message a receiver merges is exactly
what the frame carries (quantised phi, chunks), so ground mode and the UDP knowledge channel of the
onboard mode (`swarmctl agent`) feed the same merges.

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

Concurrency: none of its own; publish and poll from one thread (the controller's event loop).
Deliveries wait in each receiver's inbox until it polls (KnowledgeExchange.poll), i.e. until the next
decision round, as messages from the radio do.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from swarmctl.knowledge.codec import KIND_NAMES, PT_DELTA, PT_DETECTION, KnowledgeCodec
from swarmctl.knowledge.trust import KnowledgeTrust
from swarmctl.world.channel import Channel

if TYPE_CHECKING:
    from swarmctl.knowledge.exchange import KnowledgeExchange

IDEAL_KINDS = frozenset({PT_DELTA, PT_DETECTION})  # what an ideal bus delivers (see the module docstring)


class KnowledgeBus:
    """Delivers each member's messages to every other member once (see the module docstring)."""

    def __init__(self, channel: Channel | None = None, seed: int = 0):
        self.channel = channel or Channel("ideal")
        self.seed = int(seed)
        self.members: list[KnowledgeExchange] = []
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

    def join(self, member: KnowledgeExchange) -> None:
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

    def leave(self, member: KnowledgeExchange) -> None:
        if member in self.members:
            self.members.remove(member)

    def publish(self, sender: KnowledgeExchange, payload_type: int, payload: bytes, size: int) -> int:
        """One TUNNEL payload of `sender` (its frame `size` bytes long) to every other member, lost as the
        channel says; returns how many members it reached."""
        self.published += 1
        if self.ideal and payload_type not in IDEAL_KINDS:
            self.skipped += 1
            return 0
        assert self._codec is not None, "publish before join"
        message = self._codec.decode(payload_type, payload)
        if message is None:  # never for a member's own encoding; counted in the bus codec's rejections
            return 0
        if not self.trust.admit(message, sender.system_id):  # counted in trust.rejected, delivered to no one
            return 0
        kind = KIND_NAMES[payload_type]
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

    def _lost(self, tx: KnowledgeExchange, rx: KnowledgeExchange, tx_cell: tuple[int, int] | None) -> bool:
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
