"""Connecting a vehicle: the driver is chosen by what the vehicle reports, not by a name in a file.

`Connector.connect` opens (or shares) the vehicle's pymavlink `MavlinkLink`, waits for its HEARTBEAT
and reads the `autopilot` field; the description registered for it (autopilots/base.py) names the
driver. ArduPilot is flown on that link. A PX4 is flown through MAVSDK, which opens the connection
itself: a link that carries only this vehicle is closed and handed over; a shared one is an error
(PX4 vehicles need a connection each). When the mission names the autopilot, it must agree with the
report, or `AutopilotMismatch` (an InputError: `fly` exits 2) stops the mission; a mission naming PX4
goes to MAVSDK at once and MAVSDK's autopilot type is checked instead.
"""

from __future__ import annotations

import asyncio
import importlib
import logging
import time
from collections import Counter
from collections.abc import Callable

from swarmctl.errors import InputError
from swarmctl.mavlink.autopilots import AUTOPILOT_NAMES
from swarmctl.mavlink.autopilots.base import Autopilot, autopilot_for_heartbeat, autopilot_named, registered
from swarmctl.mavlink.codec import Endpoint, parse_connection
from swarmctl.mavlink.errors import MavlinkError, WaitTimeout, WrongAutopilot
from swarmctl.mavlink.network import MavlinkLink
from swarmctl.mavlink.vehicle import Home, Position, Vehicle

log = logging.getLogger(__name__)


class AutopilotMismatch(InputError):
    """What a vehicle reports about its autopilot does not fit the mission: its `autopilot` key says
    another firmware, or a PX4 shares its connection with other vehicles."""


def driver_of(autopilot: Autopilot) -> type[Vehicle]:
    """The Vehicle class that flies `autopilot` (its `driver_path`, imported on first use)."""
    module, _, cls = autopilot.driver_path.partition(":")
    return getattr(importlib.import_module(module), cls)


class Connector:
    """Builds each vehicle's driver from what the vehicle reports, sharing the pymavlink links.

    `links` maps each connection (normalised, `str(Endpoint)`) to its open MavlinkLink; the connector
    adds the links it opens (after calling `on_open(link)`) and removes the ones it hands to MAVSDK.
    Call `expect(connection)` once for every vehicle to be connected before connecting any, so that a
    link's sharing is known when a PX4 shows up on it.
    """

    def __init__(
        self,
        links: dict[str, MavlinkLink],
        *,
        signing_key: bytes | None = None,
        telemetry_hz: float = 5.0,
        on_open: Callable[[MavlinkLink], None] | None = None,
        source: str = "the mission file",
        first_link_id: int | None = None,
    ):
        self.links = links
        # the signing link id of the first link opened (None: the lowest free in this process); onboard
        # agents, one process each, pass their vehicle's index so no two sign as the same stream
        self.first_link_id = first_link_id
        self.signing_key = signing_key
        self.telemetry_hz = telemetry_hz
        self.on_open = on_open
        self.source = source  # where the `autopilot` keys come from, for messages
        self._users: Counter[str] = Counter()
        self._opening = asyncio.Lock()

    def expect(self, connection: str | Endpoint) -> None:
        """Count one more vehicle on this connection."""
        self._users[str(_endpoint(connection))] += 1

    async def connect(
        self,
        connection: str | Endpoint,
        sysid: int,
        *,
        name: str,
        autopilot: str | None = None,
        timeout: float = 15.0,
    ) -> Vehicle:
        """The connected driver of vehicle `sysid` on `connection`. `autopilot` is the mission's key for
        it (None: fly what the vehicle reports). Raises AutopilotMismatch when the key disagrees with the
        vehicle or a PX4 shares its connection, MavlinkError / WaitTimeout when the vehicle cannot be
        reached or flies firmware swarmctl does not fly."""
        endpoint = _endpoint(connection)
        deadline = time.monotonic() + timeout
        expected = autopilot_named(autopilot, f"{self.source}: {name}: autopilot") if autopilot else None
        if expected is not None and expected.own_connection:
            try:
                return await self._start(expected, endpoint, sysid, name, deadline)
            except WrongAutopilot as exc:  # the driver checks the type its library identified
                said = exc.reported
                reported = autopilot_named(said) if said in AUTOPILOT_NAMES else f"autopilot type {said} (MAVSDK)"
                raise self._mismatch(name, sysid, endpoint, reported, expected) from None
        link = await self._link(endpoint)
        try:
            peer = await link.wait_heartbeat(sysid, _left(deadline))
        except WaitTimeout as exc:
            raise with_port_hints(exc, endpoint, sysid) from None
        kind = peer.heartbeat.autopilot
        found = autopilot_for_heartbeat(kind)
        if found is None:
            flies = ", ".join(f"{a.label} ({a.mav_autopilot})" for a in registered())
            what = f"MAV_AUTOPILOT {kind}, which swarmctl does not fly (it flies {flies})"
            if expected is not None:
                raise self._mismatch(name, sysid, endpoint, what, expected)
            raise MavlinkError(f"{name}: system id {sysid} on {endpoint} reports {what}")
        if expected is not None and found is not expected:
            raise self._mismatch(name, sysid, endpoint, found, expected)
        if not found.own_connection:
            return await self._start(found, endpoint, sysid, name, deadline, link)
        key = str(endpoint)
        if self._users[key] > 1:
            raise AutopilotMismatch(
                f"{self.source}: {name} (system id {sysid}) reports a {found.label} autopilot, which swarmctl flies "
                f"on a connection of its own ({driver_of(found).__name__}), but {endpoint} carries {self._users[key]} "
                f"vehicles; give {name} its own connection (e.g. its own UDP port)"
            )
        del self.links[key]
        await link.close()
        log.info(
            "%s: a %s autopilot; its connection %s goes to %s", name, found.label, endpoint, driver_of(found).__name__
        )
        return await self._start(found, endpoint, sysid, name, deadline)

    async def _link(self, endpoint: Endpoint) -> MavlinkLink:
        """The open link of this endpoint, opened (and announced to on_open) on first use."""
        key = str(endpoint)
        async with self._opening:
            link = self.links.get(key)
            if link is None:
                try:
                    link_id = self.first_link_id if not self.links else None
                    link = await MavlinkLink(endpoint, signing_key=self.signing_key, link_id=link_id).open()
                except OSError as exc:
                    raise MavlinkError(f"cannot open {endpoint}: {exc.strerror or exc}") from None
                if self.on_open is not None:
                    self.on_open(link)
                self.links[key] = link
            return link

    async def _start(
        self,
        autopilot: Autopilot,
        endpoint: Endpoint,
        sysid: int,
        name: str,
        deadline: float,
        link: MavlinkLink | None = None,
    ) -> Vehicle:
        """Build autopilot's driver (on `link`, or on the endpoint for drivers with their own connection)
        and connect it within the time left; it is closed again if that fails."""
        driver: Callable[..., Vehicle] = driver_of(autopilot)  # each firmware's driver takes its own arguments
        if autopilot.own_connection:
            if self.signing_key is not None and not autopilot.signs_link:
                log.warning("%s: %s signing is %s", name, autopilot.label, autopilot.signing)
            vehicle = driver(endpoint, sysid=sysid, name=name, telemetry_rate_hz=self.telemetry_hz)
        else:
            vehicle = driver(link, sysid, name=name, telemetry_rate_hz=self.telemetry_hz)
        try:
            await vehicle.connect(_left(deadline))
        except BaseException:
            await vehicle.close()
            raise
        return vehicle

    def _mismatch(
        self, name: str, sysid: int, endpoint: Endpoint, reported: Autopilot | str, expected: Autopilot
    ) -> AutopilotMismatch:
        """The one-line error: the vehicle, what it reported, what the file says, the fix."""
        if isinstance(reported, Autopilot):
            says = f"a {reported.label} autopilot"
            fix = f'write autopilot = "{reported.name}" for it, or leave the key out to fly what the vehicle reports'
        else:
            says, fix = reported, "check its connection and system id"
        return AutopilotMismatch(
            f"{self.source}: {name} (system id {sysid} on {endpoint}) reports {says}, "
            f'but autopilot = "{expected.name}" is set for it; {fix}'
        )


class NotConnected:
    """Stands for a vehicle until it is connected, with the state the controller reads: no telemetry,
    not armed, lost, autopilot not known."""

    autopilot_info = None
    autopilot = None
    position: Position | None = None
    home: Home | None = None
    armed = False
    mode = "UNKNOWN"
    lost = True
    battery_remaining: int | None = None
    target = None
    distance_flown_m = 0.0

    def __init__(self, name: str):
        self.name = name

    async def close(self) -> None:
        """Nothing to release."""


def with_port_hints(exc: WaitTimeout, endpoint: Endpoint, sysid: int) -> WaitTimeout:
    """The timeout, with what each firmware says about a vehicle not heard on this port (PX4 SITL's port
    wrap above instance 9)."""
    port = endpoint.port if endpoint.kind == "udpin" else None
    hints = [h for a in registered() if (h := a.silent_port_hint(port, sysid))]
    if not hints:
        return exc
    return WaitTimeout(exc.what, exc.vehicle, exc.timeout, "; ".join(hints))


def _endpoint(connection: str | Endpoint) -> Endpoint:
    return connection if isinstance(connection, Endpoint) else parse_connection(connection)


def _left(deadline: float) -> float:
    return max(0.1, deadline - time.monotonic())
