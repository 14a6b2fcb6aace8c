"""What the controller's MAVLink side does about links that lose frames (docs/mavlink.md, "What the
link does on the wire"): a lost position target sent again as soon as the vehicle's reports of its
target show the old one (once a second when it reports none), a confirmed one not repeated, the
controller's heartbeat twice a second; and a short search with every link through a lossy relay."""

from __future__ import annotations

import asyncio
import time

import pytest

import swarmctl.mavlink.autopilots.ardupilot as ardupilot
from swarmctl.mavlink.autopilots.ardupilot import TARGET_REPORTS, ArduPilotVehicle
from swarmctl.mavlink.codec import offset_m
from swarmctl.mavlink.network import MavlinkLink
from swarmctl.sim.relay import LinkFaults
from swarmctl.sim.swarm import SimSwarm
from tests.mavlink_support import HOME, mock_vehicles, our_threads, run
from tests.mission_support import fly, small_grid

TARGET = "SET_POSITION_TARGET_GLOBAL_INT"


@pytest.fixture(autouse=True)
def no_leftover_threads():
    yield
    assert our_threads() == []


def targets_received(mock) -> int:
    return sum(1 for mtype, _src, _cmd in mock.received if mtype == TARGET)


async def flying(link: MavlinkLink, mock) -> ArduPilotVehicle:
    v = ArduPilotVehicle(link, 1)
    await v.connect(5)
    await v.arm_and_takeoff(20, timeout=20)
    return v


def test_a_lost_position_target_is_sent_again_when_the_reports_show_the_old_one():
    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}", speed=2.0)) as (m,):
                v = await flying(link, m)
                # the first target asks for the reports of the vehicle's target; wait until they come
                await v.goto(*offset_m(HOME[0], HOME[1], 5, 0), 20)
                await link.wait_until(lambda: TARGET_REPORTS.name in link.peers[1].messages, 5, "reports", "v1")
                await v.wait_reached(0.5, 10)
                m.drop_received(TARGET, 1)  # the next target is lost on the way
                before = targets_received(m)
                sent = time.monotonic()
                await v.goto(*offset_m(HOME[0], HOME[1], 10, 0), 20)
                await v.wait_reached(0.5, 10)  # resends as the mission's round waiter does (keep_going)
                took = time.monotonic() - sent
                assert targets_received(m) - before == 1  # the one sent again
                resent = dict(v.resent)
                await v.close()
                return took, resent

    took, resent = run(scenario())
    # two reports of the old target at 5 Hz and the 5 m flown at 40 m/s, not the second the resend
    # waited before
    assert took < 0.8 and resent == {"stale": 1}


def test_a_confirmed_target_is_not_repeated_while_the_vehicle_flies_to_it():
    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}", speed=1.0)) as (m,):
                v = await flying(link, m)
                await v.goto(*offset_m(HOME[0], HOME[1], 3, 0), 20)
                await link.wait_until(lambda: TARGET_REPORTS.name in link.peers[1].messages, 5, "reports", "v1")
                await v.wait_reached(0.5, 10)
                before = targets_received(m)
                started = time.monotonic()
                await v.goto(*offset_m(HOME[0], HOME[1], 63, 0), 20)  # 60 m at 20 m/s: 3 s
                await v.wait_reached(0.5, 10)
                took = time.monotonic() - started
                resent = dict(v.resent)
                await v.close()
                return targets_received(m) - before, took, resent

    received, took, resent = run(scenario())
    assert took > 2.0  # long enough for two resends once a second, as before the reports
    assert received == 1 and resent == {}


def test_without_reports_of_its_target_a_target_is_sent_again_once_a_second_and_the_reports_given_up(monkeypatch):
    monkeypatch.setattr(ardupilot, "STREAM_PATIENCE_S", 0.3)
    monkeypatch.setattr(ardupilot, "KEEP_TELEMETRY_S", 0.1)

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")) as (m,):
                m.drop_sent(TARGET_REPORTS.name, None)  # a firmware that takes the request, sends nothing
                v = await flying(link, m)
                await v.goto(*offset_m(HOME[0], HOME[1], 5, 0), 20)
                m.drop_received(TARGET, None)  # and that never gets the target
                await link.wait_until(lambda: TARGET_REPORTS.name in v.unsupported, 5, "giving up", "v1")
                asks = v.requests[TARGET_REPORTS.name]
                start = time.monotonic()
                while time.monotonic() - start < 2.3:
                    await v.keep_going()
                    await asyncio.sleep(0.05)
                resent = dict(v.resent)
                await v.close()
                return asks, resent

    asks, resent = run(scenario())
    assert asks == ardupilot.TARGET_REPORT_ASKS
    assert resent.get("stale", 0) == 0 and 2 <= resent["silent"] <= 3


def test_a_vehicle_whose_answers_are_all_lost_is_flown_by_what_it_reports():
    """Every COMMAND_ACK lost: the telemetry requests, GUIDED, the arm and the take-off are judged by
    what the vehicle then reports (the streams, its mode, its armed flag, its climb)."""

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")) as (m,):
                m.drop_sent("COMMAND_ACK", None)
                v = ArduPilotVehicle(link, 1, command_timeout=0.2, retries=1)
                await v.connect(5)  # before: CommandTimeout on the first telemetry request
                await v.arm_and_takeoff(20, timeout=30)
                await v.goto(*offset_m(HOME[0], HOME[1], 5, 0), 20)
                await v.wait_reached(0.5, 10)
                result = v.mode, v.armed, m.state().rel_alt, dict(v.requests)
                await v.close()
                return result

    mode, armed, alt, requests = run(scenario(), timeout=90)
    assert mode == "GUIDED" and armed and alt == pytest.approx(20.0, abs=0.6)
    assert all(n == 1 for name, n in requests.items() if name != TARGET_REPORTS.name)  # they came


def test_a_parameter_read_is_sent_six_times_before_it_is_given_up():
    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")) as (m,):
                v = ArduPilotVehicle(link, 1, command_timeout=0.2)
                await link.wait_heartbeat(1, 5)
                m.drop_sent("PARAM_VALUE", 5)  # five answers lost: the sixth read is answered
                value = await v.read_parameter("WPNAV_SPEED")
                await v.close()
                return value, v.parameter_retries

    value, retries = run(scenario())
    assert value > 0 and retries == ardupilot.PARAMETER_RETRIES == 5


def test_the_controller_heartbeat_is_twice_a_second():
    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")) as (m,):
                await link.wait_heartbeat(1, 5)
                first = sum(1 for mtype, src, _ in m.received if mtype == "HEARTBEAT" and src == 255)
                await asyncio.sleep(2.0)
                later = sum(1 for mtype, src, _ in m.received if mtype == "HEARTBEAT" and src == 255)
                return later - first

    assert 3 <= run(scenario()) <= 5


@pytest.mark.slow
def test_a_search_with_detectors_over_lossy_links_completes_and_loses_no_vehicle_and_no_step(tmp_path):
    """The demo's kind of mission (detectors, hidden targets, the coordinated planner) with every link
    through a relay losing 20 % each way (30 +- 20 ms, 2 % duplicates): it completes, no vehicle judged
    lost, none sent home by its GCS failsafe, no step timed out (tools/lossy_links.py flies the demo
    itself on seeds 0-4)."""
    faults = LinkFaults(loss=0.2, delay=0.03, jitter=0.02, duplicate=0.02)
    with SimSwarm(small_grid(), uavs=2, seed=1, speedup=30.0, link_faults=faults) as swarm:
        plan = swarm.plan("coordinated", end_action="land", time_limit=60.0)
        controller, outcome = fly(plan, tmp_path)
        counts = [r.counts() for r in swarm.relays]
        failsafes = [m.state().gcs_failsafe for m in swarm.mocks]
    assert outcome == "complete"
    assert all(c.forward.lost > 0 and c.back.lost > 0 for c in counts)
    events = [line for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert not any('"change":"lost"' in e or '"event":"step_timeout"' in e for e in events)
    assert not any(failsafes)
    assert [a.end_state for a in controller.agents] == ["landed", "landed"]
