"""How received messages reach the loop: listeners by type, batch listeners, every link's messages in
order and each once (the loop's inbox gathers what several links' readers hand over)."""

from __future__ import annotations

import socket

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.mavlink.network import MAV, MavlinkLink
from tests.mavlink_support import our_threads, run, until


class _Frames:
    """A pymavlink writer that keeps each packed frame."""

    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.frames.append(bytes(data))


def frames(sysid: int, count: int) -> list[bytes]:
    """`count` frames from system `sysid`: HEARTBEATs and SYS_STATUSes in turn (sequence numbers 0, 1, ...)."""
    out = _Frames()
    mav = mavlink2.MAVLink(out, srcSystem=sysid, srcComponent=1)
    for i in range(count):
        if i % 2:
            mav.send(mav.sys_status_encode(0, 0, 0, 0, 12000, -1, 80, 0, 0, 0, 0, 0, 0))
        else:
            mav.send(mav.heartbeat_encode(MAV.MAV_TYPE_QUADROTOR, MAV.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 4, 4))
    return out.frames


def test_listeners_get_their_types_and_batches_hold_every_frame_once_in_order():
    async def scenario():
        links = [await MavlinkLink("udpin:127.0.0.1:0").open() for _ in range(2)]
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            typed, everything, batches = ([], []), ([], []), ([], [])
            status = [lambda m, i=i: typed[i].append(m.get_type()) for i in range(2)]
            for i, link in enumerate(links):
                link.add_listener(status[i], ("SYS_STATUS",))
                link.add_listener(lambda m, i=i: everything[i].append(m.get_seq()))
                link.add_batch_listener(lambda ms, i=i: batches[i].append([m.get_seq() for m in ms]))
            sent = [frames(sysid, 60) for sysid in (3, 4)]
            for a, b in zip(*sent):  # interleaved, one datagram each, and some bad data on the first link
                sock.sendto(a, ("127.0.0.1", links[0].local_port))
                sock.sendto(b, ("127.0.0.1", links[1].local_port))
            sock.sendto(b"\xfd\x09not a frame", ("127.0.0.1", links[0].local_port))
            await until(lambda: len(everything[0]) == 60 and len(everything[1]) == 60 and links[0].stats.bad_data)
            # a listener removed hears nothing more; the others do
            links[0].remove_listener(status[0])
            for frame in frames(3, 2):
                sock.sendto(frame, ("127.0.0.1", links[0].local_port))
            await until(lambda: len(everything[0]) == 62)
            return typed, everything, batches, [link.stats.received for link in links], links[0].peers[3].messages
        finally:
            sock.close()
            for link in links:
                await link.close()

    typed, everything, batches, received, latest = run(scenario())
    assert typed == (["SYS_STATUS"] * 30, ["SYS_STATUS"] * 30)
    assert everything == (list(range(60)) + [0, 1], list(range(60)))
    assert [seq for batch in batches[0] for seq in batch] == everything[0]  # each frame once, in order
    assert [seq for batch in batches[1] for seq in batch] == everything[1]
    assert received == [62, 60]
    assert latest["SYS_STATUS"].get_seq() == 1 and latest["HEARTBEAT"].get_seq() == 0
    assert our_threads() == []


def test_a_failing_listener_silences_its_vehicle_but_not_the_link_or_the_others():
    """A listener that raises on a vehicle's message: that vehicle is judged silent (lost; its messages
    reach no listener again, while the batches, the recording, still have them); the other vehicles'
    messages reach every listener. A batch listener that raises is not called again; the others are."""

    async def scenario():
        link = await MavlinkLink("udpin:127.0.0.1:0").open()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            heard, batches, broken_batches = [], [], []

            def broken(msg):
                if msg.get_srcSystem() == 5:
                    raise ValueError("a listener's bug")

            def broken_batch(msgs):
                broken_batches.append(len(msgs))
                raise ValueError("a batch listener's bug")

            link.add_listener(broken, ("HEARTBEAT",))
            link.add_batch_listener(broken_batch)
            link.add_listener(lambda m: heard.append((m.get_srcSystem(), m.get_type())), ("HEARTBEAT",))
            link.add_batch_listener(lambda ms: batches.append(len(ms)))
            for a, b in zip(frames(5, 4), frames(6, 4)):
                sock.sendto(a, ("127.0.0.1", link.local_port))
                sock.sendto(b, ("127.0.0.1", link.local_port))
            await until(lambda: sum(batches) == 8)
            return heard, len(broken_batches), dict(link.silenced), link.is_lost(5), link.is_lost(6)
        finally:
            sock.close()
            await link.close()

    heard, broken_calls, silenced, five_lost, six_lost = run(scenario())
    assert heard == [(6, "HEARTBEAT"), (6, "HEARTBEAT")]
    assert broken_calls == 1 and list(silenced) == [5] and "ValueError" in silenced[5]
    assert five_lost and not six_lost


def _parsed(frames_: list[bytes]) -> list:
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    return [m for f in frames_ for m in parser.parse_buffer(f) or []]


def test_a_batch_with_bad_and_unknown_frames_reaches_listeners_and_batches_without_them():
    """The dispatch's fast path: BAD_DATA and unknown ids are counted and left out of the batch, the
    valid messages reach their listeners in order; a listener added or removed takes effect at once."""

    async def scenario():
        link = await MavlinkLink("udpin:127.0.0.1:0").open()
        try:
            unknown = bytes([0xFD, 1, 0, 0, 9, 5, 1, 0x60, 0xEA, 0]) + b"\x00\x00\x00"  # message id 60000
            good = frames(5, 4)
            msgs = _parsed([good[0], unknown, good[1]]) + [mavlink2.MAVLink_bad_data(b"\xfdjunk", "bad")]
            msgs += _parsed(good[2:])
            everything, statuses, batches = [], [], []
            link.add_listener(lambda m: everything.append(m.get_seq()))
            link.add_batch_listener(lambda ms: batches.append([m.get_seq() for m in ms]))
            link._dispatch(msgs)
            link.add_listener(lambda m: statuses.append(m.get_seq()), ("SYS_STATUS",))
            link._dispatch(_parsed(frames(5, 2)))
            return everything, statuses, batches, link.stats
        finally:
            await link.close()

    everything, statuses, batches, stats = run(scenario())
    assert everything == [0, 1, 2, 3, 0, 1] and statuses == [1]
    assert batches == [[0, 1, 2, 3], [0, 1]]
    assert (stats.received, stats.unknown, stats.bad_data) == (6, 1, 1)


def test_a_batch_listener_on_several_links_gets_each_hand_over_once_link_after_link():
    """The recorder's tap on every link: one call per hand-over of the loop's inbox with every link's
    valid messages, each link's in their order; a listener of one link still gets only its own."""

    async def scenario():
        links = [await MavlinkLink("udpin:127.0.0.1:0").open() for _ in range(3)]
        try:
            shared, own = [], []

            def tap(ms):
                shared.append([(m.get_srcSystem(), m.get_seq()) for m in ms])

            for link in links:
                link.add_batch_listener(tap)
            links[1].add_batch_listener(lambda ms: own.append([m.get_seq() for m in ms]))
            box = links[0]._inbox
            box.put(links[0], _parsed(frames(3, 2)))
            box.put(links[1], _parsed(frames(4, 3)))
            box.put(links[0], _parsed(frames(3, 3)[2:]))
            box.put(links[2], [mavlink2.MAVLink_bad_data(b"\xfdjunk", "bad")])
            await until(lambda: shared)
            return shared, own
        finally:
            for link in links:
                await link.close()

    shared, own = run(scenario())
    assert shared == [[(3, 0), (3, 1), (3, 2), (4, 0), (4, 1), (4, 2)]]
    assert own == [[0, 1, 2]]
