"""The ArduPilot driver's preflight against real ArduCopter SITL (x5): on SERIAL0 its boot text is console
text, every telemetry message is asked for once, the vehicle gets ready in GUIDED saying why it waits,
and its speed parameters are read. About 10 s; skipped without the binary (tests/sitl_support.py)."""

from __future__ import annotations

import asyncio

import pytest

from swarmctl.mavlink.autopilots.ardupilot import TELEMETRY, ArduPilotVehicle
from swarmctl.mavlink.network import MAV, MavlinkLink
from tests.sitl_support import arducopter_sitl, mavlink_client, wait_message

pytestmark = pytest.mark.sitl


def test_preflight_against_arducopter_sitl():
    said: list[str] = []

    async def scenario(connection: str, sysid: int):
        async with MavlinkLink(connection) as link:
            v = ArduPilotVehicle(link, sysid, name="copter")
            await v.connect(20)
            await v.wait_ready(60, report=said.append)
            mode, requests = v.mode, dict(v.requests)
            limits = await v.read_limits()
            await v.close()
            return mode, requests, limits, link.stats, link.console

    with arducopter_sitl(1, speedup=5) as [copter]:
        mode, requests, limits, stats, console = asyncio.run(
            asyncio.wait_for(scenario(copter.connection, copter.sysid), 90)
        )
    assert mode == "GUIDED" and requests == {s.name: 1 for s in TELEMETRY}
    assert stats.bad_data == 0 and stats.console_bytes >= 150 and console.startswith(b"\n\nInit ArduCopter V4.7")
    assert "PreArm: Need Position Estimate" in said and "EKF3 IMU0 is using GPS" in said
    assert len(limits.read) == 10 and (limits.speed, limits.climb, limits.land_speed) == (10.0, 2.5, 0.5)


def test_arducopter_sitl_undoes_a_mode_accepted_during_its_boot():
    """What the mock's boot_resets_mode models and why wait_ready asks for GUIDED only after BOOT: SITL
    (x1; it runs only once a client is on SERIAL0, so its first heartbeats say BOOT) accepts GUIDED
    then and reports it, and its first STANDBY heartbeat is in STABILIZE again."""
    with arducopter_sitl(1) as [copter], mavlink_client(copter.connection) as conn:
        first = wait_message(conn, "HEARTBEAT", 20, sysid=copter.sysid)
        assert first.system_status == MAV.MAV_STATE_BOOT, "SITL had booted before the test could ask"
        conn.mav.command_long_send(copter.sysid, 1, MAV.MAV_CMD_DO_SET_MODE, 0, 1, 4, 0, 0, 0, 0, 0)
        ack = wait_message(conn, "COMMAND_ACK", 5, condition=lambda m: m.command == MAV.MAV_CMD_DO_SET_MODE)
        guided = wait_message(conn, "HEARTBEAT", 5, sysid=copter.sysid, condition=lambda m: m.custom_mode == 4)
        standby = wait_message(
            conn, "HEARTBEAT", 20, sysid=copter.sysid, condition=lambda m: m.system_status == MAV.MAV_STATE_STANDBY
        )
    assert ack.result == MAV.MAV_RESULT_ACCEPTED and guided.system_status == MAV.MAV_STATE_BOOT
    assert standby.custom_mode == 0  # STABILIZE, ArduCopter's INITIAL_MODE
