"""The agents' state machine: the transitions it has, the ones it refuses, what each vehicle report
leads to, and a low-battery return flown end to end (the controller keeps the task it starts)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from types import SimpleNamespace

import pytest

from swarmctl.mavlink.autopilots.descriptions import ARDUPILOT, PX4
from swarmctl.mission.agent import TRANSITIONS, Agent, IllegalTransition, State
from swarmctl.sim.swarm import SimSwarm
from tests.mission_support import fly, small_grid, wait_for


@dataclass
class FakeVehicle:
    lost: bool = False
    mode: str = "GUIDED"
    battery_remaining: int | None = 80
    autopilot_info: object = ARDUPILOT
    armed: bool = True
    position: object = None


def agent(state: State, **vehicle) -> Agent:
    a = Agent.__new__(Agent)  # only the fields the state machine reads
    a.spec, a.vehicle, a.state, a.cell, a.saw_loss, a.pilot_since = (
        SimpleNamespace(name="uav1"),
        FakeVehicle(**vehicle),
        state,
        (1, 1),
        False,
        None,
    )
    a.lost_at, a.status = None, None
    return a


def test_the_machine_has_the_documented_transitions_and_nothing_else():
    assert TRANSITIONS[State.NEW] == {State.CONNECT, State.ENDED}  # ended: stopped before connecting
    assert TRANSITIONS[State.SEARCH] == {
        State.HOVER,
        State.LOST,
        State.OVERRIDE,
        State.LOW_BATTERY,
        State.FAILED,
        State.ENDED,
    }
    # a lost vehicle is never failed or hovering; back in a pilot's mode it is the pilot's
    assert TRANSITIONS[State.LOST] == {State.REJOIN, State.OVERRIDE, State.ENDED}
    assert TRANSITIONS[State.ENDED] == set()
    assert TRANSITIONS[State.OVERRIDE] == {State.ENDED}  # once the pilot has it, only the end
    # home on low battery: back with a fresh battery, or the pilot's
    assert TRANSITIONS[State.LOW_BATTERY] == {State.REJOIN, State.OVERRIDE, State.ENDED}


def test_a_transition_the_machine_lacks_is_refused_and_staying_is_not_a_change():
    a = agent(State.HOVER)
    with pytest.raises(IllegalTransition, match="hover to low battery"):
        a.enter(State.LOW_BATTERY)
    assert a.enter(State.HOVER) is False and a.state is State.HOVER
    assert a.enter(State.LOST) is True and a.state is State.LOST


@pytest.mark.parametrize(
    "state, vehicle, expected",
    [
        (State.SEARCH, dict(lost=True), State.LOST),
        (State.HOVER, dict(lost=True), State.LOST),
        (State.REJOIN, dict(lost=True), State.LOST),
        (State.LOST, dict(lost=False), State.REJOIN),
        (State.LOST, dict(lost=False, mode="RTL"), State.REJOIN),  # its own failsafe's mode: taken back
        (State.LOST, dict(lost=False, mode="LOITER"), State.OVERRIDE),  # a pilot chose it meanwhile
        (State.LOST, dict(lost=True), None),
        (State.SEARCH, dict(mode="LOITER"), State.OVERRIDE),  # ArduPilot: anything but GUIDED is the pilot's
        (State.SEARCH, dict(battery_remaining=10), State.LOW_BATTERY),
        (State.HOVER, dict(battery_remaining=10), None),  # a hovering vehicle holds its target
        (State.SEARCH, dict(battery_remaining=None), None),  # no battery report: nothing to act on
        (State.TAKEOFF, dict(lost=True), None),  # before the search the launch handles its own failures
    ],
)
def test_what_each_report_leads_to(state, vehicle, expected):
    change = agent(state, **vehicle).next_state(low_battery=15, now=100.0)
    assert (change[0] if change else None) == expected


def test_a_brief_link_loss_seen_since_the_last_look_counts_once():
    a = agent(State.SEARCH)
    a.saw_loss = True
    assert a.next_state(15, now=0.0) == (State.LOST, {"last_cell": (1, 1)}) and not a.saw_loss


def test_a_pilot_mode_must_last_the_autopilots_debounce_time():
    a = agent(State.SEARCH, mode="POSCTL", autopilot_info=PX4)  # PX4 reports modes through MAVSDK, late
    assert a.next_state(15, now=10.0) is None
    assert a.next_state(15, now=10.0 + PX4.mode_debounce_s - 0.01) is None
    assert a.next_state(15, now=10.0 + PX4.mode_debounce_s)[0] is State.OVERRIDE
    a.vehicle.mode = "HOLD"
    assert a.next_state(15, now=20.0) is None and a.pilot_since is None


@pytest.mark.slow
def test_a_vehicle_low_on_battery_is_sent_home_and_the_return_is_seen_through(tmp_path):
    grid = small_grid()
    with SimSwarm(grid, uavs=2, seed=4, speedup=30.0) as swarm:
        plan = swarm.plan("frontier", end_action="hover", time_limit=120.0)
        weak = swarm.mocks[1]

        async def drain(controller):
            # once it climbs (past the battery check before take-off) and before the search starts, so that
            # the search cannot end before the controller has seen the battery low
            await wait_for(lambda: weak.rel_alt > 1.0, 60, "uav2 to climb")
            with weak._lock:
                weak.battery = 10.0  # below battery.return_below (15 %)

        controller, outcome = fly(plan, tmp_path, during=drain)
        landed_home = not weak.armed and weak.rel_alt == 0.0
    a = controller.agents[1]
    assert a.state is State.ENDED and a.end_action == "rtl" and a.end_state == "landed at home" and landed_home
    events = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert any(e["event"] == "state" and e["vehicle"] == "uav2" and e["state"] == "low battery" for e in events)
    assert not controller.state.tasks  # the RTL command the controller started is done, not left behind
    assert outcome in ("partial", "time limit")
