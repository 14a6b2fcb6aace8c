"""Missions with mock ArduCopters booting as SITL does: the preflight waits in GUIDED and says why, the
waits follow each vehicle's speeds, a stopped mission counts no step timeouts, and the summary says
who hovered where and how far each vehicle flew."""

from __future__ import annotations

import asyncio
import io
import json

import pytest

from swarmctl.mavlink.network import MAV
from swarmctl.mission.service import LiveView
from swarmctl.sim.swarm import SimSwarm
from tests.mission_support import fly, our_threads, small_grid, wait_for

pytestmark = pytest.mark.slow


def events(folder, kind=None) -> list[dict]:
    lines = [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]
    return [e for e in lines if kind is None or e["event"] == kind]


def test_a_slow_ekf_holds_its_vehicle_in_preflight_and_the_reasons_are_shown(tmp_path):
    """uav2's EKF uses the GPS only once uav2 has waited in preflight for 1.5 s (the slow-EKF fault, moved
    on from the test): meanwhile it says why, and it arms at the first try once ready."""
    grid = small_grid()
    view = io.StringIO()
    with SimSwarm(grid, uavs=2, seed=1, speedup=30.0) as swarm:
        slow = swarm.mocks[1]
        slow.slow_ekf(1e9)
        plan = swarm.plan("frontier", end_action="land", time_limit=2.0, step_timeout=7.0)

        async def ekf_later(c):
            uav2 = c.agents[1]
            await wait_for(lambda: uav2.state == "preflight" and uav2.status is not None, 60, "uav2 in preflight")
            await asyncio.sleep(1.5)
            slow.slow_ekf(slow.sim_time + 15.0)  # 0.5 s from now

        controller, outcome = fly(plan, tmp_path, during=ekf_later, view=LiveView(stream=view, live=False))
        arms = [r for c, r in slow.commands if c == MAV.MAV_CMD_COMPONENT_ARM_DISARM]
    assert outcome in ("time limit", "complete") and [a.end_state for a in controller.agents] == ["landed"] * 2
    said = [(e["t"], e["text"]) for e in events(tmp_path, "preflight") if e["vehicle"] == "uav2"]
    texts = [text for _t, text in said]
    assert "PreArm: Need Position Estimate" in texts and "EKF3 IMU0 is using GPS" in texts
    assert any(t.startswith("waiting for the EKF's position estimate") for t in texts)
    assert "uav2: PreArm: Need Position Estimate" in view.getvalue().splitlines()  # the progress lines
    states = {(e["vehicle"], e["state"]): e["t"] for e in events(tmp_path, "state")}
    ekf = next(t for t, text in said if text == "EKF3 IMU0 is using GPS")
    assert states["uav2", "preflight"] + 1.5 < ekf < states["uav2", "takeoff"]  # it waited for its EKF ...
    assert arms[0] == MAV.MAV_RESULT_ACCEPTED  # ... and armed at the first try, in GUIDED
    limits = {e["vehicle"]: e for e in events(tmp_path, "limits")}
    assert limits["uav1"]["step_timeout"] == limits["uav2"]["step_timeout"] == 7.0  # the mission's
    assert len(limits["uav1"]["read"]) == 10 and limits["uav1"]["speed"] == 10.0  # read from WPNAV_SPEED
    assert not our_threads()


def test_a_vehicle_not_ready_in_time_fails_naming_its_last_reason(tmp_path):
    grid = small_grid()
    with SimSwarm(grid, uavs=1, seed=1, speedup=30.0) as swarm:
        swarm.mocks[0].slow_ekf(100_000.0)
        plan = swarm.plan("frontier", end_action="land", time_limit=5.0, ready_timeout=1.5)
        controller, outcome = fly(plan, tmp_path)
    assert outcome == "failed"
    error = controller.agents[0].error
    assert error.startswith("uav1: not ready to arm after 1.5 s: PreArm: Need Position Estimate (waiting for ")
    assert events(tmp_path, "state")[-1]["error"] == error


def test_a_stopped_mission_counts_no_step_timeouts(tmp_path):
    """Slow vehicles (0.5 m/s): the stop comes while they fly to their cells; those aborted waits are not
    timeouts (the derived step timeout, 46 vehicle seconds a cell, is never reached either)."""
    grid = small_grid()
    with SimSwarm(grid, uavs=3, seed=3, speedup=30.0, speed=0.5) as swarm:
        plan = swarm.plan("frontier", end_action="land", time_limit=120.0)

        async def interrupt(c):
            def flying() -> bool:
                return sum(1 for a in c.agents if a.vehicle.target and not a.vehicle.reached(0.5)) >= 2

            await wait_for(lambda: c.step >= 2 and flying(), 60, "a round with vehicles on their way")
            c.stop()  # what SIGINT and SIGTERM do

        stopped, outcome = fly(plan, tmp_path, during=interrupt)
    assert outcome == "interrupted"
    assert [a.timeouts for a in stopped.agents] == [0, 0, 0] and not events(tmp_path, "step_timeout")
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert [v["step_timeouts"] for v in summary["vehicles"]] == [0, 0, 0]
    limits = events(tmp_path, "limits")[0]
    assert limits["speed"] == 0.5 and limits["step_timeout"] == pytest.approx(46.4, abs=0.1)


def test_a_complete_mission_ending_in_rtl_says_who_hovered_where_and_the_whole_flight_counts(tmp_path):
    grid = small_grid()
    with SimSwarm(grid, uavs=2, seed=4, speedup=30.0) as swarm:
        plan = swarm.plan("frontier", end_action="rtl", time_limit=120.0)
        controller, outcome = fly(plan, tmp_path)
        hidden = sorted(tuple(t) for t in swarm.targets.tolist())
    assert outcome == "complete"
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert [v["end_state"] for v in summary["vehicles"]] == ["landed at home"] * 2
    assert sorted(tuple(c) for c in summary["vehicles_on_targets"]) == hidden
    altitude = plan.spec.mission.altitude
    for v, a in zip(summary["vehicles"], controller.agents):
        # up, out, back and down again: at least the climb and the descent, 3-D
        assert v["distance_3d_m"] >= 2 * (altitude - 0.5), v
        assert v["distance_3d_m"] == round(a.vehicle.distance_flown_m, 1)
    assert not our_threads()
