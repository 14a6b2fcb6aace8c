"""The attacks of a hostile radio, against full missions over loopback UDP (mock ArduCopters, the real
controller): a spoofed setpoint, forged detections from a sender that is not in the mission."""

from __future__ import annotations

import asyncio
import json
import socket

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.knowledge.codec import KnowledgeCodec
from swarmctl.knowledge.model import Detection
from swarmctl.mavlink.autopilots.ardupilot import TYPE_MASK_POSITION_ONLY
from swarmctl.mavlink.codec import to_deg_e7
from swarmctl.sim.swarm import SimSwarm
from tests.mission_support import fly, our_threads, small_grid, wait_for

ATTACKER = 42  # the sysid the spoofed setpoint comes from


def events(folder) -> list[dict]:
    return [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]


def spoofer(port: int):
    """A MAVLink sender of system 42 aimed at a mock's udpin port."""
    return mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=ATTACKER, source_component=190)


def spoof_setpoint(conn, sysid: int, lat: float, lon: float, alt: float) -> None:
    conn.mav.set_position_target_global_int_send(
        0, sysid, 1, mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, TYPE_MASK_POSITION_ONLY,
        to_deg_e7(lat), to_deg_e7(lon), alt, 0, 0, 0, 0, 0, 0, 0, 0,
    )  # fmt: skip


def recorder(controller, sent: list[int]):
    """A goto for the controller's first vehicle that notes the round (controller.step) of every setpoint."""
    goto = controller.agents[0].vehicle.goto

    async def recorded(lat, lon, alt):
        sent.append(controller.step)
        await goto(lat, lon, alt)

    return recorded


@pytest.mark.slow
@pytest.mark.parametrize("persistent", [False, True], ids=["once", "persistent"])
def test_a_spoofed_setpoint_is_flagged_and_re_commanded_and_a_persistent_one_taken_over(tmp_path, persistent):
    """SET_POSITION_TARGET_GLOBAL_INT from sysid 42 sends a vehicle down to 5 m over a building. Once:
    flagged, its setpoint sent again, back on course, the search goes on. Kept up: after
    `off_course_rounds` rounds the vehicle is treated as taken over and the others carry on."""
    grid = small_grid()
    blocked = (grid.width // 2, grid.height // 2)
    with SimSwarm(grid, uavs=3, seed=9, speedup=30.0) as swarm:
        plan = swarm.plan("frontier", end_action="rtl", time_limit=120.0)
        victim = swarm.mocks[0]
        sent: list[int] = []  # the rounds the controller sent the victim a setpoint in
        lows: list[float] = []

        async def spoof(controller):
            await wait_for(lambda: controller.step >= 2, 60, "the search to start")
            controller.agents[0].vehicle.goto = recorder(controller, sent)
            conn = spoofer(victim.local_port)
            a = controller.agents[0]
            # once: until the controller notices; persistent: until it gives the vehicle up
            done = (lambda: a.state == "override") if persistent else (lambda: a.alarm is not None)
            loop = asyncio.get_running_loop()
            deadline = loop.time() + 30.0
            try:
                while not done() and loop.time() < deadline:
                    spoof_setpoint(conn, victim.sysid, *grid.cell_to_latlon(*blocked), 5.0)
                    lows.append(victim.rel_alt)
                    await asyncio.sleep(0.05)
            finally:
                conn.close()

        controller, outcome = fly(plan, tmp_path, during=spoof)
    ev = events(tmp_path)
    off = [e for e in ev if e["event"] == "off_course" and e["vehicle"] == "uav1"]
    flagged = [e for e in off if not e.get("cleared")]
    assert flagged and min(lows) < plan.spec.mission.altitude - 1.0, (off, min(lows))  # the spoof took it down
    assert all(e["step"] in sent for e in flagged), (flagged, sent)  # each time its setpoint went out again
    a = controller.agents[0]
    if persistent:
        over = [e for e in ev if e["event"] == "state" and e["vehicle"] == "uav1" and e["state"] == "override"]
        assert len(over) == 1 and over[0]["reason"] == "not commanded", over
        n = plan.spec.flight.off_course_rounds
        assert [e["rounds"] for e in flagged][-n:] == list(range(1, n + 1)) and over[0]["rounds"] == n + 1
        assert a.end_state.startswith("taken over, not commanded") and a.end_action is None
        assert outcome == "partial"
        assert [b.end_state for b in controller.agents[1:]] == ["landed at home"] * 2  # the others carried on
    else:
        assert any(e.get("cleared") for e in off)  # back on course
        assert len(flagged) <= plan.spec.flight.off_course_rounds and a.state != "override"
        assert outcome == "complete", outcome
    assert not our_threads()


@pytest.mark.slow
def test_forged_detections_from_a_sender_not_in_the_mission_find_nothing(tmp_path):
    """DETECTION frames claiming every free cell is a target, sent to the knowledge channel while the
    mission runs by vehicle index 7 (not in the mission), by a member's index from a stranger's sysid
    and by a member as itself: the mission finds only its real targets, rejections counted by reason."""
    grid = small_grid()
    with SimSwarm(grid, uavs=3, seed=7, speedup=30.0) as swarm:
        plan = swarm.plan("frontier", end_action="hover", time_limit=120.0, radio=True)
        plan.only = [0, 1, 2]  # onboard mode, every vehicle here: each agent reads the knowledge channel
        every = [(x, y) for x in range(grid.width) for y in range(grid.height) if not grid.blocked[x, y]]
        forged = []
        # a stranger; a member's index from another sysid; a member as itself, claiming what it cannot see
        for sender, sysid in ((7, 8), (1, ATTACKER), (1, 2)):
            codec = KnowledgeCodec(plan.spec.mission.id, grid.width, grid.height, system_id=sysid)
            for cells in (every[i : i + 20] for i in range(0, len(every), 20)):
                forged += codec.frames(Detection(sender, 1, cells[0], True, np.array(cells)))

        async def forge(controller):
            await wait_for(lambda: controller.step >= 2, 60, "the search to start")
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                for _ in range(3):
                    for frame in forged:
                        s.sendto(frame, swarm.radio.address)
                    await asyncio.sleep(0.5)

        controller, outcome = fly(plan, tmp_path, during=forge)
        hidden = {tuple(t) for t in swarm.targets.tolist()}
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert outcome == "complete", outcome
    assert {tuple(t["cell"]) for t in summary["targets_found"]} == hidden
    for a in controller.agents:
        assert set(a.knowledge.targets) <= hidden
    rejected = summary["messages"]["knowledge_rejections"]
    assert rejected.get("member", 0) > 0 and rejected.get("sysid", 0) > 0, rejected
    assert rejected.get("footprint", 0) + rejected.get("speed", 0) > 0, rejected
    assert not our_threads()
