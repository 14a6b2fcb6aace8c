"""`swarmctl replay --gaps`: the cells left to search as polygons, KML and a prior for the next mission."""

from __future__ import annotations

import json
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import shapely
from shapely.geometry import shape

from swarmctl.cli import main
from swarmctl.errors import InputError
from swarmctl.geo.grid import GeoGrid
from swarmctl.replay.gaps import Gaps, find_gaps, write_gaps
from swarmctl.replay.recording import load
from swarmctl.world.prior import density, residual

DATA = Path(__file__).resolve().parent / "data"
SITL3 = DATA / "logs" / "sitl3-mission"  # three ArduCopter SITL vehicles, 25 steps, no prior line
OLD_DEMO = DATA / "old" / "demo-d0f4aa4"  # two mock vehicles on a 10 x 10 grid, knowledge snapshots
KML = "{http://www.opengis.net/kml/2.2}"


def in_cells(grid: GeoGrid, geometry):
    """A lon/lat geometry in the grid's cell units (cell (x, y) is the square [x, x+1] x [y, y+1])."""
    return grid.geometry_to_grid(grid.projection.geometry_to_metres(geometry))


def check_files(folder: Path, gaps: Gaps, grid: GeoGrid) -> list:
    """The three files agree with `gaps`: valid polygons covering exactly the cells left, each with its cells,
    area and probability; the KML has the same polygons; the prior sums to 1. Returns the polygons."""
    features = json.loads((folder / "gaps.geojson").read_text())["features"]
    polys = [shape(f["geometry"]) for f in features]
    assert all(p.is_valid and p.geom_type == "Polygon" for p in polys)
    assert all(p.exterior.is_ccw and not any(r.is_ccw for r in p.interiors) for p in polys)  # RFC 7946
    left = gaps.left
    assert sum(f["properties"]["cells"] for f in features) == int(left.sum())
    assert sum(f["properties"]["probability"] for f in features) == pytest.approx(gaps.residual[left].sum())
    if left.any():
        xs, ys = np.nonzero(left)
        squares = shapely.union_all(shapely.box(xs, ys, xs + 1, ys + 1))
        union = in_cells(grid, shapely.union_all(polys))
        assert union.symmetric_difference(squares).area < 1e-5 * squares.area
        assert shapely.hausdorff_distance(union, squares) < 1e-4  # cells: the written coordinates' rounding
        lat, lon = grid.cells_to_latlon(*np.nonzero(left))
        centres = shapely.points(np.column_stack([lon, lat]))
        for f, p in zip(features, polys):
            inside = shapely.contains(p, centres)
            assert f["properties"]["cells"] == int(inside.sum())
            assert f["properties"]["area_m2"] == pytest.approx(inside.sum() * grid.cell**2)
            cells = tuple(np.array(np.nonzero(left))[:, inside])
            assert f["properties"]["probability"] == pytest.approx(gaps.residual[cells].sum())
    marks = ET.parse(folder / "gaps.kml").getroot().iter(f"{KML}Placemark")
    assert sum(len(m.findall(f"{KML}Polygon")) for m in marks) == len(polys)
    prior = json.loads((folder / "gaps.prior.geojson").read_text())["features"]
    assert [shape(f["geometry"]).equals(p) for f, p in zip(prior, polys)] == [True] * len(polys)
    if polys:
        assert sum(f["properties"]["probability"] for f in prior) == pytest.approx(1.0, abs=1e-12)
    return polys


def recording_with(tmp_path: Path, prior: dict | None, passes: object = None, summary: bool = True) -> Path:
    """The old demo recording with a `prior` line after its mission line and `passes` in its summary (or no
    summary.json: a recording cut off before it)."""
    rec = tmp_path / "rec"
    shutil.copytree(OLD_DEMO, rec)
    if prior is not None:
        lines = (rec / "events.jsonl").read_text().splitlines()
        line = json.dumps({"t": json.loads(lines[0])["t"], "event": "prior", **prior})
        (rec / "events.jsonl").write_text("\n".join([lines[0], line, *lines[1:]]) + "\n")
    body = json.loads((rec / "summary.json").read_text())
    if passes is not None:
        body["passes"] = passes
    (rec / "summary.json").write_text(json.dumps(body))
    if not summary:
        (rec / "summary.json").unlink()
    return rec


def hotspot(w: int = 10, h: int = 10) -> list[list[float]]:
    """A prior heavier towards high x (W lists of H numbers, summing to 1)."""
    weights = np.outer(np.arange(1, w + 1), np.ones(h))
    return (weights / weights.sum()).tolist()


def test_a_real_missions_gaps_are_the_free_cells_it_never_saw(tmp_path):
    replay = load(SITL3)
    gaps = find_gaps(replay)
    assert replay.knowledge is not None
    explored = replay.knowledge.explored(replay.frames - 1)
    free = ~replay.grid.blocked
    np.testing.assert_array_equal(gaps.left, free & ~explored)
    assert gaps.probability == pytest.approx((free & ~explored).sum() / free.sum())
    write_gaps(gaps, replay.name, tmp_path)
    check_files(tmp_path, gaps, replay.grid)
    (line,) = gaps.summary_lines(replay.grid.cell)
    assert line.startswith(f"gaps: {int(gaps.left.sum())} cells, ") and "uniform prior, pod 1" in line


def test_a_recorded_prior_and_passes_leave_the_cells_above_the_threshold(tmp_path):
    passes = np.zeros((10, 10), dtype=int)
    passes[:6] = 1
    passes[:3] = 3
    weights = hotspot()
    rec = recording_with(tmp_path, {"pod": 0.5, "weights": weights, "source": "hotspots.geojson"}, passes.tolist())
    replay = load(rec)
    gaps = find_gaps(replay)
    free = ~replay.grid.blocked
    prior = np.where(free, weights, 0.0) / np.where(free, weights, 0.0).sum()
    np.testing.assert_allclose(gaps.residual, residual(prior, passes, 0.5))
    np.testing.assert_array_equal(gaps.left, density(prior, passes, 0.5, free) > 0.1)
    assert gaps.left[9].all() or not free[9].all()  # unsearched and likely
    assert not gaps.left[0].any()  # three passes over the least likely cells
    out = tmp_path / "out"
    out.mkdir()
    write_gaps(gaps, replay.name, out)
    check_files(out, gaps, replay.grid)
    assert "prior hotspots.geojson, pod 0.5; passes from summary.json" in gaps.summary_lines(replay.grid.cell)[0]
    # a stricter threshold leaves fewer cells
    assert find_gaps(replay, 1.0).left.sum() < gaps.left.sum()


def test_a_recording_cut_off_before_its_summary_counts_its_explored_cells_once(tmp_path):
    rec = recording_with(tmp_path, {"pod": 0.8, "weights": hotspot(), "source": "x"}, summary=False)
    replay = load(rec)
    gaps = find_gaps(replay, 0.0)
    assert replay.knowledge is not None
    explored = replay.knowledge.explored(replay.frames - 1)
    free = ~replay.grid.blocked
    np.testing.assert_array_equal(gaps.left, free)  # one pass at pod 0.8 leaves a fifth of each cell
    np.testing.assert_allclose(gaps.residual[explored & free].sum() * 5, 1 - gaps.residual[~explored].sum())
    lines = gaps.summary_lines(replay.grid.cell)
    assert len(lines) == 2 and "cut off" in lines[1] and "passes from the explored cells" in lines[0]


def test_nothing_left_still_writes_the_three_files(tmp_path):
    rec = recording_with(tmp_path, None, np.ones((10, 10), dtype=int).tolist())
    replay = load(rec)
    gaps = find_gaps(replay)
    assert not gaps.left.any() and gaps.gaps == []
    out = tmp_path / "out"
    out.mkdir()
    paths = write_gaps(gaps, replay.name, out)
    assert [p.name for p in paths] == ["gaps.geojson", "gaps.kml", "gaps.prior.geojson"]
    for name in ("gaps.geojson", "gaps.prior.geojson"):
        assert json.loads((out / name).read_text()) == {"type": "FeatureCollection", "features": []}
    assert check_files(out, gaps, replay.grid) == []
    assert gaps.summary_lines(replay.grid.cell)[0].startswith("gaps: 0 cells, 0 m2 (0.00 ha) in 0 polygons")


def test_the_prior_for_the_next_mission_reads_back_as_a_mission_prior(tmp_path):
    geo_prior = pytest.importorskip("swarmctl.geo.prior")
    passes = np.ones((10, 10), dtype=int)
    passes[7:, 2:8] = 0
    passes[0:2, 0:2] = 0
    rec = recording_with(tmp_path, {"pod": 1, "weights": hotspot(), "source": "x"}, passes.tolist())
    replay = load(rec)
    gaps = find_gaps(replay)
    out = tmp_path / "out"
    out.mkdir()
    write_gaps(gaps, replay.name, out)
    polys = check_files(out, gaps, replay.grid)
    assert len(polys) == 2
    prior = geo_prior.load_prior(out / "gaps.prior.geojson", replay.grid)
    assert prior[~gaps.left].sum() < 1e-5  # all of it on the cells left, but slivers of the coordinates' rounding
    share = gaps.residual[7:, 2:8].sum() / gaps.probability
    assert prior[7:, 2:8].sum() == pytest.approx(share, abs=1e-5)


BAD = [
    ({"pod": 0.5, "weights": hotspot(9, 10), "source": "x"}, "weights has 9 lists, not the grid's 10"),
    ({"pod": 0.5, "weights": hotspot(10, 11), "source": "x"}, "weights [0] has 11 entries"),
    ({"pod": 0.5, "weights": [[float("nan")] * 10] * 10, "source": "x"}, "weights[0][0] is nan"),
    ({"pod": 0.5, "weights": [[-1.0] * 10] * 10, "source": "x"}, "weights[0][0] is -1"),
    ({"pod": 0.5, "weights": [["a"] * 10] * 10, "source": "x"}, 'weights [0][0] is "a", not a number'),
    ({"pod": 0.5, "weights": [[0.0] * 10] * 10, "source": "x"}, "the free cells carry no weight"),
    ({"pod": 1.5, "weights": hotspot(), "source": "x"}, "pod 1.5 is not a probability of detection"),
    ({"pod": float("nan"), "weights": hotspot(), "source": "x"}, "pod NaN"),
]


@pytest.mark.parametrize(
    "prior,needle", BAD, ids=["width", "height", "nan", "negative", "string", "no-weight", "pod-over-1", "pod-nan"]
)
def test_a_bad_prior_line_is_one_input_error_naming_it(tmp_path, prior, needle):
    replay = load(recording_with(tmp_path, prior))
    with pytest.raises(InputError) as err:
        find_gaps(replay)
    assert "events.jsonl line 2: the prior event: " in str(err.value) and needle in str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("passes,needle", [([[1] * 10] * 9, "passes has 9 lists"), ([[-1] * 10] * 10, "is -1")])
def test_bad_passes_are_one_input_error_naming_the_summary(tmp_path, passes, needle):
    replay = load(recording_with(tmp_path, None, passes))
    with pytest.raises(InputError, match=needle) as err:
        find_gaps(replay)
    assert "summary.json: passes" in str(err.value)


def test_the_command_refuses_a_bad_prior_line_before_writing_anything(tmp_path, capsys):
    rec = recording_with(tmp_path, {"pod": 0.5, "weights": [[-1.0] * 10] * 10, "source": "x"})
    out = tmp_path / "out"
    assert main(["replay", str(rec), "--out", str(out), "--quiet", "--gaps"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "the prior event" in err and "Traceback" not in err
    assert not out.exists() or not any(out.iterdir())
    assert main(["replay", str(rec), "--out", str(out), "--quiet", "--gaps-min", "0.5"]) == 2
    assert "--gaps-min is for --gaps" in capsys.readouterr().err
