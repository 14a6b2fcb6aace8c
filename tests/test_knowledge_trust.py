"""Knowledge you can trust: what a vehicle takes from the channel (swarmctl.knowledge.trust), signed
knowledge frames, answers bounded per peer (swarmctl.knowledge.budget), tables fed from the wire bounded."""

from __future__ import annotations

import logging
import socket
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.knowledge.amplification import KINDS, measure
from swarmctl.knowledge.bus import KnowledgeBus
from swarmctl.knowledge.codec import KnowledgeCodec
from swarmctl.knowledge.exchange import DATAGRAM_MIN, DATAGRAM_PARSE, POLL_BYTES, KnowledgeExchange
from swarmctl.knowledge.model import Delta, Detection, Knowledge, disc_cells
from swarmctl.knowledge.trust import (
    FIRST_AHEAD,
    FOOTPRINT_SLACK,
    SPEED_SLACK,
    STEP_AHEAD,
    STEP_RATE,
    STEP_RATE_S,
    KnowledgeTrust,
)
from swarmctl.mavlink.network import MavlinkLink
from swarmctl.mavlink.transport import MAX_SOURCES
from swarmctl.sim.radio import Radio
from swarmctl.world.channel import Channel
from tests.knowledge_helpers import Walkers, settle
from tests.mavlink_support import run

MEMBERS = {0: 1, 1: 2, 2: 3}
KEY = bytes(range(100, 132))


def delta(sender: int, step: int, cell) -> Delta:
    return Delta(sender, step, cell, False, np.zeros((0, 2), np.int64), np.zeros(0, np.uint8), np.zeros(0, bool))


# ----- the acceptance checks ------------------------------------------------------------------------
def test_only_members_with_their_system_ids_are_taken(caplog):
    trust = KnowledgeTrust(MEMBERS, fov=2.0)
    with caplog.at_level(logging.WARNING, logger="swarmctl.knowledge"):
        assert not trust.admit(delta(7, 1, (0, 0)), sysid=8)
        assert not trust.admit(delta(7, 2, (0, 0)), sysid=8)
        assert not trust.admit(delta(1, 1, (0, 0)), sysid=42)
        assert trust.admit(delta(1, 1, (0, 0)), sysid=2)
        assert trust.admit(delta(2, 1, (5, 5)), sysid=None)  # the frame's sysid unknown: the index decides
    assert trust.counters() == {"member": 2, "sysid": 1, "step": 0, "speed": 0, "footprint": 0}
    assert len(caplog.records) == 2  # once per reason
    assert not trust.is_member(7) and trust.is_member(1)


@settings(max_examples=200, deadline=None)
@given(
    start=st.tuples(st.integers(0, 40), st.integers(0, 40)),
    jump=st.tuples(st.integers(-20, 20), st.integers(-20, 20)),
    steps=st.integers(-10, 10),
)
def test_a_position_is_taken_only_as_far_as_a_vehicle_can_fly(start, jump, steps):
    trust = KnowledgeTrust(MEMBERS)
    trust.advance(20)  # the receiver's own step
    assert trust.admit(delta(1, 20, start), sysid=2)
    to = (start[0] + jump[0], start[1] + jump[1])
    reachable = abs(jump[0]) + abs(jump[1]) <= abs(steps) + SPEED_SLACK
    assert trust.admit(delta(1, 20 + steps, to), sysid=2) == reachable
    assert trust.rejected["speed"] == (0 if reachable else 1)


@settings(max_examples=200, deadline=None)
@given(
    at=st.tuples(st.integers(0, 40), st.integers(0, 40)),
    offsets=st.lists(st.tuples(st.integers(-6, 6), st.integers(-6, 6)), min_size=1, max_size=6),
    fov=st.sampled_from([1.0, 2.0, 3.5]),
)
def test_a_detection_is_taken_only_inside_the_senders_footprint(at, offsets, fov):
    trust = KnowledgeTrust(MEMBERS, fov=fov)
    targets = np.array([(at[0] + dx, at[1] + dy) for dx, dy in offsets])
    inside = all(np.hypot(dx, dy) <= fov + FOOTPRINT_SLACK for dx, dy in offsets)
    assert trust.admit(Detection(0, 5, at, False, targets), sysid=1) == inside
    assert not trust.admit(Detection(0, 6, None, False, targets), sysid=1)  # from nowhere: never


def cells_delta(sender: int, step: int, cell, cells, repair: bool = False) -> Delta:
    c = np.asarray(cells, np.int64).reshape(-1, 2)
    return Delta(sender, step, cell, False, c, np.full(len(c), 255, np.uint8), np.ones(len(c), bool), repair)


def test_a_step_from_the_future_is_refused_and_pins_nothing():
    """The audit's attack: a step of 2^32 - 1 allowed a 90-cell jump and pinned the position for good."""
    trust = KnowledgeTrust(MEMBERS, fov=2.0, clock=lambda: 0.0)
    trust.advance(10)
    assert trust.admit(delta(1, 10, (0, 0)), sysid=2)
    assert not trust.admit(Detection(1, 2**32 - 1, (45, 45), True, np.array([[45, 45]])), sysid=2)
    assert not trust.admit(delta(1, 10 + STEP_AHEAD + 1, (0, 1)), sysid=2)  # past the credit: refused too
    assert not trust.admit(delta(2, 10 + FIRST_AHEAD + 1, (9, 9)), sysid=3)  # not heard yet: past now + FIRST_AHEAD
    assert trust.counters()["step"] == 3
    for s in range(11, 21):  # the real vehicle goes on, stepping with the receiver
        trust.advance(s)
        assert trust.admit(delta(1, s, (s - 10, 0)), sysid=2)
    assert not trust.admit(Detection(1, 21, (30, 10), False, np.array([[30, 10]])), sysid=2)  # speed still on
    assert trust.counters() == {"member": 0, "sysid": 0, "step": 3, "speed": 1, "footprint": 0}


@settings(max_examples=200, deadline=None)
@given(now=st.integers(0, 1000), leads=st.lists(st.integers(0, 40), min_size=1, max_size=8), waits=st.integers(0, 6))
def test_a_sender_never_leads_the_receiver_by_more_than_its_credit(now, leads, waits):
    """Whatever the steps claimed, a sender's accepted steps lead the receiver's own by at most STEP_AHEAD
    plus STEP_RATE per step the receiver made since it first heard it."""
    trust = KnowledgeTrust(MEMBERS, clock=lambda: 0.0)
    trust.advance(now)
    assert trust.admit(delta(1, now, None), sysid=2)  # first heard (a first message may lead by FIRST_AHEAD)
    first = now
    step = now
    for lead in leads:
        step += lead
        if trust.admit(delta(1, step, None), sysid=2):
            assert step <= first + STEP_AHEAD + STEP_RATE * (trust.now - first)
        else:
            step -= lead
    trust.advance(now + waits)
    assert not trust.admit(delta(1, now + waits + STEP_AHEAD + STEP_RATE * waits + 1, None), sysid=2)
    assert trust.admit(delta(1, step, None), sysid=2)  # the newest step again: always taken


def test_an_agent_restarted_is_believed_from_where_its_vehicle_was():
    """A companion computer rebooted mid-mission: its agent counts its steps from 0 again, from the
    cell its vehicle holds; its positions, deltas and finds are taken from the first on."""
    trust = KnowledgeTrust(MEMBERS, fov=2.0, clock=lambda: 0.0)
    for s in range(0, 301):
        trust.advance(s)
        assert trust.admit(delta(1, s, (min(s, 40), 5)), sysid=2)
    for s in range(1, 51):  # restarted at (40, 5), flying west a cell a step
        trust.advance(300 + s)
        assert trust.admit(cells_delta(1, s, (40 - s // 2, 5), [(40 - s // 2, 6)]), sysid=2)
    assert trust.admit(Detection(1, 50, (15, 5), False, np.array([[15, 6]])), sysid=2)
    assert trust.counters()["speed"] == 0 and trust.counters()["step"] == 0


def test_a_late_agent_hears_senders_more_than_first_ahead_in_the_end():
    seconds = [0.0]
    trust = KnowledgeTrust(MEMBERS, clock=lambda: seconds[0])
    taken = []
    for k in range(3000):  # the sender 5,000 steps ahead, both at one step a second
        seconds[0] = float(k)
        trust.advance(k)
        taken.append(trust.admit(delta(1, 5000 + k, None), sysid=2))
    assert not taken[0] and taken[-1]


def test_a_delta_carries_only_cells_its_sender_can_have_sensed():
    """The audit's attack: one DELTA (repair flag or not) from a position next to the real one marked every
    cell explored, a target and an obstacle."""
    trust = KnowledgeTrust(MEMBERS, fov=2.0)
    trust.advance(10)
    trust.own(0, 10, (25, 25))
    assert trust.admit(delta(1, 10, (0, 0)), sysid=2)
    everything = [(x, y) for x in range(50) for y in range(50)]
    for repair in (False, True):
        parts = cells_delta(1, 11, (1, 0), everything, repair).split(36)
        assert not any(trust.admit(p, sysid=2) for p in parts)
    assert trust.counters()["footprint"] == 2 * len(parts)
    assert trust.admit(cells_delta(1, 11, (1, 0), disc_cells((1, 0), 50, 50, 2.0)), sysid=2)  # its own footprint
    assert not trust.admit(cells_delta(1, 12, (1, 1), [(25, 25)]), sysid=2)  # not its own: refused ...
    assert trust.admit(cells_delta(1, 12, (1, 1), [(25, 25)], repair=True), sysid=2)  # ... a repair may carry it
    assert not trust.admit(cells_delta(1, 12, (1, 1), [(40, 5)], repair=True), sysid=2)  # nobody was near


@settings(max_examples=150, deadline=None)
@given(
    start=st.tuples(st.integers(0, 40), st.integers(0, 40)),
    moves=st.lists(st.sampled_from([(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)]), min_size=1, max_size=8),
    heard=st.lists(st.booleans(), min_size=8, max_size=8),
    fov=st.sampled_from([1.0, 2.0, 3.0]),
)
def test_an_honest_delta_of_unpublished_steps_is_taken(start, moves, heard, fov):
    """A vehicle that sensed at every cell of its walk but whose positions were heard only at some steps
    (lost messages, steps it did not publish) sends all the cells at the end: they are taken."""
    trust = KnowledgeTrust(MEMBERS, fov=fov)
    trust.advance(5 + len(moves))
    cell = start
    assert trust.admit(delta(1, 5, cell), sysid=2)
    sensed = [disc_cells(cell, 50, 50, fov)]
    for i, (dx, dy) in enumerate(moves):
        cell = (min(max(cell[0] + dx, 0), 49), min(max(cell[1] + dy, 0), 49))
        sensed.append(disc_cells(cell, 50, 50, fov))
        if heard[i] and i < len(moves) - 1:
            assert trust.admit(delta(1, 6 + i, cell), sysid=2)
    cells = np.unique(np.concatenate(sensed), axis=0)
    assert trust.admit(cells_delta(1, 5 + len(moves), cell, cells), sysid=2)


def test_one_poll_reads_a_bounded_batch(monkeypatch):
    """The audit's flood: 65 KB datagrams of HEARTBEATs kept one poll(0.0) busy 8.56 s of CPU."""
    import swarmctl.knowledge.exchange as exchange

    monkeypatch.setattr(exchange, "POLL_BYTES", 8 * DATAGRAM_PARSE)  # a socket buffer's worth of the flood
    mav = mavlink2.MAVLink(None, srcSystem=9, srcComponent=1)
    hb = bytes(mavlink2.MAVLink_heartbeat_message(0, 0, 0, 0, 0, 0).pack(mav))
    big = hb * (65000 // len(hb))
    ex = KnowledgeExchange(Knowledge(10, 10, 0), 7, ("127.0.0.1", 9), members=MEMBERS, fov=2.0)
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for _ in range(12):
                s.sendto(big, ex.address)
            for _ in range(192):
                s.sendto(hb, ex.address)
        n = ex.poll(0.5)
        assert n == 8  # the rest waits for the next poll
        assert ex.codec.ignored["HEARTBEAT"] <= 8 * DATAGRAM_PARSE // len(hb) + 1
        assert ex.rejections()["datagram"] == n
        while ex.poll(0.2):
            pass
        assert ex.stats["received_packets"] == 12 + 192  # every datagram read in the end
    finally:
        ex.close()


def test_one_poll_keeps_up_with_a_big_swarms_round():
    """An onboard agent polls once a round: 40 agents send about 80 datagrams a round, all read at once."""
    mav = mavlink2.MAVLink(None, srcSystem=9, srcComponent=1)
    hb = bytes(mavlink2.MAVLink_heartbeat_message(0, 0, 0, 0, 0, 0).pack(mav))
    ex = KnowledgeExchange(Knowledge(10, 10, 0), 7, ("127.0.0.1", 9), members=MEMBERS, fov=2.0)
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for _ in range(400):
                s.sendto(hb * 5, ex.address)
        assert ex.poll(0.5) == 400
        assert 400 * DATAGRAM_MIN <= POLL_BYTES
    finally:
        ex.close()


# ----- signed knowledge ------------------------------------------------------------------------------
def test_with_a_key_only_signed_knowledge_frames_are_read():
    with Radio(Channel("ideal"), seed=0) as radio:
        agents = [
            KnowledgeExchange(Knowledge(10, 10, v), 7, radio.address, members=MEMBERS, fov=2.0, signing_key=KEY)
            for v in range(2)
        ]
        try:
            for a in agents:
                radio.add_peer(a.address, system_id=a.system_id)
            agents[0].step(1, (1, 1), False, np.array([[1, 1]]), np.array([0.5]), np.array([False]))
            settle(radio, agents)
            assert agents[1].knowledge.explored[1, 1] and agents[1].merged() > 0
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                for key in (None, bytes(32)):  # unsigned; signed with another key
                    forger = KnowledgeCodec(7, 10, 10, system_id=3, signing_key=key)
                    for frame in forger.frames(Detection(2, 1, (5, 5), False, np.array([[5, 5]]))):
                        s.sendto(frame, agents[1].address)
            agents[1].poll(1.0)
            while agents[1].poll(0.2):
                pass
            assert agents[1].rejections().get("signature", 0) == 2
            assert (5, 5) not in agents[1].knowledge.targets
        finally:
            for a in agents:
                a.close()


def test_on_the_bus_the_frames_that_leave_are_signed_and_strangers_never_delivered():
    bus = KnowledgeBus(Channel("ideal"), seed=0)
    frames: list[bytes] = []
    agents = [
        KnowledgeExchange(
            Knowledge(10, 10, v), 7, bus=bus, outlet=frames.append, members=MEMBERS, fov=2.0, signing_key=KEY
        )
        for v in range(2)
    ]
    agents[0].step(1, (1, 1), False, np.array([[1, 1]]), np.array([0.5]), np.array([False]))
    agents[1].poll(0.0)
    assert frames and all(f[0] == 0xFD and f[2] & 0x01 for f in frames)  # MAVLink 2, incompat flag: signed
    reader = KnowledgeCodec(7, 10, 10, signing_key=KEY)
    assert all(reader.parse_datagram(f) for f in frames)
    assert agents[1].knowledge.explored[1, 1]


# ----- answers bounded per peer ------------------------------------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
def test_no_kind_of_message_earns_twice_its_size_in_answers(kind):
    """The forged DIGEST (34 bytes) and REQUEST (x98 and x24 answered before the answer budget), and
    the other kinds, one a round from a sender claiming a member's index and sysid on an unsigned
    channel (the worst case: a stranger, or a forger on a signed channel, gets nothing)."""
    member = measure(kind, size=20, steps=20)
    assert member.received > 0 and member.ratio < 2.0, member
    if kind == "DIGEST":
        assert member.received // 20 == 34 and member.answered > 0  # answered, within the bound
    assert measure(kind, member=False, size=20, steps=10).answered == 0
    assert measure(kind, size=20, steps=10, signed=True).answered == 0


@pytest.mark.parametrize("signed", [False, True], ids=["unsigned", "signed"])
def test_a_late_joiner_still_converges(signed):
    """Two vehicles search 30 steps; a third joins and stays put: the answers its digests and requests
    earn bring it everything they know within a few digest periods."""
    key = KEY if signed else None
    walkers = Walkers(3, 20, seed=4)
    with Radio(Channel("ideal"), seed=0) as radio:
        agents = []
        try:

            def join(v):
                a = KnowledgeExchange(
                    Knowledge(20, 20, v), 7, radio.address, members=MEMBERS, fov=3.0, digest_every=5, signing_key=key
                )
                radio.add_peer(a.address, system_id=a.system_id)
                agents.append(a)

            join(0)
            join(1)
            for step in range(1, 31):
                walkers.move()
                walkers.step_all(agents, step)
                settle(radio, agents)
            join(2)
            walkers.cells[2] = walkers.cells[0]  # no jump between its reports
            step = 30
            while not agents[2].knowledge.same_map(agents[0].knowledge):
                step += 1
                assert step <= 30 + 8 * 5, "the late joiner did not converge within 8 digest periods"
                walkers.step_all(agents, step)
                settle(radio, agents)
        finally:
            for a in agents:
                a.close()
    assert sum(a.stats["answer_bytes"] for a in agents[:2]) > 0


# ----- tables fed from the wire stay bounded --------------------------------------------------------------
def unknown_frame(msgid: int, seq: int) -> bytes:
    """A MAVLink 2 frame of a message id the dialect does not have (pymavlink checks no CRC for it)."""
    header = struct.pack("<BBBBBBBHB", 0xFD, 1, 0, 0, seq & 0xFF, 9, 9, msgid & 0xFFFF, msgid >> 16)
    return header + b"\x00" + b"\x00\x00"


def test_unknown_message_ids_add_no_counter_keys():
    codec = KnowledgeCodec(7, 10, 10)
    data = b"".join(unknown_frame(60000 + i, i) for i in range(5000))
    codec.parse_datagram(data)
    assert codec.ignored["unknown"] == 5000 and len(codec.ignored) == 1


def test_udpin_answers_only_the_most_recent_sources_that_sent_valid_frames():
    """50 source ports sending junk, then 100 sending heartbeats: the link answers MAX_SOURCES addresses,
    the most recent, never one that sent only junk."""

    async def scenario():
        link = await MavlinkLink("udpin:127.0.0.1:0").open()
        sockets = []
        try:
            mav = mavlink2.MAVLink(None, srcSystem=9, srcComponent=1)
            hb = bytes(mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, 3, 0, 0, 0).pack(mav))
            for i in range(150):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                s.bind(("127.0.0.1", 0))
                sockets.append(s)
                s.sendto(b"junk" * 8 if i < 50 else hb, ("127.0.0.1", link.local_port))  # junk first
            await link.wait_until(lambda: link.stats.received >= 100, 5, "the heartbeats", "vehicle 9")
            peers = set(link._transport.peers)
            return peers, [s.getsockname() for s in sockets]
        finally:
            for s in sockets:
                s.close()
            await link.close()

    peers, addresses = run(scenario())
    assert peers == set(addresses[-MAX_SOURCES:])  # the most recent; junk (the first 50) earns no answers


def test_a_sender_that_fell_behind_its_credit_is_believed_again():
    """A receiver that does not step (in preflight) while a sender steps on: the sender's steps run past
    the credit and are refused, then taken again as the receiver's clock gives credit back."""
    seconds = [0.0]
    trust = KnowledgeTrust(MEMBERS, clock=lambda: seconds[0])
    assert trust.admit(delta(1, 0, None), sysid=2)
    taken = []
    for step in range(1, 200):  # the sender at 10 steps a second, the receiver at step 0
        seconds[0] = step / 10
        taken.append(trust.admit(delta(1, step, None), sysid=2))
    assert not all(taken)  # faster than the credit comes back: some refused
    for step in range(200, 260):  # the sender at 4 steps a second, slower than STEP_RATE_S
        seconds[0] += 0.25
        taken.append(trust.admit(delta(1, step, None), sysid=2))
    assert all(taken[-20:])
    assert STEP_RATE_S > 4


def test_a_late_agent_hears_senders_far_ahead_of_it():
    trust = KnowledgeTrust(MEMBERS, clock=lambda: 0.0)
    trust.advance(3)  # started late: the others are at step 300
    assert trust.admit(delta(1, 300, None), sysid=2)
    trust.advance(4)
    assert trust.admit(delta(1, 301, None), sysid=2)
