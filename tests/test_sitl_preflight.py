"""The ArduPilot driver's preflight against real ArduCopter SITL (x5): on SERIAL0 its boot text is console
text, every telemetry message is asked for once, the vehicle gets ready in GUIDED saying why it waits,
and its speed parameters are read. About 10 s; skipped without the binary (tests/sitl_support.py)."""

from __future__ import annotations

import asyncio

import pytest

from swarmctl.mavlink.autopilots.ardupilot import TELEMETRY, ArduPilotVehicle
from swarmctl.mavlink.network import MavlinkLink
from tests.sitl_support import arducopter_sitl

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
