"""The in-process knowledge bus (ground mode): each message once to every other agent, the channel
model's losses as the radio applies them, the digest protocol recovering them, frames once on the
agent's own outlet."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.knowledge.bus import KnowledgeBus
from swarmctl.knowledge.exchange import KnowledgeExchange
from swarmctl.knowledge.model import Knowledge
from swarmctl.world.channel import Channel
from tests.knowledge_helpers import Walkers

DIGEST_EVERY = 5


@contextlib.contextmanager
def on_bus(n: int, size: int = 20, channel: Channel | None = None, seed: int = 0, **kw):
    """A bus and n exchanges on it; each exchange's outlet keeps the frames it was given."""
    bus = KnowledgeBus(channel, seed=seed)
    outlets: list[list[bytes]] = [[] for _ in range(n)]
    agents = []
    for v in range(n):
        kw.setdefault("digest_every", DIGEST_EVERY)
        agents.append(
            KnowledgeExchange(
                Knowledge(size, size, v), 7, bus=bus, outlet=lambda f, o=outlets[v]: o.append(f) or True, **kw
            )
        )
    try:
        yield bus, agents, outlets
    finally:
        for a in agents:
            a.close()
    assert not bus.members


def test_an_ideal_bus_delivers_every_delta_and_detection_once_and_no_digests():
    with on_bus(3) as (bus, agents, outlets):
        w = Walkers(3, 20, seed=1)
        found = None
        for step in range(1, 13):
            w.move()
            w.step_all(agents, step)
            if step == 4:
                found = tuple(w.cells[2])
                agents[2].report_targets(np.array([found]), step)
            bus.settle()
            union = Knowledge(20, 20)
            for a in agents:
                union.merge(a.knowledge)
            for a in agents:  # every agent knows at once everything the others sensed
                assert a.knowledge.same_map(union) and set(a.knowledge.positions) == {0, 1, 2}
        assert all(found in a.knowledge.targets for a in agents)
        # every frame went once to its own agent's outlet, as real MAVLink 2 TUNNEL frames from its system id
        parser = mavlink2.MAVLink(None)
        kinds_sent = []
        for i, (a, frames) in enumerate(zip(agents, outlets)):
            assert len(frames) == a.stats["sent_packets"] == a.stats["link_packets"] > 0
            msgs = [parser.parse_char(f) for f in frames]
            assert {(m.get_type(), m.get_srcSystem(), m.get_srcComponent()) for m in msgs} == {("TUNNEL", i + 1, 191)}
            kinds_sent.append([m.payload_type for m in msgs])
        assert any(32801 in k for k in kinds_sent)  # digests were sent (on the outlets) ...
        for i, a in enumerate(agents):
            kinds = {k for k, v in a.codec.accepted.items() if v}
            assert kinds == {"delta", "detection"} or kinds == {"delta"}  # ... but not delivered
            # each delta and detection another agent sent arrived here once
            wanted = sum(t in (32800, 32803) for j, k in enumerate(kinds_sent) if j != i for t in k)
            assert a.stats["received_packets"] == sum(a.codec.accepted.values()) == wanted
        assert bus.skipped > 0 and bus.lost == 0
        assert sum(a.stats["requests"] + a.stats["repairs"] + a.stats["pushes"] for a in agents) == 0


def test_the_bus_loses_messages_with_the_channel_models_probability():
    """Two vehicles 12 cells apart with 10 m cells: the model's loss at 120 m, within 4 sigma (as the
    radio over UDP: tests/test_knowledge_udp.py)."""
    channel = Channel("model", cell_size=10.0)
    p = float(channel.loss_probability(12.0))
    n = 600
    with on_bus(2, 30, channel, seed=4, digest_every=0) as (bus, (near, far), _):
        for step in range(n):
            near.step(step, (2, 5))
            far.step(step, (14, 5))
            bus.settle()
        lost = 2 * n - (near.stats["received_packets"] + far.stats["received_packets"])
        assert lost == bus.lost and bus.delivered + bus.lost == 2 * n
    sigma = np.sqrt(2 * n * p * (1 - p))
    assert 0.3 < p < 0.8 and abs(lost - 2 * n * p) < 4 * sigma + 2, (lost, 2 * n * p)


def test_losses_repeat_with_the_seed_whatever_order_the_agents_publish_in():
    def run(seed: int, order: list[int]) -> list[int]:
        with on_bus(3, 20, Channel("fixed", loss=0.5), seed=seed, digest_every=0) as (bus, agents, _):
            got = []
            for step in range(40):
                for i in order:
                    agents[i].step(step, (i, 0))
                bus.settle()
                got.append(tuple(a.stats["received_packets"] for a in agents))
            return got

    a, b, c = run(3, [0, 1, 2]), run(3, [2, 0, 1]), run(4, [0, 1, 2])
    assert a == b and a != c


@pytest.mark.parametrize("seed", range(3))
def test_with_30_percent_loss_the_digest_protocol_recovers_on_the_bus(seed):
    with on_bus(3, 20, Channel("fixed", loss=0.3), seed=seed) as (bus, agents, _):
        walkers = Walkers(3, 20, seed=seed)
        step = 0
        for step in range(1, 21):
            walkers.move()
            walkers.step_all(agents, step)
            bus.settle()
        extra = 0
        while not all(agents[0].knowledge.same_map(a.knowledge) for a in agents):
            extra += 1
            assert extra <= 4 * DIGEST_EVERY, "no convergence within 4 digest rounds"
            walkers.step_all(agents, step + extra)
            bus.settle()
        assert bus.lost > 0 and sum(a.stats["repairs"] + a.stats["pushes"] for a in agents) > 0


def test_a_bus_holds_one_mission_and_each_vehicle_once():
    bus = KnowledgeBus()
    KnowledgeExchange(Knowledge(5, 5, 0), 7, bus=bus)
    with pytest.raises(ValueError, match="same mission on the same grid"):
        KnowledgeExchange(Knowledge(6, 5, 1), 7, bus=bus)
    with pytest.raises(ValueError, match="same mission"):
        KnowledgeExchange(Knowledge(5, 5, 1), 8, bus=bus)
    with pytest.raises(ValueError, match="vehicle 0 is on the bus already"):
        KnowledgeExchange(Knowledge(5, 5, 0), 7, bus=bus)
    with pytest.raises(ValueError, match="UDP peer or on a bus"):
        KnowledgeExchange(Knowledge(5, 5, 2), 7)
