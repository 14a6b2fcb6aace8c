"""Preflight as ArduPilot means it, against a mock that boots as ArduCopter 4.7 SITL does: telemetry asked
for once after the first heartbeat, GUIDED first, readiness judged in GUIDED, the vehicle's reasons
reported, console text on a TCP link, the speed parameters read."""

from __future__ import annotations

import asyncio
import logging
import time

import pytest

from swarmctl.mavlink.autopilots.ardupilot import PREARM_BIT, TELEMETRY, ArduPilotVehicle
from swarmctl.mavlink.errors import CommandRejected, NotReady
from swarmctl.mavlink.network import MAV, MavlinkLink
from swarmctl.sim.autopilot import MockAutopilot
from tests.mavlink_support import HOME, mock_vehicles, our_threads, run

REQUEST = MAV.MAV_CMD_SET_MESSAGE_INTERVAL


@pytest.fixture(autouse=True)
def no_leftover_threads():
    yield
    assert our_threads() == []


def requests(mock: MockAutopilot) -> int:
    return sum(1 for _t, _src, command in mock.received if command == REQUEST)


async def in_executor(fn, *args):
    return await asyncio.get_running_loop().run_in_executor(None, fn, *args)


def test_the_mock_boots_as_sitl_does():
    """Seen from a link: BOOT then STANDBY; no telemetry before "ArduPilot Ready"; lat/lon 0 until the GPS
    fix; home (HOME_POSITION, GPS_GLOBAL_ORIGIN) later; the EKF's absolute position later still."""
    first: dict[str, float] = {}

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            spec = dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}", speedup=10.0, ready_after=30.0)
            with mock_vehicles(spec) as (m,):
                t0 = time.monotonic()

                def seen(msg):
                    kind = msg.get_type()
                    if kind == "HEARTBEAT":
                        kind = f"HEARTBEAT {msg.system_status}"
                    elif kind == "GLOBAL_POSITION_INT" and msg.lat:
                        kind = "a position"
                    elif kind == "EKF_STATUS_REPORT" and msg.flags & MAV.EKF_POS_HORIZ_ABS:
                        kind = "the EKF's position"
                    first.setdefault(kind, time.monotonic() - t0)

                link.add_listener(seen)
                await link.wait_heartbeat(1, 5)
                for name in ("GLOBAL_POSITION_INT", "HOME_POSITION", "GPS_GLOBAL_ORIGIN", "EKF_STATUS_REPORT"):
                    await link.set_message_interval(1, getattr(MAV, f"MAVLINK_MSG_ID_{name}"), 5.0)
                await link.wait_until(lambda: m.ready, 10, "the mock to be ready", "vehicle 1")
                await asyncio.sleep(0.5)

    run(scenario())
    assert first["HEARTBEAT 1"] < first["HEARTBEAT 3"]  # MAV_STATE_BOOT, then STANDBY
    assert first["GLOBAL_POSITION_INT"] < first["a position"] < first["HOME_POSITION"] < first["the EKF's position"]
    assert abs(first["GPS_GLOBAL_ORIGIN"] - first["HOME_POSITION"]) < 0.3  # both with the EKF origin
    assert first["the EKF's position"] > 2.5  # 30 simulated seconds at x10


def test_preflight_switches_to_guided_first_and_waits_for_the_ekf_there():
    """The slow-EKF fault: the pre-arm bit reads healthy in STABILIZE long before GUIDED can arm; GUIDED is
    accepted at once, then the bit is unhealthy there and arming fails ("Arm: Need Position Estimate")
    until the EKF uses the GPS (here 2 s after GUIDED). wait_ready reports the vehicle's texts and
    returns only then."""
    said: list[str] = []

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            spec = dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}", speedup=20.0, ready_after=2.0)
            with mock_vehicles(spec) as (m,):
                m.slow_ekf(1e9)  # moved on below
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                await in_executor(m.wait_for, lambda mm: mm.boot.has("manual"), 5)
                prearm_ok = lambda: bool(v._msg("SYS_STATUS").onboard_control_sensors_health & PREARM_BIT)  # noqa: E731
                await link.wait_until(prearm_ok, 3, "the pre-arm bit healthy in STABILIZE", "vehicle 1")
                stabilize_ok = v.mode == "STABILIZE" and not m.ready
                t0 = time.monotonic()
                ready = asyncio.ensure_future(v.wait_ready(10, report=said.append))
                await link.wait_until(lambda: v.mode == "GUIDED", 3, "GUIDED", "vehicle 1")
                guided_before_ready = not m.ready
                with pytest.raises(CommandRejected) as refused:
                    await link.command(1, MAV.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,))
                await asyncio.sleep(max(0.0, 2.0 - (time.monotonic() - t0)))
                m.slow_ekf(m.sim_time)  # the EKF uses the GPS now
                await ready
                waited = time.monotonic() - t0
                await v.arm(5)  # at once: no refusal
                arms = [r for c, r in m.commands if c == MAV.MAV_CMD_COMPONENT_ARM_DISARM]
                await v.disarm()
                await v.close()
                prearm = [at for at, _sev, t in link.peers[1].statustexts if t == "PreArm: Need Position Estimate"]
                return stabilize_ok, guided_before_ready, refused.value, waited, m.ready, arms, prearm

    stabilize_ok, guided_before_ready, refused, waited, ready, arms, prearm_received = run(scenario())
    assert stabilize_ok and guided_before_ready and ready
    assert refused.result == "FAILED" and refused.reason == "Arm: Need Position Estimate"
    assert arms == [MAV.MAV_RESULT_FAILED, MAV.MAV_RESULT_ACCEPTED]  # our probe, then the one arm
    assert 2.0 < waited < 6.0
    texts = said
    assert "PreArm: Need Position Estimate" in texts and "EKF3 IMU0 is using GPS" in texts
    assert any(t.startswith("waiting for the EKF's position estimate (EKF_STATUS_REPORT flags 167)") for t in texts)
    # each text once as it comes: the vehicle repeats its PreArm text every 30 s (1.5 s here)
    assert texts.count("PreArm: Need Position Estimate") == len(prearm_received)
    assert all(later - earlier > 1.2 for earlier, later in zip(prearm_received, prearm_received[1:]))


def set_modes(mock: MockAutopilot) -> int:
    return sum(1 for _t, _src, command in mock.received if command == MAV.MAV_CMD_DO_SET_MODE)


def test_the_mock_arducopter_undoes_a_mode_accepted_during_its_boot_as_sitl_does():
    """ArduCopter SITL accepts GUIDED while its heartbeat says BOOT and reports it, then ends its
    initialisation in STABILIZE ("ArduPilot Ready", STANDBY): the mode asked for is gone."""

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            m = MockAutopilot(home=HOME, sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}", speedup=20.0)
            m.slow_boot(1e9)
            m.start()
            try:
                peer = await link.wait_heartbeat(1, 5)
                await link.command(1, MAV.MAV_CMD_DO_SET_MODE, (1.0, 4.0))  # GUIDED: accepted
                await link.wait_until(lambda: peer.heartbeat.custom_mode == 4, 5, "GUIDED", "vehicle 1")
                in_boot = (peer.heartbeat.custom_mode, peer.heartbeat.system_status)
                m.slow_boot(m.sim_time)  # the initialisation ends now
                await link.wait_until(
                    lambda: peer.heartbeat.system_status == MAV.MAV_STATE_STANDBY, 5, "STANDBY", "vehicle 1"
                )
                return in_boot, peer.heartbeat.custom_mode
            finally:
                m.stop()

    in_boot, after = run(scenario())
    assert in_boot == (4, MAV.MAV_STATE_BOOT)
    assert after == 0  # STABILIZE


def test_preflight_asks_for_guided_only_once_the_autopilot_has_booted():
    """In CI a loaded ArduCopter SITL accepted GUIDED during its boot and ended it in STABILIZE, and the
    controller gave up on the mode 3 s later. wait_ready sends no DO_SET_MODE while the heartbeat says
    BOOT (it reports that it waits for the end of the boot), then one."""
    said: list[str] = []

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            m = MockAutopilot(
                home=HOME, sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}", speedup=20.0, ready_after=2.0
            )
            m.slow_boot(1e9)
            m.start()
            try:
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                ready = asyncio.ensure_future(v.wait_ready(20, report=said.append))
                booting = "waiting for the end of its boot (HEARTBEAT system_status BOOT)"
                await link.wait_until(lambda: any(t.startswith(booting) for t in said), 5, "the report", "vehicle 1")
                sent_in_boot = set_modes(m)
                m.slow_boot(m.sim_time)
                await ready
                result = sent_in_boot, set_modes(m), v.mode, m.mode_name
                await v.close()
                return result
            finally:
                m.stop()

    sent_in_boot, sent, mode, mock_mode = run(scenario())
    assert sent_in_boot == 0
    assert sent == 1 and mode == mock_mode == "GUIDED"


def test_a_mode_accepted_but_not_reported_in_time_is_waited_for_again_not_fatal():
    """The vehicle accepts GUIDED, then its heartbeats stop for 4.5 s: the mode is not seen within
    set_mode's 3 s. wait_ready reports it and goes on; when the heartbeats come back in GUIDED the
    vehicle is ready."""
    said: list[str] = []

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            spec = dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}", speedup=20.0, ready_after=2.0)
            with mock_vehicles(spec) as (m,):
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                await in_executor(m.wait_for, lambda mm: mm.ready, 5)
                m.drop_heartbeats(4.5)
                await v.wait_ready(20, report=said.append)
                result = v.mode, m.mode_name
                await v.close()
                return result

    mode, mock_mode = run(scenario())
    assert mode == mock_mode == "GUIDED"
    assert "mode GUIDED accepted but not reported (STABILIZE), asking again" in said


def test_a_vehicle_that_never_gets_ready_times_out_naming_its_last_reason():
    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            spec = dict(sysid=4, connect=f"udpout:127.0.0.1:{link.local_port}", speedup=20.0, ready_after=2.0)
            with mock_vehicles(spec) as (m,):
                m.slow_ekf(10_000.0)
                v = ArduPilotVehicle(link, 4, name="alpha")
                await v.connect(5)
                with pytest.raises(NotReady) as err:
                    await v.wait_ready(2.5)
                await v.close()
                return str(err.value)

    text = run(scenario())
    assert text.startswith("alpha: not ready to arm after 2.5 s: PreArm: Need Position Estimate (waiting for ")
    assert "the EKF's position estimate (EKF_STATUS_REPORT flags 167)" in text and "\n" not in text


def test_telemetry_is_asked_for_once_per_message_and_again_only_for_one_that_does_not_come():
    """The streams start 1.8 s after the first heartbeat (as SITL's at "ArduPilot Ready"): nothing is asked
    twice. A request acknowledged and then lost (SITL does that before its first heartbeat) is repeated
    alone, after its patience."""

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            slow_boot = dict(speedup=1.0, ready_after=30.0)  # streams from 1.8 s, home at 14 s
            with mock_vehicles(
                dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}", **slow_boot),
                dict(sysid=2, connect=f"udpout:127.0.0.1:{link.local_port}", speedup=20.0),
            ) as (slow, lossy):
                lossy.forget_intervals("GPS_RAW_INT", 1)
                vehicles = [ArduPilotVehicle(link, 1), ArduPilotVehicle(link, 2)]
                await asyncio.gather(*(v.connect(5) for v in vehicles))
                await link.wait_until(
                    lambda: all(k in link.peers[2].messages for k in ("GPS_RAW_INT", "HOME_POSITION")),
                    12,
                    "every stream of vehicle 2",
                    "vehicle 2",
                )
                await asyncio.sleep(5.0)  # the slow one's streams have started, nothing asked again
                got = {n for n in link.peers[1].messages if n in {s.name for s in TELEMETRY}}
                counts = [dict(v.requests) for v in vehicles]
                seen = [requests(slow), requests(lossy)]
                for v in vehicles:
                    await v.close()
                return got, counts, seen

    got, (slow, lossy), seen = run(scenario(), timeout=40)
    assert got >= {"GLOBAL_POSITION_INT", "SYS_STATUS", "EKF_STATUS_REPORT", "GPS_RAW_INT"}  # (home later)
    assert slow == {s.name: 1 for s in TELEMETRY} and seen[0] == 5
    assert lossy == {**{s.name: 1 for s in TELEMETRY}, "GPS_RAW_INT": 2} and seen[1] == 6


def test_boot_text_on_a_tcp_link_is_console_text_not_bad_data(caplog):
    """The mock on a TCP port (as SITL's SERIAL0): it boots when the controller connects, prints its
    console text before MAVLink and between its first heartbeats. Bad bytes once it is up are bad data."""

    async def scenario():
        with mock_vehicles(dict(sysid=1, connect="tcpin:127.0.0.1:0", speedup=1.0)) as (m,):
            await asyncio.sleep(0.3)  # the mock waits: it boots when the controller connects (STANDBY at 0.14 s)
            async with MavlinkLink(f"tcp:127.0.0.1:{m.local_port}") as link:
                first = []
                link.add_listener(lambda msg: msg.get_type() == "HEARTBEAT" and first.append(msg.system_status))
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                await v.wait_ready(10)
                clean = (link.stats.bad_data, link.stats.console_bytes, link.console)
                m._write(b"garbage that is not MAVLink")
                await link.wait_until(lambda: link.stats.bad_data > 0, 3, "bad data", "vehicle 1")
                await v.close()
                return first[0], clean

    with caplog.at_level(logging.INFO, logger="swarmctl.mavlink.network"):
        first_status, (bad, console, text) = run(scenario())
    console_text = b"".join(MockAutopilot().personality.console)
    assert first_status == MAV.MAV_STATE_BOOT  # it booted when the controller connected, 0.3 s after its start
    assert bad == 0 and console == len(console_text) and text == console_text
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and warnings[0].startswith("rejected bad MAVLink data on tcp:127.0.0.1:")


def test_the_speed_parameters_are_read_and_give_the_timeouts():
    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            spec = dict(sysid=3, connect=f"udpout:127.0.0.1:{link.local_port}", speed=4.0, climb_rate=1.0)
            with mock_vehicles(spec) as (m,):
                m.params["RTL_ALT"] = 3000.0
                v = ArduPilotVehicle(link, 3)
                await v.connect(5)
                defaults = v.limits
                limits = await v.read_limits()
                await v.close()
                return defaults, limits

    defaults, limits = run(scenario())
    assert defaults.read == () and defaults.speed == 10.0  # ArduCopter's defaults until read
    assert len(limits.read) == 10 and (limits.speed, limits.climb, limits.rtl_alt) == (4.0, 1.0, 30.0)
    assert limits.takeoff_timeout(40.0) > defaults.takeoff_timeout(40.0)


def test_guided_is_taken_before_the_vehicle_can_arm_and_refused_only_in_the_air_without_a_position():
    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            spec = dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}", speedup=1.0, ready_after=60.0)
            with mock_vehicles(spec) as (m,):
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                await v.set_mode("GUIDED")
                return v.mode, m.ready, m.state().mode

    mode, ready, mock_mode = run(scenario())
    assert mode == mock_mode == "GUIDED" and not ready


def test_home_is_asked_for_again_when_the_ekf_has_a_position_but_no_home_came():
    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}", home=HOME)) as (m,):
                m.forget_intervals("HOME_POSITION", 1)
                v = ArduPilotVehicle(link, 1)
                await v.connect(5)
                await v.wait_ready(12)
                counts = dict(v.requests)
                await v.close()
                return counts

    assert run(scenario(), timeout=30)["HOME_POSITION"] == 2


@pytest.mark.parametrize("mock_first", [False, True], ids=["controller listening first", "mock 1 s earlier"])
def test_a_plain_pymavlink_client_on_udpin_gets_positions_whenever_the_mock_starts(mock_first):
    """The issue's set-up: a plain pymavlink client listening on udpin, the mock sending to it (udpout),
    started while the client listens or 1 s before; one request after the first heartbeat starts the stream."""
    import socket

    from tests.sitl_support import mavlink_client, request_message_interval, wait_message

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    mock = MockAutopilot(sysid=1, connect=f"udpout:127.0.0.1:{port}", speedup=1.0, ready_after=12.0)  # GPS at 3 s
    try:
        if mock_first:
            mock.start()
            time.sleep(1.0)
        with mavlink_client(f"udpin:0.0.0.0:{port}") as conn:
            if not mock_first:
                mock.start()
            wait_message(conn, "HEARTBEAT", 5, sysid=1)
            request_message_interval(conn, 1, MAV.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 5.0)
            first = wait_message(conn, "GLOBAL_POSITION_INT", 3, sysid=1)
            fix = wait_message(conn, "GLOBAL_POSITION_INT", 5, sysid=1, condition=lambda m: m.lat != 0)
    finally:
        mock.stop()
    assert first.lat == 0 and abs(fix.lat / 1e7 - HOME[0]) < 1e-6  # zeros until the GPS fix, then home
    assert requests(mock) == 1
