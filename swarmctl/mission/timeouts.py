"""The mission's waits for a vehicle: the `[timing]` value when the mission gives one, else derived from
the vehicle's speeds (its FlightLimits: the parameters read at preflight, or its firmware's defaults)
and the distance it flies, with the margin of swarmctl.mavlink.limits (2 x the physics + 5 s).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from swarmctl.mavlink.codec import distance_m

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.mavlink.vehicle import Vehicle


def takeoff(given: float | None, vehicle: Vehicle, altitude: float) -> float:
    """Arming and climbing to `altitude` metres above home."""
    return given if given is not None else vehicle.limits.takeoff_timeout(altitude)


def move(given: float | None, vehicle: Vehicle, lat: float, lon: float, rel_alt: float) -> float:
    """Flying from where the vehicle is to (lat, lon, rel_alt); from the ground when its position is
    not known."""
    if given is not None:
        return given
    pos = vehicle.position
    if pos is None:
        return vehicle.limits.move_timeout(0.0, rel_alt)
    return vehicle.limits.move_timeout(distance_m(pos.lat, pos.lon, lat, lon), rel_alt - pos.rel_alt)


def end(given: float | None, vehicle: Vehicle, action: str, altitude: float) -> float:
    """Landing after the end action ("land": where it is; "rtl": home first), until disarmed; from
    `altitude` when the vehicle's position is not known."""
    if given is not None:
        return given
    pos, home = vehicle.position, vehicle.home
    height = pos.rel_alt if pos is not None else altitude
    if action == "rtl":
        away = distance_m(pos.lat, pos.lon, home.lat, home.lon) if pos is not None and home is not None else 0.0
        return vehicle.limits.rtl_timeout(away, height)
    return vehicle.limits.land_timeout(height)
