"""Whole missions through `swarmctl fly` against real ArduCopter and PX4 SITL (tests/sitl_fly.py).

Every scenario the selected tests need is flown at once when the first of them asks (the `flights`
fixture), each on instance numbers of its own, so the module's wall time is about
that of its longest scenarios rather than their sum. ArduCopter runs at x5 (its timings scale exactly,
docs/mavlink.md); the search is kept short (CI asserts >= 3 distinct cells per vehicle; the 90 s figure
is tools/sitl_search.py's). Skipped with the reason when a binary is missing (ARDUPILOT_SITL, PX4_SITL).
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.mission_support import small_grid
from tests.sitl_fly import (
    ARDUCOPTER,
    MIXED,
    PX4_PAIR,
    TRIO,
    Craft,
    Flight,
    FlightResult,
    Flights,
    Scenario,
    Unavailable,
    within,
)

pytestmark = pytest.mark.sitl

HOME_M = 3.0  # "landed at home": within this of the home the autopilot reports (RTL lands 0.02-0.7 m off)
MIN_CELLS = 3  # distinct cells per vehicle in CI's short search (kept short for CI's time)
# the PX4 pair's 40 s search, steered in OFFBOARD: 10 distinct cells each (tools/sitl_search.py --swarm px4
# --time-limit 40; rounds of 3.2-11 s); in HOLD with repositions and a 3-D reach it was 4-5 (rounds of 6-22 s)
PX4_MIN_CELLS = 7
FOV = 3  # the planners' sensing radius in cells (the mission's footprint)
DDQL = "ddql:models/obstacles-3uav.pt:straggler=frontier"
COVERED_GRID = small_grid(6, 6)
COVERED_LKP = COVERED_GRID.cell_to_latlon(1, 1)  # the parallel track's last known point, inside its area


def kill_then_terminate(victim: str, survivors: list[str], steps_after: int = 3):
    """While fly flies: once everyone searches, SIGKILL `victim`'s simulator; once the survivors have made
    `steps_after` more decisions each and the controller has marked the victim lost, SIGTERM fly."""

    def during(flight: Flight) -> None:
        everyone = [victim, *survivors]
        flight.wait(lambda: flight.searching(everyone, steps=2), 240, "every vehicle searching")
        before = {n: flight.steps(n) for n in survivors}
        flight.kill(victim)
        flight.wait(lambda: "lost" in flight.states(victim), 60, f"{victim} marked lost")
        flight.mark(f"{victim} lost")
        flight.wait(
            lambda: all(flight.steps(n) >= before[n] + steps_after for n in survivors),
            60,
            f"{steps_after} more steps of {survivors} after the kill",
        )
        flight.mark("survivors carried on")
        flight.terminate()

    return during


SCENARIOS = {
    s.name: s
    for s in [
        Scenario("trio", TRIO, time_limit=20.0),
        Scenario("trio-ddql", TRIO, time_limit=20.0, policy=DDQL),
        Scenario("detector", [Craft("alpha", ARDUCOPTER, (0, 0), detector=True)], time_limit=40.0, targets=((3, 3),)),
        # a finish line of the mission file: a 6 x 6 grid (a 2 x 2 block in the middle) covered ends it, the
        # vehicles flying a parallel track (lanes 30 m apart, one each) from a last known point
        Scenario(
            "covered",
            [Craft("alpha", ARDUCOPTER, (0, 0)), Craft("bravo", ARDUCOPTER, (2, 0))],
            time_limit=120.0,
            end_action="land",
            policy="pattern:parallel",
            grid=COVERED_GRID,
            mission={"finish": '"covered"', "lkp": f"[{COVERED_LKP[0]!r}, {COVERED_LKP[1]!r}]", "spacing_m": "30.0"},
        ),
        # the kill scenarios end by SIGTERM; the time limit only bounds a search whose vehicles come up late
        Scenario("kill", TRIO, time_limit=300.0, during=kill_then_terminate("charlie", ["alpha", "bravo"])),
        # the policy raises in the search's third round: the mission stops there, the vehicle comes home
        Scenario("fault", [Craft("alpha", ARDUCOPTER, (0, 0))], time_limit=60.0, fault="policy"),
        Scenario("px4-pair", PX4_PAIR, time_limit=40.0),
        Scenario("mixed", MIXED, time_limit=40.0),
        Scenario(
            "px4-kill",
            PX4_PAIR,
            time_limit=300.0,
            during=kill_then_terminate("quebec", ["papa"]),
        ),
    ]
}


@pytest.fixture(scope="module")
def flights(request):
    """Every scenario named by a selected test's `scenario` marker, flown at once."""
    wanted = []
    for item in request.session.items:
        marker = item.get_closest_marker("scenario")
        if marker is not None and marker.args[0] not in wanted:
            wanted.append(marker.args[0])
    with Flights([SCENARIOS[name] for name in wanted]) as running:
        yield running
    reporter = request.config.pluginmanager.get_plugin("terminalreporter")
    capture = request.config.pluginmanager.get_plugin("capturemanager")
    if reporter is not None and capture is not None:  # the CI budget's figures: each scenario's wall time
        with capture.global_and_fixture_disabled():
            reporter.write_line("")
            for name in wanted:
                reporter.write_line(f"SITL scenario {name}: {running.timing(name)}")


def flown(flights: Flights, name: str) -> FlightResult:
    try:
        return flights.result(name)
    except Unavailable as exc:
        pytest.skip(str(exc))


def footprint(cells: set[tuple[int, int]], shape: tuple[int, int]) -> np.ndarray:
    """The cells within FOV of any of `cells` (what the vehicle's own sensor covered)."""
    xs, ys = np.indices(shape)
    covered = np.zeros(shape, dtype=bool)
    for x, y in cells:
        covered |= (xs - x) ** 2 + (ys - y) ** 2 <= FOV**2
    return covered


def assert_searched_shared_and_home(r: FlightResult, names: list[str], min_cells: int = MIN_CELLS) -> None:
    """Each vehicle flew >= `min_cells` distinct cells of its own, learnt cells only the others flew over
    (their knowledge crossed), got its end action and stands landed near home."""
    shape = (r.grid.width, r.grid.height)
    cells = {n: r.cells(n) for n in names}
    for n in names:
        assert len(cells[n]) >= min_cells, r.describe()
        others = set().union(*(cells[m] for m in names if m != n))
        assert cells[n] - others, f"{n} flew only cells the others flew\n{r.describe()}"
        assert r.vehicle(n)["knowledge_received"] > 0, r.describe()
        # cells the others' sensors covered and its own never did, marked explored in its knowledge
        learnt = r.explored(n) & ~footprint(cells[n], shape)
        assert learnt.sum() >= 5, f"{n} learnt {learnt.sum()} cells from the others\n{r.describe()}"
    assert r.end_actions() == {n: r.scenario.end_action for n in names}, r.describe()
    for n in names:
        assert r.vehicle(n)["end_state"] == "landed at home", r.describe()
        assert within(HOME_M, r.landings[n]), f"{n}: {r.landings[n]}\n{r.describe()}"


def assert_lost_and_interrupted(r: FlightResult, victim: str, survivors: list[str]) -> None:
    """fly exited 130 on SIGTERM after the survivors had carried on without the killed `victim`, which the
    summary records as lost; every survivor got its end action and stands landed near home."""
    assert r.rc == 130 and r.summary["outcome"] == "interrupted", r.describe()
    assert r.marks["survivors carried on"] <= r.marks["SIGTERM"], r.describe()
    assert r.vehicle(victim)["final_state"] == "lost", r.describe()
    assert r.end_actions().keys() >= set(survivors), r.describe()
    for n in survivors:
        assert r.vehicle(n)["end_state"] == "landed at home", r.describe()
        assert within(HOME_M, r.landings[n]), f"{n}: {r.landings[n]}\n{r.describe()}"


# --- ArduCopter ----------------------------------------------------------------------------------------------


@pytest.mark.scenario("trio")
def test_three_arducopters_frontier_search_distinct_cells_share_knowledge_and_come_home(flights):
    r = flown(flights, "trio")
    # a coverage search (no detector) runs to its time limit: fly's documented exit status 1
    assert (r.rc, r.summary["outcome"]) == (1, "time limit"), r.describe()
    assert_searched_shared_and_home(r, ["alpha", "bravo", "charlie"])
    assert all(v["error"] is None and v["step_timeouts"] == 0 for v in r.summary["vehicles"]), r.describe()


@pytest.mark.scenario("trio-ddql")
def test_three_arducopters_with_the_ddql_model_search_share_and_come_home(flights):
    r = flown(flights, "trio-ddql")
    assert (r.rc, r.summary["outcome"]) == (1, "time limit"), r.describe()
    assert r.summary["policy"].startswith("ddql:"), r.describe()
    assert_searched_shared_and_home(r, ["alpha", "bravo", "charlie"])


@pytest.mark.scenario("detector")
def test_a_detector_fed_the_real_position_finds_the_target_and_the_vehicle_hovers_on_it(flights):
    r = flown(flights, "detector")
    assert (r.rc, r.summary["outcome"]) == (0, "complete"), r.describe()
    assert [tuple(c) for c in r.summary["vehicles_on_targets"]] == [(3, 3)], r.describe()
    assert [tuple(t["cell"]) for t in r.summary["targets_found"]] == [(3, 3)], r.describe()
    assert r.vehicle("alpha")["sensor_reports"] > 0, r.describe()
    assert within(HOME_M, r.landings["alpha"]), r.describe()


@pytest.mark.scenario("covered")
def test_two_arducopters_end_a_covered_search_complete_once_every_reachable_cell_is_explored(flights):
    r = flown(flights, "covered")
    assert (r.rc, r.summary["outcome"]) == (0, "complete"), r.describe()
    assert r.summary["policy"] == "pattern:parallel", r.describe()
    assert r.summary["finish"] == {"rule": "covered", "expected_targets": None, "on_find": "hold", "met": True}
    assert r.summary["covered_fraction"] == 1.0, r.describe()
    assert r.summary["search_time_s"] < r.scenario.time_limit, r.describe()  # the finish line ended it
    assert r.end_actions() == {"alpha": "land", "bravo": "land"}, r.describe()
    for n in ("alpha", "bravo"):
        assert r.vehicle(n)["end_state"] == "landed", r.describe()
        assert r.landings[n] is not None and not r.landings[n].armed, r.describe()


@pytest.mark.scenario("fault")
def test_a_fault_in_the_policy_mid_search_still_brings_the_arducopter_home_and_says_where(flights):
    r = flown(flights, "fault")
    assert (r.rc, r.summary["outcome"]) == (1, "failed"), r.describe()
    fault = r.summary["fault"]
    assert fault["part"] == "mission" and fault["error"].startswith("Injected"), r.describe()
    assert [e["where"] for e in r.events if e["event"] == "fault"] == [fault["where"]], r.describe()
    assert "unexpected error" in r.output and "Traceback" not in r.output, r.describe()
    assert r.end_actions() == {"alpha": "rtl"}, r.describe()
    assert r.vehicle("alpha")["end_state"] == "landed at home", r.describe()
    assert within(HOME_M, r.landings["alpha"]), r.describe()


@pytest.mark.scenario("kill")
def test_an_arducopter_killed_mid_mission_the_others_carry_on_and_sigterm_ends_with_130(flights):
    assert_lost_and_interrupted(flown(flights, "kill"), "charlie", ["alpha", "bravo"])


# --- PX4 -----------------------------------------------------------------------------------------------------


@pytest.mark.scenario("px4-pair")
def test_two_px4_vehicles_search_distinct_cells_share_knowledge_and_come_home(flights):
    r = flown(flights, "px4-pair")
    assert (r.rc, r.summary["outcome"]) == (1, "time limit"), r.describe()
    # steered in OFFBOARD, at the pace of its speed limits: no step waited for its timeout
    assert all(v["error"] is None and v["step_timeouts"] == 0 for v in r.summary["vehicles"]), r.describe()
    assert_searched_shared_and_home(r, ["papa", "quebec"], min_cells=PX4_MIN_CELLS)


@pytest.mark.scenario("mixed")
def test_a_mixed_swarm_of_px4_and_arducopter_searches_shares_and_comes_home(flights):
    r = flown(flights, "mixed")
    assert (r.rc, r.summary["outcome"]) == (1, "time limit"), r.describe()
    assert {v["name"]: v["autopilot"] for v in r.summary["vehicles"]} == {
        "papa": "px4",
        "alpha": "ardupilot",
        "bravo": "ardupilot",
    }, r.describe()
    assert_searched_shared_and_home(r, ["papa", "alpha", "bravo"])


@pytest.mark.scenario("px4-kill")
def test_a_px4_killed_mid_mission_the_other_carries_on_and_sigterm_ends_with_130(flights):
    assert_lost_and_interrupted(flown(flights, "px4-kill"), "quebec", ["papa"])


# --- the harness ---------------------------------------------------------------------------------------------


def test_the_pool_hands_each_number_to_one_scenario_and_a_wait_for_more_than_are_free_ends(monkeypatch):
    import threading

    from tests import sitl_fly

    monkeypatch.setattr(sitl_fly, "arducopter_busy", lambda n: "busy" if n == 4 else None)  # another program's
    monkeypatch.setattr(sitl_fly, "instance_busy", lambda n: None)
    pool, stopping = sitl_fly.InstancePool(), threading.Event()
    with pool.hold(2, 1, stopping, timeout=5.0) as (ac, px4):
        with pool.hold(2, 1, stopping, timeout=5.0) as (ac2, px42):
            assert (ac, ac2, px4, px42) == ([0, 1], [2, 3], [5], [6])
        with pytest.raises(sitl_fly.SitlError, match=r"free after 0.3 s: ArduCopter \[2, 3\]"):
            with pool.hold(3, 0, stopping, timeout=0.3):
                pass
    with pool.hold(4, 0, stopping, timeout=5.0) as (again, _):
        assert again == [0, 1, 2, 3]  # released numbers are handed out again; 4 stays another program's
