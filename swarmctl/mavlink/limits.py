"""How fast a vehicle flies, and the timeouts that follow from it and the distances flown.

`FlightLimits` holds a vehicle's speeds in SI units (what its firmware's speed parameters say: ArduPilot's
WPNAV_SPEED, WPNAV_SPEED_UP, LAND_SPEED, ...; PX4's MPC_XY_CRUISE, MPC_TKO_SPEED, MPC_LAND_SPEED, ...;
each firmware's description turns its parameters into one, see autopilots/descriptions.py) and the
physics of a move, a take-off, a landing and a return home. The timeouts are that physics with a
margin: `MARGIN` times the physics plus `SLACK_S` (command round trips, the last half metre, a loaded
simulator). All times are vehicle seconds: a simulator running faster than the wall clock only makes
them more generous. Pure: no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

MARGIN = 2.0  # a timeout is MARGIN x the physics ...
SLACK_S = 5.0  # ... plus this many seconds

# Two heights above home that tell a flying vehicle from one on the ground, for two uses that err on
# opposite sides. Counting the distance flown, a stretch counts once either end is AIRBORNE_M high or
# higher: low, so that the whole climb and descent count and only the noise of a vehicle standing on
# the ground does not (a stretch counted in error adds that noise, centimetres). Taking a vehicle back
# after a link loss (mission.launch.Launch.rejoin), an armed vehicle higher than RESUME_ABOVE_M is resumed in
# the air, else it takes off again: higher, so that a landed vehicle whose altitude reads somewhat high
# (barometer drift) still gets the take-off a resume would never give it.
AIRBORNE_M = 0.5  # the odometer (Vehicle.distance_flown_m) and the replay's distance flown
RESUME_ABOVE_M = 1.0  # rejoin: resume in the air above this, take off again below


def timeout_for(physics_s: float) -> float:
    """The timeout of something the physics says takes `physics_s` seconds."""
    return MARGIN * max(0.0, physics_s) + SLACK_S


def travel_s(distance: float, speed: float, accel: float) -> float:
    """Seconds to fly `distance` metres from a stop to a stop, accelerating and braking at `accel`
    (m/s^2) up to `speed` (m/s): the triangular profile when the distance is too short to reach it."""
    distance = abs(distance)
    if distance < speed * speed / accel:
        return 2.0 * math.sqrt(distance / accel)
    return distance / speed + speed / accel


@dataclass(frozen=True)
class FlightLimits:
    """A vehicle's speeds (m/s, m/s^2, metres, seconds) and the physics of its manoeuvres.

    `read` names the parameters these came from; empty: the firmware's defaults (not read)."""

    speed: float  # horizontal speed to a position target
    accel: float  # horizontal acceleration
    climb: float  # climb rate (take-off)
    descent: float  # descent rate above land_alt_low
    land_speed: float  # final descent rate, below land_alt_low
    land_alt_low: float  # height where the final descent starts
    rtl_alt: float  # the return's minimum altitude above home
    rtl_speed: float  # horizontal speed of the return
    rtl_loiter_s: float  # hover over home before the return's descent
    spool_s: float  # from the take-off command to leaving the ground
    disarm_s: float  # from touching down to disarmed
    settle_s: float = 0.5  # from arriving to holding within the reach tolerance (0.5 m)
    read: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        for name in ("speed", "accel", "climb", "descent", "land_speed", "rtl_speed"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"FlightLimits.{name} must be a positive number of m/s, not {value!r}")
        for name in ("land_alt_low", "rtl_alt", "rtl_loiter_s", "spool_s", "disarm_s", "settle_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"FlightLimits.{name} must be a number >= 0, not {value!r}")

    def with_read(self, names: tuple[str, ...]) -> FlightLimits:
        return replace(self, read=tuple(names))

    # --- physics (vehicle seconds) ----------------------------------------------------------------------
    def move_s(self, horizontal: float, vertical: float = 0.0) -> float:
        """A move of `horizontal` metres and `vertical` metres up (> 0) or down (< 0), both at once, and
        settling at the target."""
        up_down = vertical / self.climb if vertical > 0 else -vertical / self.descent
        return max(travel_s(horizontal, self.speed, self.accel), up_down) + self.settle_s

    def takeoff_s(self, altitude: float) -> float:
        """From the take-off command to `altitude` metres above home."""
        return self.spool_s + max(0.0, altitude) / self.climb

    def descent_s(self, height: float) -> float:
        """Down from `height` metres to the ground: `descent` to land_alt_low, then `land_speed`."""
        height = max(0.0, height)
        low = min(height, self.land_alt_low)
        return (height - low) / self.descent + low / self.land_speed

    def land_s(self, height: float) -> float:
        """A landing from `height` metres, until disarmed."""
        return self.descent_s(height) + self.disarm_s

    def rtl_s(self, distance: float, height: float) -> float:
        """A return from `distance` metres away and `height` metres up, until disarmed: climb to
        rtl_alt if lower, fly home at rtl_speed, hover rtl_loiter_s, land."""
        cruise = max(height, self.rtl_alt)
        climb = (cruise - max(0.0, height)) / self.climb
        home = travel_s(distance, self.rtl_speed, self.accel)
        return climb + home + self.rtl_loiter_s + self.land_s(cruise)

    # --- timeouts --------------------------------------------------------------------------------------
    def move_timeout(self, horizontal: float, vertical: float = 0.0) -> float:
        return timeout_for(self.move_s(horizontal, vertical))

    def takeoff_timeout(self, altitude: float) -> float:
        return timeout_for(self.takeoff_s(altitude))

    def land_timeout(self, height: float) -> float:
        return timeout_for(self.land_s(height))

    def rtl_timeout(self, distance: float, height: float) -> float:
        return timeout_for(self.rtl_s(distance, height))
