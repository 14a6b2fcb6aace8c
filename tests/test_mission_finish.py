"""The finish line of a mission file ([mission] finish, expected_targets, on_find): the spec's grammar,
and missions flown over loopback with mock vehicles that end where their file says they should."""

from __future__ import annotations

import json
import socket
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from pymavlink import mavutil

from swarmctl.cli import main
from swarmctl.errors import EXIT_OK, InputError
from swarmctl.knowledge.model import Knowledge
from swarmctl.mission.crew import Crew
from swarmctl.mission.decide import FieldPolicy
from swarmctl.mission.events import check_event
from swarmctl.mission.finish import STATUSTEXT_CHARS, FinishLine, find_text
from swarmctl.mission.plan import make_plan
from swarmctl.mission.service import run_controller
from swarmctl.mission.spec import MissionSpec, VehicleSpec, load_spec
from swarmctl.mission.state import MissionState
from swarmctl.replay.recording import load as load_replay
from swarmctl.replay.tracks import write_tracks
from swarmctl.sim.swarm import SimSwarm
from tests.mission_support import small_grid, small_mission

FAST = dict(takeoff_at_once=4, end_timeout=0.0)  # all climb at once; the end action is not waited for


def events(folder) -> list[dict]:
    return [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]


# --- the grammar ---------------------------------------------------------------------------------------


def test_a_mission_file_without_the_keys_finishes_as_before(tmp_path):
    spec = load_spec(small_mission(tmp_path))
    m = spec.mission
    assert (m.finish, m.expected_targets, m.on_find) == ("held", None, "hold")
    plan = make_plan(spec)
    line = FinishLine(plan, Crew(len(spec.vehicles), None, rec=None), MissionState(), rec=None)
    assert line.classic and not line.marks and line.expected == 1  # the vehicle count


def test_the_keys_are_read(tmp_path):
    m = load_spec(small_mission(tmp_path, finish='"found"', expected_targets="2", on_find='"mark"')).mission
    assert (m.finish, m.expected_targets, m.on_find) == ("found", 2, "mark")


@pytest.mark.parametrize(
    "key, value, says",
    [
        (
            "finish",
            '"all"',
            'mission.finish = "all": must be held, found, covered or pos >= X (0 < X <= 1); write for example finish =',
        ),
        ("finish", "1", "mission.finish = 1: must be held, found, covered or pos >= X (0 < X <= 1)"),
        ("expected_targets", "0", "mission.expected_targets = 0: must be a whole number from 1 to 32768 (targets)"),
        ("expected_targets", "-3", "mission.expected_targets = -3: must be a whole number from 1"),
        ("expected_targets", "40000", "mission.expected_targets = 40000: must be a whole number from 1 to 32768"),
        ("expected_targets", "2.0", "mission.expected_targets = 2.0: must be a whole number"),
        ("expected_targets", '"2"', 'mission.expected_targets = "2": must be a whole number'),
        ("expected_targets", "true", "mission.expected_targets = true: must be a whole number"),
        ("on_find", '"hover"', 'mission.on_find = "hover": must be one of hold, mark; write for example on_find ='),
    ],
)
def test_bad_values_are_refused_in_one_line(tmp_path, key, value, says):
    extra = {key: value, **({"finish": '"found"'} if key != "finish" else {})}
    with pytest.raises(InputError) as exc:
        load_spec(small_mission(tmp_path, **extra))
    text = str(exc.value)
    assert says in text and "\n" not in text, text


def test_held_with_mark_is_refused_naming_the_key_and_the_fix(tmp_path):
    for extra in ({"on_find": '"mark"'}, {"finish": '"held"', "on_find": '"mark"'}):
        with pytest.raises(InputError) as exc:
            load_spec(small_mission(tmp_path, **extra))
        text = str(exc.value)
        assert "\n" not in text
        assert 'mission.on_find = "mark": contradicts finish = "held"' in text
        assert 'write finish = "found" or finish = "covered" with on_find = "mark", or on_find = "hold"' in text


def test_more_targets_to_hold_than_vehicles_or_to_find_than_free_cells_is_refused(tmp_path):
    with pytest.raises(InputError, match=r"mission.expected_targets = 2: is more than the 1 vehicle\(s\) listed"):
        load_spec(small_mission(tmp_path, expected_targets="2"))
    spec = load_spec(small_mission(tmp_path, finish='"found"', expected_targets="97"))  # 100 cells, 4 blocked
    with pytest.raises(InputError, match="expected_targets = 97: the grid has 96 free cells"):
        make_plan(spec)
    make_plan(load_spec(small_mission(tmp_path, finish='"found"', expected_targets="96")))


def test_built_specs_route_the_keys_and_demo_refuses_contradictions_naming_its_options(tmp_path, capsys):
    vehicle = VehicleSpec(name="a", connection="udpin:127.0.0.1:14551", sysid=1)
    spec = MissionSpec.build([vehicle], name="m", policy="frontier", finish="covered", on_find="mark")
    assert (spec.mission.finish, spec.mission.on_find) == ("covered", "mark")
    for argv, says in (
        (["--on-find", "mark"], "--on-find mark with the default finish held: a marking vehicle never hovers"),
        (["--finish", "held", "--expected-targets", "4", "--uavs", "3"], "--expected-targets 4: more than the 3"),
        (["--expected-targets", "0"], "Invalid value for '--expected-targets': 0 is not in the range 1<=x<=32768"),
        (["--finish", "some"], "--finish 'some': must be held, found, covered or pos >= X"),
    ):
        assert main(["demo", "--out", str(tmp_path / "never"), *argv]) == 2
        err = capsys.readouterr().err
        assert says in err and err.count("\n") == 1, err
    assert not (tmp_path / "never").exists()


def test_the_statustext_of_a_find_fits_mavlink():
    assert find_text(41.882930, -87.630998, "uav1") == "swarmctl: target at 41.88293,-87.63100 by uav1"
    assert find_text(1.5, 2.25, "a") == "swarmctl: target found at 1.50000,2.25000 by a"
    long = find_text(-33.123456, -151.123456, "a-vehicle-with-a-very-long-name")
    assert len(long) == STATUSTEXT_CHARS and long.startswith("target at -33.12346,-151.12346 by a-veh")


def test_with_mark_the_policy_is_not_drawn_back_to_a_target_already_found():
    """frontier sends a vehicle to a known target nobody holds; with the targets done it searches on."""
    kn = Knowledge(12, 12, vehicle_id=0)
    kn.set_position(1, (5, 5))
    cells = np.array([[x, y] for x in range(12) for y in range(2, 12)])  # all but the two southern rows
    kn.sense(cells, np.zeros(len(cells)), np.zeros(len(cells), dtype=bool))
    kn.add_targets(np.array([[5, 6]]), 1)  # the target north of it, found
    policy = FieldPolicy("frontier")
    assert policy.choose([kn], 1, 1)[0].move == 1  # north, onto the target
    beliefs = policy.beliefs([kn], 1, 1, targets_done=True)
    assert not beliefs.targets.any() and beliefs.phi_hat[0, 0, 5, 6] == 0.0
    assert policy.choose([kn], 1, 1, targets_done=True)[0].move == 3  # south, to the cells still unexplored


# --- flown with mock vehicles ----------------------------------------------------------------------------


@pytest.mark.slow
def test_covered_ends_complete_when_every_reachable_cell_is_explored(tmp_path):
    grid = small_grid(6, 6)  # 32 free cells round a 2 x 2 block
    with SimSwarm(grid, uavs=2, seed=1, speedup=30.0, carry_detectors=False) as swarm:
        plan = swarm.plan("frontier", end_action="land", time_limit=60.0, finish="covered", **FAST)
        code, summary = run_controller(plan, tmp_path, None)
    assert (code, summary["outcome"]) == (EXIT_OK, "complete"), summary
    assert summary["finish"] == {"rule": "covered", "expected_targets": None, "on_find": "hold", "met": True}
    assert summary["covered_fraction"] == 1.0 and summary["finds"] == [] and summary["targets_found"] == []
    assert summary["search_time_s"] < 30  # the finish line ended it, not the time limit
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert on_disk["finish"]["met"] and on_disk["covered_fraction"] == 1.0
    ev = events(tmp_path)
    assert [e["outcome"] for e in ev if e["event"] == "end"] == ["complete"]
    mission = next(e for e in ev if e["event"] == "mission")
    assert (mission["finish"], mission["expected_targets"], mission["on_find"]) == ("covered", None, "hold")
    for e in ev:
        check_event(e, strict=True)


def gcs_socket() -> socket.socket:
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    gcs.bind(("127.0.0.1", 0))
    gcs.setblocking(False)
    return gcs


def statustexts(data: list[bytes]) -> list:
    parser = mavutil.mavlink.MAVLink(None)
    return [m for d in data for m in parser.parse_buffer(d) or [] if m.get_type() == "STATUSTEXT"]


@pytest.mark.slow
def test_found_one_marked_ends_at_the_find_with_its_report_and_nobody_hovers(tmp_path, capsys):
    """`swarmctl demo --finish found --expected-targets 1 --on-find mark`: the find ends it (exit 0), in
    the summary, the events, a STATUSTEXT to the ground station and on the vehicle's link, the exports."""
    mission = small_mission(tmp_path)  # 10 x 10 cells
    out = tmp_path / "run"
    gcs = gcs_socket()
    argv = ["demo", "--mission", str(mission), "--uavs", "2", "--targets", "1", "--seed", "3", "--speedup", "30"]
    argv += ["--out", str(out), "--no-live", "--policy", "frontier", "--end-action", "land"]
    argv += ["--gcs", f"udpout:127.0.0.1:{gcs.getsockname()[1]}"]
    code = main([*argv, "--finish", "found", "--expected-targets", "1", "--on-find", "mark"])
    received = []
    while True:
        try:
            received.append(gcs.recv(65535))
        except BlockingIOError:
            break
    gcs.close()
    assert code == 0, capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "complete"
    assert summary["finish"] == {"rule": "found", "expected_targets": 1, "on_find": "mark", "met": True}
    [find] = summary["finds"]
    assert find["cell"] == summary["hidden_targets"][0] and find["vehicle"] in ("uav1", "uav2")
    assert 0 < find["time_s"] <= summary["search_time_s"] and find["step"] == summary["steps"]
    assert [t["cell"] for t in summary["targets_found"]] == [find["cell"]]
    assert summary["targets_found"][0]["time_s"] == find["time_s"]
    assert summary["vehicles_on_targets"] == []
    ev = events(out)
    assert not any(e["event"] == "state" and e["state"] == "hover" for e in ev)
    [event] = [e for e in ev if e["event"] == "find"]
    assert {k: event[k] for k in find} == find
    # the report: a STATUSTEXT (NOTICE) from the finder's system id and the agent's component
    sysid = int(find["vehicle"].removeprefix("uav"))
    text = find_text(find["lat"], find["lon"], find["vehicle"])
    to_gcs = [(m.get_srcSystem(), m.get_srcComponent(), m.severity, m.text) for m in statustexts(received)]
    assert (sysid, 191, mavutil.mavlink.MAV_SEVERITY_NOTICE, text) in to_gcs
    log = mavutil.mavlink_connection(str(out / "mission.tlog"))
    on_link = []
    while (m := log.recv_match(type="STATUSTEXT")) is not None:
        on_link.append((m.get_srcSystem(), m.get_srcComponent(), m.text))
    assert (sysid, 191, text) in on_link
    # the exports
    [point] = json.loads((out / "targets.geojson").read_text())["features"]
    assert point["properties"]["vehicle"] == find["vehicle"] and point["properties"]["found_s"] == find["time_s"]
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    [description] = ET.parse(out / "targets.kml").getroot().findall(".//k:Placemark/k:description", ns)
    assert f"by {find['vehicle']}, {find['time_s']:g} s into the search" in description.text
    assert "finish found 1, on find mark" in capsys.readouterr().err
    for e in ev:
        check_event(e, strict=True)
    # swarmctl replay's exports of the recording say who found it and when, too
    (tmp_path / "replayed").mkdir()
    write_tracks(load_replay(out), tmp_path / "replayed")
    [point] = json.loads((tmp_path / "replayed" / "targets.geojson").read_text())["features"]
    assert point["properties"]["vehicle"] == find["vehicle"] and point["properties"]["found_s"] == find["time_s"]


@pytest.mark.slow
def test_marking_vehicles_search_on_past_a_find_until_all_expected_are_found(tmp_path):
    grid = small_grid(12, 12)
    with SimSwarm(grid, uavs=2, seed=1, speedup=30.0, targets=[[11, 11], [0, 11]]) as swarm:
        plan = swarm.plan(
            "frontier", end_action="land", time_limit=60.0, finish="found", expected_targets=2, on_find="mark", **FAST
        )
        code, summary = run_controller(plan, tmp_path, None)
    assert (code, summary["outcome"]) == (EXIT_OK, "complete"), summary
    finds = summary["finds"]
    assert sorted(f["cell"] for f in finds) == [[0, 11], [11, 11]]
    assert finds[0]["time_s"] < finds[1]["time_s"] and finds[0]["step"] < finds[1]["step"]  # it went on
    ev = events(tmp_path)
    assert not any(e["event"] == "state" and e["state"] == "hover" for e in ev)
    assert [e["cell"] for e in ev if e["event"] == "find"] == [f["cell"] for f in finds]


@pytest.mark.slow
def test_held_with_fewer_targets_than_vehicles_ends_when_that_many_are_held(tmp_path):
    grid = small_grid(10, 10)
    with SimSwarm(grid, uavs=2, seed=2, speedup=30.0, targets=[[8, 8]]) as swarm:
        plan = swarm.plan("frontier", end_action="hover", time_limit=60.0, expected_targets=1, **FAST)
        code, summary = run_controller(plan, tmp_path, None)
    assert (code, summary["outcome"]) == (EXIT_OK, "complete"), summary
    assert summary["finish"] == {"rule": "held", "expected_targets": 1, "on_find": "hold", "met": True}
    assert summary["vehicles_on_targets"] == [[8, 8]]
    assert sorted(v["end_action"] for v in summary["vehicles"]) == ["hover", "rtl"]  # the other comes home
