"""The autopilot descriptions (mode tables, the registry, the questions the controller asks) and the mock's
personalities built on them."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as MAV

from swarmctl.errors import InputError
from swarmctl.mavlink.autopilots import AUTOPILOT_NAMES
from swarmctl.mavlink.autopilots.ardupilot import ArduPilotVehicle
from swarmctl.mavlink.autopilots.base import autopilot_for_heartbeat, autopilot_named, registered
from swarmctl.mavlink.autopilots.descriptions import ARDUPILOT, PX4, px4_decode, px4_encode
from swarmctl.mavlink.autopilots.px4 import PX4Vehicle
from swarmctl.mavlink.codec import MAV_RESULT_NAMES
from swarmctl.mavlink.connect import driver_of
from swarmctl.sim.autopilot import MockAutopilot
from swarmctl.sim.personality import PERSONALITIES, personality_named

DESCRIPTIONS = (ARDUPILOT, PX4)
described_mode = st.sampled_from(DESCRIPTIONS).flatmap(lambda a: st.tuples(st.just(a), st.sampled_from(list(a.modes))))


@given(described_mode)
def test_every_mode_name_round_trips_through_its_table(pair):
    autopilot, name = pair
    custom_mode = autopilot.custom_mode(name)
    assert 0 <= custom_mode < 2**32
    assert autopilot.mode_name(custom_mode) == name
    assert autopilot.custom_mode(name.lower()) == custom_mode  # names are case-blind


@given(described_mode)
def test_do_set_mode_params_ask_for_the_mode_they_were_made_from(pair):
    autopilot, name = pair
    param2, param3 = autopilot.set_mode_params(name)
    assert autopilot.custom_mode_from_command(param2, param3) == autopilot.custom_mode(name)


@given(st.sampled_from(DESCRIPTIONS), st.integers(0, 2**32 - 1))
def test_any_reported_custom_mode_has_a_stable_name(autopilot, custom_mode):
    name = autopilot.mode_name(custom_mode)
    assert name and name == autopilot.mode_name(custom_mode)
    if name in autopilot.modes:  # a known mode: its canonical number has the same name
        assert autopilot.mode_name(autopilot.custom_mode(name)) == name
    else:
        with pytest.raises(ValueError, match="known: "):
            autopilot.custom_mode(name)


@given(st.integers(0, 255), st.integers(0, 255))
def test_px4_custom_mode_round_trip(main_mode, sub_mode):
    cm = px4_encode(main_mode, sub_mode)
    assert 0 <= cm < 2**32 and cm & 0xFFFF == 0
    assert px4_decode(cm) == (main_mode, sub_mode)


def test_the_numbers_the_firmwares_put_in_heartbeat_custom_mode():
    assert ARDUPILOT.custom_mode("GUIDED") == 4 and ARDUPILOT.mode_name(6) == "RTL"
    assert ARDUPILOT.mode_name(99) == "MODE99"
    assert PX4.custom_mode("HOLD") == 0x03040000 and PX4.mode_name(0x03040000) == "HOLD"  # AUTO.LOITER
    assert PX4.mode_name(px4_encode(6)) == "OFFBOARD" and PX4.mode_name(px4_encode(4, 5)) == "RTL"
    assert PX4.mode_name(px4_encode(3, 7)) == "POSCTL"  # an unknown sub mode of a known main mode
    assert PX4.mode_name(px4_encode(9, 1)) == "PX4(9,1)"


def test_the_registry_finds_a_description_by_heartbeat_and_by_mission_name():
    assert autopilot_for_heartbeat(MAV.MAV_AUTOPILOT_ARDUPILOTMEGA) is ARDUPILOT
    assert autopilot_for_heartbeat(MAV.MAV_AUTOPILOT_PX4) is PX4
    for other in (MAV.MAV_AUTOPILOT_GENERIC, MAV.MAV_AUTOPILOT_INVALID, 200):
        assert autopilot_for_heartbeat(other) is None
    assert tuple(sorted(a.name for a in registered())) == tuple(sorted(AUTOPILOT_NAMES))  # the mission's values
    assert all(autopilot_named(name).name == name for name in AUTOPILOT_NAMES)
    with pytest.raises(InputError) as err:
        autopilot_named("inav", "mission.toml: vehicles[1].autopilot")
    assert str(err.value) == "mission.toml: vehicles[1].autopilot = 'inav' is unknown; use one of ardupilot, px4"


def test_each_description_names_its_driver_and_the_driver_its_description():
    assert driver_of(ARDUPILOT) is ArduPilotVehicle and ArduPilotVehicle.autopilot_info is ARDUPILOT
    assert driver_of(PX4) is PX4Vehicle and PX4Vehicle.autopilot_info is PX4
    assert not ARDUPILOT.own_connection and PX4.own_connection  # PX4: MAVSDK opens the connection


@pytest.mark.parametrize(
    "autopilot, mode, pilot",
    [
        (ARDUPILOT, "GUIDED", False),
        (ARDUPILOT, "UNKNOWN", False),
        (ARDUPILOT, "LOITER", True),
        (ARDUPILOT, "RTL", True),  # the vehicle's own failsafe takes it as a pilot would
        (PX4, "HOLD", False),
        (PX4, "TAKEOFF", False),
        (PX4, "RTL", False),
        (PX4, "POSCTL", True),
        (PX4, "RATTITUDE", True),  # MAVSDK's name, although swarmctl's table has no number for it
    ],
)
def test_a_pilots_mode_by_firmware(autopilot, mode, pilot):
    assert autopilot.is_pilot_mode(mode) is pilot


def test_the_answers_that_differ_by_firmware():
    assert (ARDUPILOT.command_mode, PX4.command_mode) == ("GUIDED", "HOLD")
    assert (ARDUPILOT.mode_debounce_s, PX4.mode_debounce_s) == (0.0, 1.5)
    assert ARDUPILOT.signs_link and not PX4.signs_link and "not available" in PX4.signing
    assert ARDUPILOT.retries_arm("FAILED") and not ARDUPILOT.retries_arm("DENIED")
    assert PX4.retries_arm("COMMAND_DENIED")  # MAVSDK's own name for a refused arm


@pytest.mark.parametrize("name", AUTOPILOT_NAMES)
def test_a_personality_is_built_on_its_firmwares_description(name):
    p = personality_named(name)
    a = p.autopilot
    assert a is autopilot_named(name) and p.name == name
    for mode in (p.boot_mode, p.breach_mode, a.command_mode, *p.target_modes, *p.setpoint_modes):
        assert mode in a.modes
    assert a.command_mode in p.target_modes
    assert a.retries_arm(MAV_RESULT_NAMES[p.arm_refused])  # the driver retries what the mock answers
    # after boot: ArduCopter in STABILIZE (a pilot's mode), PX4 SITL in AUTO.LOITER (HOLD, swarmctl's)
    assert p.boot_mode == {"ardupilot": "STABILIZE", "px4": "HOLD"}[name]


@pytest.mark.parametrize("name", AUTOPILOT_NAMES)
def test_the_mock_plays_the_personality_it_is_given(name):
    mock = MockAutopilot(autopilot=name, speed=7.0, climb_rate=3.0)
    p = PERSONALITIES[name]
    assert mock.personality is p and mock.autopilot == name
    # the parameters: the personality's defaults, those that are its speeds saying what the mock flies at
    speeds = {n: getattr(mock, attribute) / scale for n, (attribute, scale) in p.physics_params.items()}
    assert mock.params == {**p.params, **speeds} and mock.params is not p.params
    limits = p.autopilot.flight_limits(mock.params)
    assert (limits.speed, limits.climb) == (7.0, 3.0) and limits.descent == mock.descent_rate
    assert mock.mode_name == p.boot_mode
    assert mock.intervals == dict(p.default_streams)
    mock.mav = MAV.MAVLink(None, srcSystem=1, srcComponent=1)
    hb = mock._heartbeat()
    assert hb.autopilot == p.autopilot.mav_autopilot and p.autopilot.mode_name(hb.custom_mode) == p.boot_mode


def test_an_unknown_autopilot_for_the_mock_names_the_choices():
    with pytest.raises(ValueError, match="autopilot must be 'ardupilot' or 'px4', not 'inav'"):
        MockAutopilot(autopilot="inav")
