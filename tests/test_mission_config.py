"""Mission files: a good one loads; every bad one is one line naming the key and the fix."""

import textwrap

import pytest

from swarmctl.errors import InputError
from swarmctl.mission.config import load_mission
from swarmctl.policy.checkpoint import save_checkpoint
from swarmctl.policy.qnet import QNetwork

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


def test_a_good_mission_loads(tmp_path):
    m = load_mission(write(tmp_path, GOOD))
    assert m.mission_id == 9 and m.end_action == "land" and m.altitude == 40.0
    assert [v.name for v in m.vehicles] == ["alpha", "bravo"]
    assert m.vehicles[1].autopilot == "px4" and m.grid == (tmp_path / "grid.npz").resolve()
    assert m.fence is False


def test_fence_is_a_switch(tmp_path):
    m = load_mission(write(tmp_path, GOOD.replace("id = 9", "id = 9\nfence = true", 1)))
    assert m.fence is True
    with pytest.raises(InputError) as err:
        load_mission(write(tmp_path, GOOD.replace("id = 9", 'id = 9\nfence = "yes"', 1)))
    assert str(err.value) == (
        f"{tmp_path / 'm.toml'}: mission.fence must be true or false, not 'yes'; write "
        "fence = true to upload the search area's boundary to every vehicle as its "
        "geofence, or leave it out"
    )


@pytest.mark.parametrize(
    "old, new, key",
    [
        ('name = "test"', 'name = "test"\nspeed = 3', "mission.speed"),
        ('grid = "grid.npz"', 'grid = "nope.npz"', "mission.grid"),
        ('grid = "grid.npz"', "", "mission.grid"),
        ('name = "bravo"', 'name = "alpha"', "vehicles[1].name"),
        ("sysid = 2", "sysid = 1", "vehicles[1].sysid"),
        ("sysid = 2", "sysid = 300", "vehicles[1].sysid"),
        ("sysid = 2", 'sysid = "two"', "vehicles[1].sysid"),
        ('autopilot = "px4"', 'autopilot = "inav"', "vehicles[1].autopilot"),
        ('end_action = "land"', 'end_action = "crash"', "mission.end_action"),
        ('policy = "la:4"', 'policy = "magic"', "mission.policy"),
        ('policy = "la:4"', 'policy = "ddql:missing.pt"', "mission.policy"),
        ("id = 9", "id = 70000", "mission.id"),
        ("id = 9", 'id = 9\ngcs = "udpin:0.0.0.0:14550"', "mission.gcs"),
        ("id = 9", 'id = 9\ngcs = "udpout:nowhere"', "mission.gcs"),
        ("id = 9", "id = 9\nfence = 1", "mission.fence"),
        ('connection = "udpin:127.0.0.1:14552"', 'connection = "carrier-pigeon:1"', "vehicles[1].connection"),
        ("[knowledge]", "[knowledge]\nfoo = 1", "knowledge.foo"),
    ],
)
def test_each_bad_key_is_named(tmp_path, old, new, key):
    p = write(tmp_path, GOOD.replace(old, new, 1))
    with pytest.raises(InputError) as err:
        load_mission(p)
    assert key in str(err.value) and str(p) in str(err.value)
    assert "\n" not in str(err.value)


def test_a_model_for_another_observation_size_is_refused(tmp_path):
    save_checkpoint(tmp_path / "small.pt", QNetwork(8), {}, {}, {})
    p = write(tmp_path, GOOD.replace('policy = "la:4"', 'policy = "ddql:small.pt"'))
    with pytest.raises(InputError, match="mission.policy.*trained for 8 x 8"):
        load_mission(p)


def test_a_model_with_options_keeps_them_and_a_bad_option_is_named(tmp_path):
    save_checkpoint(tmp_path / "m.pt", QNetwork(20), {}, {}, {})
    spec = "ddql:m.pt:tau=0.05:straggler=frontier"
    cfg = load_mission(write(tmp_path, GOOD.replace('policy = "la:4"', f'policy = "{spec}"')))
    assert cfg.policy == f"ddql:{(tmp_path / 'm.pt').resolve()}:tau=0.05:straggler=frontier"
    p = write(tmp_path, GOOD.replace('policy = "la:4"', 'policy = "ddql:m.pt:straggler=maybe"'))
    with pytest.raises(InputError, match="mission.policy.*straggler must be network or frontier"):
        load_mission(p)


def test_not_toml(tmp_path):
    p = write(tmp_path, "[mission\nname=")
    with pytest.raises(InputError, match="not valid TOML"):
        load_mission(p)
