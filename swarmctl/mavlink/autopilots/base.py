"""What swarmctl needs to know about an autopilot firmware, asked as questions, and the registry that
finds the description a vehicle's HEARTBEAT names.

An `Autopilot` describes a firmware, not a vehicle: its MAV_AUTOPILOT id, its flight modes
(HEARTBEAT.custom_mode numbers), which modes mean a pilot has taken over, how long a mode report must
last before it counts, how it refuses an arm that is not ready yet, which parameters give a vehicle's
speeds (and so its timeouts), what signing means on the path swarmctl flies it by, and the driver
class that flies it (by name: the connector imports it). The controller, the connector and the mock
autopilot ask these questions instead of comparing autopilot names. Nothing here does I/O or imports
pymavlink or MAVSDK.
"""

from __future__ import annotations

import abc
import importlib
from collections.abc import Mapping
from typing import ClassVar, TypeVar

from swarmctl.errors import InputError
from swarmctl.mavlink.limits import FlightLimits

_BY_ID: dict[int, Autopilot] = {}
_BY_NAME: dict[str, Autopilot] = {}


class Autopilot(abc.ABC):
    """One autopilot firmware as swarmctl flies it. One instance per firmware is registered with `register`."""

    name: ClassVar[str]  # the mission file's `autopilot` value: "ardupilot", "px4"
    label: ClassVar[str]  # for messages: "ArduPilot", "PX4"
    mav_autopilot: ClassVar[int]  # HEARTBEAT.autopilot (MAV_AUTOPILOT)
    command_mode: ClassVar[str]  # the mode swarmctl steers the vehicle in with position targets
    mode_debounce_s: ClassVar[float] = 0.0  # a pilot's mode must be reported this long before it counts
    # the modes the vehicle's own failsafes switch to (GCS link, battery): one found in them when its link
    # comes back is taken back into the search; any other pilot's mode was a person's choice and is kept
    failsafe_modes: ClassVar[frozenset[str]] = frozenset()
    signs_link: ClassVar[bool]  # the mission's signing key signs this vehicle's MAVLink
    signing: ClassVar[str]  # what signing means on the path swarmctl flies it by
    arm_refusal: ClassVar[str]  # the MAV_RESULT the autopilot answers an arm with while it is not ready
    driver_path: ClassVar[str]  # "module:Class" of the Vehicle driver (swarmctl.mavlink.connect.driver_of)
    # the parameters the driver reads at preflight for `flight_limits` (empty: none can be read, so the
    # firmware's defaults give every vehicle's timeouts)
    limit_parameters: ClassVar[tuple[str, ...]] = ()
    # True: the driver opens the vehicle's connection itself (MAVSDK) and cannot share a pymavlink link
    own_connection: ClassVar[bool] = False
    # the parameters that say what the vehicle does by itself, read at preflight (mission/failsafes.py):
    # when the controller's heartbeats stop (the GCS failsafe), on a low battery, on a geofence breach
    gcs_failsafe_parameter: ClassVar[str] = ""
    battery_failsafe_parameter: ClassVar[str] = ""
    fence_failsafe_parameter: ClassVar[str] = ""
    gcs_failsafe_fix: ClassVar[str] = ""  # how to turn the GCS failsafe on: "set ... to ..."
    # parameter -> {value: what the vehicle does}; a value missing from a table is reported by number
    failsafe_actions: ClassVar[Mapping[str, Mapping[int, str]]] = {}

    def failsafe_action(self, parameter: str, value: float) -> str:
        """What the vehicle does when `parameter` (one of the failsafe parameters) has `value`."""
        if not float(value).is_integer():  # NaN, infinite or a fraction: not one of its values
            return f"unknown ({parameter} {value!r})"
        unknown = f"{parameter} {int(value)} (unknown to swarmctl)"
        return self.failsafe_actions.get(parameter, {}).get(int(value), unknown)

    def failsafe_is_off(self, parameter: str, value: float) -> bool:
        """True when `parameter` at `value` makes the vehicle do nothing (its failsafe is off): the
        values its table says "nothing" for (0 for each of them; PX4's GF_ACTION 1 too), and a value that
        is no whole number (nothing can be told from it)."""
        action = self.failsafe_action(parameter, value)
        return action.startswith("nothing") or action.startswith("unknown (")

    @property
    @abc.abstractmethod
    def modes(self) -> Mapping[str, int]:
        """The flight modes swarmctl knows by name, with their HEARTBEAT.custom_mode."""

    @abc.abstractmethod
    def mode_name(self, custom_mode: int) -> str:
        """The name of a HEARTBEAT.custom_mode (a made-up but stable name for modes not in `modes`)."""

    def custom_mode(self, name: str) -> int:
        """The HEARTBEAT.custom_mode of a mode name; ValueError naming the known modes otherwise."""
        try:
            return self.modes[name.upper()]
        except KeyError:
            raise ValueError(f"unknown {self.label} mode {name!r}; known: {', '.join(self.modes)}") from None

    @abc.abstractmethod
    def set_mode_params(self, name: str) -> tuple[float, float]:
        """MAV_CMD_DO_SET_MODE's param2 and param3 (param1 is MAV_MODE_FLAG_CUSTOM_MODE_ENABLED) for a mode."""

    @abc.abstractmethod
    def custom_mode_from_command(self, param2: float, param3: float) -> int:
        """The custom_mode a MAV_CMD_DO_SET_MODE with these param2 and param3 asks for."""

    @abc.abstractmethod
    def is_pilot_mode(self, mode: str) -> bool:
        """True when a vehicle reported in `mode` (as its driver names it) is no longer flown by swarmctl:
        the pilot took it over."""

    @abc.abstractmethod
    def flight_limits(self, values: Mapping[str, float]) -> FlightLimits:
        """A vehicle's speeds from the `limit_parameters` values read (by name, in the firmware's own
        units); a parameter missing, or not a usable number, counts as the firmware's default."""

    def silent_port_hint(self, port: int | None, sysid: int | None) -> str:
        """Why no vehicle of this firmware may be heard on `port` (the mission's UDP port, None for other
        links) with this system id, and the fix; "" when there is nothing to say."""
        return ""

    def retries_arm(self, result: str) -> bool:
        """True when an arm refused with this MAV_RESULT name means "not ready yet, try again"."""
        return result in (self.arm_refusal, "TEMPORARILY_REJECTED")

    def __repr__(self) -> str:
        return f"<autopilot {self.name} (MAV_AUTOPILOT {self.mav_autopilot})>"


_A = TypeVar("_A", bound="Autopilot")


def register(description: _A) -> _A:
    """Make `description` the one for its MAV_AUTOPILOT id and its name; returns it."""
    _BY_ID[description.mav_autopilot] = description
    _BY_NAME[description.name] = description
    return description


def autopilot_for_heartbeat(mav_autopilot: int) -> Autopilot | None:
    """The description of the autopilot a HEARTBEAT's `autopilot` field names; None for firmware
    swarmctl does not fly."""
    _load()
    return _BY_ID.get(int(mav_autopilot))


def autopilot_named(name: str, field: str = "autopilot") -> Autopilot:
    """The description of the autopilot with this mission-file name; InputError naming `field` otherwise."""
    _load()
    try:
        return _BY_NAME[name]
    except KeyError:
        raise InputError(f"{field} = {name!r} is unknown; use one of {', '.join(sorted(_BY_NAME))}") from None


def registered() -> tuple[Autopilot, ...]:
    """Every registered description, by MAV_AUTOPILOT id."""
    _load()
    return tuple(_BY_ID[k] for k in sorted(_BY_ID))


def _load() -> None:
    importlib.import_module("swarmctl.mavlink.autopilots.descriptions")  # registers the firmwares
