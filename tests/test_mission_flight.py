"""Full missions over loopback UDP: mock ArduCopters carrying hidden targets, the real controller."""

from __future__ import annotations

import json
import time
from collections import Counter

import pytest
from pymavlink import mavutil

from swarmctl.sim.swarm import SimSwarm
from tests.mission_support import fly, our_threads, small_grid, wait_for


def read_tlog(path) -> Counter:
    log = mavutil.mavlink_connection(str(path))
    counts: Counter = Counter()
    while (m := log.recv_match()) is not None:
        counts[m.get_type()] += 1
    return counts


def events(folder) -> list[dict]:
    return [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_three_ardupilot_and_one_px4_find_and_hover_on_distinct_targets(tmp_path):
    grid = small_grid()
    with SimSwarm(grid, uavs=4, seed=1, speedup=30.0, autopilots=["ardupilot"] * 3 + ["px4"]) as swarm:
        plan = swarm.plan("frontier", end_action="hover", time_limit=120.0)
        started = time.monotonic()
        controller, outcome = fly(plan, tmp_path)
        took = time.monotonic() - started
        hidden = {tuple(t) for t in swarm.targets.tolist()}
        mock_cells = [grid.latlon_to_cell(m.lat, m.lon) for m in swarm.mocks]
        armed = [m.armed for m in swarm.mocks]
    assert outcome == "complete", (outcome, took)
    summary = json.loads((tmp_path / "summary.json").read_text())
    ends = {v["name"]: v for v in summary["vehicles"]}
    assert all(v["end_state"] == "hovering on target" for v in ends.values()), ends
    cells = [tuple(v["cell"]) for v in ends.values()]
    assert len(set(cells)) == 4 and set(cells) <= hidden  # distinct targets, the hidden ones
    assert set(mock_cells) == set(cells) and all(armed)  # the vehicles really are there, in the air
    assert {tuple(t["cell"]) for t in summary["targets_found"]} == hidden
    assert summary["steps"] > 0 and all(v["steps"] > 0 for v in ends.values())
    # the whole flight, 3-D: the climb to the mission's altitude counts (from 0.5 m up) and the search
    climb = plan.spec.mission.altitude - 0.5
    assert all(v["distance_3d_m"] > climb + 10 for v in ends.values()), [v["distance_3d_m"] for v in ends.values()]
    assert summary["messages"]["knowledge_sent"] > 0 and summary["messages"]["mavlink_received"] > 0
    for key in ("time_s", "search_time_s", "messages", "overhead_ms", "policy", "outcome"):
        assert key in summary
    overhead = summary["overhead_ms"]  # the whole process's CPU holds the loop thread's
    assert overhead["process_cpu_mean"] >= overhead["cpu_mean"] - 0.01 > 0, overhead
    # the recording: every step, every packet
    ev = events(tmp_path)
    steps = [e for e in ev if e["event"] == "step"]
    assert [e["step"] for e in steps] == list(range(1, summary["steps"] + 1))
    for e in steps:
        for v in e["vehicles"]:
            assert {"cell", "obs", "q", "move", "guarded", "refused", "received"} <= set(v)
    assert sum(1 for e in ev if e["event"] == "end_action") == 4
    assert ends["uav4"]["autopilot"] == "px4" and ends["uav4"]["sensor_reports"] > 0  # via the detector socket
    counts = read_tlog(tmp_path / "mission.tlog")
    assert counts["HEARTBEAT"] > 0 and counts["SET_POSITION_TARGET_GLOBAL_INT"] > 0 and counts["TUNNEL"] > 0
    assert counts["COMMAND_ACK"] > 0 and counts["GLOBAL_POSITION_INT"] > 0
    assert not our_threads()


@pytest.mark.slow
def test_a_vehicle_losing_its_link_is_left_alone_and_the_others_finish(tmp_path):
    grid = small_grid()
    with SimSwarm(grid, uavs=3, seed=2, speedup=30.0, gcs_failsafe=None) as swarm:
        plan = swarm.plan("frontier", end_action="hover", time_limit=120.0)
        victim = swarm.mocks[1]

        async def cut_link(controller):
            await wait_for(lambda: controller.step >= 2, 60, "the search to start")
            victim.blackout(600.0)  # silent for the rest of the test

        controller, outcome = fly(plan, tmp_path, during=cut_link)
    assert outcome == "partial"  # the live vehicles hover on distinct targets; one vehicle dropped out
    states = {a.name: (a.state, a.end_state) for a in controller.agents}
    assert states["uav2"] == ("lost", "lost (left to its failsafe)")
    others = [a for a in controller.agents if a.name != "uav2"]
    assert all(a.end_state == "hovering on target" for a in others)
    assert len({a.cell for a in others}) == 2
    ev = events(tmp_path)
    assert any(e["event"] == "state" and e["vehicle"] == "uav2" and e["state"] == "lost" for e in ev)
    assert not any(
        e["event"] == "end_action" and e["vehicle"] == "uav2" and e["action"] != "none: link lost" for e in ev
    )
    assert not our_threads()


@pytest.mark.slow
def test_stopping_mid_mission_gives_every_vehicle_its_end_action(tmp_path):
    grid = small_grid()
    with SimSwarm(grid, uavs=3, seed=3, speedup=30.0) as swarm:
        plan = swarm.plan("random", end_action="rtl", time_limit=120.0)

        async def interrupt(controller):
            await wait_for(lambda: controller.step >= 3, 60, "a few steps")
            controller.stop()  # what SIGINT / SIGTERM do

        controller, outcome = fly(plan, tmp_path, during=interrupt)
        landed_home = [(not m.armed, m.rel_alt, grid.latlon_to_cell(m.lat, m.lon)) for m in swarm.mocks]
    assert outcome == "interrupted"
    assert [a.end_action for a in controller.agents] == ["rtl"] * 3
    assert [a.end_state for a in controller.agents] == ["landed at home"] * 3
    for (disarmed, alt, cell), start in zip(landed_home, swarm.starts):
        assert disarmed and alt == 0.0 and cell == start
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["outcome"] == "interrupted"
    assert not our_threads()


@pytest.mark.slow
@pytest.mark.parametrize("back_when", ["landed", "descending"])
def test_a_vehicle_that_comes_back_rejoins_the_search(tmp_path, back_when):
    """Its own failsafe (1.5 s without the controller's heartbeat) brings it home; its link comes back
    once it has landed there (it takes off again) or while it is still coming down (it is taken back
    in the air)."""
    grid = small_grid(16, 16)
    far_corner = [(13, 14), (15, 12), (14, 15)]  # the others search long enough for it to come back
    with SimSwarm(grid, uavs=3, seed=6, speedup=30.0, gcs_failsafe=1.5, targets=far_corner) as swarm:
        plan = swarm.plan("frontier", end_action="hover", time_limit=120.0, step_period=0.2)
        victim = swarm.mocks[2]
        if back_when == "descending":
            victim.descent_rate = 0.3  # m/s: slow enough to catch it on the way down

        def back() -> bool:
            if back_when == "landed":
                return not victim.armed
            return victim.armed and victim.mode_name == "RTL" and 2.0 < victim.rel_alt < 15.0

        async def outage(controller):
            await wait_for(lambda: controller.step >= 1, 60, "the search to start")
            victim.blackout(600.0)
            await wait_for(lambda: controller.agents[2].state == "lost", 30, "the link loss to be seen")
            await wait_for(back, 60, f"the vehicle to be {back_when}")
            victim.blackout(0.0)

        controller, outcome = fly(plan, tmp_path, during=outage)
    assert outcome == "complete"
    assert all(a.end_state == "hovering on target" for a in controller.agents)
    ev = [e for e in events(tmp_path) if e["event"] == "state" and e["vehicle"] == "uav3"]
    assert [e["state"] for e in ev][-5:] == ["lost", "rejoin", "search", "hover", "ended"]
    assert any(e.get("rejoined") for e in ev)


@pytest.mark.slow
def test_onboard_mode_two_processes_share_only_through_the_knowledge_channel(tmp_path):
    """Two controllers (as two `swarmctl agent` processes would be), one with two vehicles, one with one."""
    import asyncio

    from swarmctl.mission.controller import Controller
    from swarmctl.mission.recorder import Recorder

    grid = small_grid()
    with SimSwarm(grid, uavs=3, seed=7, speedup=30.0) as swarm:
        plans = [swarm.plan("frontier", end_action="hover", time_limit=120.0, radio=True) for _ in range(2)]
        plans[0].only, plans[1].only = [0, 1], [2]
        recs = [Recorder(tmp_path / f"p{i}") for i in range(2)]
        controllers = [Controller(p, r) for p, r in zip(plans, recs)]

        async def both():
            return await asyncio.wait_for(asyncio.gather(*(c.run() for c in controllers)), 150)

        try:
            outcomes = asyncio.run(both())
        finally:
            for r in recs:
                r.close()
        hidden = {tuple(t) for t in swarm.targets.tolist()}
    assert outcomes == ["complete", "complete"]
    cells = [a.cell for c in controllers for a in c.agents]
    assert len(set(cells)) == 3 and set(cells) <= hidden
    # each process knows the other's vehicle only from the knowledge channel
    assert 2 in controllers[0].agents[0].knowledge.positions and 0 in controllers[1].agents[0].knowledge.positions
    assert not our_threads()


@pytest.mark.slow
def test_a_ddql_policy_flies_and_every_step_records_its_q_values(tmp_path):
    """The learned path: observations from each agent's knowledge, one batched forward pass per round
    (an untrained network: the test is about the plumbing, not the search)."""
    import torch

    from swarmctl.policy.checkpoint import save_checkpoint
    from swarmctl.policy.qnet import QNetwork

    torch.manual_seed(0)
    model = tmp_path / "model.pt"
    save_checkpoint(model, QNetwork(window=20), {"window": 20}, {}, {"note": "untrained, for tests"})
    grid = small_grid()
    with SimSwarm(grid, uavs=3, seed=8, speedup=30.0) as swarm:
        plan = swarm.plan(f"ddql:{model}:tau=1.0", end_action="land", time_limit=6.0)
        controller, outcome = fly(plan, tmp_path / "rec")
        landed = [not m.armed and m.rel_alt == 0.0 for m in swarm.mocks]
    assert outcome in ("time limit", "complete")
    assert all(landed) and [a.end_state for a in controller.agents] == ["landed"] * 3
    steps = [e for e in events(tmp_path / "rec") if e["event"] == "step"]
    assert steps
    for e in steps:
        for v in e["vehicles"]:
            assert len(v["q"]) == 5 and len(v["obs"]) == 16


@pytest.mark.slow
def test_a_pilot_taking_over_is_left_alone(tmp_path):
    grid = small_grid()
    with SimSwarm(grid, uavs=3, seed=9, speedup=30.0) as swarm:
        plan = swarm.plan("frontier", end_action="rtl", time_limit=120.0, step_timeout=3.0)
        pilot = swarm.mocks[0]

        async def take_over(controller):
            await wait_for(lambda: controller.step >= 2, 60, "the search to start")
            with pilot._lock:
                pilot._set_mode_name("LOITER")  # as the pilot's mode switch would

        controller, outcome = fly(plan, tmp_path, during=take_over)
        still_flying = pilot.armed and pilot.mode_name == "LOITER"
    assert outcome == "partial"
    a = controller.agents[0]
    assert a.state == "override" and a.end_state == "pilot (LOITER)" and a.end_action is None
    assert still_flying  # swarmctl sent it nothing: no end action, no mode change
    assert [b.end_state for b in controller.agents[1:]] == ["landed at home"] * 2


@pytest.mark.slow
def test_with_the_fence_on_every_vehicle_takes_it_before_take_off_and_the_search_completes(tmp_path):
    grid = small_grid()
    with SimSwarm(grid, uavs=3, seed=4, speedup=30.0, autopilots=["ardupilot", "ardupilot", "px4"]) as swarm:
        plan = swarm.plan("frontier", end_action="hover", time_limit=120.0, fence=True)
        controller, outcome = fly(plan, tmp_path)
        states = [m.state() for m in swarm.mocks]
    assert outcome == "complete"
    fence = [(round(lat * 1e7), round(lon * 1e7)) for lat, lon in controller.fence]
    for s in states:
        assert [(round(lat * 1e7), round(lon * 1e7)) for lat, lon in s.fence[0]] == fence
        assert s.fence_enabled and s.fence_refused == 0 and s.armed
    ev = events(tmp_path)
    assert ev[0]["event"] == "mission" and len(ev[0]["fence"]) == len(fence)
    for name in ("uav1", "uav2", "uav3"):
        mine = [e for e in ev if e.get("vehicle") == name and e["event"] in ("fence", "state")]
        uploaded = next(i for i, e in enumerate(mine) if e["event"] == "fence")
        took_off = next(i for i, e in enumerate(mine) if e.get("state") == "takeoff")
        assert mine[uploaded]["uploaded"] is True and uploaded < took_off
    assert not our_threads()


@pytest.mark.slow
def test_a_vehicle_rebooted_mid_mission_gets_its_fence_on_again_before_it_rejoins(tmp_path):
    """ArduPilot does not save DO_FENCE_ENABLE: a rebooted vehicle keeps its stored fence but has it off."""
    grid = small_grid(16, 16)
    far_corner = [(13, 14), (15, 12), (14, 15)]
    with SimSwarm(grid, uavs=3, seed=6, speedup=30.0, targets=far_corner) as swarm:
        plan = swarm.plan("frontier", end_action="hover", time_limit=120.0, step_period=0.2, fence=True)
        victim = swarm.mocks[2]
        fence_off = []

        async def reboot(controller):
            await wait_for(lambda: controller.step >= 1, 60, "the search to start")
            victim.reboot(600.0)
            await wait_for(lambda: controller.agents[2].state == "lost", 30, "the link loss to be seen")
            victim.blackout(0.0)  # it boots now: disarmed, on the ground
            await wait_for(lambda: not victim.armed and victim.state().fence, 30, "the vehicle to boot")
            fence_off.append(not victim.state().fence_enabled)

        controller, outcome = fly(plan, tmp_path, during=reboot)
        state = victim.state()
    assert fence_off == [True]  # the reboot switched it off
    assert outcome == "complete" and state.fence_enabled and state.armed
    mine = [e for e in events(tmp_path) if e.get("vehicle") == "uav3" and e["event"] in ("fence", "state")]
    kinds = [e.get("state", "fence") for e in mine]
    rejoin = kinds.index("rejoin")
    assert kinds.count("fence") == 2 and kinds.index("fence") < kinds.index("takeoff")
    assert kinds[rejoin : rejoin + 3] == ["rejoin", "fence", "search"]
    assert all(e["uploaded"] for e in mine if e["event"] == "fence")


@pytest.mark.slow
def test_a_vehicle_that_refuses_the_fence_stays_on_the_ground_and_the_others_fly(tmp_path):
    from pymavlink.dialects.v20 import ardupilotmega as MAV

    grid = small_grid()
    with SimSwarm(grid, uavs=2, seed=5, speedup=30.0) as swarm:
        swarm.mocks[1].fence.max_items = 3  # too small for the grid's fence
        plan = swarm.plan("frontier", end_action="land", time_limit=3.0, fence=True)
        controller, outcome = fly(plan, tmp_path)
        refused = swarm.mocks[1]
        commands = {c for c, _ in refused.commands}
        on_the_ground = refused.rel_alt == 0.0 and not refused.armed
    assert outcome in ("partial", "time limit")
    good, bad = controller.agents
    assert good.end_state == "landed" and good.steps > 0
    assert bad.state == "failed" and on_the_ground and MAV.MAV_CMD_COMPONENT_ARM_DISARM not in commands
    assert bad.error.startswith("uav2: the fence upload was refused: NO_SPACE (")
    assert "Only 3 items are supported" in bad.error  # the vehicle's STATUSTEXT
    assert bad.error.endswith("; without its fence uav2 does not take off")
    fence_events = [e for e in events(tmp_path) if e["event"] == "fence"]
    assert {(e["vehicle"], e["uploaded"]) for e in fence_events} == {("uav1", True), ("uav2", False)}
    assert not our_threads()


@pytest.mark.slow
def test_a_vehicle_launched_outside_the_fence_does_not_take_off(tmp_path):
    import shapely

    grid = small_grid()
    # the area is the grid's east half only: the vehicles start at its south-west (cells (0, 0), (2, 0))
    east = shapely.box(*grid.grid_to_metres(6, 0), *grid.grid_to_metres(10, 10))
    grid.area_wkt = grid.projection.geometry_to_lonlat(east).wkt
    with SimSwarm(grid, uavs=2, seed=6, speedup=30.0) as swarm:
        plan = swarm.plan("frontier", end_action="land", time_limit=30.0, fence=True)
        controller, outcome = fly(plan, tmp_path)
        armed = [m.armed or m.rel_alt > 0 for m in swarm.mocks]
    assert outcome == "failed" and not any(armed)
    for a in controller.agents:
        assert a.state == "failed" and "is outside the fence (the search area's boundary)" in a.error
    assert all(not e["uploaded"] for e in events(tmp_path) if e["event"] == "fence")


def test_the_last_progress_line_tells_the_search_as_it_ended_not_as_the_vehicles_land(tmp_path):
    import io
    import re

    from swarmctl.mission.service import LiveView

    view = io.StringIO()
    with SimSwarm(small_grid(), uavs=2, seed=1, speedup=30.0) as swarm:
        plan = swarm.plan("frontier", end_action="land", time_limit=120.0)
        controller, outcome = fly(plan, tmp_path, view=LiveView(stream=view, live=False))
    assert outcome == "complete" and [a.end_state for a in controller.agents] == ["landed"] * 2
    last = [line for line in view.getvalue().splitlines() if line.startswith("step ")][-1]
    summary = json.loads((tmp_path / "summary.json").read_text())
    match = re.fullmatch(r"step (\d+)  targets found 2  hovering 2/2  ([\d.]+) s  -> complete", last)
    assert match is not None, last  # both were hovering when it ended: not 0/2 once they had landed
    assert abs(float(match[2]) - summary["search_time_s"]) <= 0.06 and int(match[1]) == summary["steps"]
