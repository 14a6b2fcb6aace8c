"""Search patterns flown as policies: the cell routes, RoutePolicy on hand-built beliefs, the mission file
`swarmctl plan` writes, and that file flown by mock vehicles."""

from __future__ import annotations

import json

import numpy as np
import pytest
import shapely

from swarmctl.cli import main
from swarmctl.errors import InputError
from swarmctl.geo.cli import PATTERNS
from swarmctl.geo.grid import GeoGrid
from swarmctl.geo.patterns import plan_pattern
from swarmctl.mission.plan import make_plan, pattern_routes
from swarmctl.mission.spec import CONNECTION_PLACEHOLDER, MissionTable, load_spec
from swarmctl.policy.coordinated import CoordinatedPolicy
from swarmctl.policy.registry import make_policy
from swarmctl.policy.routes import ROUTE_PATTERNS, RoutePolicy
from swarmctl.sim.swarm import SimSwarm
from swarmctl.world.beliefs import Beliefs, ObservationSettings
from swarmctl.world.guard import SafetyGuard
from swarmctl.world.moves import MOVES
from swarmctl.world.scenario import fov_offsets
from tests.geo_helpers import feature, to_lonlat, write_geojson
from tests.test_patterns import l_file, l_grid, lkp_latlon, lkp_text  # noqa: F401  (fixtures)

FOV = 3.0


def test_the_policy_and_the_planner_name_the_same_patterns():
    assert ROUTE_PATTERNS == PATTERNS


@pytest.mark.parametrize("pattern", PATTERNS)
def test_cell_routes_cover_every_free_cell_of_the_pattern(l_grid, pattern):  # noqa: F811
    m = MissionTable.model_validate({"name": "l", "policy": f"pattern:{pattern}", "lkp": list(lkp_latlon())})
    routes = pattern_routes(m, l_grid, 2, FOV, "mission.toml")
    assert len(routes) == 2 and all(len(r) for r in routes)
    seen = np.zeros(l_grid.blocked.shape, dtype=bool)
    offsets = fov_offsets(FOV)
    for route in routes:
        assert l_grid.in_grid(route[:, 0], route[:, 1]).all() and not l_grid.blocked[route[:, 0], route[:, 1]].any()
        around = (route[:, None, :] + offsets[None]).reshape(-1, 2)
        around = around[l_grid.in_grid(around[:, 0], around[:, 1])]
        seen[around[:, 0], around[:, 1]] = True
    cells = plan_pattern(l_grid, pattern, lkp_latlon(), 2, 2 * FOV * l_grid.cell).cells
    assert len(cells) and seen[cells[:, 0], cells[:, 1]].all()


# --- RoutePolicy on hand-built beliefs ------------------------------------------------------------------


def beliefs(
    pos: list[tuple[int, int]], explored: np.ndarray, truth: np.ndarray, step: int = 0, fov: float = 1.0
) -> Beliefs:
    """Every vehicle deciding, in one batch, each knowing every position and the explored cells' obstacles,
    sensing `fov` cells round each cell reached."""
    n = len(pos)
    w, h = truth.shape
    seen = np.broadcast_to(explored, (1, n, w, h))
    positions = np.broadcast_to(np.array(pos), (1, n, n, 2))
    return Beliefs(
        seen,
        np.ones((1, n, w, h), dtype=np.float32),
        seen & truth,
        np.zeros((1, n, w, h), dtype=bool),
        positions,
        np.zeros((1, n, n), dtype=bool),
        np.arange(n)[None],
        [0],
        step,
        ObservationSettings(fov=fov),
    )


def fly_routes(
    policy, start: list[tuple[int, int]], truth: np.ndarray, steps: int, sense: float = 1.0
) -> list[list[tuple[int, int]]]:
    """Each vehicle's cells, step by step, under `policy` and the guard (which must refuse nothing); each
    vehicle explores the disc of radius `sense` round every cell it reaches."""
    w, h = truth.shape
    explored = np.zeros((w, h), dtype=bool)
    offsets = fov_offsets(sense)
    guard = SafetyGuard(truth, 40.0)
    pos = list(start)
    tracks = [[p] for p in pos]

    def look() -> None:
        for x, y in pos:
            around = np.array([x, y]) + offsets
            ok = (around[:, 0] >= 0) & (around[:, 0] < w) & (around[:, 1] >= 0) & (around[:, 1] < h)
            explored[around[ok, 0], around[ok, 1]] = True

    look()
    policy.reset(beliefs(pos, explored, truth, 0, sense), seed=0)
    for step in range(steps):
        moves = policy.act(beliefs(pos, explored, truth, step, sense))[0]
        proposed = np.array(pos) + MOVES[moves]
        decisions = guard.guard_moves(np.array(pos), proposed)
        assert [d.refused for d in decisions] == [None] * len(pos), (step, pos, moves)
        pos = [d.cell for d in decisions]
        for track, p in zip(tracks, pos):
            track.append(p)
        look()
    return tracks


def test_a_vehicle_follows_its_route_in_order_round_a_blocked_cell():
    truth = np.zeros((8, 6), dtype=bool)
    truth[3, 0] = True  # on the way from the first route cell to the second
    route = [(6, 0), (7, 5), (0, 5), (0, 2)]
    policy = RoutePolicy([route])
    (track,) = fly_routes(policy, [(0, 0)], truth, 22, sense=1.0)  # it sees the cells next to it
    assert (3, 0) not in track
    # each route cell seen (reached, or next to the cell reached), in order
    at = [next(i for i, (x, y) in enumerate(track) if abs(x - cx) + abs(y - cy) <= 1) for cx, cy in route]
    assert at == sorted(at)
    assert all(abs(a[0] - b[0]) + abs(a[1] - b[1]) <= 1 for a, b in zip(track, track[1:]))


def test_cells_explored_or_out_of_reach_are_skipped_and_a_done_route_falls_back_to_the_coordinated_planner():
    truth = np.zeros((8, 6), dtype=bool)
    truth[4:6, 2:4] = True
    policy = RoutePolicy([[(1, 0), (4, 2), (2, 1)]])  # (4, 2) is blocked: skipped once known
    (track,) = fly_routes(policy, [(0, 0)], truth, 2, sense=1.0)  # (1, 0) and (2, 1) are explored from start
    assert track[1] != (0, 0) or track[2] != (0, 0)  # it never idles
    explored = np.zeros((8, 6), dtype=bool)
    explored[:3, :3] = True
    b = beliefs([(1, 1)], explored, truth, step=3)
    policy = RoutePolicy([[(2, 2), (1, 0)]])  # all explored already: the route is done
    policy.reset(b, seed=5)
    coordinated = CoordinatedPolicy()
    coordinated.reset(b, seed=5)
    assert policy.act(b)[0, 0] == coordinated.act(b)[0, 0] != 0


def test_two_vehicles_on_crossing_routes_are_never_refused_by_the_guard():
    truth = np.zeros((9, 7), dtype=bool)
    truth[4, 1:6] = True
    routes = [[(6, 3), (8, 0)], [(2, 3), (0, 6)]]  # head on, through the gaps round the wall
    tracks = fly_routes(RoutePolicy(routes), [(0, 3), (8, 3)], truth, 40, sense=1.0)
    assert all(a != b for a, b in zip(*tracks))
    assert any(x > 4 for x, _ in tracks[0]) and any(x < 4 for x, _ in tracks[1])  # each round the wall


# --- the mission file --------------------------------------------------------------------------------------


def test_pattern_specs_are_refused_where_no_mission_gives_their_routes():
    with pytest.raises(InputError, match="lkp"):
        make_policy("pattern:parallel")  # swarmctl eval
    from swarmctl.mission.decide import FieldPolicy

    with pytest.raises(InputError, match="not a search pattern"):
        FieldPolicy("pattern:spiral")


def plan_out(tmp_path, *args: str):
    return main(["plan", str(tmp_path / "l.geojson"), *args, "--out", str(tmp_path / "out")])


def test_plan_writes_a_mission_file_whose_placeholders_are_refused_naming_the_vehicle(
    tmp_path,
    l_file,  # noqa: F811
    capsys,
):
    assert plan_out(tmp_path, "--pattern", "sector", "--lkp", lkp_text(), "--uavs", "2", "--spacing", "50") == 0
    mission = tmp_path / "out" / "mission.toml"
    text = mission.read_text()
    assert 'policy = "pattern:sector"' in text and "spacing_m = 50.0" in text and '# prior = "' in text
    assert text.count("[[vehicles]]") == 2 and 'finish = "covered"' in text
    capsys.readouterr()
    assert main(["fly", str(mission), "--yes"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "vehicles[0].connection" in err and "fill in the connection of vehicle 'uav1'" in err
    for k in (1, 2):
        text = text.replace(f'"{CONNECTION_PLACEHOLDER}"', f'"udpin:127.0.0.1:{14550 + k}"', 1)
    mission.write_text(text)
    plan = make_plan(load_spec(mission), mission_file=mission)
    assert plan.policy.follows_routes and plan.spec.mission.lkp == list(lkp_latlon())


def test_a_plain_plan_writes_a_coordinated_mission(tmp_path, l_file, capsys):  # noqa: F811
    assert plan_out(tmp_path, "--uavs", "4") == 0
    text = (tmp_path / "out" / "mission.toml").read_text()
    assert 'policy = "coordinated"' in text and "lkp" not in text.split("[[vehicles]]")[0].replace("with lkp", "")
    assert text.count(f'connection = "{CONNECTION_PLACEHOLDER}"') == 4


@pytest.mark.parametrize(
    "change,says",
    [
        ({"lkp": None}, 'mission.policy = "pattern:parallel": searches from a last known point, and lkp is missing'),
        ({"policy": '"frontier"'}, "mission.lkp = [45."),
        ({"spacing_m": "60.0", "policy": '"la:4"', "lkp": None}, "mission.spacing_m = 60.0: is for a search pattern"),
        ({"lkp": "[45.0, 4.0]"}, "mission.lkp = [45, 4] lies outside the grid"),
        ({"lkp": "[95.0, 4.0]"}, "mission.lkp = [95.0, 4.0]: is not [LAT, LON]"),
    ],
)
def test_bad_pattern_keys_are_one_line_naming_the_key(tmp_path, l_grid, change, says, capsys):  # noqa: F811
    l_grid.save(tmp_path / "grid.npz")
    lat, lon = lkp_latlon()
    keys = {"policy": '"pattern:parallel"', "lkp": f"[{lat!r}, {lon!r}]", **change}
    body = '[mission]\nname = "l"\ngrid = "grid.npz"\n' + "".join(f"{k} = {v}\n" for k, v in keys.items() if v)
    body += '[[vehicles]]\nname = "a"\nconnection = "udpin:127.0.0.1:14551"\nsysid = 1\n'
    (tmp_path / "m.toml").write_text(body)
    assert main(["fly", str(tmp_path / "m.toml"), "--yes"]) == 2
    err = capsys.readouterr().err
    assert says in err and len(err.strip().splitlines()) == 1, err


# --- flown by mock vehicles --------------------------------------------------------------------------------


@pytest.mark.slow
def test_the_planned_mission_file_is_flown_by_mock_vehicles_to_the_end(tmp_path, capsys):
    area = shapely.box(0, 0, 120, 80)  # 12 x 8 cells of 10 m: two lanes
    write_geojson(tmp_path / "box.geojson", feature(to_lonlat(area)))
    lkp = to_lonlat(shapely.Point(20, 30))
    out = tmp_path / "out"
    argv = ["plan", str(tmp_path / "box.geojson"), "--pattern", "parallel", "--lkp", f"{lkp.y!r},{lkp.x!r}"]
    assert main([*argv, "--uavs", "2", "--out", str(out)]) == 0
    grid = GeoGrid.load(out / "grid.npz")
    mission = out / "mission.toml"
    with SimSwarm(grid, uavs=2, seed=1, speedup=30.0, carry_detectors=False) as swarm:
        text = mission.read_text()
        for vehicle in swarm.specs:
            text = text.replace(f'"{CONNECTION_PLACEHOLDER}"', f'"{vehicle.connection}"', 1)
        text = text.replace("step_period = 1.0", "step_period = 0.0\nend_timeout = 0.0")
        text = text.replace("time_limit = 900.0", "time_limit = 60.0")
        mission.write_text(text + "\n[flight]\ntakeoff_at_once = 2\n")
        capsys.readouterr()
        code = main(["fly", str(mission), "--yes", "--out", str(tmp_path / "run"), "--no-live", "--quiet"])
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert code == 0, capsys.readouterr().err
    assert summary["outcome"] == "complete" and summary["covered_fraction"] == 1.0
    assert [v["end_action"] for v in summary["vehicles"]] == ["rtl", "rtl"]
