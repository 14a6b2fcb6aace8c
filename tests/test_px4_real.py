"""The PX4 driver against real PX4 SITL (../shared/px4, SIH physics; skipped without it): readiness,
the reposition in both frames the SITL build takes, a refused frame answered without harm, knowledge
frames on the vehicle's link, the speed parameters read, a landing; steering in OFFBOARD (targets sent
without an answer, the end actions from it, what the vehicle does when the setpoint stream stops, a
pilot's mode left alone).

The harness (tests/px4_support.py) starts a free instance of the tests' PX4 numbers (-i 5-9, system id N+1) and
always stops it.
"""

from __future__ import annotations

import asyncio
import math
import time

import pytest

from swarmctl.knowledge.codec import KnowledgeCodec
from swarmctl.knowledge.model import Delta
from swarmctl.mavlink.autopilots.descriptions import MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_INT, PX4
from swarmctl.mavlink.autopilots.px4 import PX4Vehicle
from swarmctl.mavlink.codec import distance_m, offset_m
from swarmctl.mavlink.errors import MavlinkError
from swarmctl.mavlink.network import MAV
from tests.mavlink_support import run
from tests.px4_support import px4_sitl

pytestmark = pytest.mark.sitl

HEIGHT = 6.0  # metres: low, so that the take-off and the landing stay short


async def fly(sitl) -> dict:
    """Connect, wait ready, take off, reposition in GLOBAL_INT then GLOBAL, send a refused frame and
    knowledge frames, land; what was seen on the way."""
    seen: dict = {}
    t0 = time.monotonic()
    # the reposition (what the driver falls back to where OFFBOARD is not used): OFFBOARD off
    v = PX4Vehicle(sitl.connection, sysid=sitl.sysid, name=f"px4 -i {sitl.instance}", offboard=False)
    try:
        await v.connect(20)
        seen["connected_s"] = time.monotonic() - t0
        await v.wait_ready(30)
        seen["ready_s"] = time.monotonic() - t0
        seen["limits"] = {name: await v.read_parameter(name) for name in PX4.limit_parameters}
        seen["takeoff_alt_default"] = await v.action.get_takeoff_altitude()
        await v.arm_and_takeoff(HEIGHT, timeout=60)
        home = v.home
        frames = []
        for east, frame in ((12.0, None), (0.0, MAV_FRAME_GLOBAL)):
            if frame is not None:
                v.reposition_frame = frame  # as if a PX4 refusing GLOBAL_INT had taught it
            lat, lon = offset_m(home.lat, home.lon, 0.0, east)
            await v.goto(lat, lon, HEIGHT)
            await v.wait_reached(1.0, 40)
            frames.append(v.reposition_frame)
            seen.setdefault("errors_m", []).append(distance_m(v.position.lat, v.position.lon, lat, lon))
        seen["frames"] = frames
        relative = dict(frame=MAV.MAV_FRAME_GLOBAL_RELATIVE_ALT, command=MAV.MAV_CMD_DO_REPOSITION, current=0)
        relative.update(autocontinue=0, param1=-1.0, param2=1.0, param3=0.0, param4=math.nan)
        relative.update(x=round(home.lat * 1e7), y=round(home.lon * 1e7), z=HEIGHT)
        seen["relative_result"] = await v.command_int("reposition", relative)
        codec = KnowledgeCodec(mission_id=7, width=12, height=12, system_id=v.sysid)
        knowledge = codec.frames(Delta(0, 1, (0, 0), False, cells=[(0, 0)], phi=[255], obstacle=[0]))
        seen["written"] = [v.write_frame(f) for f in knowledge]
        await v._poll(lambda: v.frames_sent == len(knowledge), 5, "the knowledge frames")
        seen["on_ground_flying"] = v.on_ground
        await v.land()
        await v.wait_landed(60)
        await v._poll(lambda: v.on_ground, 10, "the land detector")
        seen["on_ground_landed"] = v.on_ground
        seen["landed_s"] = time.monotonic() - t0
    finally:
        await v.close()
    return seen


def test_px4_sitl_is_ready_repositions_in_both_frames_and_answers_a_refused_frame():
    with px4_sitl(1) as (sitl,):
        seen = run(fly(sitl), timeout=240)
    assert seen["connected_s"] < 10 and seen["ready_s"] < 20  # measured 0.9-1.4 s and 4.9-5.4 s
    assert seen["takeoff_alt_default"] == pytest.approx(2.5)  # MIS_TAKEOFF_ALT's default
    assert seen["frames"] == [MAV_FRAME_GLOBAL_INT, MAV_FRAME_GLOBAL] and max(seen["errors_m"]) < 1.0
    assert seen["relative_result"] == 9  # UNSUPPORTED_MAV_FRAME, and the process lives on
    assert all(seen["written"])
    assert (seen["on_ground_flying"], seen["on_ground_landed"]) == (False, True)  # EXTENDED_SYS_STATE, API link
    assert seen["limits"]["MPC_XY_CRUISE"] == pytest.approx(5.0) and seen["limits"]["RTL_RETURN_ALT"] == 30.0


def test_px4_sitl_parameters_a_user_sets_exist_with_the_documented_defaults():
    """docs/mavlink.md's PX4 parameter table, read from the SITL build through MAVSDK's param plugin."""
    documented = {
        "MAV_SYS_ID": None,  # the instance number + 1
        "NAV_DLL_ACT": 0.0,
        "COM_DL_LOSS_T": 10.0,
        "COM_FAIL_ACT_T": 5.0,
        "MIS_TAKEOFF_ALT": 2.5,
        "GF_ACTION": 2.0,
        "GF_MAX_HOR_DIST": 0.0,
        "GF_MAX_VER_DIST": 0.0,
        "GF_SOURCE": 0.0,
        "GF_PREDICT": 0.0,
        "MPC_XY_CRUISE": 5.0,
        "RTL_RETURN_ALT": 30.0,
        "COM_OF_LOSS_T": 1.0,
    }

    async def read(sitl) -> dict[str, float]:
        v = PX4Vehicle(sitl.connection, sysid=sitl.sysid)
        try:
            await v.connect(20)
            values = {name: await v.read_parameter(name) for name in documented}
            with pytest.raises(MavlinkError):  # no signing parameter in this build (docs/mavlink.md)
                await v.read_parameter("MAV_SIGN_CFG")
            return values
        finally:
            await v.close()

    with px4_sitl(1) as (sitl,):
        values = asyncio.run(asyncio.wait_for(read(sitl), 60))
        sysid = sitl.sysid
    assert values.pop("MAV_SYS_ID") == sysid
    assert values == {k: v for k, v in documented.items() if k != "MAV_SYS_ID"}


async def steer_in_offboard(sitl) -> dict:
    """Take off, fly two targets in OFFBOARD (the second without an answer), return from OFFBOARD and take
    the vehicle back, stop the setpoint stream with the controller alive, hand it to a pilot (MAVSDK's
    manual control, POSCTL), land; what was seen on the way."""
    from mavsdk.asyncio.plugins.manual_control import ManualControlAsync
    from mavsdk.asyncio.plugins.offboard import OffboardAsync

    seen: dict = {}
    v = PX4Vehicle(sitl.connection, sysid=sitl.sysid, name=f"px4 -i {sitl.instance}")
    sticks: asyncio.Task | None = None

    async def mode(name: str, timeout: float = 5.0) -> float:
        t = time.monotonic()
        await v._poll(lambda: v.mode == name, timeout, f"mode {name}")
        return round(time.monotonic() - t, 2)

    async def fly_to(north: float, east: float) -> tuple[bool, float]:
        lat, lon = offset_m(home.lat, home.lon, north, east)
        t = time.monotonic()
        nowait = v.goto_nowait(lat, lon, HEIGHT)
        if not nowait:
            await v.goto(lat, lon, HEIGHT)
        await v.wait_reached(0.5, 20)
        return nowait, round(time.monotonic() - t, 2)

    try:
        await v.connect(20)
        await v.wait_ready(30)
        await v.arm_and_takeoff(HEIGHT, timeout=60)
        await v._poll(lambda: v.offboard_loss is not None, 10, "COM_OBL_RC_ACT read")
        seen["offboard_loss"] = v.offboard_loss
        home = v.home
        seen["first"] = await fly_to(0.0, 8.0)  # enters OFFBOARD: goto, an acknowledged mode change
        seen["steering"], seen["mode"] = v.steering, v.mode
        seen["second"] = await fly_to(0.0, 0.0)  # in OFFBOARD: goto_nowait
        await v.rtl()  # the end action from OFFBOARD
        seen["rtl_s"] = await mode("RTL")
        await v.resume()  # taken back from a return, as a rejoin does
        await mode("HOLD")
        seen["third"] = await fly_to(6.0, 0.0)
        seen["back_in"] = v.mode
        # the stream stops while the controller lives: the vehicle leaves OFFBOARD by itself
        assert v._offboard is not None
        v._offboard.destroy()
        v._offboard = None
        seen["stream_lost_s"] = await mode("RTL", 10)
        v._offboard = OffboardAsync(v._system)
        await v.resume()
        await mode("HOLD")
        seen["fourth"] = await fly_to(0.0, 0.0)
        # a pilot: MAVSDK's manual control (sticks centred, 20 Hz), then POSCTL
        pilot = ManualControlAsync(v._system)

        async def centred() -> None:
            while True:
                await pilot.set_manual_control_input(0.0, 0.0, 0.5, 0.0)
                await asyncio.sleep(0.05)

        sticks = asyncio.create_task(centred())
        await asyncio.sleep(0.5)
        await pilot.start_position_control()
        await mode("POSCTL")
        lat, lon = offset_m(home.lat, home.lon, 0.0, 8.0)
        seen["nowait_in_posctl"] = v.goto_nowait(lat, lon, HEIGHT)
        await v.goto(lat, lon, HEIGHT)  # kept, not sent
        await asyncio.sleep(2.5)  # in OFFBOARD the vehicle would have flown 6-7 m east by now
        seen["after_pilot"] = (v.mode, round(distance_m(v.position.lat, v.position.lon, home.lat, home.lon), 1))
        await v.land()  # from POSCTL, the pilot still there
        await v.wait_landed(60)
    finally:
        if sticks is not None:
            sticks.cancel()
        await v.close()
    return seen


def test_px4_sitl_steers_in_offboard_and_is_safe_when_the_stream_stops_or_a_pilot_takes_it():
    with px4_sitl(1) as (sitl,):
        seen = run(steer_in_offboard(sitl), timeout=150)
    # COM_OBL_RC_ACT 0 (PX4's default): position mode, and without manual control the RC-loss action
    assert seen["offboard_loss"].startswith("position mode"), seen
    assert (seen["steering"], seen["mode"], seen["back_in"]) == ("offboard", "OFFBOARD", "OFFBOARD"), seen
    assert seen["first"][0] is False and seen["second"][0] is True, seen  # the second went out at once
    assert max(seen[k][1] for k in ("first", "second", "third", "fourth")) < 8.0, seen  # 8 m: 2.6-3.8 s measured
    assert seen["rtl_s"] < 3.0, seen
    # the stream stopped for COM_OF_LOSS_T (1 s): NAV_RCL_ACT's return (measured 1.7-1.9 s)
    assert seen["stream_lost_s"] < 5.0, seen
    assert seen["nowait_in_posctl"] is False and seen["after_pilot"][0] == "POSCTL", seen
    assert seen["after_pilot"][1] < 3.0, seen  # held where the pilot has it (1.4 m: SIH's noise), not sent 8 m east
