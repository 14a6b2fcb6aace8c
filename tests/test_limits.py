"""A vehicle's speeds from its parameters, the physics of its manoeuvres, and the timeouts they give."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarmctl.mavlink.autopilots.descriptions import ARDUPILOT, PX4
from swarmctl.mavlink.limits import MARGIN, SLACK_S, FlightLimits, timeout_for, travel_s
from swarmctl.mavlink.vehicle import Odometer, Position

# ArduCopter 4.7 SITL's parameters (copter.parm and firmware defaults), as read there
SITL_PARAMS = {
    "WPNAV_SPEED": 1000.0,
    "WPNAV_ACCEL": 250.0,
    "WPNAV_SPEED_UP": 250.0,
    "WPNAV_SPEED_DN": 150.0,
    "LAND_SPEED": 50.0,
    "LAND_SPEED_HIGH": 0.0,
    "LAND_ALT_LOW": 1000.0,
    "RTL_ALT": 1500.0,
    "RTL_SPEED": 0.0,
    "RTL_LOIT_TIME": 5000.0,
}


def test_the_physics_matches_what_arducopter_sitl_flew():
    """The x1 timings of ArduCopter SITL with its default parameters: a 10 m move within 0.5 m after 4.2 s,
    50 m after 9.4 s, the climb to 39.5 m 21.1 s after the take-off's ack, a landing from 40 m disarmed
    after 44.4 s, a return from 51.7 m out at 40 m disarmed after 62.2 s."""
    limits = ARDUPILOT.flight_limits(SITL_PARAMS)
    assert limits.read == tuple(SITL_PARAMS)
    assert (limits.speed, limits.accel, limits.climb, limits.descent, limits.land_speed) == (10.0, 2.5, 2.5, 1.5, 0.5)
    assert limits.rtl_speed == 10.0 and limits.rtl_alt == 15.0 and limits.rtl_loiter_s == 5.0  # 0 means WPNAV_SPEED
    for physics, sitl, within in (
        (limits.move_s(10.0), 4.2, 0.5),
        (limits.move_s(50.0), 9.4, 0.5),
        (limits.takeoff_s(39.5), 21.1, 1.0),
        (limits.land_s(40.0), 44.4, 1.5),
        (limits.rtl_s(51.7, 40.0), 62.2, 5.0),
    ):
        assert abs(physics - sitl) <= within, (physics, sitl)
    assert limits.move_timeout(10.0) == MARGIN * limits.move_s(10.0) + SLACK_S


def test_zero_and_unusable_parameters_fall_back_to_what_the_firmware_does():
    limits = ARDUPILOT.flight_limits({"WPNAV_SPEED": 500.0, "WPNAV_SPEED_DN": 100.0, "LAND_SPEED_HIGH": 0.0})
    assert limits.descent == 1.0  # LAND_SPEED_HIGH 0: the landing descends at WPNAV_SPEED_DN
    assert limits.rtl_speed == 5.0  # RTL_SPEED missing: WPNAV_SPEED
    bad = ARDUPILOT.flight_limits({"WPNAV_SPEED": math.nan, "WPNAV_SPEED_UP": -3.0, "WPNAV_ACCEL": 0.0})
    default = ARDUPILOT.flight_limits({})
    assert (bad.speed, bad.climb, bad.accel) == (default.speed, default.climb, default.accel)
    assert bad.read == ("WPNAV_SPEED", "WPNAV_ACCEL", "WPNAV_SPEED_UP") and default.read == ()


def test_px4_speeds_come_from_its_own_parameters():
    limits = PX4.flight_limits({"MPC_XY_CRUISE": 8.0, "MPC_TKO_SPEED": 1.0, "MPC_LAND_SPEED": 0.5})
    assert (limits.speed, limits.rtl_speed, limits.climb, limits.land_speed) == (8.0, 8.0, 1.0, 0.5)
    assert PX4.flight_limits({}).takeoff_s(40.0) > ARDUPILOT.flight_limits({}).takeoff_s(40.0)  # 1.5 vs 2.5 m/s


def test_a_limit_that_is_no_speed_is_refused():
    with pytest.raises(ValueError, match="FlightLimits.climb must be a positive number"):
        FlightLimits(10, 2.5, 0.0, 1.5, 0.5, 10, 15, 10, 5, 5, 4)


distances = st.floats(0.0, 5000.0)
speeds = st.floats(0.1, 30.0)


@given(distances, distances, speeds, st.floats(0.1, 10.0))
def test_travel_takes_longer_the_farther_and_never_less_than_at_full_speed(a, b, speed, accel):
    near, far = sorted((a, b))
    assert travel_s(near, speed, accel) <= travel_s(far, speed, accel) + 1e-9
    assert travel_s(far, speed, accel) >= far / speed - 1e-9


@given(distances, st.floats(-100.0, 100.0), st.floats(0.0, 300.0))
def test_every_timeout_is_the_physics_with_the_margin(horizontal, vertical, height):
    limits = ARDUPILOT.flight_limits({})
    for physics, timeout in (
        (limits.move_s(horizontal, vertical), limits.move_timeout(horizontal, vertical)),
        (limits.land_s(height), limits.land_timeout(height)),
        (limits.rtl_s(horizontal, height), limits.rtl_timeout(horizontal, height)),
    ):
        assert timeout == timeout_for(physics) >= physics + SLACK_S
    assert limits.rtl_s(horizontal, height) >= limits.land_s(max(height, limits.rtl_alt))


def test_the_odometer_counts_the_flight_in_3d_and_not_the_ground():
    o = Odometer()
    lat, lon = 41.879653, -87.635357
    for rel_alt in (0.0, 0.02, 0.01, 0.0):  # GPS noise on the ground: nothing
        o.add(Position(lat + rel_alt * 1e-6, lon, rel_alt, 180.0))
    assert o.metres == 0.0
    for rel_alt in (0.3, 10.0, 40.0):  # the climb from 0.3 m: 39.7 m
        o.add(Position(lat, lon, rel_alt, 180.0 + rel_alt))
    o.add(Position(lat + 30.0 / 111_319.5, lon, 40.0, 220.0))  # 30 m north at 40 m
    assert o.metres == pytest.approx(39.7 + 30.0, abs=0.05)
