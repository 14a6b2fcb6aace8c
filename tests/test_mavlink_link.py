"""The link's guarantees: acks, retries, refusals, link loss, failsafe, signing, shared links."""

from __future__ import annotations

import asyncio
import time

import pytest

from swarmctl.mavlink.autopilots.ardupilot import ArduPilotVehicle
from swarmctl.mavlink.autopilots.descriptions import px4_encode
from swarmctl.mavlink.codec import distance_m
from swarmctl.mavlink.errors import CommandRejected, CommandTimeout
from swarmctl.mavlink.network import MAV, MavlinkLink
from tests.mavlink_support import HOME, mock_vehicles, our_threads, run


@pytest.fixture(autouse=True)
def no_leftover_threads():
    yield
    assert our_threads() == []


async def one_vehicle(link_kw=None, vehicle_kw=None, **mock_kw):
    """(link, vehicle, mock context) for one ArduCopter mock; the caller closes/exits them."""
    link = await MavlinkLink("udpin:127.0.0.1:0", **(link_kw or {})).open()
    ctx = mock_vehicles(dict(sysid=mock_kw.pop("sysid", 1), connect=f"udpout:127.0.0.1:{link.local_port}", **mock_kw))
    return link, ctx


def count(mock, command):
    return sum(1 for t, _src, c in mock.received if c == command)


def test_command_retried_until_acked_and_timeout_names_command_and_vehicle():
    async def scenario():
        link, ctx = await one_vehicle()
        try:
            with ctx as (m,):
                v = ArduPilotVehicle(link, 1, name="copter-1", command_timeout=0.3, retries=3)
                await v.connect(5)
                await v.wait_ready(10)  # in GUIDED: one DO_SET_MODE
                before = count(m, MAV.MAV_CMD_DO_SET_MODE)
                m.drop_commands(MAV.MAV_CMD_DO_SET_MODE, 2)  # first two attempts get no answer
                await v.set_mode("LOITER")
                retried = count(m, MAV.MAV_CMD_DO_SET_MODE) - before
                m.drop_commands(MAV.MAV_CMD_COMPONENT_ARM_DISARM, None)  # never answered
                t0 = time.monotonic()
                with pytest.raises(CommandTimeout) as err:
                    await v.arm(timeout=1)
                took = time.monotonic() - t0
                attempts = count(m, MAV.MAV_CMD_COMPONENT_ARM_DISARM)
                await v.close()
                return retried, attempts, took, str(err.value), v.mode
        finally:
            await link.close()

    retried, attempts, took, text, mode = run(scenario())
    assert retried == 3 and mode == "LOITER"
    assert attempts == 4 and 1.1 < took < 3.0
    assert "MAV_CMD_COMPONENT_ARM_DISARM" in text and "copter-1" in text


def test_refusals_are_errors_naming_command_vehicle_and_reason():
    async def scenario():
        link, ctx = await one_vehicle()
        errors = {}
        try:
            with ctx as (m,):
                v = ArduPilotVehicle(link, 1, command_timeout=0.3)
                await v.connect(5)
                # arming refused: FAILED + an "Arm: ..." STATUSTEXT, as ArduPilot does
                m.refuse_arming("Hardware safety switch")
                await v.wait_ready(10)
                await v.set_mode("GUIDED")
                with pytest.raises(CommandRejected) as e:
                    await v.arm(timeout=0.5)
                errors["arm"] = e.value
                m.refuse_arming(None)
                # take-off while disarmed: FAILED
                with pytest.raises(CommandRejected) as e:
                    await v.takeoff(40)
                errors["takeoff"] = e.value
                # an unknown command: UNSUPPORTED
                with pytest.raises(CommandRejected) as e:
                    await link.command(1, MAV.MAV_CMD_DO_SET_SERVO, (9, 1500), vehicle="vehicle 1")
                errors["servo"] = e.value
                # DENIED (forced), e.g. a vehicle configured to refuse RTL
                m.force_result(MAV.MAV_CMD_DO_SET_MODE, MAV.MAV_RESULT_DENIED)
                with pytest.raises(CommandRejected) as e:
                    await v.rtl()
                errors["rtl"] = e.value
                await v.close()
                return errors, m.state()
        finally:
            await link.close()

    errors, state = run(scenario())
    arm = errors["arm"]
    assert arm.result == "FAILED" and "Arm: Hardware safety switch" in arm.reason
    assert "vehicle 1" in str(arm) and "MAV_CMD_COMPONENT_ARM_DISARM" in str(arm)
    assert errors["takeoff"].result == "FAILED" and errors["takeoff"].command == "MAV_CMD_NAV_TAKEOFF"
    assert errors["servo"].result == "UNSUPPORTED"
    assert errors["rtl"].result == "DENIED" and errors["rtl"].command == "MAV_CMD_DO_SET_MODE"
    assert not state.armed and state.mode == "GUIDED"


def test_arming_is_retried_while_the_vehicle_is_not_ready():
    async def scenario():
        link, ctx = await one_vehicle(ready_after=30.0)  # 1.5 s wall at speedup 20
        try:
            with ctx as (m,):
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                await v.arm(timeout=10)  # STABILIZE is armable; pre-arm fails until ready
                results = [r for c, r in m.commands if c == MAV.MAV_CMD_COMPONENT_ARM_DISARM]
                await v.disarm()
                await v.close()
                return results
        finally:
            await link.close()

    results = run(scenario())
    assert results[0] == MAV.MAV_RESULT_FAILED and results[-1] == MAV.MAV_RESULT_ACCEPTED


@pytest.mark.slow
def test_link_loss_detected_after_3_s_and_recovery():
    async def scenario():
        link, ctx = await one_vehicle()
        try:
            with ctx as (m,):
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                await link.wait_until(lambda: "GLOBAL_POSITION_INT" in link.peers[1].messages, 5, "telemetry", "v1")
                m.blackout(4.5)  # the radio out of range: nothing either way
                t0 = time.monotonic()
                await link.wait_until(lambda: v.lost, 6, "loss", "vehicle 1")
                lost_after = time.monotonic() - t0
                m.drop_heartbeats(4.5 - lost_after + 1.5)  # its telemetry comes back 1.5 s before its heartbeat
                peer = link.peers[1]
                telemetry = lambda: peer.received_at["GLOBAL_POSITION_INT"] > t0 + 4.5  # noqa: E731
                await link.wait_until(telemetry, 3, "telemetry after the blackout", "vehicle 1")
                lost_with_telemetry = v.lost
                await link.wait_until(lambda: not v.lost, 6, "recovery", "vehicle 1")
                back_after = time.monotonic() - t0
                await v.close()
                return lost_after, lost_with_telemetry, back_after, [e for _t, _s, e in link.events]
        finally:
            await link.close()

    lost_after, lost_with_telemetry, back_after, events = run(scenario())
    assert 2.5 < lost_after < 4.0  # the last frame (5 Hz telemetry) just before the blackout, + 3 s
    # back at its heartbeat, not its first position report: the rejoin reads the heartbeat's mode
    assert lost_with_telemetry and 5.9 < back_after < 7.5
    assert events == ["seen", "lost", "back"]


@pytest.mark.slow
def test_a_vehicle_whose_heartbeats_stop_while_its_telemetry_flows_is_not_lost():
    """Its autopilot is heard: the link is up (on heartbeats alone, a link losing 20 % gave 3 false losses
    in a 90 s search of 3 vehicles)."""

    async def scenario():
        link, ctx = await one_vehicle()
        try:
            with ctx as (m,):
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                await link.wait_until(lambda: "GLOBAL_POSITION_INT" in link.peers[1].messages, 5, "telemetry", "v1")
                m.drop_heartbeats(4.5)
                t0 = time.monotonic()
                lost = False
                while time.monotonic() - t0 < 4.5:
                    lost = lost or v.lost
                    await asyncio.sleep(0.05)
                heartbeat_gap = time.monotonic() - link.peers[1].last_heartbeat
                await v.close()
                return lost, heartbeat_gap, [e for _t, _s, e in link.events]
        finally:
            await link.close()

    lost, heartbeat_gap, events = run(scenario())
    assert heartbeat_gap > 3.0  # the watchdog would have judged it lost on heartbeats alone
    assert not lost and events == ["seen"]


@pytest.mark.slow
def test_gcs_failsafe_sends_the_vehicle_home_when_the_controller_goes_silent():
    async def scenario():
        link, ctx = await one_vehicle(gcs_failsafe_timeout=2.5)
        with ctx as (m,):
            try:
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                await v.arm_and_takeoff(20, timeout=20)
                from swarmctl.mavlink.codec import offset_m

                await v.goto(*offset_m(HOME[0], HOME[1], 40, 0), 20)
                await v.wait_reached(0.05, 10)
                await v.close()
            finally:
                await link.close()  # the controller's heartbeats stop here
            ok = await asyncio.get_running_loop().run_in_executor(None, m.wait_for, lambda mm: not mm.armed, 15)
            return ok, m.state()

    ok, s = run(scenario())
    assert ok and s.gcs_failsafe and s.mode == "RTL"
    assert distance_m(s.lat, s.lon, HOME[0], HOME[1]) < 0.05 and s.rel_alt == 0.0


def test_telemetry_is_requested_again_after_a_reboot():
    async def scenario():
        link, ctx = await one_vehicle()
        try:
            with ctx as (m,):
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                await v.wait_ready(10)
                before = count(m, MAV.MAV_CMD_SET_MESSAGE_INTERVAL)
                m.reboot(downtime=0.5)
                t_reboot = time.monotonic()
                peer = link.peers[1]
                await link.wait_until(
                    lambda: peer.received_at.get("GLOBAL_POSITION_INT", 0) > t_reboot + 1.0,
                    8,
                    "position after reboot",
                    "vehicle 1",
                )
                after = count(m, MAV.MAV_CMD_SET_MESSAGE_INTERVAL)
                await v.close()
                return before, after
        finally:
            await link.close()

    before, after = run(scenario())
    assert after > before  # the stream stopped with the reboot and was requested again


def test_gps_glitch_shows_as_a_position_jump():
    async def scenario():
        link, ctx = await one_vehicle()
        try:
            with ctx as (m,):
                v = ArduPilotVehicle(link, 1, telemetry_rate_hz=10)
                await v.connect(5)
                await v.wait_ready(10)
                m.gps_glitch(north_m=80.0, east_m=0.0, seconds=0.6)
                jumped = lambda: distance_m(v.position.lat, v.position.lon, HOME[0], HOME[1]) > 70
                await link.wait_until(jumped, 3, "the glitch", "vehicle 1")
                await link.wait_until(lambda: not jumped(), 3, "the glitch to end", "vehicle 1")
                await v.close()
        finally:
            await link.close()

    run(scenario())


def test_signing_vehicle_accepts_only_signed_commands(tmp_path):
    key = bytes(range(1, 33))
    wrong = bytes(32)

    async def scenario():
        out = {}
        for label, link_key in (("signed", key), ("unsigned", None), ("wrong key", wrong)):
            link = await MavlinkLink("udpin:127.0.0.1:0", signing_key=link_key).open()
            try:
                spec = dict(sysid=3, connect=f"udpout:127.0.0.1:{link.local_port}", signing_key=key)
                with mock_vehicles(spec) as (m,):
                    v = ArduPilotVehicle(link, 3, command_timeout=0.3, retries=1)
                    try:
                        if label == "wrong key":  # its own heartbeats fail our signature check
                            await link.wait_until(lambda link=link: link.stats.bad_data >= 2, 5, "two refused", "v3")
                            out[label] = (link.stats.bad_data, 3 in link.peers)
                            continue
                        await link.wait_heartbeat(3, 5)
                        await m_ready(m)
                        try:
                            await link.command(3, MAV.MAV_CMD_COMPONENT_ARM_DISARM, (1,), timeout=0.3, retries=1)
                            result = "accepted"
                        except CommandTimeout:
                            result = "no answer"
                        out[label] = (result, m.state().armed, m.rejected_unsigned)
                    finally:
                        await v.close()
            finally:
                await link.close()
        return out

    out = run(scenario())
    assert out["signed"] == ("accepted", True, 0)
    result, armed, rejected = out["unsigned"]
    assert result == "no answer" and not armed and rejected >= 2
    bad, seen = out["wrong key"]
    assert bad > 0 and not seen


async def m_ready(m):
    await asyncio.get_running_loop().run_in_executor(None, m.wait_for, lambda mm: mm.ready, 5)


def test_two_vehicles_on_one_link_commands_reach_only_the_addressed_one():
    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            port = link.local_port
            with mock_vehicles(
                dict(sysid=1, connect=f"udpout:127.0.0.1:{port}"), dict(sysid=2, connect=f"udpout:127.0.0.1:{port}")
            ) as (m1, m2):
                v1, v2 = ArduPilotVehicle(link, 1), ArduPilotVehicle(link, 2)
                await asyncio.gather(v1.connect(5), v2.connect(5))
                await v2.wait_ready(10)
                await v2.set_mode("GUIDED")
                await v2.arm()
                await v2.takeoff(10)
                await link.wait_until(lambda: v2.position.rel_alt > 5, 10, "climb", "vehicle 2")
                s1, s2 = m1.state(), m2.state()
                ignored = m1.ignored
                cmds_at_1 = [c for t, _s, c in m1.received if t == "COMMAND_LONG"]
                await v1.close()
                await v2.close()
                return s1, s2, ignored, cmds_at_1, v1.position, v2.position

    s1, s2, ignored, cmds_at_1, p1, p2 = run(scenario())
    assert s2.armed and s2.mode == "GUIDED" and s2.rel_alt > 5
    assert not s1.armed and s1.mode == "STABILIZE" and s1.rel_alt == 0.0
    # vehicle 1 heard vehicle 2's commands on the shared channel and ignored them
    assert ignored > 0
    assert MAV.MAV_CMD_COMPONENT_ARM_DISARM not in cmds_at_1
    assert p1.rel_alt == 0.0 and p2.rel_alt > 5  # telemetry kept apart by system id


def test_px4_personality_refuses_offboard_without_a_setpoint_stream():
    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            spec = dict(sysid=6, connect=f"udpout:127.0.0.1:{link.local_port}", autopilot="px4")
            with mock_vehicles(spec) as (m,):
                await link.wait_heartbeat(6, 5)
                hb = link.peers[6].heartbeat
                await m_ready(m)
                offboard = (1.0, 6.0, 0.0)  # base mode CUSTOM, main mode OFFBOARD
                with pytest.raises(CommandRejected) as err:
                    await link.command(6, MAV.MAV_CMD_DO_SET_MODE, offboard)
                for _ in range(5):  # a 10 Hz setpoint stream
                    link.send(
                        link.mav.set_position_target_local_ned_encode(
                            0, 6, 1, MAV.MAV_FRAME_LOCAL_NED, 0b110111111000, 0, 0, -5, 0, 0, 0, 0, 0, 0, 0, 0
                        )
                    )
                    await asyncio.sleep(0.1)
                await link.command(6, MAV.MAV_CMD_DO_SET_MODE, offboard)
                return hb, err.value, m.mode_name

    hb, err, mode = run(scenario())
    assert hb.autopilot == MAV.MAV_AUTOPILOT_PX4 and hb.type == MAV.MAV_TYPE_QUADROTOR
    assert hb.custom_mode == px4_encode(4, 3)  # AUTO.LOITER (HOLD) after boot, as PX4 SITL
    assert err.result == "TEMPORARILY_REJECTED" and "Offboard" in err.reason
    assert mode == "OFFBOARD"


def test_ardupilot_heartbeat_matches_the_sitl_log():
    """Values read from a real ArduCopter 4.7 SITL tlog (shared data, arducopter_sitl_guided_takeoff):
    type 2 (quadrotor), autopilot 3 (ArduPilot), base_mode 89 disarmed / 217 armed,
    custom_mode 4 in GUIDED, system_status 3 standby / 4 active, mavlink_version 3."""

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")):
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                await v.wait_ready(10)
                await v.set_mode("GUIDED")
                disarmed = link.peers[1].heartbeat
                await v.arm()
                armed = link.peers[1].heartbeat
                fresh = dict(link.peers[1].messages)
                await v.close()
                return disarmed, armed, fresh

    disarmed, armed, fresh = run(scenario())
    assert (
        disarmed.type,
        disarmed.autopilot,
        disarmed.base_mode,
        disarmed.custom_mode,
        disarmed.system_status,
        disarmed.mavlink_version,
    ) == (2, 3, 89, 4, 3, 3)
    assert (armed.base_mode, armed.system_status) == (217, 4)
    assert {"GLOBAL_POSITION_INT", "HOME_POSITION", "SYS_STATUS", "EKF_STATUS_REPORT", "GPS_RAW_INT"} <= set(fresh)
    st = fresh["SYS_STATUS"]
    assert st.onboard_control_sensors_health & MAV.MAV_SYS_STATUS_PREARM_CHECK


def test_fresh_ardupilot_mock_sends_only_heartbeats_until_asked():
    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")):
                await link.wait_heartbeat(1, 5)
                await asyncio.sleep(1.2)
                return set(link.peers[1].messages)

    assert run(scenario()) <= {"HEARTBEAT", "STATUSTEXT"}


def test_bad_bytes_are_counted_and_dropped_without_breaking_the_link():
    import socket

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")):
                await link.wait_heartbeat(1, 5)
                with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                    for junk in (
                        b"\xfd\x09\x00\x00\x00\x01\x01\x00\x00\x00" + bytes(11),
                        b"\xfe\x05garbage!",
                        bytes(range(256)),
                    ):
                        s.sendto(junk, ("127.0.0.1", link.local_port))
                await link.wait_until(lambda: link.stats.bad_data > 0, 3, "the junk counted", "v1")
                bad = link.stats.bad_data
                t = time.monotonic()
                await link.wait_until(lambda: link.peers[1].last_heartbeat > t, 3, "heartbeat", "v1")
                return bad

    assert run(scenario()) > 0


def test_udp_link_reads_on_the_loop_a_burst_longer_than_a_read_batch_in_order():
    """A UDP link has no reader thread: its socket is read on the loop, at the inbox's drains, READ_BATCH
    datagrams at a time. A burst queued while the loop was busy arrives whole and in order, and once
    the link is closed its socket is no longer read."""
    import socket

    from swarmctl.mavlink.inbox import READ_BATCH

    burst = 2 * READ_BATCH + 22

    async def scenario():
        link = await MavlinkLink("udpin:127.0.0.1:0").open()
        fd = link._transport.sock.fileno()
        threads = [t for t in our_threads() if t.startswith("mavlink-rx")]
        seen: list[int] = []
        link.add_listener(lambda msg: seen.append(msg.custom_mode), ["HEARTBEAT"])
        tx = MAV.MAVLink(None, srcSystem=7, srcComponent=1)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
            for i in range(burst):  # all queued before the loop runs again
                frame = tx.heartbeat_encode(MAV.MAV_TYPE_QUADROTOR, MAV.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, i, 0).pack(tx)
                sender.sendto(frame, ("127.0.0.1", link.local_port))
            deadline = time.monotonic() + 10
            while len(seen) < burst and time.monotonic() < deadline:
                await asyncio.sleep(0.01)
        watched_open = _watched(link, fd)
        await link.close()
        return threads, seen, watched_open, _watched(link, fd)

    threads, seen, watched_open, watched_closed = run(scenario())
    assert threads == []
    assert seen == list(range(burst))
    assert watched_open and not watched_closed


def test_udp_links_read_in_passes_without_empty_reads(monkeypatch):
    """Datagrams queued on several UDP links while the loop was busy reach each link's listeners whole
    and in order, read one per ready socket a pass: a drain never calls recvfrom on a socket that has
    nothing (the selector says which have more), and a link closed with datagrams still queued is not
    read again."""
    import socket

    empty_reads = []
    read_one = MavlinkLink._read_datagram

    def counted(self):
        msgs = read_one(self)
        if msgs is None and not self._stop.is_set():
            empty_reads.append(self)
        return msgs

    monkeypatch.setattr(MavlinkLink, "_read_datagram", counted)
    bursts = (5, 1, 9)

    async def scenario():
        links = [await MavlinkLink("udpin:127.0.0.1:0").open() for _ in bursts]
        seen: list[list[int]] = [[] for _ in bursts]
        for link, got in zip(links, seen):
            link.add_listener(lambda msg, got=got: got.append(msg.custom_mode), ["HEARTBEAT"])
        tx = MAV.MAVLink(None, srcSystem=7, srcComponent=1)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
            for i in range(max(bursts)):  # interleaved over the links, all queued before the loop runs again
                for link, n in zip(links, bursts):
                    if i < n:
                        frame = tx.heartbeat_encode(MAV.MAV_TYPE_QUADROTOR, MAV.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, i, 0)
                        sender.sendto(frame.pack(tx), ("127.0.0.1", link.local_port))
            deadline = time.monotonic() + 10
            while [len(got) for got in seen] != list(bursts) and time.monotonic() < deadline:
                await asyncio.sleep(0.01)
            closing = links.pop()
            sender.sendto(frame.pack(tx), ("127.0.0.1", closing.local_port))
            await closing.close()  # its datagram stays queued in a socket no longer read
            for link in links:
                await link.close()
        return seen

    seen = run(scenario())
    assert seen == [list(range(n)) for n in bursts]
    assert empty_reads == []


def _watched(link: MavlinkLink, fd: int) -> bool:
    """`fd` is among the sockets the loop's inbox reads."""
    from swarmctl.mavlink.inbox import inbox_for

    sockets = inbox_for(asyncio.get_running_loop())._sockets
    return sockets is not None and fd in {key.fd for key in sockets.get_map().values()}


@pytest.mark.slow
def test_a_controller_stalled_longer_than_the_loss_time_sees_the_loss_as_it_runs_again():
    """The event loop blocked 4.5 s (a stopped or starved process): the frames the socket kept are read as
    it runs again, maybe before the watchdog's turn (here: the watchdog never runs); the vehicle was silent
    to us all the same: lost, then back with its heartbeat (never an unbroken link whose failsafe mode
    looks like a pilot's)."""

    async def scenario():
        link, ctx = await one_vehicle()
        try:
            with ctx:
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                await link.wait_until(lambda: "GLOBAL_POSITION_INT" in link.peers[1].messages, 5, "telemetry", "v1")
                link._check_heartbeats = lambda now: None  # the watchdog never gets its turn first
                time.sleep(4.5)  # noqa: ASYNC251 - the stall under test: nothing on this loop runs
                await link.wait_until(lambda: [e for _t, _s, e in link.events][-1:] == ["back"], 3, "back", "v1")
                await v.close()
                return [e for _t, _s, e in link.events]
        finally:
            await link.close()

    assert run(scenario()) == ["seen", "lost", "back"]
