"""End to end over real UDP on 127.0.0.1: agents exchange knowledge through the loopback radio."""

import socket

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.errors import InputError
from swarmctl.knowledge.codec import KnowledgeCodec
from swarmctl.knowledge.exchange import KnowledgeExchange
from swarmctl.knowledge.model import Delta, Knowledge
from swarmctl.sim.radio import Radio
from swarmctl.world.channel import Channel
from tests.knowledge_helpers import Walkers, settle, swarm

DIGEST_EVERY = 5
# Measured by tools/knowledge_convergence.py over seeds 0..99 (3 agents, 20 x 20, 20 moving steps, a
# digest every 5 steps, 30 % loss), digest rounds after the last move until all maps are equal:
# 0 rounds 33, 1 round 51, 2 rounds 13, 3 rounds 3 (pull only: up to 10). One round of room.
MAX_EXTRA_ROUNDS_AT_30_PERCENT = 4


def run_until_converged(agents, radio, walkers, moving_steps=20, max_rounds=30):
    """Move for `moving_steps`, then keep stepping in place; returns the digest rounds (periods of
    DIGEST_EVERY steps) after the last move until every agent holds the same map."""
    step = 0
    for step in range(1, moving_steps + 1):
        walkers.move()
        walkers.step_all(agents, step)
        settle(radio, agents)
    extra = 0
    while not all(agents[0].knowledge.same_map(a.knowledge) for a in agents):
        extra += 1
        assert extra <= max_rounds * DIGEST_EVERY, "no convergence"
        walkers.step_all(agents, step + extra)
        settle(radio, agents)
    return -(-extra // DIGEST_EVERY)


@pytest.mark.parametrize("seed", range(5))
def test_with_30_percent_loss_maps_converge_within_a_few_digest_rounds(seed):
    with swarm(3, 20, Channel("fixed", loss=0.3), seed=seed, digest_every=DIGEST_EVERY) as (radio, agents):
        rounds = run_until_converged(agents, radio, Walkers(3, 20, seed=seed))
        assert rounds <= MAX_EXTRA_ROUNDS_AT_30_PERCENT
        union = Knowledge(20, 20)
        for a in agents:
            union.merge(a.knowledge)
        assert agents[0].knowledge.same_map(union)  # converged to everything anyone saw
        assert radio.dropped > 0
        for a in agents:  # every agent knows where every other one was at some step
            assert a.knowledge.peers.keys() == {0, 1, 2} - {a.vehicle_id}


def test_pull_only_also_converges():
    with swarm(3, 20, Channel("fixed", loss=0.3), seed=3, push=False) as (radio, agents):
        run_until_converged(agents, radio, Walkers(3, 20, seed=3))
        assert sum(a.stats["requests"] for a in agents) > 0 and sum(a.stats["repairs"] for a in agents) > 0
        assert sum(a.stats["pushes"] for a in agents) == 0


def _sniffer(radio):
    """A plain UDP socket the radio treats as one more agent: it records what is broadcast."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(5.0)
    radio.add_peer(s.getsockname())
    return s


def test_duplicated_reordered_and_corrupted_packets_change_nothing_they_should_not():
    with swarm(2, 20, Channel("ideal")) as (radio, agents):
        sniff = _sniffer(radio)
        try:
            w = Walkers(2, 20, seed=5)
            frames = []
            for step in range(1, 6):
                w.move()
                w.step_all(agents[:1], step)  # only agent 0 speaks
                frames.append(sniff.recvfrom(65535)[0])
                if step == 5:  # its digest
                    frames.append(sniff.recvfrom(65535)[0])
            settle(radio, agents)
        finally:
            sniff.close()
        reference = agents[1].knowledge.copy()
        assert reference.explored.any()

        # fresh receivers fed directly (no radio): in order, reversed, duplicated, corrupted
        def feed(datagrams):
            k = Knowledge(20, 20, vehicle_id=1)
            codec = KnowledgeCodec(7, 20, 20)
            for d in datagrams:
                for m in codec.parse_datagram(d):
                    if isinstance(m, Delta):
                        k.merge(m)
            return k, codec

        in_order, _ = feed(frames)
        reordered, _ = feed(frames[::-1])
        duplicated, _ = feed(frames + frames[2:4] + frames)
        corrupted_frames = []
        for f in frames:
            b = bytearray(f)
            b[len(b) // 2] ^= 0x5A
            corrupted_frames.append(bytes(b))
        corrupted, codec = feed(frames[:2] + corrupted_frames + frames[2:])
        for k in (reordered, duplicated, corrupted):
            assert k.same_map(in_order) and k.positions == in_order.positions
        assert in_order.same_map(reference) and in_order.positions[0] == reference.positions[0]
        assert codec.rejected["mavlink"] == len(frames)

        # through the live exchange: replays and garbage sent to agent 1's socket change nothing
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            for d in frames[::-1] + frames + corrupted_frames + [b"\xfd\x09junk", b""]:
                tx.sendto(d, agents[1].address)
            expected = agents[1].stats["received_packets"] + 2 * len(frames) + len(corrupted_frames) + 2
            while agents[1].stats["received_packets"] < expected:
                assert agents[1].poll(5.0) > 0, "datagrams did not arrive"
        finally:
            tx.close()
        assert agents[1].knowledge.same_map(reference)
        assert agents[1].knowledge.positions[0] == reference.positions[0]  # old positions did not win
        assert agents[1].counters()["rejected_mavlink"] >= len(corrupted_frames)


def test_two_missions_on_one_radio_never_mix():
    with Radio(Channel("ideal")) as radio:
        with (
            swarm(2, 20, mission_id=100, radio=radio) as (_, blue),
            swarm(2, 20, mission_id=200, radio=radio) as (_, red),
        ):
            wb, wr = Walkers(2, 20, seed=8), Walkers(2, 20, seed=9)
            for step in range(1, 6):
                wb.move()
                wr.move()
                wb.step_all(blue, step)
                wr.step_all(red, step)
                settle(radio, blue + red)
            for team, walkers in ((blue, wb), (red, wr)):
                union = np.zeros((20, 20), bool)
                for a in team:
                    union |= a.knowledge.explored
                for a in team:
                    assert np.array_equal(a.knowledge.explored, union)
                    assert a.knowledge.positions.keys() == {0, 1}
                    assert {p.cell for p in a.knowledge.positions.values()} == set(walkers.cells)
                    assert a.codec.rejected["mission"] > 0 and a.codec.accepted["delta"] > 0
    assert radio._thread.is_alive() is False


def test_radio_drops_tunnel_packets_with_the_channel_models_probability():
    """Two vehicles 12 cells apart with 10 m cells: the model's loss at 120 m, within 4 sigma."""
    channel = Channel("model", cell_size=10.0)
    p = float(channel.loss_probability(12.0))
    n = 600
    with swarm(2, 30, channel, seed=4, digest_every=0) as (radio, (near, far)):
        for step in range(n):
            near.step(step, (2, 5))
            far.step(step, (14, 5))
            if step % 50 == 49:
                settle(radio, [near, far])
        settle(radio, [near, far])
        lost = 2 * n - (near.stats["received_packets"] + far.stats["received_packets"])
    sigma = np.sqrt(2 * n * p * (1 - p))
    assert abs(lost - 2 * n * p) < 4 * sigma + 2, (lost, 2 * n * p)


def test_radio_forwards_other_mavlink_unchanged_and_is_reproducible():
    def run(seed):
        with Radio(Channel("fixed", loss=0.5), seed=seed) as radio:
            rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                rx.bind(("127.0.0.1", 0))
                rx.settimeout(5.0)
                tx.bind(("127.0.0.1", 0))
                radio.add_peer(rx.getsockname(), system_id=9)
                mav = mavlink2.MAVLink(None, 5, 1)
                codec = KnowledgeCodec(1, 10, 10, system_id=5)
                hb = mav.heartbeat_encode(2, 3, 0, 0, 0).pack(mav)
                tunnel = codec.frames(Delta(4, 1, (1, 1)))[0]
                got = []
                for _ in range(40):
                    tx.sendto(tunnel, radio.address)
                    tx.sendto(hb, radio.address)
                    data = rx.recvfrom(65535)[0]
                    if data == tunnel:  # the tunnel frame survived: the heartbeat follows
                        data = rx.recvfrom(65535)[0]
                        got.append(1)
                    else:
                        got.append(0)
                    assert data == hb  # never lost, never changed
                return got
            finally:
                rx.close()
                tx.close()

    a, b, c = run(11), run(11), run(12)
    assert a == b and a != c and 0 < sum(a) < 40


def test_a_busy_port_is_an_input_error():
    with Radio() as radio:
        with KnowledgeExchange(Knowledge(5, 5, 0), 1, radio.address) as ex:
            with pytest.raises(InputError, match="cannot open UDP"):
                KnowledgeExchange(Knowledge(5, 5, 1), 1, radio.address, port=ex.address[1])


def test_clean_shutdown_closes_sockets_and_stops_the_thread():
    radio = Radio()
    ex = KnowledgeExchange(Knowledge(5, 5, 0), 1, radio.address)
    radio.close()
    ex.close()
    assert radio.sock.fileno() == -1 and ex.sock.fileno() == -1 and not radio._thread.is_alive()
