"""The controller's parts on their own, without a flight: each built with only what it needs (hand-made
agents, vehicles and a recorder that keeps its events in a list) and checked on the rules it owns."""

from __future__ import annotations

import asyncio
import time
from types import SimpleNamespace

import numpy as np
import pytest

from swarmctl.errors import InputError
from swarmctl.knowledge.model import Knowledge, Position
from swarmctl.mavlink.codec import ne_m
from swarmctl.mission.agent import Agent, State
from swarmctl.mission.crew import Crew
from swarmctl.mission.decide import FieldPolicy
from swarmctl.mission.ending import Ending
from swarmctl.mission.launch import Launch
from swarmctl.mission.rounds import Rounds
from swarmctl.mission.spec import BatteryTable, VehicleSpec
from swarmctl.mission.state import MissionState
from swarmctl.mission.watch import NOT_COMMANDED, Watch
from swarmctl.policy.hover import OUT_OF_TOUCH_STEPS
from tests.mavlink_support import run
from tests.mission_support import small_grid

GRID = small_grid()


class Events:
    """A recorder that keeps its events (name, fields) in a list."""

    def __init__(self) -> None:
        self.events: list[tuple[str, dict]] = []

    def event(self, name: str, **fields) -> None:
        self.events.append((name, fields))

    def named(self, name: str) -> list[dict]:
        return [f for n, f in self.events if n == name]


class Vehicle:
    """What the parts read of a vehicle, and what they send it."""

    def __init__(self, armed: bool = True) -> None:
        self.armed, self.lost, self.silenced, self.mode = armed, False, None, "GUIDED"
        self.position = None
        self.autopilot_info = None
        self.battery_remaining: int | None = 90
        self.sent: list[tuple] = []

    async def goto(self, lat: float, lon: float, alt: float) -> None:
        self.sent.append(("goto", round(lat, 7), round(lon, 7), alt))

    async def land(self) -> None:
        self.sent.append(("land",))

    async def rtl(self) -> None:
        self.sent.append(("rtl",))

    async def wait_landed(self, seconds: float) -> None:
        self.sent.append(("wait_landed",))


def agent(index: int, state: State = State.SEARCH, cell: tuple[int, int] | None = (0, 0)) -> Agent:
    spec = VehicleSpec(name=f"uav{index + 1}", connection=f"udpin:127.0.0.1:{14551 + index}", sysid=index + 1)
    knowledge = Knowledge(GRID.width, GRID.height, index)
    exchange = SimpleNamespace(knowledge=knowledge, step=lambda *a: None, merged=lambda: 0)
    a = Agent(index, spec, Vehicle(), exchange, feed=None)
    a.state, a.cell = state, cell
    return a


def crew(*agents: Agent, vehicles: int | None = None, only: list[int] | None = None) -> Crew:
    c = Crew(vehicles if vehicles is not None else len(agents), only, Events())
    c.agents.extend(agents)
    return c


# --- MissionState ----------------------------------------------------------------------------------------


def test_a_stop_cancels_what_waits_for_it_and_keeps_the_first_refusal():
    async def scenario():
        state = MissionState()
        started = asyncio.Event()

        async def forever():
            started.set()
            await asyncio.Event().wait()

        waiting = asyncio.ensure_future(state.until_stopped(forever()))
        await started.wait()
        state.fail(InputError("first"))
        state.fail(InputError("second"))
        return state, await asyncio.wait_for(waiting, 5)

    state, result = run(scenario())
    assert result is None and state.stopping
    assert str(state.mission_error) == "first" and state.outcome == "failed"


def test_the_operators_pause_holds_a_waiter_until_resume_or_stop_and_leaves_the_clock_out():
    """What a rejoining vehicle waits on (Launch.rejoin): the pause, not a round."""

    async def scenario():
        state = MissionState()
        state.search_started = time.monotonic()
        await asyncio.wait_for(state.while_held(), 1)  # not paused: at once
        assert state.hold() and not state.hold()
        waiter = asyncio.ensure_future(state.while_held(poll=0.01))
        await asyncio.sleep(0.5)
        held = not waiter.done()
        assert state.resume() and not state.resume()
        await asyncio.wait_for(waiter, 1)
        clock = state.search_seconds()
        state.hold()
        stopped = asyncio.ensure_future(state.while_held(poll=0.01))
        state.stop()
        await asyncio.wait_for(stopped, 1)
        return held, clock

    held, clock = run(scenario())
    assert held and clock < 0.5  # the 0.5 s paused is not search time


def test_spawned_tasks_are_kept_until_done_and_the_late_ones_cancelled_at_the_end():
    async def scenario():
        state = MissionState()
        quick = state.spawn(asyncio.sleep(0), "quick")
        slow = state.spawn(asyncio.sleep(3600), "slow")
        await state.settle_tasks(seconds=0.2)
        return state, quick, slow

    state, quick, slow = run(scenario())
    assert quick.done() and not quick.cancelled() and slow.cancelled()
    assert state.tasks == set()


def test_the_search_clock_stops_when_the_mission_ends():
    state = MissionState()
    assert state.search_seconds() == 0.0
    state.search_started = time.monotonic() - 10.0
    state.ended = state.search_started + 4.0
    assert state.search_seconds() == pytest.approx(4.0)


# --- Crew ------------------------------------------------------------------------------------------------


def test_ground_mode_holds_its_agents_cells_but_not_the_failed_ones_or_the_excluded():
    a, b, c = agent(0, cell=(1, 1)), agent(1, cell=(2, 2)), agent(2, State.FAILED, cell=(3, 3))
    swarm = crew(a, b, c)
    assert swarm.held() == {(1, 1), (2, 2)}
    assert swarm.held(exclude=a) == {(2, 2)}
    assert swarm.ours(2) and not swarm.ours(3) and not swarm.ours(-1)


def test_onboard_the_others_are_known_from_the_knowledge_channel():
    mine = agent(0, cell=(1, 1))
    swarm = crew(mine, vehicles=3, only=[0])
    assert not swarm.others_hovering()  # vehicles 1 and 2 never heard of
    mine.knowledge.merge_position(1, Position(4, (5, 5), on_target=True))
    mine.knowledge.merge_position(2, Position(4, (6, 6), on_target=False))
    assert swarm.held() == {(1, 1), (5, 5), (6, 6)}
    assert swarm.held_targets() == {(5, 5)}
    assert not swarm.others_hovering()  # vehicle 2 still searches
    mine.knowledge.merge_position(2, Position(5, (6, 6), on_target=True))
    assert swarm.others_hovering() and swarm.held_targets() == {(5, 5), (6, 6)}


def test_a_transition_is_recorded_once_and_an_illegal_one_refused():
    a = agent(0, State.SEARCH)
    swarm = crew(a)
    swarm.enter(a, State.HOVER)
    swarm.enter(a, State.HOVER)  # no change, nothing to record
    assert [e["state"] for e in swarm.rec.named("state")] == [State.HOVER]
    with pytest.raises(Exception, match="no transition"):
        swarm.enter(a, State.TAKEOFF)


# --- Watch -----------------------------------------------------------------------------------------------


def at(cell: tuple[int, int], north_m: float = 0.0, alt: float = 40.0):
    """A position report `north_m` metres north of the cell's centre."""
    lat, lon = GRID.cell_to_latlon(*cell)
    dlat = north_m / 111_320.0
    assert abs(ne_m(lat, lon, lat + dlat, lon)[0] - north_m) < 1.0
    return SimpleNamespace(lat=lat + dlat, lon=lon, rel_alt=alt)


def test_a_vehicle_held_off_course_is_flagged_resent_then_taken_as_not_commanded():
    a = agent(0, cell=(2, 2))
    swarm = crew(a)
    state = MissionState()
    limits = SimpleNamespace(off_course_m=15.0, below_altitude_m=10.0, off_course_rounds=2)
    guard = SimpleNamespace(setpoint_altitude=lambda: 40.0)
    watch = Watch(GRID, guard, limits, swarm.rec, state, swarm)
    a.vehicle.position = at((2, 2))
    run(watch.check())  # on course: nothing
    assert a.alarm is None and a.vehicle.sent == []
    a.vehicle.position = at((2, 2), north_m=60.0)  # pushed away by someone else's setpoint
    run(watch.check())
    assert a.alarm is not None and a.alarm.startswith(NOT_COMMANDED) and a.off_course == 1
    assert len(a.vehicle.sent) == 1 and a.vehicle.sent[0][0] == "goto"  # its setpoint again
    run(watch.check())
    run(watch.check())  # the third round in a row: taken over
    assert a.state is State.OVERRIDE and a.override_reason == NOT_COMMANDED and a.cell is None
    assert [e.get("rounds") for e in swarm.rec.named("off_course")] == [1, 2]


def test_a_vehicle_back_on_course_clears_its_alarm():
    a = agent(0, cell=(2, 2))
    swarm = crew(a)
    limits = SimpleNamespace(off_course_m=15.0, below_altitude_m=10.0, off_course_rounds=5)
    watch = Watch(GRID, SimpleNamespace(setpoint_altitude=lambda: 40.0), limits, swarm.rec, MissionState(), swarm)
    a.vehicle.position = at((2, 2))
    run(watch.check())
    a.vehicle.position = at((2, 2), north_m=60.0)
    run(watch.check())
    a.vehicle.position = at((2, 2))
    run(watch.check())
    assert a.alarm is None and a.off_course == 0
    assert swarm.rec.named("off_course")[-1]["cleared"] is True


# --- Rounds: when the search ends, and who parks ---------------------------------------------------------


def rounds(
    swarm: Crew, *, classic: bool = True, parks: bool = True, time_limit: float = 60.0, hover: str = "defer"
) -> Rounds:
    state = MissionState()
    state.search_started = time.monotonic()
    finish = SimpleNamespace(classic=classic, marks=False, check=lambda: None)
    policy = SimpleNamespace(parks=lambda known, vehicles, out_of_touch=0: parks, hover=hover)
    timing = SimpleNamespace(time_limit=time_limit)
    battery = BatteryTable(return_below=20)
    return Rounds(timing, battery, policy, None, swarm.rec, state, swarm, None, None, None, finish)


def test_the_search_is_complete_when_every_vehicle_hovers_on_its_own_target():
    a, b = agent(0, State.HOVER, (1, 1)), agent(1, State.HOVER, (2, 2))
    assert rounds(crew(a, b)).ended() == "complete"
    b.state = State.FAILED
    assert rounds(crew(a, b)).ended() == "partial"  # one dropped out
    b.state, b.cell = State.SEARCH, (3, 3)
    assert rounds(crew(a, b)).ended() is None
    assert rounds(crew(a, b), time_limit=-1.0).ended() == "time limit"
    a.state = b.state = State.FAILED
    assert rounds(crew(a, b)).ended() == "failed"


def test_a_stop_interrupts_whatever_else_holds():
    r = rounds(crew(agent(0, State.HOVER, (1, 1))))
    r.state.stop()
    assert r.ended() == "interrupted"


def test_a_vehicle_on_a_known_target_parks_when_the_hover_rule_lets_it_and_nobody_holds_it():
    a, b = agent(0, State.SEARCH, (1, 1)), agent(1, State.SEARCH, (2, 2))
    for x in (a, b):
        x.knowledge.add_targets(np.array([[1, 1]]), step=1)
    rounds(crew(a, b), parks=False).update_states()
    assert a.state is State.SEARCH  # the rule defers the hover
    rounds(crew(a, b), parks=True).update_states()
    assert a.state is State.HOVER and b.state is State.SEARCH


@pytest.mark.parametrize("c_state", [State.FAILED, State.TAKEOFF])
def test_a_teammate_gone_silent_is_not_waited_for_one_taking_off_is(c_state):
    """Under defer a vehicle of three on the one target two know of parks only when the third has gone
    silent (failed, its last report OUT_OF_TOUCH_STEPS rounds old), not while it is taking off."""
    a, b, c = agent(0, State.SEARCH, (1, 1)), agent(1, State.SEARCH, (2, 2)), agent(2, c_state, None)
    r = rounds(crew(a, b, c))
    r.policy = FieldPolicy("coordinated")
    r.state.step = 1 + OUT_OF_TOUCH_STEPS + 1
    a.knowledge.set_position(r.state.step, (1, 1))
    a.knowledge.merge_position(1, Position(r.state.step, (2, 2), False))
    a.knowledge.merge_position(2, Position(1, (4, 4), False))  # c's last report
    a.knowledge.add_targets(np.array([[1, 1], [3, 3]]), step=1)
    r.update_states()
    assert r.out_of_touch(a) == (1 if c_state is State.FAILED else 0)
    assert a.state is (State.HOVER if c_state is State.FAILED else State.SEARCH)


def test_under_the_hover_rule_no_the_swarm_holds_once_every_vehicle_sits_on_a_target_of_its_own():
    a, b = agent(0, State.SEARCH, (1, 1)), agent(1, State.SEARCH, (2, 2))
    for x in (a, b):
        x.knowledge.add_targets(np.array([[1, 1], [3, 3]]), step=1)
    r = rounds(crew(a, b), parks=False, hover="no")
    r.update_states()
    assert a.state is State.SEARCH and b.state is State.SEARCH  # b is on no target: nobody parks on the way
    b.cell = (3, 3)
    r.update_states()
    assert a.state is State.HOVER and b.state is State.HOVER  # both on targets of their own: held
    assert r.ended() == "complete"
    c, d = agent(0, State.SEARCH, (1, 1)), agent(1, State.SEARCH, (1, 1))
    for x in (c, d):
        x.knowledge.add_targets(np.array([[1, 1]]), step=1)
    rounds(crew(c, d), parks=False, hover="no").update_states()
    assert c.state is State.SEARCH and d.state is State.SEARCH  # one target for two: not held


# --- Ending ----------------------------------------------------------------------------------------------


def test_end_actions_by_state():
    searching, hovering = agent(0, State.SEARCH), agent(1, State.HOVER, (1, 1))
    lost, low = agent(2, State.LOST), agent(3, State.LOW_BATTERY)
    lost.vehicle.lost = True
    on_ground = agent(4, State.PREFLIGHT)
    on_ground.vehicle.armed = False
    swarm = crew(searching, hovering, lost, low, on_ground)
    timing = SimpleNamespace(end_timeout=0.0)
    run(Ending("hover", 40.0, timing, swarm.rec, swarm).all())
    assert searching.end_action == "rtl" and searching.vehicle.sent == [("rtl",)]  # only targets hold
    assert hovering.end_action == "hover" and hovering.vehicle.sent == []
    assert hovering.end_state == "hovering on target"
    assert lost.end_action is None and lost.end_state == "lost (left to its failsafe)"
    assert low.end_action == "rtl"
    assert on_ground.end_state == State.PREFLIGHT and on_ground.vehicle.sent == []
    recorded = {e["vehicle"]: e["action"] for e in swarm.rec.named("end_action")}
    assert recorded == {"uav1": "rtl", "uav2": "hover", "uav3": "none: link lost", "uav4": "rtl"}


def test_a_vehicle_whose_command_fails_does_not_keep_the_others_from_theirs():
    broken, fine = agent(0, State.SEARCH), agent(1, State.SEARCH)

    async def refuse() -> None:
        raise RuntimeError("driver bug")

    broken.vehicle.land = refuse
    swarm = crew(broken, fine)
    run(Ending("land", 40.0, SimpleNamespace(end_timeout=0.0), swarm.rec, swarm).all())
    assert fine.vehicle.sent == [("land",)] and fine.state is State.ENDED
    assert broken.end_state.startswith("end action failed: unexpected RuntimeError")


# --- Launch ----------------------------------------------------------------------------------------------


def test_a_refused_vehicle_fails_and_stops_the_mission_with_its_reason():
    a = agent(0, State.PREFLIGHT)
    swarm = crew(a)
    state = MissionState()
    plan = SimpleNamespace(spec=SimpleNamespace(flight=SimpleNamespace(takeoff_at_once=1)))
    launch = Launch(plan, None, None, swarm.rec, state, swarm, None)
    launch.refuse(a, InputError("uav1: FS_GCS_ENABLE is 0"))
    assert a.state is State.FAILED and state.stopping and state.outcome == "failed"
    assert str(state.mission_error) == "uav1: FS_GCS_ENABLE is 0"


def test_a_preflight_note_repeated_soon_is_shown_once():
    a = agent(0, State.PREFLIGHT)
    swarm = crew(a)
    shown = []
    plan = SimpleNamespace(spec=SimpleNamespace(flight=SimpleNamespace(takeoff_at_once=1)))
    launch = Launch(plan, None, None, swarm.rec, MissionState(), swarm, None, show=lambda: shown.append(1))
    for text in ("waiting for GPS", "waiting for GPS", "ready"):
        launch.note(a, text)
    assert [e["text"] for e in swarm.rec.named("preflight")] == ["waiting for GPS", "ready"]
    assert a.status == "ready" and len(shown) == 2


# --- a link that comes back ------------------------------------------------------------------------------


def back_from_a_loss(mode: str) -> tuple[Agent, tuple]:
    from swarmctl.mavlink.autopilots.descriptions import ARDUPILOT

    a = agent(0, State.SEARCH, (2, 2))
    a.vehicle.autopilot_info = ARDUPILOT
    a.vehicle.lost = True
    assert a.next_state(20, now=100.0)[0] is State.LOST
    a.enter(State.LOST)
    a.vehicle.lost, a.vehicle.mode = False, mode
    a.vehicle.position = SimpleNamespace(lat=41.88, lon=-87.63, rel_alt=12.04)
    return a, a.next_state(20, now=108.1)


def test_a_vehicle_back_in_its_failsafe_mode_rejoins_and_says_what_it_found():
    a, (state, found) = back_from_a_loss("RTL")
    assert state is State.REJOIN
    assert found == dict(mode="RTL", armed=True, position=[41.88, -87.63, 12.0], lost_s=8.1)
    assert a.status == "link back after 8.1 s: RTL, armed, 12 m above home; rejoining"


def test_a_vehicle_back_in_a_mode_a_pilot_chose_is_left_to_the_pilot():
    a, (state, found) = back_from_a_loss("LOITER")
    assert state is State.OVERRIDE and found["reason"] == "pilot" and found["mode"] == "LOITER"
    assert a.override_reason == "pilot" and a.status.endswith("left to the pilot")
    a.enter(state)  # a transition the state machine has


def test_an_end_action_not_waited_for_is_not_called_hovering():
    searching, landing = agent(0, State.SEARCH), agent(1, State.SEARCH)
    swarm = crew(searching)
    run(Ending("rtl", 40.0, SimpleNamespace(end_timeout=0.0), swarm.rec, swarm).all())
    assert searching.end_state == "returning home"
    swarm = crew(landing)
    run(Ending("land", 40.0, SimpleNamespace(end_timeout=0.0), swarm.rec, swarm).all())
    assert landing.end_state == "landing"


def test_the_sensor_feed_keeps_the_latest_reports_of_the_last_cells_only():
    from swarmctl.knowledge.model import Delta
    from swarmctl.mission.detector import LATEST_CELLS_KEPT, SensorFeed

    feed = SensorFeed(0, 1, GRID.width, GRID.height)
    cells = [(x, y) for x in range(GRID.width) for y in range(GRID.height)][: LATEST_CELLS_KEPT + 5]
    for step, cell in enumerate(cells):
        feed.take(Delta(0, step, cell, cells=np.array([cell]), phi=np.array([255], dtype=np.uint8), obstacle=[False]))
    assert list(feed.latest) == cells[-LATEST_CELLS_KEPT:] and feed.reports == len(cells)
