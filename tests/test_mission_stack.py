"""Ground mode with the knowledge stack flies and records exactly what the per-agent path (each agent
its own Knowledge, each delivery merged one by one, as onboard agents keep) does: same seed, same moves
and the same knowledge snapshots, on the ideal bus and on a lossy one."""

from __future__ import annotations

import json

import pytest

import swarmctl.mission.controller as controller_module
from swarmctl.knowledge.bus import KnowledgeBus
from swarmctl.sim.swarm import SimSwarm
from swarmctl.world.channel import Channel
from tests.mission_support import fly, small_grid


def per_agent_bus(plan):
    """The bus without a stack: every agent's Knowledge on its own (the reference path)."""
    return None if plan.onboard else KnowledgeBus(plan.bus_channel, seed=plan.seed)


def recording(folder, channel, stacked: bool, monkeypatch) -> tuple[list, list]:
    with monkeypatch.context() as m:
        if not stacked:
            m.setattr(controller_module, "make_bus", per_agent_bus)
        grid = small_grid(14, 14)
        with SimSwarm(grid, uavs=4, seed=7, speedup=30.0, carry_detectors=False, channel=channel) as swarm:
            plan = swarm.plan("frontier", end_action="land", time_limit=5.0)
            controller, _ = fly(plan, folder)
        assert (controller.bus.stack is not None) == stacked
    lines = [json.loads(x) for x in (folder / "events.jsonl").read_text().splitlines()]
    steps = [(e["step"], e["vehicles"]) for e in lines if e["event"] == "step"]
    snaps = [
        {k: v for k, v in json.loads(x).items() if k != "t"}
        for x in (folder / "knowledge.jsonl").read_text().splitlines()
    ]
    return steps, snaps


@pytest.mark.slow
@pytest.mark.parametrize("channel", [None, Channel("fixed", loss=0.3)], ids=["ideal", "lossy"])
def test_the_stack_records_the_moves_and_knowledge_of_the_per_agent_path(tmp_path, monkeypatch, channel):
    ref_steps, ref_snaps = recording(tmp_path / "per-agent", channel, False, monkeypatch)
    steps, snaps = recording(tmp_path / "stacked", channel, True, monkeypatch)
    common = min(len(ref_steps), len(steps))  # the time limit may cut one run a round earlier
    assert common >= 5, "too few rounds to compare"
    assert steps[:common] == ref_steps[:common]
    last = steps[common - 1][0]
    assert [s for s in snaps if s["step"] <= last] == [s for s in ref_snaps if s["step"] <= last]
