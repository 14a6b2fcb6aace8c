"""PX4 through MAVSDK beyond the happy path, and the TCP transport."""

from __future__ import annotations

import asyncio
import select
import socket
import threading
import time

import pytest

from swarmctl.mavlink.autopilots.ardupilot import ArduPilotVehicle
from swarmctl.mavlink.autopilots.px4 import PX4Vehicle
from swarmctl.mavlink.codec import distance_m, offset_m
from swarmctl.mavlink.network import MAV, MavlinkLink
from tests.mavlink_support import HOME, mock_vehicles, our_threads, run


@pytest.fixture(autouse=True)
def no_leftover_threads():
    yield
    assert our_threads() == []


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_px4_arming_retried_then_rtl_and_link_loss_seen_through_mavsdk():
    port = free_udp_port()

    async def scenario():
        v = PX4Vehicle(f"udpin:127.0.0.1:{port}", arm_retry_period=0.2)
        try:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{port}", autopilot="px4")) as (m,):
                await v.connect(10)
                await v.wait_ready(10)
                m.refuse_arming("Preflight Fail: ekf2 missing data")
                arming = asyncio.create_task(v.arm(timeout=10))
                await asyncio.sleep(1.0)
                m.refuse_arming(None)
                await arming
                results = [r for c, r in m.commands if c == MAV.MAV_CMD_COMPONENT_ARM_DISARM]
                await v.arm_and_takeoff(15.0, timeout=20)
                await v.goto(*offset_m(HOME[0], HOME[1], 0.0, 30.0), 15.0)
                await v.wait_reached(0.05, 15)
                await v.rtl()
                await v.wait_landed(30)
                home_dist = distance_m(m.lat, m.lon, HOME[0], HOME[1])
                m.drop_heartbeats(4.0)
                t0 = time.monotonic()
                await v._poll(lambda: v.lost, 8, "loss")
                lost_after = time.monotonic() - t0
                await v._poll(lambda: not v.lost, 8, "recovery")
                return results, home_dist, lost_after, v.mode
        finally:
            await v.close()

    results, home_dist, lost_after, mode = run(scenario(), timeout=90)
    assert results[0] == MAV.MAV_RESULT_TEMPORARILY_REJECTED and results[-1] == MAV.MAV_RESULT_ACCEPTED
    assert home_dist < 0.05 and mode == "HOLD"  # PX4 SITL: AUTO.LOITER once disarmed after the return
    assert lost_after < 6.0


class TcpToUdpBridge:
    """A TCP server that relays one client's bytes to a UDP peer and back (like a serial bridge)."""

    def __init__(self) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.tcp_port = self.server.getsockname()[1]
        self.udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.udp.bind(("127.0.0.1", 0))
        self.udp_port = self.udp.getsockname()[1]
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="mock-autopilot-tcp-bridge")

    def _run(self) -> None:
        conn, peer = None, None
        while not self.stop.is_set():
            socks = [self.server, self.udp] + ([conn] if conn else [])
            ready, _, _ = select.select(socks, [], [], 0.05)
            for s in ready:
                if s is self.server:
                    conn, _ = self.server.accept()
                elif s is self.udp:
                    data, peer = self.udp.recvfrom(65535)
                    if conn:
                        conn = self._relay(conn, data)
                elif s is conn:
                    try:
                        data = conn.recv(65535)
                    except OSError:
                        data = b""
                    if not data:  # the client went away: wait for the next one
                        conn.close()
                        conn = None
                    elif peer:
                        self.udp.sendto(data, peer)
        if conn:
            conn.close()

    @staticmethod
    def _relay(conn: socket.socket, data: bytes) -> socket.socket | None:
        try:
            conn.sendall(data)
            return conn
        except OSError:  # reset by the client closing its end
            conn.close()
            return None

    def __enter__(self) -> TcpToUdpBridge:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(5)
        self.server.close()
        self.udp.close()


def test_tcp_link_flies_a_vehicle():
    with TcpToUdpBridge() as bridge:

        async def scenario():
            with mock_vehicles(dict(sysid=8, connect=f"udpout:127.0.0.1:{bridge.udp_port}")) as (m,):
                async with MavlinkLink(f"tcp:127.0.0.1:{bridge.tcp_port}") as link:
                    v = ArduPilotVehicle(link, 8)
                    await v.connect(5)
                    await v.arm_and_takeoff(5.0, timeout=20)
                    await v.land()
                    await v.wait_landed(20)
                    await v.close()
                    return m.state(), link.stats.bad_data

        state, bad = run(scenario())
        assert not state.armed and state.mode == "LAND" and bad == 0
