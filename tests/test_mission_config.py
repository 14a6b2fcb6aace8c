"""Mission files: a good one loads; every bad one is one line naming the key, the value and the fix;
any valid spec round-trips through TOML; docs/mission.md lists exactly the spec's keys."""

from __future__ import annotations

import re
import textwrap
import typing
from pathlib import Path

import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from swarmctl.errors import InputError
from swarmctl.mavlink.codec import Endpoint
from swarmctl.mission.spec import (
    DOC_BEGIN,
    DOC_END,
    MAX_BYTES,
    TABLES,
    BatteryTable,
    MissionSpec,
    MissionTable,
    load_spec,
    validate,
)
from swarmctl.mission.spec_text import markdown_table

ROOT = Path(__file__).resolve().parent.parent

GOOD = """
[mission]
name = "test"
id = 9
grid = "grid.npz"
policy = "la:4"
end_action = "land"

[knowledge]
channel = "udpout:127.0.0.1:14600"

[[vehicles]]
name = "alpha"
connection = "udpin:127.0.0.1:14551"
sysid = 1

[[vehicles]]
name = "bravo"
connection = "udpin:127.0.0.1:14552"
sysid = 2
autopilot = "px4"
"""


def write(tmp_path, text):
    (tmp_path / "grid.npz").write_bytes(b"placeholder")
    p = tmp_path / "m.toml"
    p.write_text(textwrap.dedent(text))
    return p


def error(path) -> str:
    with pytest.raises(InputError) as err:
        load_spec(path)
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"{path}: ")
    return message.removeprefix(f"{path}: ")


def test_a_good_mission_loads(tmp_path):
    s = load_spec(write(tmp_path, GOOD))
    m = s.mission
    assert m.id == 9 and m.end_action == "land" and m.policy == "la:4" and m.fence is False
    assert m.grid == (tmp_path / "grid.npz").resolve()
    assert m.altitude is None and m.cell_size is None and m.footprint_m is None  # the plan fills them in
    assert [v.name for v in s.vehicles] == ["alpha", "bravo"]
    assert s.vehicles[0].autopilot is None and s.vehicles[1].autopilot == "px4"  # None: as the heartbeat says
    assert s.vehicles[0].connection == Endpoint("udpin", "127.0.0.1", 14551)
    assert s.knowledge.channel == Endpoint("udpout", "127.0.0.1", 14600)
    assert s.battery.takeoff_min == 30 and s.flight.takeoff_at_once == 1
    # the waits that follow a vehicle's speeds are derived from it unless the mission sets them
    assert (s.timing.step_timeout, s.timing.takeoff_timeout, s.timing.end_timeout) == (None, None, None)


def test_every_setting_has_a_key(tmp_path):
    tables = (
        "[timing]\nstep_timeout = 12.5\nend_timeout = 0\n[flight]\ntakeoff_at_once = 3\n"
        "[battery]\ntakeoff_min = 40\nreturn_below = 20\n[knowledge]\npush = false"
    )
    body = GOOD.replace("[knowledge]", tables)
    s = load_spec(write(tmp_path, body))
    assert (s.timing.step_timeout, s.timing.end_timeout, s.flight.takeoff_at_once) == (12.5, 0.0, 3)
    assert (s.battery.takeoff_min, s.battery.return_below, s.knowledge.push) == (40, 20, False)


def test_the_name_defaults_to_the_file_name(tmp_path):
    p = write(tmp_path, GOOD.replace('name = "test"\n', "", 1))
    assert load_spec(p).mission.name == "m"


def test_fence_is_a_switch(tmp_path):
    assert load_spec(write(tmp_path, GOOD.replace("id = 9", "id = 9\nfence = true", 1))).mission.fence is True
    p = write(tmp_path, GOOD.replace("id = 9", 'id = 9\nfence = "yes"', 1))
    assert error(p) == 'mission.fence = "yes": must be true or false; write for example fence = false'


@pytest.mark.parametrize(
    "value, shown",
    [("nan", "nan"), ("inf", "inf"), ("-inf", "-inf"), ("+inf", "inf"), ("1.5", "1.5"), ("501", "501"),
     ("true", "true"), ('"40"', '"40"'), ("[40]", "[40]")],
)  # fmt: skip
def test_altitude_must_be_a_finite_number_in_range(tmp_path, value, shown):
    p = write(tmp_path, GOOD.replace("id = 9", f"id = 9\naltitude = {value}", 1))
    assert error(p) == (
        f"mission.altitude = {shown}: must be a finite number from 2 to 500 (metres above home); "
        "write for example altitude = 40.0"
    )


def test_an_unknown_key_is_refused_with_the_known_ones(tmp_path):
    known = ", ".join(sorted(MissionTable.model_fields))
    p = write(tmp_path, GOOD.replace('name = "test"', 'name = "test"\nspeed = 3'))
    assert error(p) == f"mission.speed is not a key of [mission]; use one of {known}"
    p = write(tmp_path, GOOD.replace("sysid = 2", "sysid = 2\ncolour = 1"))
    assert error(p) == (
        "vehicles[1].colour is not a key of [[vehicles]]; use one of autopilot, connection, detector, name, sysid"
    )
    p = write(tmp_path, "[missions]\n" + GOOD)
    assert error(p).startswith("[missions] is not a known table; use one of [mission], [timing], [flight]")


def test_a_key_in_the_wrong_table_is_sent_to_its_own(tmp_path):
    p = write(tmp_path, GOOD.replace("id = 9", "id = 9\nstep_timeout = 10.0", 1))
    assert error(p) == "mission.step_timeout belongs in [timing], not [mission]; move it there"
    p = write(tmp_path, "time_limit = 60.0\n" + GOOD)
    assert error(p) == "time_limit belongs in [timing]; write it below that table's heading"


@pytest.mark.parametrize(
    "old, new, key",
    [
        ('grid = "grid.npz"', 'grid = "nope.npz"', "mission.grid"),
        ('grid = "grid.npz"', "", "mission.grid"),
        ('grid = "grid.npz"', 'grid = "grid.npz"\narea = "grid.npz"', "mission.grid"),
        ('grid = "grid.npz"', 'grid = "grid.npz"\nbuildings = "grid.npz"', "mission.buildings"),
        ('name = "test"', 'name = "a/b"', "mission.name"),
        ('name = "bravo"', 'name = "alpha"', "vehicles[1].name"),
        ("sysid = 2", "sysid = 1", "vehicles[1].sysid"),
        ("sysid = 2", "sysid = 300", "vehicles[1].sysid"),
        ("sysid = 2", "sysid = 0", "vehicles[1].sysid"),
        ("sysid = 2", 'sysid = "two"', "vehicles[1].sysid"),
        ("sysid = 2", "sysid = 2.0", "vehicles[1].sysid"),
        ("sysid = 2", "", "vehicles[1].sysid"),
        ('autopilot = "px4"', 'autopilot = "inav"', "vehicles[1].autopilot"),
        ('end_action = "land"', 'end_action = "crash"', "mission.end_action"),
        ('policy = "la:4"', 'policy = ""', "mission.policy"),
        ('policy = "la:4"', "", "mission.policy"),
        ('policy = "la:4"', 'policy = "ddql:missing.pt"', "mission.policy"),
        ("id = 9", "id = 70000", "mission.id"),
        ("id = 9", "id = -1", "mission.id"),
        ("id = 9", "id = 9\ncell_size = 0.5", "mission.cell_size"),
        ("id = 9", "id = 9\nfootprint_m = nan", "mission.footprint_m"),
        ("id = 9", 'id = 9\ngcs = "udpin:0.0.0.0:14550"', "mission.gcs"),
        ("id = 9", 'id = 9\ngcs = "udpout:nowhere"', "mission.gcs"),
        ("id = 9", "id = 9\nfence = 1", "mission.fence"),
        ("id = 9", 'id = 9\nsigning_key = "no.key"', "mission.signing_key"),
        ('connection = "udpin:127.0.0.1:14552"', 'connection = "carrier-pigeon:1"', "vehicles[1].connection"),
        ('connection = "udpin:127.0.0.1:14552"', "connection = 14552", "vehicles[1].connection"),
        ("sysid = 2", 'sysid = 2\ndetector = "tcp:x"', "vehicles[1].detector"),
        ("sysid = 2", 'sysid = 2\ndetector = "udp:127.0.0.1:0"', "vehicles[1].detector"),
        ('channel = "udpout:127.0.0.1:14600"', 'channel = "udpin:0.0.0.0:14600"', "knowledge.channel"),
        ("[knowledge]", "[knowledge]\nfoo = 1", "knowledge.foo"),
        ("[knowledge]", "[knowledge]\ndigest_every = 0", "knowledge.digest_every"),
        ("[knowledge]", "[knowledge]\npush = 1", "knowledge.push"),
        ("[knowledge]", "[timing]\nstep_period = -1.0\n[knowledge]", "timing.step_period"),
        ("[knowledge]", "[timing]\ntime_limit = inf\n[knowledge]", "timing.time_limit"),
        ("[knowledge]", "[flight]\ntakeoff_at_once = 0\n[knowledge]", "flight.takeoff_at_once"),
        ("[knowledge]", "[flight]\ntelemetry_hz = true\n[knowledge]", "flight.telemetry_hz"),
        ("[knowledge]", "[battery]\nreturn_below = 50\n[knowledge]", "battery.return_below"),
        ("[knowledge]", "[battery]\ntakeoff_min = 101\n[knowledge]", "battery.takeoff_min"),
        ("[knowledge]", "timing = 3\n[knowledge]", "mission.timing"),
    ],
)
def test_each_bad_key_is_named(tmp_path, old, new, key):
    message = error(write(tmp_path, GOOD.replace(old, new, 1)))
    assert message.startswith(key + " ") and ";" in message


def test_missing_and_mistyped_tables(tmp_path):
    assert error(write(tmp_path, GOOD.split("[[vehicles]]")[0])) == (
        "[[vehicles]] is missing; add one [[vehicles]] table per vehicle (name, connection, sysid)"
    )
    assert error(write(tmp_path, "vehicles = []\n" + GOOD.split("[[vehicles]]")[0])).startswith("[[vehicles]] is empty")
    assert error(write(tmp_path, GOOD.split("[knowledge]", 1)[1].replace("channel", "[knowledge]\nchannel", 1))) == (
        "[mission] is missing; add a [mission] table with at least policy and grid or area"
    )
    assert error(write(tmp_path, "timing = 3\n" + GOOD)).startswith("[timing] must be a table")
    many = "".join(
        f'[[vehicles]]\nname = "v{i}"\nconnection = "udpin:127.0.0.1:{20000 + i}"\nsysid = {i % 250 + 1}\n'
        for i in range(251)
    )
    assert error(write(tmp_path, GOOD.split("[[vehicles]]")[0] + many)) == (
        "[[vehicles]]: 251 of them, more than the 250 a mission may have; fly fewer"
    )


def test_a_huge_file_is_refused_before_it_is_parsed(tmp_path):
    p = write(tmp_path, GOOD + "# " + "x" * MAX_BYTES + "\n")
    assert error(p) == "over 1000 kB, too large for a mission file; give the mission's TOML"


def test_not_toml_and_not_text(tmp_path):
    assert error(write(tmp_path, "[mission\nname=")).startswith("not valid TOML (")
    p = tmp_path / "bin.toml"
    p.write_bytes(b"\xff\xfe\x00mission")
    assert error(p) == "not a text file; a mission file is TOML"
    with pytest.raises(InputError, match="no such mission file"):
        load_spec(tmp_path / "none.toml")


def test_a_model_path_is_resolved_and_its_options_kept(tmp_path):
    (tmp_path / "m.pt").write_bytes(b"the plan loads it, not the spec")
    spec = "ddql:m.pt:tau=0.05:straggler=frontier"
    s = load_spec(write(tmp_path, GOOD.replace('policy = "la:4"', f'policy = "{spec}"')))
    assert s.mission.policy == f"ddql:{(tmp_path / 'm.pt').resolve()}:tau=0.05:straggler=frontier"


def test_the_chicago_mission_loads():
    s = load_spec(ROOT / "missions/chicago-loop/mission.toml")
    assert s.mission.name == "chicago-loop" and len(s.vehicles) == 3 and s.mission.grid.is_file()


# --- properties ---------------------------------------------------------------------------------------

NUMBERS = [
    (table, key)
    for table, model in TABLES.items()
    if table != "vehicles"
    for key in model.model_fields
    if model.bounds(key)[0] is not None
]


def _with(table: str, key: str, value: str) -> str:
    """GOOD with `key = value` in its table."""
    if table == "mission":
        return GOOD.replace("id = 9", f"id = {value}" if key == "id" else f"id = 9\n{key} = {value}", 1)
    if table == "knowledge":
        return GOOD.replace("[knowledge]", f"[knowledge]\n{key} = {value}", 1)
    return GOOD.replace("[knowledge]", f"[{table}]\n{key} = {value}\n[knowledge]", 1)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(NUMBERS), st.sampled_from(["nan", "inf", "-inf", "below", "above", "true", "string"]))
def test_every_number_is_finite_typed_and_in_range(tmp_path, where, bad):
    table, key = where
    lo, hi = TABLES[table].bounds(key)
    value = {"below": repr(lo - 1), "above": repr(hi + 1), "string": f'"{lo}"'}.get(bad, bad)
    message = error(write(tmp_path, _with(table, key, value)))
    assert message.startswith(f"{table}.{key} = ") and f"from {lo:g} to {hi:g}" in message


def _vehicles() -> st.SearchStrategy:
    host = st.sampled_from(["127.0.0.1", "0.0.0.0", "10.1.2.3", "gcs.local"])
    port = st.integers(1, 65535)
    link = st.one_of(
        st.builds(lambda k, h, p: f"{k}:{h}:{p}", st.sampled_from(["udpin", "udpout", "tcp"]), host, port),
        st.builds(lambda d, b: f"{d}:{b}", st.sampled_from(["/dev/ttyUSB0", "/dev/ttyACM1"]), st.integers(1, 921600)),
    )
    vehicle = st.fixed_dictionaries(
        {"connection": link},
        optional={
            "autopilot": st.sampled_from(["ardupilot", "px4"]),
            "detector": st.builds(lambda h, p: f"udp:{h}:{p}", host, port),
        },
    )

    def named(vs: list[dict]) -> list[dict]:
        return [{**v, "name": f"v{i}", "sysid": i + 1} for i, v in enumerate(vs)]

    return st.lists(vehicle, min_size=1, max_size=4).map(named)


def _table(model) -> st.SearchStrategy:
    """Any subset of a table's number, switch and choice keys, with values the spec must take."""
    optional = {}
    for key, info in model.model_fields.items():
        lo, hi = model.bounds(key)
        types = (info.annotation, *typing.get_args(info.annotation))
        if lo is not None and int in types:
            optional[key] = st.integers(lo, hi)
        elif lo is not None:
            optional[key] = st.floats(lo, hi, allow_nan=False)
        elif bool in types:
            optional[key] = st.booleans()
        elif typing.get_origin(info.annotation) is typing.Literal:
            optional[key] = st.sampled_from(typing.get_args(info.annotation))
    return st.fixed_dictionaries({}, optional=optional)


def _mission() -> st.SearchStrategy:
    place = st.sampled_from([{"grid": "grid.npz"}, {"area": "area.geojson"}, {"area": "a.kml", "buildings": "b.json"}])
    extra = st.fixed_dictionaries(
        {
            "name": st.from_regex(r"\A[A-Za-z0-9][A-Za-z0-9_.-]{0,20}\Z"),
            "policy": st.sampled_from(
                ["frontier", "random", "la:3", "ddql:m.pt", "ddql-greedy:m.pt:taken=keep", "pattern:sector"]
            ),
        },
        optional={
            "signing_key": st.just("swarm.key"),
            "gcs": st.builds(lambda p: f"udpout:127.0.0.1:{p}", st.integers(1, 65535)),
        },
    )
    return st.builds(lambda a, b, c: {**a, **b, **c}, _table(MissionTable), place, extra)


def _battery(b: dict) -> dict:
    """return_below at most takeoff_min, as the spec wants (given or default)."""
    if b:
        default = BatteryTable()
        b["return_below"] = min(b.get("return_below", default.return_below), b.get("takeoff_min", default.takeoff_min))
    return b


def _finish(d: dict) -> dict:
    """The finish line as the spec wants it: finish held (given or default) neither marks nor expects more
    targets than vehicles. And a pattern's keys with a pattern only: lkp with it, spacing_m nowhere else."""
    m = d["mission"]
    if m["policy"].startswith("pattern:"):
        m["lkp"] = [41.8819, -87.6278]
    else:
        m.pop("spacing_m", None)
    if m.get("finish", "held") == "held":
        if m.get("on_find") == "mark":
            m["on_find"] = "hold"
        if "expected_targets" in m:
            m["expected_targets"] = min(m["expected_targets"], len(d["vehicles"]))
    return d


SPECS = st.fixed_dictionaries(
    {"mission": _mission(), "vehicles": _vehicles()},
    optional={
        "timing": _table(TABLES["timing"]),
        "flight": _table(TABLES["flight"]),
        "battery": _table(TABLES["battery"]).map(_battery),
        "knowledge": st.builds(
            lambda t, c: {**t, **c},
            _table(TABLES["knowledge"]),
            st.fixed_dictionaries({}, optional={"channel": st.just("udpout:192.168.1.9:5000")}),
        ),
    },
).map(_finish)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("spec")
    for name in ("grid.npz", "area.geojson", "a.kml", "b.json", "swarm.key", "m.pt"):
        (folder / name).write_bytes(b"only its existence is checked")
    return folder


@settings(max_examples=120, deadline=None)
@given(SPECS)
def test_any_valid_spec_round_trips_through_toml(files, data):
    spec = validate(data, "generated", base=files)
    path = files / "dumped.toml"
    path.write_text(tomli_w.dumps(spec.model_dump(mode="json", exclude_none=True)))
    again = load_spec(path)
    assert again == spec
    for table in ("timing", "flight", "battery", "knowledge"):
        for key, value in data.get(table, {}).items():
            got = getattr(getattr(again, table), key)
            assert (str(got) if isinstance(got, Endpoint) else got) == value  # what was written is what is read


# --- the doc ---------------------------------------------------------------------------------------------


def test_the_doc_lists_every_key_of_the_spec_and_no_other():
    doc = (ROOT / "docs/mission.md").read_text()
    assert DOC_BEGIN in doc and DOC_END in doc
    table = doc.split(DOC_BEGIN, 1)[1].split(DOC_END, 1)[0].strip()
    documented = set(re.findall(r"^\| (\[\[?\w+\]\]?) \| `(\w+)` \|", table, re.MULTILINE))
    spec = {("[[vehicles]]" if t == "vehicles" else f"[{t}]", k) for t, m in TABLES.items() for k in m.model_fields}
    assert spec - documented == set(), "keys of the spec without a doc line"
    assert documented - spec == set(), "keys in the doc that the spec lacks"
    assert table == markdown_table(MissionSpec), "regenerate: python -m swarmctl.mission.spec --write docs/mission.md"
    keys_in_prose = set(re.findall(r"`(\w+) = ", doc.replace(table, "")))
    every = {k for m in TABLES.values() for k in m.model_fields}
    assert keys_in_prose <= every, f"the doc's examples name keys the spec lacks: {keys_in_prose - every}"
