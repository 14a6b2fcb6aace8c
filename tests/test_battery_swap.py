"""Going home on the energy the return takes, and a battery swap that brings the vehicle back into the
search: the rule on hand-built figures, the consumption measured from noisy whole-% reports, the agent's
transitions, the mock's swap, and a mission flown through all of it."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import pytest

from swarmctl.mavlink.autopilots.descriptions import ARDUPILOT
from swarmctl.mavlink.vehicle import Home, Position
from swarmctl.mission.agent import Agent, State
from swarmctl.mission.energy import MIN_RATE, MIN_SPAN_S, PRIOR_RATE, ChargeLog, consumption_rate, home_check
from swarmctl.mission.events import check_event
from swarmctl.mission.spec import BatteryTable
from swarmctl.sim.autopilot import MockAutopilot
from swarmctl.sim.swarm import SimSwarm
from tests.mission_support import fly, small_grid, wait_for

LIMITS = ARDUPILOT.flight_limits({})  # ArduCopter's default speeds: 10 m/s, RTL_ALT 15 m


# --- the rule ----------------------------------------------------------------------------------------------


def test_a_far_vehicle_goes_home_before_a_near_one_with_the_same_charge():
    near = home_check(30, floor=15, reserve=15, rate=0.1, distance_m=50.0, height_m=40.0, limits=LIMITS)
    far = home_check(30, floor=15, reserve=15, rate=0.1, distance_m=2000.0, height_m=40.0, limits=LIMITS)
    assert not near.go and far.go and far.reason == "energy"
    assert far.seconds_home > near.seconds_home and far.needed > 30 > near.needed
    # the figures it decided on: reserve + rate x the return's seconds
    assert far.needed == pytest.approx(15 + 0.1 * LIMITS.rtl_s(2000.0, 40.0))
    record = far.record()
    assert record["reason"] == "energy" and record["distance_m"] == 2000.0 and record["rate"] == 0.1
    assert set(record) == {"battery", "reason", "distance_m", "rate", "seconds_home", "needed"}


def test_the_floor_holds_whatever_the_figures_and_alone_where_they_are_unknown():
    at_home = home_check(14, floor=15, reserve=0, rate=0.0, distance_m=0.0, limits=LIMITS)
    assert at_home.go and at_home.reason == "floor"
    unknown = home_check(14, floor=15, reserve=15)  # no position, home or speeds: only the floor
    assert unknown.go and unknown.record() == {"battery": 14, "reason": "floor"}
    assert not home_check(16, floor=15, reserve=15).go


def test_the_rate_is_measured_from_noisy_whole_percent_reports():
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 300.0, 0.5)
    true = 0.1  # % per second of flight
    charges = np.round(100.0 - true * t + rng.normal(0.0, 0.8, t.size))  # noise, then the report's whole %
    assert consumption_rate(t, charges) == pytest.approx(true, rel=0.1)
    log = ChargeLog()
    for s, c in zip(t, charges):
        log.add(float(s), float(c))
    assert log.rate() == pytest.approx(true, rel=0.1)  # the log keeps what its window needs
    assert len(log.samples) < t.size
    # too little flight for a measurement: the conservative prior, or more where the drain shows faster
    assert consumption_rate(t[:10], charges[:10]) == PRIOR_RATE
    short = t < MIN_SPAN_S / 2
    assert consumption_rate(t[short], 100.0 - 0.5 * t[short]) == pytest.approx(0.5)
    assert consumption_rate(t[short], 100.0 - 0.05 * t[short]) == PRIOR_RATE
    # a charge that hardly falls over a long flight: one whole % more than fell, never free
    still = np.full(t.size, 80.0)
    assert consumption_rate(t, still) == pytest.approx(max(MIN_RATE, 1.0 / 240.0))


def test_the_battery_table_keeps_its_defaults_and_checks_the_new_keys():
    b = BatteryTable()
    assert (b.takeoff_min, b.return_below, b.reserve, b.relaunch) == (30, 15, 15, True)
    with pytest.raises(ValueError, match="reserve"):
        BatteryTable(reserve=101)


# --- the agent ---------------------------------------------------------------------------------------------


@dataclass
class FakeVehicle:
    battery_remaining: int | None = 60
    position: Position | None = None
    home: Home | None = field(default_factory=lambda: Home(41.88, -87.63, 180.0))
    limits: object = LIMITS
    distance_flown_m: float = 0.0
    lost: bool = False
    armed: bool = True
    mode: str = "GUIDED"
    autopilot_info: object = ARDUPILOT


def agent(state: State, **vehicle) -> Agent:
    vehicle.setdefault("position", Position(41.88, -87.63, 40.0, 220.0))
    exchange = SimpleNamespace(knowledge=None)
    a = Agent(0, SimpleNamespace(name="uav1"), FakeVehicle(**vehicle), exchange, feed=None)
    a.state = state
    return a


def test_the_low_battery_transition_records_the_figures_it_decided_on():
    far = Position(41.88 + 0.02, -87.63, 40.0, 220.0)  # about 2.2 km north of home
    assert agent(State.SEARCH, battery_remaining=40).next_state(15, now=0.0, reserve=15) is None
    state, record = agent(State.SEARCH, battery_remaining=40, position=far).next_state(15, now=0.0, reserve=15)
    assert state is State.LOW_BATTERY and record["reason"] == "energy" and record["rate"] == PRIOR_RATE
    assert record["distance_m"] == pytest.approx(2224, abs=5) and record["needed"] > 40


def test_sent_home_it_relaunches_only_landed_and_disarmed_with_a_fresh_battery():
    ground = Position(41.88, -87.63, 0.0, 180.0)
    a = agent(State.LOW_BATTERY, battery_remaining=12, position=ground, armed=False, mode="RTL")
    assert a.next_state(15, now=0.0, reserve=15, relaunch_at=30) is None
    a.vehicle.battery_remaining = 25  # recovering at rest: no new battery
    assert a.next_state(15, now=1.0, reserve=15, relaunch_at=30) is None
    a.vehicle.battery_remaining = 100
    assert a.next_state(15, now=2.0, reserve=15, relaunch_at=None) is None  # relaunch = false: it stays down
    a.vehicle.lost = True  # rebooting on its new battery
    assert a.next_state(15, now=3.0, reserve=15, relaunch_at=30) is None
    a.vehicle.lost = False
    assert a.next_state(15, now=4.0, reserve=15, relaunch_at=30) == (State.REJOIN, {"relaunch": True, "battery": 100})
    # armed in a pilot's mode on the way home: the pilot's, never relaunched
    b = agent(State.LOW_BATTERY, battery_remaining=20, mode="RTL")
    assert b.next_state(15, now=0.0, reserve=15, relaunch_at=30) is None  # its return, as sent
    b.vehicle.mode = "LOITER"
    assert b.next_state(15, now=1.0, reserve=15, relaunch_at=30) == (
        State.OVERRIDE,
        {"mode": "LOITER", "reason": "pilot"},
    )


def test_the_mock_swaps_its_battery_only_landed_and_disarmed():
    mock = MockAutopilot(sysid=1, connect="udpout:127.0.0.1:9")  # not started: its state only
    mock.battery, mock.armed, mock.rel_alt = 20.0, True, 30.0
    assert mock.swap_battery() is False and mock.battery == 20.0
    mock.armed, mock.rel_alt = False, 0.0
    assert mock.swap_battery() is True and mock.battery == 100.0 and mock._reboot_pending
    with pytest.raises(ValueError):
        mock.swap_battery(120.0)


# --- a mission ---------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_a_vehicle_home_on_low_battery_gets_a_fresh_one_rejoins_and_searches_on(tmp_path):
    grid = small_grid(40, 40)
    with SimSwarm(grid, uavs=2, seed=2, speedup=60.0, carry_detectors=False) as swarm:
        plan = swarm.plan(
            "frontier", end_action="land", time_limit=120.0, step_period=0.2, takeoff_at_once=2, end_timeout=0.0
        )
        weak = swarm.mocks[1]
        weak.battery_drain = 0.4  # % per simulated second: a worn battery, ...
        weak.battery = 65.0  # ... not quite full
        visited_before: set[tuple[int, int]] = set()

        async def swap_and_watch(controller):
            a = controller.agents[1]
            await wait_for(lambda: a.state == "low battery", 60, "uav2 to be sent home")
            await wait_for(lambda: weak.landed_disarmed, 60, "uav2 to land at home")
            visited_before.update(a.visited)
            weak.battery_drain = 0.08  # a good battery
            assert weak.swap_battery(downtime=0.1)
            await wait_for(lambda: a.state == "search", 60, "uav2 to rejoin")
            await wait_for(lambda: len(set(a.visited) - visited_before) >= 2, 60, "uav2 to search new cells")
            controller.stop()

        controller, outcome = fly(plan, tmp_path, during=swap_and_watch)
        modes = [m.mode_name for m in swarm.mocks]
    assert outcome == "interrupted"
    # every vehicle's end action, sent (its landing not waited for: end_timeout = 0)
    assert all(a.end_action == "land" and a.end_state == "landing" for a in controller.agents), [
        (a.end_action, a.end_state) for a in controller.agents
    ]
    assert modes == ["LAND", "LAND"]
    events = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    for e in events:
        check_event(e, strict=True)  # the new figures are in the recording's schema
    states = [e for e in events if e["event"] == "state" and e["vehicle"] == "uav2"]
    names = [e["state"] for e in states]
    at = names.index("low battery")
    assert names[at : at + 3] == ["low battery", "rejoin", "search"] and names[-1] == "ended", names
    low, rejoin, back = states[at : at + 3]
    assert low["reason"] == "energy" and low["needed"] > low["battery"] >= 15, low  # home before the floor
    assert {"distance_m", "rate", "seconds_home"} <= low.keys()
    assert rejoin["relaunch"] is True and rejoin["battery"] >= 30 and back["rejoined"] is True
    assert [e["vehicle"] for e in events if e["event"] == "end_action"] == ["uav1", "uav2"]
