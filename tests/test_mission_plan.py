"""The plan: the spec checked against its grid and policy and made concrete once (altitude and cell size
from the grid, the footprint from the policy), the policy built once, the demo's spec built in code."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import shapely

from swarmctl.errors import InputError
from swarmctl.knowledge.model import disc_cells
from swarmctl.mission.plan import make_plan
from swarmctl.mission.spec import DEMO_SETTINGS, MissionSpec, VehicleSpec, load_spec
from swarmctl.policy.checkpoint import save_checkpoint
from swarmctl.policy.qnet import QNetwork
from swarmctl.sim.swarm import SimSwarm
from tests.geo_helpers import feature, to_lonlat, write_geojson
from tests.mission_support import our_threads, small_grid, small_mission


def plan_of(tmp_path, grid=None, **mission):
    path = small_mission(tmp_path, grid, **mission)
    return make_plan(load_spec(path), mission_file=path)


def refusal(tmp_path, grid=None, **mission) -> str:
    with pytest.raises(InputError) as err:
        plan_of(tmp_path, grid, **mission)
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"{tmp_path / 'mission.toml'}: ")
    return message


def test_left_out_altitude_cell_and_footprint_come_from_the_grid_and_the_policy(tmp_path):
    plan = plan_of(tmp_path, small_grid(cell=12.0, altitude=60.0))
    m = plan.spec.mission
    assert (m.altitude, m.cell_size, m.footprint_m) == (60.0, 12.0, 36.0)  # frontier senses 3 cells
    assert plan.fov == 3.0 and plan.policy.spec == "frontier" and plan.spec.knowledge.push is True


def test_flying_below_the_grids_altitude_is_refused_with_both_numbers_and_the_fix(tmp_path):
    message = refusal(tmp_path, small_grid(altitude=300.0), altitude="40.0")
    assert "mission.altitude = 40 is below the 300 m the grid grid.npz was planned for" in message
    assert "re-plan with `swarmctl plan ... --altitude 40`, or fly at the grid's altitude" in message


def test_flying_above_the_grids_altitude_is_allowed(tmp_path):
    assert plan_of(tmp_path, small_grid(altitude=40.0), altitude="55.5").spec.mission.altitude == 55.5
    assert plan_of(tmp_path, small_grid(altitude=40.0), altitude="40").spec.mission.altitude == 40.0


def test_a_cell_size_other_than_the_grids_is_refused(tmp_path):
    assert plan_of(tmp_path, cell_size="10.0").spec.mission.cell_size == 10.0
    message = refusal(tmp_path, cell_size="5.0")
    assert "mission.cell_size = 5 differs from the 10 m cells of the grid grid.npz" in message
    assert "leave cell_size out" in message and "--cell 5" in message


def test_a_grid_outside_the_missions_range_is_refused(tmp_path):
    message = refusal(tmp_path, small_grid(altitude=800.0))
    assert "the grid grid.npz has an altitude of 800 m, outside the 2 to 500 m a mission takes" in message


@pytest.mark.parametrize("given, ok", [("30.0", True), ("32.0", True), ("27.6", True), ("33.0", False), ("20", False)])
def test_the_footprint_must_match_the_policys_fov(tmp_path, given, ok):
    if ok:
        assert plan_of(tmp_path, footprint_m=given).spec.mission.footprint_m == float(given)
        return
    message = refusal(tmp_path, footprint_m=given)
    cells = float(given) / 10
    assert f"mission.footprint_m = {float(given):g} is {cells:.2f} cells of 10 m" in message
    assert "trained to sense 3 cells; write footprint_m = 30" in message


def test_an_area_is_gridded_at_the_missions_altitude_and_cell_size(tmp_path):
    write_geojson(tmp_path / "area.geojson", feature(to_lonlat(shapely.box(0, 0, 60, 40))))
    path = small_mission(tmp_path, grid='"../none"')
    path.write_text(
        path.read_text().replace('grid = "../none"', 'area = "area.geojson"\ncell_size = 20.0\naltitude = 70.0')
    )
    plan = make_plan(load_spec(path))
    assert (plan.grid.width, plan.grid.height, plan.grid.cell, plan.grid.altitude) == (3, 2, 20.0, 70.0)
    assert (plan.spec.mission.cell_size, plan.spec.mission.altitude) == (20.0, 70.0)
    path.write_text(path.read_text().replace("cell_size = 20.0\naltitude = 70.0", ""))
    plan = make_plan(load_spec(path))
    assert (plan.grid.cell, plan.grid.altitude, plan.spec.mission.altitude) == (10.0, 40.0, 40.0)


def test_a_policy_that_cannot_fly_is_refused_naming_the_file_and_key(tmp_path):
    assert "mission.toml: mission.policy: policy 'oracle' cannot fly" in refusal(tmp_path, policy='"oracle"')
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    assert "mission.toml: mission.policy: " in refusal(tmp_path, policy='"ddql:bad.pt"')


def test_a_model_for_another_observation_size_flies_with_its_own_window(tmp_path):
    save_checkpoint(tmp_path / "small.pt", QNetwork(8), {}, {}, {})
    assert plan_of(tmp_path, policy='"ddql:small.pt"').policy.window == 8


def test_a_models_options_are_kept_and_a_bad_one_is_named(tmp_path):
    save_checkpoint(tmp_path / "m.pt", QNetwork(20), {}, {}, {})
    plan = plan_of(tmp_path, policy='"ddql:m.pt:tau=0.05:straggler=frontier"')
    assert plan.policy.spec == f"ddql:{(tmp_path / 'm.pt').resolve()}:tau=0.05:straggler=frontier"
    assert "straggler must be network or frontier" in refusal(tmp_path, policy='"ddql:m.pt:straggler=maybe"')


def test_onboard_mode_keeps_the_named_vehicles(tmp_path):
    path = small_mission(tmp_path)
    text = path.read_text() + '[[vehicles]]\nname = "b"\nconnection = "udpin:127.0.0.1:14552"\nsysid = 2\n'
    path.write_text(text + '[knowledge]\nchannel = "udpout:127.0.0.1:14600"\n')
    plan = make_plan(load_spec(path), only=["b"])
    assert plan.only == [1] and plan.onboard and not make_plan(load_spec(path)).onboard
    with pytest.raises(InputError, match="--vehicle 'z' is not in .*; use one of a, b"):
        make_plan(load_spec(path), only=["z"], mission_file=path)


def test_onboard_mode_without_a_knowledge_channel_is_refused_with_the_fix(tmp_path):
    """Agents in separate processes share only through the channel; one process flying every vehicle
    shares in memory and needs none."""
    path = small_mission(tmp_path)
    path.write_text(path.read_text() + '[[vehicles]]\nname = "b"\nconnection = "udpin:127.0.0.1:14552"\nsysid = 2\n')
    with pytest.raises(InputError) as refused:
        make_plan(load_spec(path), only=["b"], mission_file=path)
    text = str(refused.value)
    assert text.startswith(f"{path}: [knowledge] channel is missing") and "\n" not in text
    assert 'add [knowledge] channel = "udpout:HOST:PORT"' in text and "swarmctl fly" in text
    assert make_plan(load_spec(path)).spec.knowledge.channel is None  # ground mode: fine without


def _vehicles(n: int) -> list[VehicleSpec]:
    return [VehicleSpec(name=f"v{i}", connection=f"udpin:127.0.0.1:{15000 + i}", sysid=i + 1) for i in range(n)]


@pytest.mark.parametrize("vehicles, given, push", [(12, None, True), (13, None, False), (3, False, False)])
def test_knowledge_push_left_out_is_on_for_small_swarms(vehicles, given, push):
    spec = MissionSpec.build(_vehicles(vehicles), name="m", policy="frontier", push=given)
    assert make_plan(spec, grid=small_grid()).spec.knowledge.push is push


def test_a_spec_built_in_code_is_validated_like_a_file():
    spec = MissionSpec.build(_vehicles(2), name="m", policy="random", time_limit=60.0, return_below=10)
    assert spec.timing.time_limit == 60.0 and spec.battery.return_below == 10 and spec.timing.step_period == 1.0
    with pytest.raises(InputError, match=r"^demo: timing.time_limit = -1.0: must be a finite number"):
        MissionSpec.build(_vehicles(1), where="demo", name="m", policy="random", time_limit=-1.0)
    with pytest.raises(TypeError, match="'speed' is not a mission setting"):
        MissionSpec.build(_vehicles(1), name="m", policy="random", speed=3)


def test_the_demo_flies_its_own_settings_over_a_mission_files(tmp_path):
    path = small_mission(tmp_path, id="42")
    path.write_text(path.read_text().replace("[[vehicles]]", "[battery]\nreturn_below = 25\n[[vehicles]]", 1))
    base = load_spec(path)
    with SimSwarm(small_grid(), uavs=2, seed=0, mission_id=base.mission.id) as swarm:
        plan = swarm.plan("frontier", base=base, time_limit=45.0, mission_file=path)
        default = swarm.plan("random", grid=tmp_path / "grid.npz")
        onboard = swarm.plan("random", radio=True)  # the loopback radio as the channel of separate processes
        assert onboard.spec.knowledge.channel.port == swarm.radio.address[1]
    assert not our_threads()  # the radio stopped with the swarm
    spec = plan.spec
    assert (spec.mission.name, spec.mission.id, spec.battery.return_below) == ("small", 42, 25)  # the file's
    assert spec.timing.step_period == DEMO_SETTINGS["step_period"] and spec.flight.telemetry_hz == 20.0  # the demo's
    assert spec.timing.time_limit == 45.0 and plan.mission_file == path  # the caller's
    assert [v.name for v in spec.vehicles] == ["uav1", "uav2"] and spec.knowledge.channel is None  # the bus
    assert default.spec.mission.name == "demo" and default.spec.timing.time_limit == DEMO_SETTINGS["time_limit"]
    assert default.spec.battery.return_below == 15 and default.spec.mission.altitude == 40.0
    assert default.spec.mission.grid == tmp_path / "grid.npz"  # copied into the recording


def test_the_simulated_detectors_sense_the_plans_fov():
    grid = small_grid(20, 20)
    trained_at_2 = SimpleNamespace(spec="frontier", fov=2.0, follows_routes=False)  # a model trained with fov 2
    with SimSwarm(grid, uavs=2, seed=0) as swarm:
        plan = swarm.plan(trained_at_2)
        assert plan.fov == 2.0 and plan.spec.mission.footprint_m == 20.0
        assert all(d.fov == 2.0 for d in swarm.detectors)
        cells, *_ = swarm.detectors[0].observe((10, 10))
        assert len(cells) == len(disc_cells((10, 10), 20, 20, 2.0)) < len(disc_cells((10, 10), 20, 20, 3.0))
    with SimSwarm(grid, uavs=2, seed=0, fov=3.0) as swarm, pytest.raises(InputError, match="footprint_m = 30"):
        swarm.plan(trained_at_2)
