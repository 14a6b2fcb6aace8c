"""What a sender on the radio can make a controller's link do, bounded (docs/security.md): frames copied
from one signed link onto another, unsigned RADIO_STATUS and made-up heartbeats from many ports, big
datagrams packed with frames, heartbeats of made-up system ids. Over loopback UDP, with pymavlink's bytes."""

from __future__ import annotations

import asyncio
import socket
import threading
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.mavlink.inbox import LINK_DRAIN_BYTES
from swarmctl.mavlink.network import EVENTS_KEEP, MAV, MavlinkLink
from swarmctl.mavlink.transport import MAX_DATAGRAM_PARSE, MAX_SOURCES
from swarmctl.signing import SigningClock, now_timestamp, setup_signing
from tests.mavlink_support import mock_vehicles, our_threads, run, until

KEY = bytes(range(32))


@pytest.fixture(autouse=True)
def no_leftover_threads():
    yield
    assert our_threads() == []


def heartbeat(sysid: int, autopilot: int = mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA) -> bytes:
    mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
    return bytes(mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, autopilot, 0, 0, 0).pack(mav))


def tiny_heartbeat() -> bytes:
    """A 13-byte HEARTBEAT of system 9 (all-zero payload, trimmed to one byte): the most frames a datagram holds."""
    mav = mavlink2.MAVLink(None, srcSystem=9, srcComponent=1)
    return bytes(mavlink2.MAVLink_heartbeat_message(0, 0, 0, 0, 0, 0).pack(mav))


def radio_status() -> bytes:
    mav = mavlink2.MAVLink(None, srcSystem=51, srcComponent=68)
    return bytes(mav.radio_status_encode(200, 200, 100, 90, 90, 0, 0).pack(mav))


def sockets(n: int) -> list[socket.socket]:
    out = []
    for _ in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        out.append(s)
    return out


def signature(frame: bytes) -> tuple[int, int]:
    """(link id, timestamp) of a signed MAVLink 2 frame."""
    return frame[-13], int.from_bytes(frame[-12:-6], "little")


# --- 1. cross-link replay on signed links ----------------------------------------------------------------


def test_the_links_of_a_process_sign_as_streams_of_their_own_from_one_clock():
    """Two signed links: link ids of their own, timestamps increasing over both in the order sent, not
    behind the clock; a link opened after one has closed takes its id, with newer timestamps."""

    async def scenario():
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sink:
            sink.bind(("127.0.0.1", 0))
            sink.settimeout(5.0)
            to = f"udpout:127.0.0.1:{sink.getsockname()[1]}"
            a = await MavlinkLink(to, signing_key=KEY, heartbeat_period=60).open()
            b = await MavlinkLink(to, signing_key=KEY, heartbeat_period=60).open()
            await asyncio.sleep(0)  # each link's heartbeat loop sends its first heartbeat
            start = now_timestamp()
            try:
                for _ in range(20):
                    for link in (a, b, b):
                        link.send(link.mav.heartbeat_encode(MAV.MAV_TYPE_GCS, MAV.MAV_AUTOPILOT_INVALID, 0, 0, 0))
                frames = [sink.recvfrom(512)[0] for _ in range(2 + 60)]
                ids = (a.mav.signing.link_id, b.mav.signing.link_id)
                await a.close()
                c = await MavlinkLink(to, signing_key=KEY, heartbeat_period=60).open()
                await asyncio.sleep(0)
                try:
                    later = sink.recvfrom(512)[0]  # its first heartbeat
                    return ids, c.mav.signing.link_id, frames, later, start
                finally:
                    await c.close()
            finally:
                await a.close()
                await b.close()

    (id_a, id_b), id_c, frames, later, start = run(scenario())
    assert id_a != id_b and id_c == id_a
    sent = [signature(f) for f in frames[2:]]
    assert [link_id for link_id, _ in sent] == [id_a, id_b, id_b] * 20
    stamps = [ts for _, ts in sent]
    assert all(x < y for x, y in zip(stamps, stamps[1:])) and stamps[0] >= start
    assert signature(later)[0] == id_c and signature(later)[1] > max(stamps)


def test_a_frame_signed_from_another_clock_user_never_outdates_the_links_next_frame():
    """Receivers keep a timestamp per stream; a frame copied from link B to the receiver of link A is
    a new stream there (another link id) and, from the same clock, older than A's next frame."""
    clock = SigningClock()
    a, b = (mavlink2.MAVLink(None, srcSystem=255, srcComponent=190) for _ in range(2))
    setup_signing(a, KEY, link_id=0, clock=clock)
    setup_signing(b, KEY, link_id=1, clock=clock)
    receiver = mavlink2.MAVLink(None)
    receiver.robust_parsing = True
    setup_signing(receiver, KEY)

    def hb(mav):
        return bytes(mav.heartbeat_encode(MAV.MAV_TYPE_GCS, MAV.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(mav))

    def kinds(data):
        return [m.get_type() for m in receiver.parse_buffer(data) or []]

    assert kinds(hb(a)) == ["HEARTBEAT"]
    for _ in range(50):
        copied = hb(b)  # B sends more often than A
    assert kinds(copied) == ["HEARTBEAT"]
    assert kinds(hb(a)) == ["HEARTBEAT"]  # A's stream is untouched
    assert set(receiver.signing.stream_timestamps) == {(0, 255, 190), (1, 255, 190)}


def test_frames_copied_from_vehicle_2s_link_onto_vehicle_1s_channel_cost_vehicle_1_nothing():
    """The audit's attack: what link B sends to vehicle 2 is also sent to vehicle 1. Vehicle 1 takes the
    copies (signed with the key) and keeps answering link A's commands."""

    async def scenario():
        a = await MavlinkLink("udpin:127.0.0.1:0", signing_key=KEY, heartbeat_period=0.2).open()
        await asyncio.sleep(0.05)  # B opened later: a counter of its own would run 5,000 ahead of A's
        b = await MavlinkLink("udpin:127.0.0.1:0", signing_key=KEY, heartbeat_period=0.2).open()
        specs = [
            dict(sysid=i + 1, connect=f"udpout:127.0.0.1:{link.local_port}", signing_key=KEY, gcs_failsafe_timeout=None)
            for i, link in enumerate((a, b))
        ]
        spy = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            with mock_vehicles(*specs) as (m1, m2):
                await a.wait_heartbeat(1, 10)
                await b.wait_heartbeat(2, 10)
                await until(lambda: m1.last_gcs_heartbeat is not None and m2.last_gcs_heartbeat is not None)
                write = b._transport.write

                def tapped(data: bytes) -> None:  # the attacker hears B's frames and sends them to vehicle 1
                    write(data)
                    spy.sendto(data, ("127.0.0.1", m1.local_port))

                b._transport.write = tapped
                ignored = m1.ignored
                answered = 0
                for _ in range(8):
                    for _ in range(3):
                        await b.set_message_interval(2, 33, 5.0, timeout=0.5, retries=2)
                    await a.set_message_interval(1, 33, 5.0, timeout=0.5, retries=0)
                    answered += 1
                return answered, m1.ignored - ignored, m1.rejected_unsigned
        finally:
            spy.close()
            await a.close()
            await b.close()

    answered, copies_taken, refused = run(scenario())
    assert answered == 8
    assert copies_taken >= 24  # the copies passed vehicle 1's signature check (addressed to vehicle 2)
    assert refused == 0  # none of link A's frames was refused as old


# --- 2. udpin answers: unsigned RADIO_STATUS and made-up senders ------------------------------------------


def test_unsigned_radio_status_from_many_ports_neither_adds_nor_evicts_an_answered_address():
    async def scenario():
        link = await MavlinkLink("udpin:127.0.0.1:0", signing_key=KEY, heartbeat_period=0.2).open()
        flood = sockets(MAX_SOURCES + 8)
        try:
            spec = dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}", signing_key=KEY)
            with mock_vehicles({**spec, "gcs_failsafe_timeout": 2.0}) as (m,):
                await link.wait_heartbeat(1, 10)
                vehicle = ("127.0.0.1", m.local_port)
                await until(lambda: link._transport.peers == [vehicle])
                unsigned = link.mav.signing.unsigned_count
                frame = radio_status()
                for _ in range(3):
                    for s in flood:
                        s.sendto(frame, ("127.0.0.1", link.local_port))
                await until(lambda: link.mav.signing.unsigned_count >= unsigned + 3 * len(flood))
                peers, evicted = list(link._transport.peers), link._transport.evicted
                heard = sum(1 for r in m.received if r[1] == 255)
                await until(lambda: sum(1 for r in m.received if r[1] == 255) >= heard + 3)
                return peers, evicted, vehicle, m.gcs_failsafe
        finally:
            for s in flood:
                s.close()
            await link.close()

    peers, evicted, vehicle, failsafe = run(scenario())
    assert peers == [vehicle] and evicted == 0
    assert not failsafe


def test_without_a_key_only_an_expected_vehicles_heartbeat_adds_an_address_and_one_vehicle_cannot_push_out_another():
    """Unsigned link expecting vehicles 1 and 2: RADIO_STATUS and heartbeats of a made-up system id from
    40 ports add nothing; heartbeats in vehicle 2's name from 40 ports push out only vehicle 2's addresses."""

    async def scenario():
        link = await MavlinkLink("udpin:127.0.0.1:0", heartbeat_period=60).open()
        for sysid in (1, 2):  # the vehicles the controller flies on it: it asks for them
            link.peer(sysid)
        (v1,) = sockets(1)
        flood = sockets(MAX_SOURCES + 8)
        to = ("127.0.0.1", link.local_port)
        try:
            v1.sendto(heartbeat(1), to)
            await until(lambda: link._transport.peers == [v1.getsockname()])
            received = link.stats.received
            for s in flood:
                s.sendto(radio_status(), to)
                s.sendto(heartbeat(77), to)
            await until(lambda: link.stats.received >= received + 2 * len(flood))
            after_strangers = list(link._transport.peers)
            for s in flood:
                s.sendto(heartbeat(2), to)
            await until(lambda: link.stats.received >= received + 3 * len(flood))
            names = [f.getsockname() for f in flood]
            return after_strangers, list(link._transport.peers), link._transport.evicted, v1.getsockname(), names
        finally:
            v1.close()
            for s in flood:
                s.close()
            await link.close()

    after_strangers, peers, evicted, v1, flood = run(scenario())
    assert after_strangers == [v1]
    assert v1 in peers and len(peers) == MAX_SOURCES
    assert evicted == len(flood) + 1 - MAX_SOURCES
    assert peers == [v1, *flood[-(MAX_SOURCES - 1) :]]  # vehicle 2's newest senders, vehicle 1 kept


# --- 3. big datagrams packed with frames ------------------------------------------------------------------


def test_a_datagram_is_parsed_up_to_its_first_max_datagram_parse_bytes():
    async def scenario():
        link = await MavlinkLink("udpin:127.0.0.1:0", heartbeat_period=60).open()
        frame = tiny_heartbeat()
        big = frame * (65507 // len(frame))
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(big, ("127.0.0.1", link.local_port))
                await until(lambda: link.stats.received > 0)  # parsed at one drain
            return link.stats, len(big), len(frame)
        finally:
            await link.close()

    stats, size, frame = run(scenario())
    assert stats.received == MAX_DATAGRAM_PARSE // frame  # before: all 5,039
    assert stats.dropped_bytes == size - MAX_DATAGRAM_PARSE
    assert stats.bad_data >= 1  # the cut: counted and logged as bad data


def test_a_drain_parses_at_most_link_drain_bytes_of_a_link_and_the_rest_waits():
    """12 datagrams of 630 frames queued at once: read a few drains, each at most LINK_DRAIN_BYTES (the
    datagram that crosses the budget included), none lost."""

    async def scenario():
        link = await MavlinkLink("udpin:127.0.0.1:0", heartbeat_period=60).open()
        link._transport.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        per_drain: list[int] = []
        deliver = link._deliver

        def counted(msgs: list) -> list:
            per_drain.append(len(msgs))
            return deliver(msgs)

        link._deliver = counted
        frame = tiny_heartbeat()
        datagram = frame * (MAX_DATAGRAM_PARSE // len(frame))
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                for _ in range(12):  # all queued before the loop runs a drain
                    s.sendto(datagram, ("127.0.0.1", link.local_port))
                await until(lambda: link.stats.received >= 12 * len(datagram) // len(frame))
            return per_drain, len(datagram), len(datagram) // len(frame), link.stats
        finally:
            await link.close()

    per_drain, size, frames, stats = run(scenario())
    assert sum(per_drain) == 12 * frames and stats.bad_data == 0
    assert max(per_drain) <= (LINK_DRAIN_BYTES // size + 1) * frames
    assert len(per_drain) >= 3


def test_a_flood_of_big_datagrams_does_not_stop_the_controllers_heartbeats():
    """65 KB datagrams of 13-byte frames at 50 a second (5,039 frames each): the link keeps sending its
    heartbeat every 0.1 s (before: one drain parsed up to 64 of them, 2 s with the loop held)."""

    async def scenario():
        link = await MavlinkLink("udpin:127.0.0.1:0", heartbeat_period=0.1).open()
        frame = tiny_heartbeat()
        big = frame * (65507 // len(frame))
        stop = threading.Event()

        def flood() -> None:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                while not stop.wait(0.02):
                    s.sendto(big, ("127.0.0.1", link.local_port))

        flooder = threading.Thread(target=flood, name="test-flooder")
        try:
            flooder.start()
            await until(lambda: link.stats.received > 0)  # the flood is being read
            sent, t0 = link.stats.sent, time.monotonic()
            await until(lambda: link.stats.sent >= sent + 15, timeout=6.0)
            return time.monotonic() - t0
        finally:
            stop.set()
            flooder.join()
            await link.close()

    took = run(scenario())
    assert took < 6.0


# --- 4. link events of made-up system ids -----------------------------------------------------------------


def test_link_events_are_kept_only_for_the_vehicles_the_link_expects():
    """Heartbeats of vehicle 1 and 200 made-up system ids in one datagram, twice with a loss between:
    events (and callbacks, what the recording writes) for vehicle 1 only; a vehicle heard before it is
    expected is "seen" when it is."""

    async def scenario():
        link = await MavlinkLink("udpin:127.0.0.1:0", lost_after=0.3, heartbeat_period=60).open()
        calls: list[tuple[int, str]] = []
        link.on_link_change(lambda sysid, event: calls.append((sysid, event)))
        link.peer(1)  # a vehicle the controller flies: it asks for it
        burst = b"".join(heartbeat(s) for s in [1, *range(10, 210)])
        assert len(burst) <= MAX_DATAGRAM_PARSE
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(burst, ("127.0.0.1", link.local_port))
                await until(lambda: len(link.peers) == 201 and not link.is_lost(1))
                await until(lambda: all(p.lost for p in link.peers.values()), timeout=3.0)
                s.sendto(burst, ("127.0.0.1", link.local_port))
                await until(lambda: not any(p.lost for p in link.peers.values()))
            link.peer(50)  # heard, not lost: "seen" as soon as the link is asked for it
            return [(s, e) for _t, s, e in link.events], calls, link.events.maxlen
        finally:
            await link.close()

    events, calls, maxlen = run(scenario())
    assert events == [(1, "seen"), (1, "lost"), (1, "back"), (50, "seen")]
    assert calls == events
    assert maxlen == EVENTS_KEEP


def test_a_link_that_fails_to_open_keeps_neither_its_link_id_nor_its_socket(monkeypatch):
    import swarmctl.mavlink.inbox as inbox
    import swarmctl.mavlink.network as network

    def broken(self, link, sock):
        raise OSError("no selector today")

    monkeypatch.setattr(inbox.Inbox, "read", broken)

    async def scenario():
        link = MavlinkLink("udpin:127.0.0.1:0", signing_key=KEY)
        with pytest.raises(OSError):
            await link.open()
        return link

    link = run(scenario())
    assert link not in network._link_ids.values()
    assert link._transport.sock.fileno() == -1  # closed


def test_a_statustext_of_terminal_escapes_is_kept_escaped():
    """A STATUSTEXT that would clear the operator's terminal and retitle its window (what the live view
    and the log print, and preflight events record) is kept with those characters written as escapes."""
    hostile = b"\x1b]0;owned\x07\x1b[2JPreArm: ok"  # a window title (OSC 0), then clear the screen

    async def scenario():
        link = await MavlinkLink("udpin:127.0.0.1:0", heartbeat_period=60).open()
        link.peer(1)
        mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                frame = bytes(mav.statustext_encode(mavlink2.MAV_SEVERITY_WARNING, hostile).pack(mav))
                s.sendto(heartbeat(1) + frame, ("127.0.0.1", link.local_port))
                await until(lambda: link.peers[1].statustexts)
            return link.peers[1].texts_since(0)
        finally:
            await link.close()

    text = run(scenario())
    assert text == "\\x1b]0;owned\\x07\\x1b[2JPreArm: ok" and text.isprintable()
