"""The shared input checks (swarmctl.bounds) and the rules behind them: JSON depth, finite ranges, the
memory estimate against measured peaks, output probes, heights with units, what still passes."""

from __future__ import annotations

import json
import shutil
import tracemalloc
from pathlib import Path

import click
import pytest
import shapely
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from swarmctl.bounds import json_depth, read_limited, real, writable_file, writable_folder
from swarmctl.errors import InputError
from swarmctl.geo.buildings import FEET, BuildingRule, load_buildings, parse_height
from swarmctl.geo.grid import make_grid
from swarmctl.geo.load import load_area
from swarmctl.geo.readers import lonlat_ring
from swarmctl.policy.registry import make_policy
from swarmctl.world.config import WorldConfig
from swarmctl.world.env import SearchEnv, planned_bytes
from tests.geo_helpers import blocked_cells, feature, to_lonlat, write_geojson

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.text(alphabet='[]{}"\\ab,:'),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(alphabet='[]{}"a'), inner, max_size=3),
    max_leaves=20,
)


def nesting(value: object) -> int:
    if isinstance(value, list):
        return 1 + max((nesting(v) for v in value), default=0)
    if isinstance(value, dict):
        return 1 + max((nesting(v) for v in value.values()), default=0)
    return 0


@given(json_values)
def test_json_depth_counts_arrays_and_objects_never_brackets_in_strings(value):
    assert json_depth(json.dumps(value).encode()) == nesting(value)


def test_json_depth_spans_the_scan_chunks():
    deep = b"[" * 70 + b" " * (17 * 2**20) + b"]" * 70
    assert json_depth(deep) == 70


@pytest.mark.parametrize("text", ["nan", "inf", "-inf", "NaN", "1e400"])
def test_real_refuses_what_is_not_a_finite_number(text):
    with pytest.raises(click.BadParameter):
        real(0).convert(text, None, None)


def test_real_keeps_its_range_and_open_ends():
    kind = real(0, 1, above=True)
    assert kind.convert("0.5", None, None) == 0.5 and kind.convert("1", None, None) == 1.0
    with pytest.raises(click.BadParameter):
        kind.convert("0", None, None)


@pytest.mark.parametrize(
    "cfg, batch, policy",
    [
        (dict(map_size=50, uavs=2), 250, "la:4"),
        (dict(map_size=50, uavs=10, targets=10), 100, "la:4"),
        (dict(map_size=30, uavs=30, targets=30), 250, "frontier"),
        (dict(map_size=100, uavs=2, fov=10.0), 10, "random"),
        (dict(map_size=200, uavs=2), 4, "frontier"),
    ],
)
def test_the_memory_estimate_covers_the_measured_peak(cfg, batch, policy):
    world = WorldConfig(**cfg)
    tracemalloc.start()
    try:
        env = SearchEnv(world, batch=batch, observations=True)
        env.reset(0)
        chooser = make_policy(policy)
        chooser.reset(env.beliefs(), 0)
        for _ in range(2):
            env.step(chooser.act(env.beliefs()))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    estimate = planned_bytes(world, batch)
    assert peak <= estimate <= 8 * peak  # never under, and not so far over that it refuses what fits


def test_output_probes_create_nothing_and_refuse_a_file_in_the_way(tmp_path):
    assert writable_folder(tmp_path / "a" / "b", "--out") == tmp_path / "a" / "b"
    assert not (tmp_path / "a").exists()
    (tmp_path / "f").write_text("x")
    for bad in (tmp_path / "f", tmp_path / "f" / "sub"):
        with pytest.raises(InputError, match="--out .*a file is in the way"):
            writable_folder(bad, "--out")
    with pytest.raises(InputError, match="is a folder"):
        writable_file(tmp_path, "--json")
    assert writable_file(tmp_path / "new" / "r.json", "--json") == tmp_path / "new" / "r.json"


def test_read_limited_refuses_devices_and_large_files_before_reading(tmp_path):
    with pytest.raises(InputError, match="not a regular file"):
        read_limited(Path("/dev/zero"), "key file", 1024)
    big = tmp_path / "big"
    with big.open("wb") as fh:
        fh.truncate(2049)
    with pytest.raises(InputError, match="over the 2 kB"):
        read_limited(big, "key file", 2048)
    (tmp_path / "ok").write_bytes(b"x" * 2048)
    assert len(read_limited(tmp_path / "ok", "key file", 2048)) == 2048


@given(st.floats(0.01, 3280.0), st.sampled_from([("m", 1.0), (" m", 1.0), (" ft", FEET), (" feet", FEET)]))
def test_heights_with_units_and_thousands_separators_parse_back(value, unit):
    suffix, factor = unit
    assume(round(value, 2) * factor <= 1000)
    written = f"{value:,.2f}{suffix}"  # "1,234.50 ft"
    assert parse_height(written) == pytest.approx(round(value, 2) * factor, rel=1e-9)


def test_a_tower_of_1000_ft_is_an_obstacle(tmp_path):
    area = write_geojson(tmp_path / "area.geojson", feature(to_lonlat(shapely.box(0, 0, 100, 100))))
    towers = write_geojson(tmp_path / "b.geojson", feature(to_lonlat(shapely.box(42, 42, 48, 48)), height="1,000 ft"))
    bset = load_buildings(towers)
    assert bset.buildings[0].height == pytest.approx(304.8)
    grid, report = make_grid(load_area(area), 10.0, 40.0, buildings=bset, rule=BuildingRule(altitude=40.0))
    assert report.buildings_tall == 1 and (4, 4) in blocked_cells(grid)


@pytest.mark.parametrize(
    "ring",
    [
        [[178.0, -17.0], [179.9, -17.0], [179.9, -16.0], [178.0, -17.0]],  # Fiji, beside the antimeridian
        [[15.0, 78.0], [16.0, 78.0], [16.0, 78.5], [15.0, 78.0]],  # Svalbard
        [[-70.0, -84.0], [-69.0, -84.0], [-69.0, -83.5], [-70.0, -84.0]],  # Antarctica, short of 85 S
    ],
)
def test_rings_near_the_limits_still_pass(ring):
    assert lonlat_ring(ring, Path("area.geojson"), "geometry").shape == (4, 2)


@settings(max_examples=50)
@given(st.floats(-84.9, 84.9), st.floats(-179.0, 179.0))
def test_a_small_square_anywhere_short_of_the_poles_and_the_antimeridian_passes(lat, lon):
    ring = [[lon, lat], [lon + 0.01, lat], [lon + 0.01, lat + 0.01], [lon, lat + 0.01], [lon, lat]]
    assert lonlat_ring(ring, Path("a.geojson"), "g").shape == (5, 2)


def test_a_recording_with_hostile_json_replays_with_notes_and_damage(tmp_path):
    from swarmctl.replay.recording import load

    folder = tmp_path / "rec"
    shutil.copytree(Path(__file__).parent / "data/logs/sitl3-mission", folder)
    (folder / "summary.json").write_text("[" * 10_000 + "]" * 10_000)
    with (folder / "events.jsonl").open("a") as fh:
        fh.write('{"t": 1, "event": "step", "vehicles": ' + "[" * 5000 + "]" * 5000 + "}\n")
    replay = load(folder)
    assert any("summary.json: not readable" in n and "nested" in n for n in replay.notes)
    assert any("nested too deeply" in d.reason for d in replay.damage["events.jsonl"])
