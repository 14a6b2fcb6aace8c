"""PX4 through MAVSDK (the `mavsdk` 4.x package: a native libcmavsdk binding, no mavsdk_server process).

Every PX4/MAVSDK quirk the controller depends on lives here:
- MAVSDK's asyncio wrappers: `mavsdk.asyncio.Mavsdk`, `ActionAsync`, `TelemetryAsync` (`subscribe_*`
  async generators fed from MAVSDK's callback threads). Blocking calls run in the loop's executor.
- No position is streamed until a rate is set (`set_rate_position`), so connect() sets the rates.
- Health may never report "armable" (seen on simulators), so arming is retried instead of waiting for it.
- Takeoff altitude is the MIS_TAKEOFF_ALT parameter (`set_takeoff_altitude`), and goto takes an AMSL
  altitude: home AMSL + the wanted height above home.
- MAVSDK's Python binding exposes no MAVLink signing (descriptions.PX4.signing): sign at a router
  (mavlink-router) if needed.
- The speed parameters (descriptions.PX4.limit_parameters) are read with MAVSDK's param plugin.
- A geofence goes up with MAVSDK's geofence plugin (the mission protocol, mission_type FENCE). PX4 has
  no separate switch for it: an uploaded fence is enforced while GF_ACTION is not 0 (None).
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable
from typing import Any

from swarmctl.mavlink.autopilots.descriptions import PX4
from swarmctl.mavlink.codec import Endpoint, parse_connection
from swarmctl.mavlink.errors import (
    CommandRejected,
    CommandTimeout,
    MavlinkError,
    NotReady,
    WaitTimeout,
    WrongAutopilot,
)
from swarmctl.mavlink.network import cancel_tasks
from swarmctl.mavlink.vehicle import Home, Odometer, Position, Target, Vehicle, fence_vertices

log = logging.getLogger(__name__)
_mavsdk_log_installed = False

# MAVSDK flight-mode names -> the names swarmctl uses (descriptions.PX4_MODES)
_MODE_NAMES = {"RETURN_TO_LAUNCH": "RTL"}
# MAVSDK's autopilot types -> the autopilot names of swarmctl's descriptions
_AUTOPILOT_NAMES = {"PX4": "px4", "ARDUPILOT": "ardupilot"}


def _route_mavsdk_log() -> None:
    """Send MAVSDK's own log lines to Python logging instead of stdout."""
    global _mavsdk_log_installed
    if _mavsdk_log_installed:
        return
    from mavsdk import LogLevel, log_subscribe

    mlog = logging.getLogger("mavsdk")
    levels = {
        LogLevel.DEBUG: logging.DEBUG,
        LogLevel.INFO: logging.INFO,
        LogLevel.WARN: logging.WARNING,
        LogLevel.ERROR: logging.ERROR,
    }

    def forward(level: Any, message: str, file: str | None, line: int) -> bool:
        mlog.log(levels.get(level, logging.INFO), "%s", message)
        return True

    log_subscribe(forward)
    _mavsdk_log_installed = True


class PX4Vehicle(Vehicle):
    """A PX4 multicopter driven through MAVSDK, behind the same interface as ArduPilotVehicle."""

    autopilot_info = PX4

    def __init__(
        self,
        connection: str | Endpoint,
        *,
        sysid: int | None = None,
        name: str | None = None,
        telemetry_rate_hz: float = 5.0,
        arm_retry_period: float = 0.5,
    ):
        self.endpoint = connection if isinstance(connection, Endpoint) else parse_connection(connection)
        self.sysid = sysid
        self.name = name or (f"vehicle {sysid}" if sysid else f"PX4 at {self.endpoint}")
        self.telemetry_rate_hz = telemetry_rate_hz
        self.arm_retry_period = arm_retry_period
        self.target: Target | None = None
        self._sdk: Any = None
        self._system: Any = None
        self.action: Any = None
        self.telemetry: Any = None
        self.geofence: Any = None
        self.params: Any = None
        self.odometer = Odometer()
        self._tasks: list[asyncio.Task] = []
        self._position: Position | None = None
        self._home: Home | None = None
        self._armed = False
        self._mode = "UNKNOWN"
        self._connected = False
        self._battery: int | None = None
        self.reported_autopilot: str | None = None  # what MAVSDK identified: "px4", "ardupilot", "GENERIC"

    # --- connection --------------------------------------------------------------------------------

    async def connect(self, timeout: float = 15.0) -> None:
        from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
        from mavsdk.asyncio.plugins.action import ActionAsync
        from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

        _route_mavsdk_log()
        self._sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        try:
            await self._sdk.add_any_connection(self.endpoint.mavsdk_url())
        except Exception as exc:
            raise MavlinkError(f"{self.name}: MAVSDK cannot open {self.endpoint}: {exc}") from None
        deadline = time.monotonic() + timeout
        system = None
        while system is None:
            left = deadline - time.monotonic()
            if left <= 0:
                raise WaitTimeout("a PX4 autopilot", self.name, timeout)
            # first_autopilot, not get_systems: with mavsdk 4.1 a System taken from get_systems()
            # was seen to drop parameter writes (set_takeoff_altitude) silently.
            system = await self._sdk.first_autopilot(timeout_s=min(left, 1.0))
            if system is not None and self.sysid is not None and await system.get_system_id() != self.sysid:
                system = None
                for s in await self._sdk.get_systems():
                    if await s.get_system_id() == self.sysid and await s.has_autopilot():
                        system = s
                if system is None:
                    await asyncio.sleep(0.1)
        self._system = system
        self.sysid = await system.get_system_id()
        # MAVSDK picks PX4 or ArduPilot behaviour (parameters, modes) once it has identified the
        # autopilot; calls made before then can silently go nowhere, so wait for that first.
        # (an IntEnum: its str() is the number, so compare names)
        while (kind := (await system.autopilot_type()).name) == "UNKNOWN":
            if time.monotonic() > deadline:
                raise WaitTimeout("MAVSDK to identify the autopilot", self.name, timeout)
            await asyncio.sleep(0.05)
        self.reported_autopilot = _AUTOPILOT_NAMES.get(kind, kind)
        if self.reported_autopilot != PX4.name:
            raise WrongAutopilot(self.name, self.reported_autopilot, PX4.name)
        self.action, self.telemetry = ActionAsync(system), TelemetryAsync(system)
        self._connected = True
        follow = {
            "subscribe_position": self._on_position,
            "subscribe_home": self._on_home,
            "subscribe_armed": self._on_armed,
            "subscribe_flight_mode": self._on_mode,
            "subscribe_battery": self._on_battery,
        }
        self._tasks = [
            asyncio.create_task(self._follow(getattr(self.telemetry, sub), cb)) for sub, cb in follow.items()
        ]
        self._tasks.append(asyncio.create_task(self._follow(system.is_connected_state, self._on_connected)))
        await self._call("set_rate_position", self.telemetry.set_rate_position, self.telemetry_rate_hz)
        for setter in ("set_rate_home", "set_rate_battery"):
            try:
                await self._call(setter, getattr(self.telemetry, setter), 1.0)
            except MavlinkError as exc:  # optional streams
                log.info("%s: %s", self.name, exc)

    @staticmethod
    async def _follow(generator_fn: Any, callback: Any) -> None:
        async for item in generator_fn():
            callback(item)

    def _on_position(self, p: Any) -> None:
        if math.isfinite(p.latitude_deg) and (p.latitude_deg or p.longitude_deg):
            self._position = Position(p.latitude_deg, p.longitude_deg, p.relative_altitude_m, p.absolute_altitude_m)
            self.odometer.add(self._position)

    def _on_home(self, h: Any) -> None:
        if math.isfinite(h.latitude_deg) and (h.latitude_deg or h.longitude_deg):
            self._home = Home(h.latitude_deg, h.longitude_deg, h.absolute_altitude_m)

    def _on_armed(self, armed: bool) -> None:
        self._armed = bool(armed)

    def _on_mode(self, mode: Any) -> None:
        self._mode = _MODE_NAMES.get(mode.name, mode.name)

    def _on_battery(self, b: Any) -> None:
        pct = getattr(b, "remaining_percent", float("nan"))
        self._battery = int(pct) if math.isfinite(pct) else None

    def _on_connected(self, connected: bool) -> None:
        self._connected = bool(connected)
        log.info("%s: %s", self.name, "back" if connected else "lost")

    async def _call(self, what: str, fn: Any, *args: Any) -> Any:
        """Await a MAVSDK call, turning its errors into the link's CommandRejected/CommandTimeout."""
        try:
            return await fn(*args)
        except Exception as exc:
            result = getattr(exc, "result", None)
            rname = getattr(result, "name", type(exc).__name__)
            if rname == "TIMEOUT":
                raise CommandTimeout(what, self.name, 0, 0.0) from None
            raise CommandRejected(what, self.name, rname, str(exc)) from None

    async def wait_ready(self, timeout: float = 60.0, report: Callable[[str], None] | None = None) -> None:
        """Position and home known; PX4's health flags are not waited for (arming is retried)."""

        def missing() -> list[str]:
            return [what for what, known in (("a position", self._position), ("home", self._home)) if known is None]

        waiting = ""
        deadline = time.monotonic() + timeout
        while lacking := missing():
            if (text := "waiting for " + ", ".join(lacking)) != waiting:
                waiting = text
                if report is not None:
                    report(text)
            if time.monotonic() > deadline:
                raise NotReady(self.name, timeout, waiting)
            await asyncio.sleep(0.05)

    async def read_parameter(self, name: str) -> float:
        """A parameter through MAVSDK's param plugin (float, else int)."""
        from mavsdk.asyncio.plugins.param import ParamAsync

        if self._system is None:
            raise MavlinkError(f"{self.name}: not connected, cannot read {name}")
        if self.params is None:
            self.params = ParamAsync(self._system)
        try:
            return float(await self._call(f"reading parameter {name}", self.params.get_param_float, name))
        except CommandRejected as exc:
            if "WRONG_TYPE" not in (exc.result + exc.reason):
                raise
        return float(await self._call(f"reading parameter {name}", self.params.get_param_int, name))

    async def close(self) -> None:
        await cancel_tasks(self._tasks)
        self._tasks = []
        if self._sdk is not None:
            self._sdk.destroy()
            self._sdk = None

    # --- commands -------------------------------------------------------------------------------------

    async def set_mode(self, mode: str) -> None:
        actions = {"HOLD": "hold", "LAND": "land", "RTL": "return_to_launch"}
        name = mode.upper()
        if name not in actions:
            raise ValueError(f"PX4 mode {mode!r} is not supported here; use one of {', '.join(actions)}")
        await self._call(f"set mode {name}", getattr(self.action, actions[name]))

    async def arm(self, timeout: float = 30.0) -> None:
        deadline = time.monotonic() + timeout
        while True:
            try:
                await self._call("arm", self.action.arm)
                break
            except CommandRejected as exc:
                if not PX4.retries_arm(exc.result) or time.monotonic() > deadline:
                    raise
                log.info("%s: arming refused (%s), retrying", self.name, exc.result)
                await asyncio.sleep(self.arm_retry_period)
        await self._poll(lambda: self._armed, 3.0, "the armed state")

    async def arm_and_takeoff(self, rel_alt: float, timeout: float = 120.0) -> None:
        start = time.monotonic()
        left = lambda: max(1.0, timeout - (time.monotonic() - start))  # noqa: E731
        await self.wait_ready(left())
        await self._call("set_takeoff_altitude", self.action.set_takeoff_altitude, float(rel_alt))
        got = await self._call("get_takeoff_altitude", self.action.get_takeoff_altitude)
        if got is None or abs(float(got) - rel_alt) > 0.1:
            raise MavlinkError(f"{self.name}: take-off altitude reads back as {got}, not {rel_alt:g} m")
        await self.arm(min(30.0, left()))
        await self._call("takeoff", self.action.takeoff)
        pos = self._position
        assert pos is not None
        self.target = Target(pos.lat, pos.lon, rel_alt)
        await self._poll(
            lambda: (p := self._position) is not None and p.rel_alt >= 0.95 * rel_alt,
            left(),
            f"take-off altitude {rel_alt:g} m",
        )

    async def goto(self, lat: float, lon: float, rel_alt: float) -> None:
        home = self._home
        if home is None:
            raise MavlinkError(f"{self.name}: no home position yet, cannot convert to AMSL")
        self.target = Target(lat, lon, rel_alt)
        await self._call("goto_location", self.action.goto_location, lat, lon, home.alt_amsl + rel_alt, float("nan"))

    async def land(self) -> None:
        await self._call("land", self.action.land)

    async def rtl(self) -> None:
        await self._call("return_to_launch", self.action.return_to_launch)

    async def resume(self) -> None:
        # Hold stops a return or a landing; PX4 then accepts repositions (goto) in flight
        self.target = None
        await self.set_mode(PX4.command_mode)

    async def upload_fence(self, polygon: list[tuple[float, float]]) -> None:
        """Upload polygon as PX4's inclusion geofence (MAVSDK geofence plugin). PX4 enforces it as its
        GF_ACTION says (default Hold) and ignores repositions outside it."""
        from mavsdk.asyncio.plugins.geofence import FenceType, GeofenceAsync, GeofenceData, Point, Polygon

        vertices = fence_vertices(polygon)
        if self._system is None:
            raise MavlinkError(f"{self.name}: not connected, cannot upload a fence")
        if self.geofence is None:
            self.geofence = GeofenceAsync(self._system)
        fence = Polygon([Point(lat, lon) for lat, lon in vertices], FenceType.INCLUSION)
        await self._call("upload_geofence", self.geofence.upload_geofence, GeofenceData([fence], []))

    # --- state ----------------------------------------------------------------------------------------

    @property
    def position(self) -> Position | None:
        return self._position

    @property
    def home(self) -> Home | None:
        return self._home

    @property
    def armed(self) -> bool:
        return self._armed

    @property
    def mode(self) -> str:
        return self._mode

    @property
    def lost(self) -> bool:
        return not self._connected

    @property
    def battery_remaining(self) -> int | None:
        return self._battery
