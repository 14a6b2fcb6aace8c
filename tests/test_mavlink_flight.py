"""Fly mock vehicles over loopback UDP: 3 ArduCopters (pymavlink link) and 1 PX4 (MAVSDK) at once."""

from __future__ import annotations

import asyncio
import time

import pytest

from swarmctl.mavlink.autopilots.ardupilot import ArduPilotVehicle
from swarmctl.mavlink.autopilots.px4 import PX4Vehicle
from swarmctl.mavlink.codec import distance_m, offset_m
from swarmctl.mavlink.network import MavlinkLink
from swarmctl.mavlink.vehicle import Vehicle
from tests.mavlink_support import HOME, mock_vehicles, our_threads, run

LEGS = [(60.0, 0.0), (60.0, 60.0), (0.0, 60.0)]  # north/east metres from home, at 40 m


async def fly_pattern(
    v: Vehicle, home: tuple[float, float, float], offset: float, legs: list[tuple[float, float]] = LEGS
) -> list[float]:
    """Take off to 40 m, visit legs (shifted east by `offset`), land; return the miss at each leg."""
    await v.arm_and_takeoff(40.0, timeout=30)
    misses = []
    for north, east in legs:
        lat, lon = offset_m(home[0], home[1], north, east + offset)
        await v.goto(lat, lon, 40.0)
        await v.wait_reached(tolerance=0.05, timeout=20)
        pos = v.position
        assert pos is not None
        misses.append(max(distance_m(pos.lat, pos.lon, lat, lon), abs(pos.rel_alt - 40.0)))
    await v.land()
    await v.wait_landed(timeout=30)
    return misses


def free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_three_ardupilot_and_one_px4_fly_together():
    px4_port = free_udp_port()

    async def scenario():
        links = [await MavlinkLink("udpin:127.0.0.1:0").open() for _ in range(3)]
        px4 = PX4Vehicle(f"udpin:127.0.0.1:{px4_port}", sysid=4, name="px4 4")
        vehicles: list[Vehicle] = []
        try:
            specs = [dict(sysid=i + 1, connect=f"udpout:127.0.0.1:{links[i].local_port}") for i in range(3)]
            specs.append(dict(sysid=4, connect=f"udpout:127.0.0.1:{px4_port}", autopilot="px4"))
            with mock_vehicles(*specs) as mocks:
                vehicles = [ArduPilotVehicle(links[i], i + 1) for i in range(3)]
                await asyncio.gather(*(v.connect(10) for v in vehicles), px4.connect(10))
                vehicles.append(px4)
                start = time.monotonic()
                results = await asyncio.gather(*(fly_pattern(v, HOME, 10.0 * i) for i, v in enumerate(vehicles)))
                took = time.monotonic() - start
                batteries = [v.battery_remaining for v in vehicles]
                assert all(b is not None and 50 < b < 100 for b in batteries), batteries
                for mock in mocks:
                    s = mock.state()
                    assert not s.armed and s.rel_alt == 0.0 and s.battery < 100.0
                return results, took, [m.mode_name for m in mocks]
        finally:
            for v in vehicles[:3]:
                await v.close()
            await px4.close()
            for link in links:
                await link.close()

    results, took, modes = run(scenario(), timeout=90)
    for misses in results:
        assert len(misses) == len(LEGS) and max(misses) < 0.05  # reached within centimetres
    assert modes == ["LAND", "LAND", "LAND", "HOLD"]  # PX4 SITL: AUTO.LOITER once disarmed by landing
    # flown concurrently: four vehicles take about as long as one (one flight is ~4 s here)
    assert took < 20
    assert our_threads() == []


def test_position_targets_use_frame_6_and_type_mask_3576():
    seen = []

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=9, connect=f"udpout:127.0.0.1:{link.local_port}")) as (m,):
                orig = m._position_target
                m._position_target = lambda msg: (seen.append(msg), orig(msg))
                v = ArduPilotVehicle(link, 9)
                await v.connect(5)
                await v.arm_and_takeoff(10.0, timeout=20)
                lat, lon = offset_m(HOME[0], HOME[1], 20.0, -15.0)
                await v.goto(lat, lon, 12.0)
                await v.wait_reached(0.05, 10)
                await v.rtl()
                await v.wait_landed(30)
                s = m.state()
                await v.close()
                return s

    s = run(scenario())
    assert distance_m(s.lat, s.lon, HOME[0], HOME[1]) < 0.05 and not s.armed  # RTL came home
    msg = seen[0]
    assert (msg.coordinate_frame, msg.type_mask, msg.target_system) == (6, 3576, 9)
    lat, lon = offset_m(HOME[0], HOME[1], 20.0, -15.0)
    assert (msg.lat_int, msg.lon_int) == (round(lat * 1e7), round(lon * 1e7))


@pytest.mark.slow
def test_flight_survives_packet_loss_and_latency():
    loss = 0.15

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            spec = dict(sysid=5, connect=f"udpout:127.0.0.1:{link.local_port}", seed=1)
            with mock_vehicles(spec) as (m,):
                m.packet_loss, m.latency = loss, 0.05
                v = ArduPilotVehicle(link, 5, command_timeout=0.5, retries=8)
                await v.connect(10)
                misses = await fly_pattern(v, HOME, 0.0, LEGS[:1])
                await v.close()
                return misses, link.stats

    misses, stats = run(scenario(), timeout=90)
    assert max(misses) < 0.05
    assert stats.received > 0


@pytest.mark.slow
def test_mock_vehicle_command_runs_a_vehicle_in_its_own_process():
    """The CLI entry point: `swarmctl mock-vehicle` flown through the link, then stopped."""
    import subprocess
    import sys

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            proc = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "swarmctl.cli",
                    "mock-vehicle",
                    "--sysid",
                    "12",
                    "--connect",
                    f"udpout:127.0.0.1:{link.local_port}",
                    "--home",
                    ",".join(map(str, HOME)),
                    "--speedup",
                    "20",
                    "--ready-after",
                    "2",
                    "--duration",
                    "60",
                ],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
            )
            try:
                v = ArduPilotVehicle(link, 12)
                await v.connect(15)
                await v.arm_and_takeoff(10.0, timeout=20)
                await v.land()
                await v.wait_landed(20)
                await v.close()
            finally:
                proc.terminate()
                try:
                    proc.wait(5)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(5)
            with proc.stderr:
                return proc.stderr.read().decode()

    err = run(scenario())
    assert "mock ardupilot vehicle 12" in err
