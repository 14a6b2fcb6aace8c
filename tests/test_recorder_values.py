"""The recorder's JSON values: floats rounded to 6 places, tuples and arrays as lists (array floats
rounded too), numpy scalars as Python values (as they are), paths as strings, dict keys as strings;
the fast paths for plain containers write what the rules say."""

import json
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.mission.agent import State
from swarmctl.mission.recorder import Recorder, _jsonable


def _rules(value):
    """The rules, written as a lookup by the most specific kind (numpy scalars before floats: an
    np.float64 is a float, and is written as it is)."""
    kinds = [
        (dict, lambda v: {str(k): _rules(x) for k, x in v.items()}),
        ((list, tuple), lambda v: [_rules(x) for x in v]),
        (np.ndarray, lambda v: _rules(v.tolist())),
        (np.generic, lambda v: v.item()),
        (float, lambda v: round(v, 6)),
        (Path, str),
    ]
    return next((write(value) for kind, write in kinds if isinstance(value, kind)), value)


atoms = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False),
    st.integers(-(2**40), 2**40),
    st.booleans(),
    st.none(),
    st.text(max_size=4),
    st.sampled_from(list(State)),
    st.floats(0, 1).map(np.float32),
    st.floats(0, 1).map(np.float64),
    st.integers(0, 100).map(np.int64),
    st.lists(st.floats(-10, 10), max_size=4).map(np.array),
    st.just(Path("/tmp/x")),
)
values = st.recursive(
    atoms,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4),
        st.lists(inner, max_size=4).map(tuple),
        st.dictionaries(st.one_of(st.text(max_size=3), st.integers(0, 9)), inner, max_size=4),
    ),
    max_leaves=20,
)


@settings(max_examples=300)
@given(values)
def test_json_values_follow_the_rules(value):
    assert json.dumps(_jsonable(value)) == json.dumps(_rules(value))


def test_a_recording_in_the_mission_folder_keeps_the_mission_and_grid_files(tmp_path):
    """`demo --mission m/mission.toml --out m`: the files already in place are not copied onto themselves."""
    mission, grid = tmp_path / "mission.toml", tmp_path / "grid.npz"
    mission.write_text('[mission]\nname = "m"\n')
    grid.write_bytes(b"grid bytes")
    rec = Recorder(tmp_path)
    try:
        rec.copy_inputs(mission, grid)
    finally:
        rec.close()
    assert mission.read_text() == '[mission]\nname = "m"\n' and grid.read_bytes() == b"grid bytes"
    elsewhere = tmp_path / "elsewhere"
    rec = Recorder(elsewhere)
    try:
        rec.copy_inputs(mission, grid)
    finally:
        rec.close()
    assert (elsewhere / "mission.toml").read_text() == mission.read_text()
