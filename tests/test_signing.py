"""Signing that holds: one forged frame (a stream's ids, a timestamp of 2^48 - 2, a random signature)
must not cost a signed stream, on the controller's links and in the mock (swarmctl.signing)."""

from __future__ import annotations

import asyncio
import socket
import time

from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.mavlink.autopilots.ardupilot import ArduPilotVehicle
from swarmctl.mavlink.network import MAV, MavlinkLink
from swarmctl.signing import setup_signing
from tests.mavlink_support import mock_vehicles, our_threads, run

KEY = bytes(range(1, 33))
FAR_FUTURE = 2**48 - 2


def forged_heartbeat(sysid: int, compid: int, timestamp: int = FAR_FUTURE, secret: bytes = bytes(32)) -> bytes:
    """A well-formed signed HEARTBEAT of stream (link 0, sysid, compid) whose signature is not the key's."""
    mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.signing.secret_key, mav.signing.sign_outgoing, mav.signing.link_id = secret, True, 0
    mav.signing.timestamp = timestamp
    return bytes(
        mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0).pack(mav)
    )


def signed_heartbeat(sender) -> bytes:
    return bytes(
        sender.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0).pack(sender)
    )


def pair(helper: bool):
    """(sender of system 1, receiver), both with KEY: set up by swarmctl.signing, or as pymavlink alone."""
    sender = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    receiver = mavlink2.MAVLink(None)
    receiver.robust_parsing = True
    for mav in (sender, receiver):
        if helper:
            setup_signing(mav, KEY)
        else:
            s = mav.signing
            s.secret_key, s.sign_outgoing, s.link_id = KEY, True, 0
            s.timestamp = int((time.time() - 1420070400) * 100_000)
            s.allow_unsigned_callback = lambda _mav, _mid: False
    return sender, receiver


def kinds(receiver, data: bytes) -> list[str]:
    return [m.get_type() for m in receiver.parse_buffer(data) or []]


def test_pymavlink_alone_loses_the_stream_to_one_forged_frame():
    """What swarmctl.signing exists for (pymavlink 2.4: the stream's timestamp is recorded first)."""
    sender, receiver = pair(helper=False)
    assert kinds(receiver, signed_heartbeat(sender)) == ["HEARTBEAT"]
    assert kinds(receiver, forged_heartbeat(1, 1)) == ["BAD_DATA"]
    assert kinds(receiver, signed_heartbeat(sender)) == ["BAD_DATA"]  # every later frame looks old


def test_a_forged_frame_is_refused_and_the_next_signed_frame_taken():
    sender, receiver = pair(helper=True)
    assert kinds(receiver, signed_heartbeat(sender)) == ["HEARTBEAT"]
    before = dict(receiver.signing.stream_timestamps)
    assert kinds(receiver, forged_heartbeat(1, 1)) == ["BAD_DATA"]
    assert receiver.signing.stream_timestamps == before
    assert kinds(receiver, forged_heartbeat(7, 7)) == ["BAD_DATA"]  # a new stream, forged: not recorded either
    assert (0, 7, 7) not in receiver.signing.stream_timestamps
    frame = signed_heartbeat(sender)
    assert kinds(receiver, frame) == ["HEARTBEAT"]
    assert kinds(receiver, frame) == ["BAD_DATA"]  # replay protection kept: the same frame again is old


@settings(max_examples=200, deadline=None)
@given(
    timestamps=st.lists(st.integers(0, 2**48 - 1), min_size=1, max_size=5),
    secrets=st.lists(st.binary(min_size=32, max_size=32), min_size=1, max_size=5),
)
def test_no_forged_frame_changes_what_signed_frames_do(timestamps, secrets):
    sender, receiver = pair(helper=True)
    assert kinds(receiver, signed_heartbeat(sender)) == ["HEARTBEAT"]
    for ts, secret in zip(timestamps, secrets):
        if secret == KEY:
            continue
        assert kinds(receiver, forged_heartbeat(1, 1, ts, secret)) == ["BAD_DATA"]
    assert kinds(receiver, signed_heartbeat(sender)) == ["HEARTBEAT"]
    assert set(receiver.signing.stream_timestamps) == {(0, 1, 1)}


def test_a_forged_frame_neither_disables_a_signed_link_nor_fires_the_mocks_gcs_failsafe():
    """The issue's attack on `fly` with signing on: forged frames claiming to be vehicle 3 (sent to the
    controller's link) and claiming to be the controller (sent to the mock). The link keeps vehicle 3,
    a correctly signed command is accepted, and the mock's GCS failsafe stays off."""

    async def scenario():
        link = await MavlinkLink("udpin:127.0.0.1:0", signing_key=KEY).open()
        try:
            spec = dict(sysid=3, connect=f"udpout:127.0.0.1:{link.local_port}", signing_key=KEY)
            with mock_vehicles({**spec, "gcs_failsafe_timeout": 1.0}) as (m,):
                v = ArduPilotVehicle(link, 3, command_timeout=0.5, retries=3)
                try:
                    await link.wait_heartbeat(3, 5)
                    await asyncio.get_running_loop().run_in_executor(None, m.wait_for, lambda mm: mm.ready, 5)
                    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                        s.sendto(forged_heartbeat(3, 1), ("127.0.0.1", link.local_port))
                        s.sendto(forged_heartbeat(link.system_id, link.component_id), ("127.0.0.1", m.local_port))
                    await asyncio.sleep(3.5)  # longer than the failsafe's timeout (1 s) and the link's loss time (3 s)
                    peer_kept = not link.peers[3].lost
                    await link.command(3, MAV.MAV_CMD_COMPONENT_ARM_DISARM, (1,), timeout=0.5, retries=3)
                    return peer_kept, m.state().armed, m.gcs_failsafe, link.mav.signing.badsig_count
                finally:
                    await v.close()
        finally:
            await link.close()

    peer_kept, armed, failsafe, bad = run(scenario())
    assert peer_kept and armed and not failsafe
    assert bad >= 1  # the forged frame was seen, and refused
    assert our_threads() == []


def test_a_vehicle_whose_clock_runs_ahead_does_not_cost_the_other_links_their_new_vehicles():
    """Links sharing one signing clock: vehicle 1, two minutes fast, pushes the clock ahead; vehicle 2's
    first heartbeat on another link, at the wall clock's time, is a new stream and is still taken."""
    from swarmctl.signing import SigningClock, now_timestamp

    clock = SigningClock()
    link_a, link_b = mavlink2.MAVLink(None), mavlink2.MAVLink(None)
    for link_id, mav in enumerate((link_a, link_b)):
        mav.robust_parsing = True
        setup_signing(mav, KEY, link_id=link_id, clock=clock)
    fast = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    setup_signing(fast, KEY)
    fast.signing.timestamp = now_timestamp() + 120 * 100_000
    assert kinds(link_a, signed_heartbeat(fast)) == ["HEARTBEAT"]
    assert clock.now() > now_timestamp() + 100 * 100_000  # pushed ahead
    honest = mavlink2.MAVLink(None, srcSystem=2, srcComponent=1)
    setup_signing(honest, KEY)
    assert kinds(link_b, signed_heartbeat(honest)) == ["HEARTBEAT"]
