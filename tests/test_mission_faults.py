"""Faults while flying: a reply in a vehicle's name the driver did not expect, or a bug in the rounds,
fails that vehicle (or the mission) but never leaves a vehicle in the air without its end action."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarmctl.mavlink.autopilots.ardupilot import whole_parameter
from swarmctl.mavlink.errors import MavlinkError
from swarmctl.mission.agent import State
from swarmctl.sim.swarm import SimSwarm
from tests.mission_support import fly, small_grid, wait_for

TIMEOUT = 120.0


def events(folder) -> list[dict]:
    return [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]


async def second_vehicle_late(controller, swarm) -> int:
    """Wait until vehicle 1 searches while vehicle 2 still boots; let vehicle 2 boot; its link's port."""
    first, second = controller.agents
    await wait_for(
        lambda: first.state is State.SEARCH and getattr(second.vehicle, "link", None) is not None,
        TIMEOUT,
        "vehicle 1 searching, vehicle 2 connected",
    )
    swarm.mocks[1].slow_boot(swarm.mocks[1].sim_time)
    return controller.agents[1].vehicle.link.local_port


def test_a_nan_parameter_in_a_vehicles_name_fails_that_vehicle_and_the_other_still_comes_home(tmp_path):
    with SimSwarm(small_grid(), uavs=2, seed=1, speedup=30.0) as swarm:
        swarm.mocks[1].slow_boot(3000.0)  # vehicle 2 boots late: vehicle 1 is in the air first
        swarm.mocks[1].params["FENCE_TYPE"] = math.nan  # what a forger answering in its name sent
        plan = swarm.plan("frontier", end_action="rtl", time_limit=4.0, fence=True)

        async def boot_the_second(controller):
            await second_vehicle_late(controller, swarm)

        controller, outcome = fly(plan, tmp_path, timeout=TIMEOUT, during=boot_the_second)
        first = swarm.mocks[0]
        first.wait_for(lambda m: not m.state().armed, 60)
    assert outcome in ("partial", "time limit")  # flown to its end by vehicle 1
    assert controller.agents[1].state is State.FAILED
    assert "FENCE_TYPE reads as nan" in controller.agents[1].error
    ended = [e for e in events(tmp_path) if e["event"] == "end_action"]
    assert [(e["vehicle"], e["action"]) for e in ended] == [(plan.spec.vehicles[0].name, "rtl")]


def test_a_bug_in_the_rounds_still_gives_every_vehicle_in_the_air_its_end_action(tmp_path, monkeypatch):
    from swarmctl.mission.rounds import Rounds

    async def broken_search(rounds):
        await wait_for(lambda: all(a.state is State.SEARCH for a in rounds.crew.agents), TIMEOUT, "both searching")
        raise RuntimeError("a bug in the rounds")

    monkeypatch.setattr(Rounds, "search", broken_search)
    with SimSwarm(small_grid(), uavs=2, seed=2, speedup=30.0) as swarm:
        plan = swarm.plan("frontier", end_action="rtl", time_limit=30.0)
        with pytest.raises(RuntimeError, match="a bug in the rounds"):
            fly(plan, tmp_path, timeout=TIMEOUT)
        for mock in swarm.mocks:
            mock.wait_for(lambda m: not m.state().armed, 60)
    recorded = events(tmp_path)
    assert {e["vehicle"] for e in recorded if e["event"] == "end_action" and e["action"] == "rtl"} == {
        v.name for v in plan.spec.vehicles
    }
    assert [e["outcome"] for e in recorded if e["event"] == "end"] == ["failed"]


@given(st.integers(-(2**24), 2**24))
def test_whole_parameters_are_read_as_ints(value):
    assert whole_parameter("FENCE_TYPE", float(value), "alpha") == value


@given(
    st.one_of(
        st.sampled_from([math.nan, math.inf, -math.inf]),
        st.floats(-1e6, 1e6, allow_nan=False).filter(lambda v: v != int(v)),
    )
)
def test_parameters_that_are_not_whole_numbers_are_refused_with_the_name(value):
    with pytest.raises(MavlinkError, match="alpha: FENCE_TYPE reads as"):
        whole_parameter("FENCE_TYPE", value, "alpha")
