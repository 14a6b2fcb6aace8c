"""A mission searching from a prior with a detector that misses: the prior file read onto the grid, the
`[sensing] pod` and `pos >= X` finish line of the spec, the search probability's passes, the mock
detector's misses, and a flight with mock vehicles to its POS goal whose recording says how it rose."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from swarmctl.errors import EXIT_OK, InputError
from swarmctl.geo.grid import GeoGrid
from swarmctl.geo.prior import load_prior
from swarmctl.mission.events import check_event
from swarmctl.mission.probability import SearchProbability
from swarmctl.mission.service import run_controller
from swarmctl.mission.spec import load_spec, pos_goal
from swarmctl.replay.recording import load as load_replay
from swarmctl.replay.summary import pos_lines
from swarmctl.replay.verify import verify
from swarmctl.sim.detector import SimDetector
from swarmctl.sim.swarm import SimSwarm
from tests.mission_support import small_grid, small_mission

FAST = dict(takeoff_at_once=4, end_timeout=0.0)


def lonlat_box(grid: GeoGrid, x0: float, y0: float, x1: float, y1: float) -> dict:
    """A GeoJSON polygon (lon, lat) of the grid's cells [x0, x1] x [y0, y1]."""
    corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]
    ring = []
    for gx, gy in corners:
        e, n = grid.grid_to_metres(gx, gy)
        lon, lat = grid.projection.to_lonlat(e, n)
        ring.append([float(lon), float(lat)])
    return {"type": "Polygon", "coordinates": [ring]}


def collection(grid: GeoGrid, *features: tuple[tuple[float, float, float, float], dict]) -> dict:
    return {
        "type": "FeatureCollection",
        "features": [{"type": "Feature", "properties": p, "geometry": lonlat_box(grid, *b)} for b, p in features],
    }


def write(tmp_path: Path, obj: object, name: str = "prior.geojson") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(obj))
    return path


# --- the prior file -----------------------------------------------------------------------------------


def test_probabilities_go_to_their_polygons_and_the_rest_is_shared_evenly(tmp_path):
    grid = small_grid()  # 10 x 10, cells (4..5, 4..5) blocked
    path = write(
        tmp_path, collection(grid, ((0, 0, 2, 2), {"probability": 0.6}), ((8, 8, 10, 10), {"probability": 0.2}))
    )
    prior = load_prior(path, grid)
    assert prior.shape == (10, 10) and prior.sum() == pytest.approx(1.0)
    assert prior[:2, :2] == pytest.approx(np.full((2, 2), 0.15), abs=1e-6)
    assert prior[8:, 8:] == pytest.approx(np.full((2, 2), 0.05), abs=1e-6)
    assert (prior[grid.blocked] == 0).all()
    rest = np.ones((10, 10), dtype=bool)
    rest[:2, :2] = rest[8:, 8:] = False
    rest &= ~grid.blocked
    assert prior[rest] == pytest.approx(np.full(rest.sum(), 0.2 / rest.sum()), abs=1e-6)


def test_weights_are_per_unit_area_and_npz_is_read_as_is(tmp_path):
    grid = small_grid()
    path = write(tmp_path, collection(grid, ((0, 0, 2, 1), {"weight": 3.0}), ((0, 5, 1, 6), {"weight": 1.0})))
    prior = load_prior(path, grid)
    assert prior[0, 0] == pytest.approx(3 / 7, abs=1e-6) and prior[0, 5] == pytest.approx(1 / 7, abs=1e-6)
    assert prior.sum() == pytest.approx(1.0) and np.count_nonzero(prior > 1e-9) == 3
    weights = np.arange(100, dtype=float).reshape(10, 10)
    np.savez(tmp_path / "prior.npz", prior=weights)
    from_npz = load_prior(tmp_path / "prior.npz", grid)
    expected = np.where(grid.blocked, 0.0, weights)
    assert from_npz == pytest.approx(expected / expected.sum())


@pytest.mark.parametrize(
    "make, says",
    [
        (lambda g: {"type": "Feature", "properties": {}, "geometry": lonlat_box(g, 0, 0, 1, 1)}, "FeatureCollection"),
        (lambda g: collection(g, ((40, 40, 42, 42), {"probability": 0.5})), "feature 0 lies outside the grid"),
        (lambda g: collection(g, ((0, 0, 1, 1), {"probability": -0.1})), "feature 0"),
        (lambda g: collection(g, ((0, 0, 1, 1), {"probability": 1.5})), "between 0 and 1"),
        (lambda g: collection(g, ((0, 0, 1, 1), {"probability": "0.5"})), "not a number"),
        (lambda g: collection(g, ((0, 0, 1, 1), {"probability": 0.7}), ((2, 2, 3, 3), {"probability": 0.7})), "over 1"),
        (lambda g: collection(g, ((0, 0, 1, 1), {"probability": 0.5}), ((2, 2, 3, 3), {"weight": 2})), "mixes"),
        (lambda g: collection(g, ((0, 0, 1, 1), {"probability": 0.5}), ((2, 2, 3, 3), {})), "feature 1 has neither"),
        (lambda g: collection(g, ((4, 4, 6, 6), {"probability": 0.5})), "only blocked cells"),
    ],
)
def test_bad_geojson_priors_are_refused_naming_the_file_the_feature_and_the_fix(tmp_path, make, says):
    grid = small_grid()
    path = write(tmp_path, make(grid))
    with pytest.raises(InputError, match=says) as err:
        load_prior(path, grid)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_bad_npz_and_geotiff_priors_are_refused(tmp_path):
    grid = small_grid()
    cases = {
        "shape.npz": dict(prior=np.ones((3, 3))),
        "name.npz": dict(weights=np.ones((10, 10))),
        "nan.npz": dict(prior=np.full((10, 10), np.nan)),
        "negative.npz": dict(prior=-np.ones((10, 10))),
        "zero.npz": dict(prior=np.zeros((10, 10))),
    }
    says = {"shape.npz": "shape", "name.npz": "no array named", "nan.npz": "NaN", "negative.npz": "negative"}
    for name, arrays in cases.items():
        np.savez(tmp_path / name, **arrays)
        with pytest.raises(InputError, match=says.get(name, "no weight")):
            load_prior(tmp_path / name, grid)
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="not a numpy .npz"):
        load_prior(tmp_path / "bad.npz", grid)
    (tmp_path / "prior.tif").write_bytes(b"II*\x00")
    with pytest.raises(InputError, match=r"GeoTIFF.*\.npz"):
        load_prior(tmp_path / "prior.tif", grid)


# --- the spec -------------------------------------------------------------------------------------------


def test_the_pos_finish_line_pod_and_prior_keys_are_read_and_checked(tmp_path):
    grid = small_grid()
    write(tmp_path, collection(grid, ((0, 0, 2, 2), {"probability": 0.5})))
    path = small_mission(tmp_path, finish='"pos >= 0.90"', prior='"prior.geojson"')
    spec = load_spec(path)
    assert spec.mission.finish == "pos >= 0.9" and pos_goal(spec.mission.finish) == 0.9
    assert spec.sensing.pod == 1.0 and spec.mission.prior == (tmp_path / "prior.geojson").resolve()
    path.write_text(path.read_text() + "[sensing]\npod = 0.8\n")
    assert load_spec(path).sensing.pod == 0.8
    assert pos_goal("covered") is None
    for finish, says in [
        ('"pos >= 1.2"', 'or pos >= X (0 < X <= 1); write for example finish = "covered", or finish = "pos >= X"'),
        ('"pos > 0.9"', "0 < X <= 1"),
        ('"pos >= 0"', "0 < X <= 1"),
        ('"pos >= 1"', "pod = 0.8"),
    ]:
        bad = small_mission(tmp_path, finish=finish)
        bad.write_text(bad.read_text() + "[sensing]\npod = 0.8\n")
        with pytest.raises(InputError, match="mission.finish") as err:
            load_spec(bad)
        assert says in str(err.value) and "\n" not in str(err.value)
    for pod in ("0.0", "1.5", "true"):
        bad = small_mission(tmp_path)
        bad.write_text(bad.read_text() + f"[sensing]\npod = {pod}\n")
        with pytest.raises(InputError, match="sensing.pod"):
            load_spec(bad)
    ok = small_mission(tmp_path, finish='"pos >= 1"')
    assert load_spec(ok).mission.finish == "pos >= 1"  # with pod 1


# --- the search probability -----------------------------------------------------------------------------


def test_passes_count_arrivals_over_the_footprint_and_onboard_the_others_explored_cells_once():
    free = np.ones((10, 10), dtype=bool)
    search = SearchProbability(None, free, pod=0.5, fov=1.0)
    assert search.pos() == 0.0 and search.source == "uniform"
    search.look((0, 0))
    assert search.passes[0, 0] == 1 and search.passes[1, 0] == 1 and search.passes[1, 1] == 0
    assert search.pos() == pytest.approx(3 * 0.01 * 0.5)
    search.look((0, 0), "b")  # another vehicle's arrival: a second pass
    assert search.passes[0, 0] == 2 and search.pos() == pytest.approx(3 * 0.01 * 0.75)
    search.look((1, 0), "b")  # only (2, 0) and (1, 1) enter b's footprint
    assert search.passes[1, 0] == 2 and search.passes[2, 0] == 1 and search.passes[1, 1] == 1
    search.look((0, 0), "b")  # back: (0, 1) enters it again; (0, 0) and (1, 0) stayed in it
    assert search.passes[0, 0] == 2 and search.passes[0, 1] == 3
    explored = np.zeros((10, 10), dtype=bool)
    explored[0, 0] = explored[9, 9] = True
    search.note_explored(explored)
    passes = search.team_passes()
    assert passes[0, 0] == 2 and passes[9, 9] == 1  # only another process's: one pass
    assert search.density()[9, 9] == pytest.approx(0.5) and search.density()[5, 5] == pytest.approx(1.0)
    record = search.prior_record()
    assert record["pod"] == 0.5 and record["source"] == "uniform" and len(record["weights"]) == 10
    assert record["weights"][3][3] == 0.01 and search.summary()["passes"][9][9] == 1


def test_the_mock_detector_misses_at_pod_below_one_seeded_and_reports_all_at_one():
    grid = small_grid()
    targets = np.array([[1, 1]])
    counts = {}
    for pod in (1.0, 0.5):
        runs = []
        for seed in (3, 3, 4):
            det = SimDetector(grid, targets, 0, 7, 40.0, fov=2.0, pod=pod, seed=seed)
            seen = []
            for i in range(40):  # the target enters the footprint at (1, 2) and leaves it at (7, 7)
                cell = (7, 7) if i % 2 else (1, 2)
                _cells, _phi, _obstacle, in_view = det.observe(cell)
                first, again = det.seen(cell, in_view), det.seen(cell, in_view)
                assert len(first) == len(again)  # the same pass: the same look
                if not i % 2:
                    _cells, _phi, _obstacle, still = det.observe((2, 1))  # on, still in view: the same look
                    assert len(det.seen((2, 1), still)) == len(first)
                    seen.append(len(first))
            runs.append(seen)
        counts[pod] = runs
    assert all(sum(r) == 20 for r in counts[1.0])
    assert counts[0.5][0] == counts[0.5][1] and counts[0.5][0] != counts[0.5][2]  # seeded
    assert 4 <= sum(counts[0.5][0]) <= 16  # misses sometimes, finds sometimes


# --- a flight --------------------------------------------------------------------------------------------


def test_a_flight_to_its_pos_goal_records_the_prior_the_rising_pos_and_the_summary(tmp_path):
    grid = small_grid(8, 8)
    prior_file = write(tmp_path, collection(grid, ((0, 0, 3, 8), {"probability": 0.6})))
    out = tmp_path / "run"
    with SimSwarm(grid, uavs=2, seed=1, speedup=30.0, pod=0.8, targets=[[7, 7]]) as swarm:
        plan = swarm.plan(
            "coordinated",
            end_action="land",
            time_limit=120.0,
            finish="pos >= 0.6",
            on_find="mark",
            prior=prior_file,
            **FAST,
        )
        assert plan.spec.sensing.pod == 0.8 and plan.prior is not None
        code, summary = run_controller(plan, out, None)
    assert (code, summary["outcome"]) == (EXIT_OK, "complete"), summary
    assert summary["finish"]["rule"] == "pos" and summary["finish"]["met"]
    assert summary["pos_goal"] == 0.6 and summary["pos"] >= 0.6
    assert np.asarray(summary["passes"]).shape == (8, 8)
    lines = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]
    for e in lines:
        check_event(e, strict=True)
    prior = [e for e in lines if e["event"] == "prior"]
    assert len(prior) == 1 and prior[0]["pod"] == 0.8 and prior[0]["source"] == "prior.geojson"
    assert np.asarray(prior[0]["weights"]).shape == (8, 8) and sum(map(sum, prior[0]["weights"])) == pytest.approx(1)
    pos = [e["pos"] for e in lines if e["event"] == "step"]
    assert pos and all(b >= a for a, b in zip(pos, pos[1:])) and pos[-1] >= 0.6 > pos[0]
    replay = load_replay(out)
    assert pos_lines(replay)[0].startswith(f"POS {pos[-1]:.4f}") and "goal 0.6: met" in pos_lines(replay)[0]
    with pytest.raises(InputError, match="weighed a prior or a detector that misses"):
        verify(out)  # the density it decided on is not recorded: refused in one line, not a false mismatch
    # a recording from before POS (no prior event, no step pos) still replays, without a POS line
    old = [e for e in lines if e["event"] != "prior"]
    for e in old:
        e.pop("pos", None)
    (out / "events.jsonl").write_text("".join(json.dumps(e) + "\n" for e in old))
    assert pos_lines(load_replay(out)) == []
