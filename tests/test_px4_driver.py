"""The PX4 driver through MAVSDK against the mock PX4, and the mock PX4 against what PX4 SITL showed.

The reposition goes as COMMAND_INT through MAVSDK's MavlinkDirect in the frame the vehicle takes (PX4
up to 1.16 and the SITL build: GLOBAL_INT and GLOBAL; stock PX4 main refuses one of them with 9),
readiness waits name what is missing, knowledge frames go out on the vehicle's own link, and the mock
answers as the real one did (docs/mavlink.md, "What PX4 SITL showed").
"""

from __future__ import annotations

import asyncio
import math
import time

import pytest

from swarmctl.knowledge.codec import KnowledgeCodec
from swarmctl.knowledge.model import Delta
from swarmctl.mavlink.autopilots.descriptions import MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_INT, PX4, px4_encode
from swarmctl.mavlink.autopilots.px4 import PX4Vehicle
from swarmctl.mavlink.codec import distance_m, offset_m, parse_connection
from swarmctl.mavlink.connect import with_port_hints
from swarmctl.mavlink.errors import CommandRejected, NotReady, WaitTimeout
from swarmctl.mavlink.network import MAV, MavlinkLink
from swarmctl.mavlink.vehicle import Position
from swarmctl.sim.swarm import free_udp_port
from tests.mavlink_support import HOME, mock_vehicles, our_threads, run

REPOSITION = MAV.MAV_CMD_DO_REPOSITION


@pytest.fixture(autouse=True)
def no_leftover_threads():
    yield
    assert our_threads() == []


def repositions(mock) -> list[int]:
    """The MAV_RESULTs the mock gave the DO_REPOSITIONs it got, in order."""
    return [result for command, result in mock.commands if command == REPOSITION]


async def flying_px4(mock_kw: dict, port: int) -> tuple[PX4Vehicle, object]:
    """A PX4Vehicle connected to a mock PX4 (started by the caller's context) and in the air at 10 m."""
    v = PX4Vehicle(f"udpin:127.0.0.1:{port}", sysid=mock_kw.get("sysid", 1), arm_retry_period=0.2)
    await v.connect(10)
    await v.arm_and_takeoff(10.0, timeout=30)
    return v


def fly_two_repositions(**mock_kw) -> tuple[list[int], int | None, list[float]]:
    """Two repositions of a PX4 in the air: the mock's answers, the frame kept, the distances flown to."""
    port = free_udp_port()

    async def scenario():
        with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{port}", autopilot="px4", **mock_kw)) as (m,):
            v = await flying_px4(mock_kw, port)
            try:
                errors = []
                for east in (20.0, 40.0):
                    lat, lon = offset_m(HOME[0], HOME[1], 0.0, east)
                    await v.goto(lat, lon, 10.0)
                    await v.wait_reached(0.5, 20)
                    errors.append(distance_m(m.lat, m.lon, lat, lon))
                return repositions(m), v.reposition_frame, errors
            finally:
                await v.close()

    return run(scenario(), timeout=90)


@pytest.mark.slow
def test_a_px4_that_takes_global_int_is_repositioned_in_it_with_one_command():
    """PX4 up to 1.16 (and the SITL build): GLOBAL_INT, what MAVSDK's goto_location sends, is taken."""
    results, frame, errors = fly_two_repositions(reposition_frames={MAV_FRAME_GLOBAL_INT})
    assert results == [MAV.MAV_RESULT_ACCEPTED, MAV.MAV_RESULT_ACCEPTED]  # one command per reposition
    assert frame == MAV_FRAME_GLOBAL_INT and max(errors) < 0.5


@pytest.mark.slow
def test_a_px4_that_refuses_global_int_is_repositioned_in_global_and_the_choice_is_kept():
    """GLOBAL_INT refused with UNSUPPORTED_MAV_FRAME (9), as ../shared/px4/README says stock PX4 main
    does: the first reposition is sent again in GLOBAL, the second goes in GLOBAL at once."""
    results, frame, errors = fly_two_repositions(reposition_frames={MAV_FRAME_GLOBAL})
    assert results == [9, MAV.MAV_RESULT_ACCEPTED, MAV.MAV_RESULT_ACCEPTED]
    assert frame == MAV_FRAME_GLOBAL and max(errors) < 0.5


@pytest.mark.slow
def test_a_reposition_refused_in_every_frame_names_the_result_and_the_frames_tried():
    port = free_udp_port()

    async def scenario():
        spec = dict(sysid=1, connect=f"udpout:127.0.0.1:{port}", autopilot="px4", reposition_frames={3})
        with mock_vehicles(spec) as (m,):
            v = await flying_px4(spec, port)
            try:
                with pytest.raises(CommandRejected) as err:
                    await v.goto(*offset_m(HOME[0], HOME[1], 0.0, 20.0), 10.0)
                return str(err.value), repositions(m), v.reposition_frame
            finally:
                await v.close()

    said, results, frame = run(scenario(), timeout=60)
    assert said == "vehicle 1: reposition was refused: UNSUPPORTED_MAV_FRAME (frame GLOBAL_INT, GLOBAL)"
    assert results == [9, 9] and frame is None


@pytest.mark.slow
def test_knowledge_frames_go_out_on_the_px4_link_from_mavsdk_ids_with_their_payload_whole():
    port = free_udp_port()
    codec = KnowledgeCodec(mission_id=7, width=12, height=12, system_id=1)
    delta = Delta(
        sender=3, step=5, cell=(2, 4), on_target=False, cells=[(2, 4), (3, 4)], phi=[200, 100], obstacle=[False, True]
    )
    frames = codec.frames(delta)

    async def scenario():
        seen = []
        with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{port}", autopilot="px4")) as (m,):
            m.tunnel_handler = lambda _m, msg: seen.append(msg)
            v = PX4Vehicle(f"udpin:127.0.0.1:{port}", sysid=1)
            before = v.write_frame(frames[0])  # not connected yet: no link to send on
            try:
                await v.connect(10)
                sent = [v.write_frame(f) for f in frames]
                deadline = time.monotonic() + 5
                while len(seen) < len(frames) and time.monotonic() < deadline:
                    await asyncio.sleep(0.05)
                return before, sent, seen, v.frames_sent
            finally:
                await v.close()

    before, sent, seen, count = run(scenario(), timeout=30)
    assert before is False and all(sent) and count == len(frames) == len(seen)
    for frame, msg in zip(frames, seen, strict=True):
        original = MAV.MAVLink(None).parse_char(frame)
        assert (msg.get_srcSystem(), msg.get_srcComponent()) == (245, 190)  # MAVSDK's ids, not the vehicle's
        assert bytes(msg.payload[: msg.payload_length]) == bytes(original.payload[: original.payload_length])
        assert codec.decode(msg.payload_type, msg.payload, msg.payload_length).sender == 3  # the payload names it


# --- readiness --------------------------------------------------------------------------------------------


def test_a_px4_that_never_sends_a_heartbeat_is_not_taken_and_the_error_says_what_was_heard():
    port = free_udp_port()

    async def scenario():
        spec = dict(sysid=4, connect=f"udpout:127.0.0.1:{port}", autopilot="px4")
        with mock_vehicles(spec) as (m,):
            m.drop_heartbeats(60.0)  # streams, but no HEARTBEAT: MAVSDK finds no autopilot
            v = PX4Vehicle(f"udpin:127.0.0.1:{port}", sysid=4, name="uav4")
            try:
                with pytest.raises(WaitTimeout) as err:
                    await v.connect(2.0)
                return str(err.value)
            finally:
                await v.close()

    said = run(scenario(), timeout=30)
    assert said.startswith("uav4: timed out after 2 s waiting for a PX4 autopilot (")
    assert said.endswith(f"system id 4 is heard on udpin:127.0.0.1:{port} but sends no HEARTBEAT)")


def test_nothing_on_a_port_a_px4_instance_above_9_would_use_names_the_port_it_really_uses():
    # PX4 SITL instance 12 (system id 13) sends its API link to 14549, not 14552
    hint = PX4.silent_port_hint(14552, 13)
    assert hint == (
        "a PX4 SITL instance above 9 (here 12: port 14540+12, system id 13) sends its API link to UDP 14549, "
        "not 14552; connect it with udpin:0.0.0.0:14549 (one such instance at a time) or start it as an "
        "instance 0-9"
    )
    assert PX4.silent_port_hint(14545, 6) == "" and PX4.silent_port_hint(None, 3) == ""
    assert "instance above 9 (here 10" in PX4.silent_port_hint(None, 11)  # a serial link: the system id says
    # the connector's heartbeat wait (a mission without an autopilot key) says the same
    timeout = WaitTimeout("a HEARTBEAT", "vehicle 13", 20.0)
    said = str(with_port_hints(timeout, parse_connection("udpin:0.0.0.0:14552"), 13))
    assert said == f"vehicle 13: timed out after 20 s waiting for a HEARTBEAT ({hint})"
    assert with_port_hints(timeout, parse_connection("udpin:0.0.0.0:14545"), 6) is timeout


def test_a_px4_that_never_gets_a_position_is_not_ready_and_the_error_names_what_is_missing():
    port = free_udp_port()

    async def scenario():
        spec = dict(sysid=1, connect=f"udpout:127.0.0.1:{port}", autopilot="px4", ready_after=1e6)
        reports = []
        with mock_vehicles(spec):
            v = PX4Vehicle(f"udpin:127.0.0.1:{port}", sysid=1, name="uav1")
            try:
                await v.connect(10)
                with pytest.raises(NotReady) as err:
                    await v.wait_ready(2.0, report=reports.append)
                return str(err.value), reports
            finally:
                await v.close()

    said, reports = run(scenario(), timeout=30)
    assert said.startswith("uav1: not ready to arm after 2 s: waiting for a position, home, ")
    assert "a global position estimate (health)" in said and "home position OK (health)" in said
    assert reports[0] == said.split(": ", 2)[2]


# --- the mock PX4 as PX4 SITL showed itself ------------------------------------------------------------------


async def mock_on_link(**mock_kw):
    link = await MavlinkLink("udpin:127.0.0.1:0").open()
    spec = dict(sysid=6, connect=f"udpout:127.0.0.1:{link.local_port}", autopilot="px4", **mock_kw)
    return link, mock_vehicles(spec)


async def take_off(link, mock, param7: float) -> None:
    """Once the mock is ready: arm, and MAV_CMD_NAV_TAKEOFF with this param7 (AMSL; NaN: MIS_TAKEOFF_ALT)."""
    await link.wait_until(lambda: mock.ready, 10, "ready", "px4")
    await link.command(6, MAV.MAV_CMD_COMPONENT_ARM_DISARM, (1,))
    await link.command(6, MAV.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, math.nan, math.nan, math.nan, param7))


def test_the_mock_px4_heartbeat_and_streams_are_those_of_px4_sitl():
    async def scenario():
        link, ctx = await mock_on_link(speedup=1.0, ready_after=5.3)
        counts: dict[str, int] = {}
        link.add_listener(lambda msg: counts.__setitem__(msg.get_type(), counts.get(msg.get_type(), 0) + 1))
        try:
            with ctx:
                first = await link.wait_message(lambda m: m.get_type() == "HEARTBEAT", 5)
                home = await link.wait_message(lambda m: m.get_type() == "HOME_POSITION", 5)
                standby = await link.wait_message(
                    lambda m: m.get_type() == "HEARTBEAT" and m.system_status == MAV.MAV_STATE_STANDBY, 8
                )
                counts.clear()
                await asyncio.sleep(2.0)
                return first, dict(counts), standby, home
        finally:
            await link.close()

    t0 = time.monotonic()
    first, window, standby, home = run(scenario(), timeout=30)
    assert time.monotonic() - t0 >= 4.0  # standby at 0.81 of the 5.3 s to ready, home before it (0.45)
    assert (first.type, first.autopilot, first.base_mode) == (2, 12, 29)  # quadrotor, PX4, custom|auto|guided|stab
    assert first.custom_mode == px4_encode(4, 3) == 0x03040000 and first.system_status == MAV.MAV_STATE_UNINIT
    assert standby.custom_mode == 0x03040000 and round(home.latitude / 1e7, 6) == HOME[0]
    # unasked, as the API link: GLOBAL_POSITION_INT ~50 Hz (a 50 Hz tick), SYS_STATUS and
    # EXTENDED_SYS_STATE 5 Hz, GPS_RAW_INT 8 Hz; 2 s of it
    assert window.get("SYS_STATUS", 0) >= 8 and window.get("EXTENDED_SYS_STATE", 0) >= 8
    assert window.get("GPS_RAW_INT", 0) >= 12 and window.get("GLOBAL_POSITION_INT", 0) >= 40


def test_the_mock_px4_takes_off_to_mis_takeoff_alt_and_takes_repositions_as_px4_sitl():
    async def scenario():
        link, ctx = await mock_on_link()
        try:
            with ctx as (m,):
                await take_off(link, m, math.nan)
                up = await asyncio.get_running_loop().run_in_executor(
                    None, m.wait_for, lambda mm: mm.mode_name == "HOLD", 10
                )
                height = m.rel_alt
                texts = link.peer(6).texts_since(0)
                results = {}
                lat, lon = offset_m(HOME[0], HOME[1], 0.0, 5.0)
                for frame, z in ((3, 2.5), (MAV_FRAME_GLOBAL_INT, HOME[2] + 2.5), (MAV_FRAME_GLOBAL, HOME[2] + 2.5)):
                    m.commands.clear()
                    link.send(
                        link.mav.command_int_encode(
                            6, 1, frame, REPOSITION, 0, 0, -1, 1, 0, math.nan, round(lat * 1e7), round(lon * 1e7), z
                        )
                    )
                    await link.wait_until(lambda: bool(repositions(m)), 5, "the ack", "px4")
                    results[frame] = repositions(m)[0]
                return up, height, texts, results
        finally:
            await link.close()

    up, height, texts, results = run(scenario(), timeout=40)
    assert up and abs(height - 2.5) < 0.05  # MIS_TAKEOFF_ALT's 2.5 m default, then AUTO.LOITER
    assert "Takeoff detected" in texts and "Using default takeoff altitude: 2.5 m" in texts
    assert results == {3: 9, MAV_FRAME_GLOBAL_INT: 0, MAV_FRAME_GLOBAL: 0}  # GLOBAL_RELATIVE_ALT: 9 on SITL too


@pytest.mark.parametrize(
    ("nav_dll_act", "after"),
    [(0.0, ["HOLD"]), (2.0, ["HOLD", "RTL"])],
    ids=["NAV_DLL_ACT 0 (default): nothing", "NAV_DLL_ACT 2: hold, then return"],
)
def test_the_mock_px4_on_a_lost_ground_station_link_follows_nav_dll_act(nav_dll_act, after):
    """PX4 SITL: NAV_DLL_ACT 0 does nothing; 2 reports CRITICAL after COM_DL_LOSS_T, holds COM_FAIL_ACT_T,
    then returns (timeouts shortened here); the mode stays when the link is back."""

    async def scenario():
        link, ctx = await mock_on_link(gcs_failsafe_timeout=1.0)  # on: NAV_DLL_ACT decides, not this
        try:
            with ctx as (m,):
                m.params.update(NAV_DLL_ACT=nav_dll_act, COM_DL_LOSS_T=1.0, COM_FAIL_ACT_T=1.0)
                await take_off(link, m, HOME[2] + 30)
                await link.wait_until(lambda: m.rel_alt > 10, 10, "climbing", "px4")
                await link.wait_until(lambda: m.last_gcs_heartbeat is not None, 5, "the link's heartbeat", "px4")
                link._tasks[0].cancel()  # the controller's heartbeats stop (_heartbeat_loop); the link stays open
                modes, critical = [], False
                for _ in range(30):  # 3 s
                    await asyncio.sleep(0.1)
                    critical |= link.peer(6).heartbeat.system_status == MAV.MAV_STATE_CRITICAL
                    if m.armed and (not modes or modes[-1] != m.mode_name):  # landed: HOLD again
                        modes.append(m.mode_name)
                return modes, critical, m.state().gcs_failsafe
        finally:
            await link.close()

    modes, critical, failsafe = run(scenario(), timeout=40)
    took_off = modes[0] in ("TAKEOFF", "HOLD")
    assert took_off and [mode for mode in modes if mode != "TAKEOFF"] == after
    assert critical is (nav_dll_act == 2.0) and failsafe is (nav_dll_act == 2.0)


def test_the_mock_px4_returns_at_rtl_return_alt_and_holds_once_disarmed_as_px4_sitl():
    """PX4 SITL, 15 m out at 6 m: climbed to RTL_RETURN_ALT (30 m), flew home, landed, "Disarmed by
    landing", then AUTO.LOITER (HOLD) disarmed."""

    async def scenario():
        link, ctx = await mock_on_link()
        try:
            with ctx as (m,):
                await take_off(link, m, HOME[2] + 6)
                await link.wait_until(lambda: m.mode_name == "HOLD" and m.rel_alt > 5.9, 10, "the take-off", "px4")
                lat, lon = offset_m(HOME[0], HOME[1], 0.0, 15.0)
                await link.command(6, REPOSITION, (-1, 1, 0, math.nan, lat, lon, HOME[2] + 6))  # COMMAND_LONG: degrees
                await link.wait_until(lambda: distance_m(m.lat, m.lon, lat, lon) < 1, 10, "the reposition", "px4")
                await link.command(6, MAV.MAV_CMD_NAV_RETURN_TO_LAUNCH, ())
                top, modes, armed = 0.0, [], True
                while armed or len(modes) < 2:
                    with m._lock:  # the landing disarms and switches mode in one physics step
                        armed, mode, top = m.armed, m.mode_name, max(top, m.rel_alt)
                    if not modes or modes[-1] != mode:
                        modes.append(mode)
                    if not armed:
                        break
                    await asyncio.sleep(0.02)
                # the mock's state is read directly; its STATUSTEXT comes over the link, a little later
                landed = lambda: "Disarmed by landing" in link.peer(6).texts_since(0)  # noqa: E731
                await link.wait_until(landed, 2, '"Disarmed by landing"', "px4")
                texts = link.peer(6).texts_since(0)
                return top, modes, distance_m(m.lat, m.lon, HOME[0], HOME[1]), texts
        finally:
            await link.close()

    top, modes, off_home, texts = run(scenario(), timeout=60)
    assert top == pytest.approx(30.0, abs=0.1) and off_home < 0.1
    assert modes == ["RTL", "HOLD"] and "Disarmed by landing" in texts


@pytest.mark.parametrize(
    ("rel_alt", "landed_state", "armed", "landed"),
    [
        (1.25, "ON_GROUND", False, True),  # PX4 SITL's estimate 1.25 m up, landed and disarmed on the ground
        (1.25, "IN_AIR", False, False),
        (1.25, "UNKNOWN", False, False),
        (0.4, "UNKNOWN", False, True),  # no land detector heard: under 1 m, disarmed
        (0.4, "ON_GROUND", True, False),  # still armed
    ],
)
def test_a_disarmed_px4_is_landed_under_1_m_or_where_its_land_detector_says_ground(
    rel_alt, landed_state, armed, landed
):
    v = PX4Vehicle("udpin:127.0.0.1:0", sysid=1, name="uav1")
    v._armed, v._landed_state = armed, landed_state
    v._position = Position(HOME[0], HOME[1], rel_alt, HOME[2] + rel_alt)
    assert v._landed() is landed and v.on_ground is (landed_state == "ON_GROUND")
