"""PX4 through MAVSDK (the `mavsdk` 4.x package: a native libcmavsdk binding, no mavsdk_server process).

Every PX4/MAVSDK quirk the controller depends on lives here (checked against PX4 SITL, ../shared/px4):
- MAVSDK's asyncio wrappers: `mavsdk.asyncio.Mavsdk`, `ActionAsync`, `TelemetryAsync` (`subscribe_*`
  async generators fed from MAVSDK's callback threads), `MavlinkDirectAsync`. Blocking calls run in the
  loop's executor.
- connect() waits for MAVSDK's System to say is_connected() and has_autopilot() and for its autopilot
  type (calls made before can go nowhere); a vehicle not found names what was heard instead and, on a
  port of a PX4 SITL instance above 9, the port such instances really send to (14549).
- PX4 streams GLOBAL_POSITION_INT at ~50 Hz unasked; connect() sets MAVSDK's rates (position 5 Hz).
- Ready means a position, home, and MAVSDK's health for the local and global position estimates and
  home; "armable" was seen never to come on simulators, so arming is retried instead of waited for.
- Takeoff altitude is the MIS_TAKEOFF_ALT parameter (`set_takeoff_altitude`; PX4's default 2.5 m).
- A position target goes out in OFFBOARD where the vehicle allows it (descriptions.PX4: its
  COM_OBL_RC_ACT, read during the take-off, says it holds, returns or lands when the stream stops):
  SET_POSITION_TARGET_GLOBAL_INT with an AMSL altitude through MAVSDK's offboard plugin, which repeats
  it at 20 Hz from its own thread and stops at the first heartbeat that is not OFFBOARD from 3 s after
  `start()` on. The first target is followed by `start()` (the mode change, acknowledged); the next
  ones go out at once without an answer (`goto_nowait`). A refused start falls back to the reposition
  below for that target, and after PX4.offboard_refusals in a row for good. The driver never takes the
  vehicle from a pilot's mode (PX4.is_pilot_mode): a target given then is kept and not sent. `reached`
  is horizontal, with PX4.reach_vertical_m of slack in height (SITL's altitude estimate wanders 1.9 m).
- The reposition is MAV_CMD_DO_REPOSITION as COMMAND_INT with an AMSL altitude (home AMSL + the height
  above home), sent through MavlinkDirect with its COMMAND_ACK read here: MAVSDK's own command sender
  (goto_location, MavlinkDirect.send_command) cannot take an UNSUPPORTED_MAV_FRAME answer (send_command
  aborted the process, goto_location kept resending and never returned). The frame is the first of
  descriptions.PX4.reposition_frames the vehicle takes, kept per vehicle.
- Knowledge TUNNELs go out on the vehicle's link through MavlinkDirect, from MAVSDK's own system and
  component ids (245/190), unsigned; their payload names the sending vehicle.
- No MAVLink signing: MAVSDK's Python binding has none, and PX4 SITL has no MAV_SIGN_CFG
  (descriptions.PX4.signing); sign at a router (mavlink-router) if the link needs it.
- The speed parameters (descriptions.PX4.limit_parameters) are read with MAVSDK's param plugin.
- A geofence goes up with MAVSDK's geofence plugin (the mission protocol, mission_type FENCE). PX4 has
  no separate switch for it: an uploaded fence is enforced while GF_ACTION is not 0 (None); a reposition
  outside it is ACCEPTED and the vehicle holds ("Reposition is outside geofence").
- PX4 sets home again at every arming (COM_HOME_EN 1): a return goes to where the vehicle last armed.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from swarmctl.mavlink.autopilots.descriptions import PX4, REPOSITION_FRAME_REFUSED
from swarmctl.mavlink.codec import Endpoint, distance_m, parse_connection
from swarmctl.mavlink.errors import (
    CommandRejected,
    CommandTimeout,
    MavlinkError,
    WaitTimeout,
    WrongAutopilot,
)
from swarmctl.mavlink.network import MAV, cancel_tasks
from swarmctl.mavlink.vehicle import Home, Odometer, Position, Target, Vehicle

if TYPE_CHECKING:  # pragma: no cover
    from mavsdk.asyncio.plugins.offboard import OffboardAsync

log = logging.getLogger(__name__)
_mavsdk_log_installed = False

# MAVSDK flight-mode names -> the names swarmctl uses (descriptions.PX4_MODES)
_MODE_NAMES = {"RETURN_TO_LAUNCH": "RTL"}
# MAVSDK's autopilot types -> the autopilot names of swarmctl's descriptions
_AUTOPILOT_NAMES = {"PX4": "px4", "ARDUPILOT": "ardupilot"}
_RESULT_NAMES = {REPOSITION_FRAME_REFUSED: "UNSUPPORTED_MAV_FRAME"}
_FRAME_NAMES = {0: "GLOBAL", 5: "GLOBAL_INT"}
_COMMAND_ACK_S, _COMMAND_ATTEMPTS = 1.0, 3  # a COMMAND_INT sent through MavlinkDirect: wait, attempts
_OUTBOX_MAX = 256  # knowledge frames waiting for MAVSDK; more are dropped (the bus has them all the same)
_PARAMETER_WAIT_S = 5.0  # close() waits this long for a parameter read in flight (MAVSDK gives up after 3 s)


def result_name(result: int) -> str:
    """The MAV_RESULT name of a COMMAND_ACK result."""
    entry = MAV.enums["MAV_RESULT"].get(result)
    return _RESULT_NAMES.get(result) or (entry.name.removeprefix("MAV_RESULT_") if entry else f"MAV_RESULT {result}")


def _json(fields: dict[str, Any]) -> str:
    """A message's fields as MavlinkDirect's JSON (NaN, which JSON lacks, as null)."""
    return json.dumps({k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in fields.items()})


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
    armed_report = "the armed state"
    takeoff_attempts = 3  # arm and take-off sent again after a disarm on the ground

    def __init__(
        self,
        connection: str | Endpoint,
        *,
        sysid: int | None = None,
        name: str | None = None,
        telemetry_rate_hz: float = 5.0,
        arm_retry_period: float = 0.5,
        offboard: bool = True,
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
        self._landed_state = "UNKNOWN"  # MAVSDK's LandedState name (EXTENDED_SYS_STATE's landed_state)
        self._mode = "UNKNOWN"
        self._connected = False
        self._battery: int | None = None
        self.reported_autopilot: str | None = None  # what MAVSDK identified: "px4", "ardupilot", "GENERIC"
        self.direct: Any = None  # MAVSDK's MavlinkDirect plugin: raw COMMAND_INT and TUNNEL
        self.reposition_frame: int | None = None  # the MAV_FRAME this vehicle accepted a reposition in
        self._health: Any = None
        self._acks: asyncio.Queue[dict[str, Any]] = asyncio.Queue()
        self._command_lock = asyncio.Lock()
        self._outbox: asyncio.Queue[dict[str, Any]] = asyncio.Queue(_OUTBOX_MAX)
        self._parser = MAV.MAVLink(None)
        self.frames_sent = 0  # knowledge frames MAVSDK sent on the vehicle's link
        # steering in OFFBOARD (see the module's docstring); `offboard=False`: repositions only
        self.offboard_wanted = offboard
        self.steering = "reposition"  # how the last position target went out: "offboard" or "reposition"
        self.offboard_loss: str | None = None  # what the vehicle does when the stream stops; None: not known
        self._offboard: OffboardAsync | None = None
        self._offboard_check: asyncio.Task | None = None  # reads PX4.offboard_loss_parameter (_begin_offboard_check)
        self._offboard_ok = False  # OFFBOARD may be used: its loss action read and safe, not refused for good
        self._offboard_started = False  # the driver asked for OFFBOARD and has asked for no other mode since
        self._offboard_refused = 0  # refused starts in a row
        self._pilot_warned = ""  # the pilot's mode a target was last held back in

    # --- connection --------------------------------------------------------------------------------

    async def connect(self, timeout: float = 15.0) -> None:
        from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
        from mavsdk.asyncio.plugins.action import ActionAsync
        from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
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
                raise WaitTimeout("a PX4 autopilot", self.name, timeout, await self._silence())
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
        await self._wait_link(system, deadline, timeout)
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
        self.direct = MavlinkDirectAsync(system)
        self._connected = True
        follow = {
            "subscribe_position": self._on_position,
            "subscribe_home": self._on_home,
            "subscribe_armed": self._on_armed,
            "subscribe_landed_state": self._on_landed_state,
            "subscribe_flight_mode": self._on_mode,
            "subscribe_battery": self._on_battery,
            "subscribe_health": self._on_health,
        }
        self._tasks = [
            asyncio.create_task(self._follow(getattr(self.telemetry, sub), cb)) for sub, cb in follow.items()
        ]
        self._tasks.append(asyncio.create_task(self._follow(system.is_connected_state, self._on_connected)))
        acks = lambda: self.direct.subscribe_message("COMMAND_ACK")  # noqa: E731
        self._tasks.append(asyncio.create_task(self._follow(acks, self._on_ack)))
        self._tasks.append(asyncio.create_task(self._send_frames()))
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

    async def _silence(self) -> str:
        """What was heard instead of this PX4, and the instance-port wrap when the port is one of it."""
        heard = {await s.get_system_id(): await s.is_connected() for s in await self._sdk.get_systems()}
        if self.sysid in heard and not heard[self.sysid]:
            said = f"system id {self.sysid} is heard on {self.endpoint} but sends no HEARTBEAT"
        elif heard:
            said = f"heard system ids {', '.join(map(str, sorted(heard)))} on {self.endpoint}"
            said += f", not {self.sysid}" if self.sysid is not None else ", none of them an autopilot"
        else:
            said = f"nothing heard on {self.endpoint}"
        port = self.endpoint.port if self.endpoint.kind == "udpin" else None
        hint = PX4.silent_port_hint(port, self.sysid)
        return f"{said}; {hint}" if hint else said

    async def _wait_link(self, system: Any, deadline: float, timeout: float) -> None:
        """MAVSDK's System is_connected() and has_autopilot(): a first script without this wait stalled."""
        while True:
            lacking = [
                what
                for what, ok in (
                    ("is_connected()", await system.is_connected()),
                    ("has_autopilot()", await system.has_autopilot()),
                )
                if not ok
            ]
            if not lacking:
                return
            if time.monotonic() > deadline:
                raise WaitTimeout("MAVSDK's link to the PX4", self.name, timeout, "false: " + ", ".join(lacking))
            await asyncio.sleep(0.05)

    def _on_position(self, p: Any) -> None:
        if math.isfinite(p.latitude_deg) and (p.latitude_deg or p.longitude_deg):
            self._position = Position(p.latitude_deg, p.longitude_deg, p.relative_altitude_m, p.absolute_altitude_m)
            self.odometer.add(self._position)
            self._position_reported()

    def _on_home(self, h: Any) -> None:
        if math.isfinite(h.latitude_deg) and (h.latitude_deg or h.longitude_deg):
            self._home = Home(h.latitude_deg, h.longitude_deg, h.absolute_altitude_m)

    def _on_armed(self, armed: bool) -> None:
        self._armed = bool(armed)

    def _on_landed_state(self, state: Any) -> None:
        self._landed_state = getattr(state, "name", str(state))

    def _on_mode(self, mode: Any) -> None:
        self._mode = _MODE_NAMES.get(mode.name, mode.name)

    def _on_battery(self, b: Any) -> None:
        pct = getattr(b, "remaining_percent", float("nan"))
        self._battery = int(pct) if math.isfinite(pct) else None

    def _on_health(self, h: Any) -> None:
        self._health = h

    def _on_ack(self, m: Any) -> None:
        try:
            ack = json.loads(m.fields_json)
        except ValueError:
            return
        if m.system_id == self.sysid:
            self._acks.put_nowait(ack)

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

    def not_ready(self) -> list[str]:
        """What the vehicle lacks to be flown: a position and home, and MAVSDK's health for the local and
        global position estimates and the home position (empty: ready; arming is retried, not waited for:
        MAVSDK's "armable" was seen never to come on simulators)."""
        h = self._health
        health = (
            ("a local position estimate (health)", h is not None and h.is_local_position_ok),
            ("a global position estimate (health)", h is not None and h.is_global_position_ok),
            ("home position OK (health)", h is not None and h.is_home_position_ok),
        )
        known = (("a position", self._position is not None), ("home", self._home is not None), *health)
        return [what for what, ok in known if not ok]

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

    def _begin_offboard_check(self) -> None:
        """Read the offboard-loss action in the background, once (the take-off starts it, else the first
        `goto`; that target and those before the answer go as repositions). Not at connect: MAVSDK reads one
        parameter at a time, and a parameter the vehicle lacks holds the others up for its 3 s of retries."""
        if self.offboard_wanted and self._offboard_check is None and self._system is not None:
            self._offboard_check = asyncio.create_task(self._check_offboard_loss())
            self._tasks.append(self._offboard_check)

    async def _check_offboard_loss(self) -> None:
        """Read what the vehicle does when the OFFBOARD setpoint stream stops (PX4.offboard_loss_parameter) and
        allow OFFBOARD when that is one of PX4.offboard_loss_safe; a parameter that cannot be read allows none."""
        from mavsdk.asyncio.plugins.offboard import OffboardAsync

        name = PX4.offboard_loss_parameter
        try:
            value = await self.read_parameter(name)
        except MavlinkError as exc:
            log.info("%s: %s not read (%s): steering by reposition", self.name, name, exc)
            return
        self.offboard_loss = PX4.failsafe_action(name, value)
        if not (value.is_integer() and int(value) in PX4.offboard_loss_safe):
            log.warning(
                "%s: %s %g (%s) is not a safe end for a lost OFFBOARD setpoint stream: steering by reposition "
                "(set it to 5, hold, or 3, return, to steer in OFFBOARD)",
                self.name, name, value, self.offboard_loss,
            )  # fmt: skip
            return
        self._offboard = OffboardAsync(self._system)
        self._offboard_ok = True
        log.info("%s: steers in OFFBOARD; if its setpoint stream stops: %s (%s %g)", self.name, self.offboard_loss,
                 name, value)  # fmt: skip

    async def close(self) -> None:
        self._offboard_started = False
        check = self._offboard_check
        if check is not None and not check.done():
            # its parameter read is a blocking MAVSDK call in the loop's executor: destroying MAVSDK under it
            # leaves that thread blocked for good (and asyncio.run waiting for it); it ends within MAVSDK's
            # retries (3 s where the vehicle lacks the parameter)
            await asyncio.wait({check}, timeout=_PARAMETER_WAIT_S)
        await cancel_tasks(self._tasks)
        self._tasks = []
        if self._offboard is not None:
            self._offboard.destroy()
            self._offboard = None
        if self.direct is not None:
            self.direct.destroy()
            self.direct = None
        if self._sdk is not None:
            self._sdk.destroy()
            self._sdk = None

    # --- commands -------------------------------------------------------------------------------------

    async def set_mode(self, mode: str) -> None:
        actions = {"HOLD": "hold", "LAND": "land", "RTL": "return_to_launch"}
        name = mode.upper()
        if name not in actions:
            raise ValueError(f"PX4 mode {mode!r} is not supported here; use one of {', '.join(actions)}")
        self._offboard_started = False  # MAVSDK's stream stops by itself once the vehicle has left OFFBOARD
        await self._call(f"set mode {name}", getattr(self.action, actions[name]))

    async def _send_arm(self) -> None:
        await self._call("arm", self.action.arm)

    def _refusal(self, exc: CommandRejected) -> str:
        return exc.result  # MAVSDK's refusals are logged by their result alone

    async def _prepare_takeoff(self, rel_alt: float, left: Callable[[], float]) -> None:
        """The take-off altitude is MIS_TAKEOFF_ALT, set and read back; the target is set before arming."""
        await self._call("set_takeoff_altitude", self.action.set_takeoff_altitude, float(rel_alt))
        got = await self._call("get_takeoff_altitude", self.action.get_takeoff_altitude)
        if got is None or abs(float(got) - rel_alt) > 0.1:
            raise MavlinkError(f"{self.name}: take-off altitude reads back as {got}, not {rel_alt:g} m")
        await self._aim_above(rel_alt, left(), "before take-off")

    async def _take_off(self, rel_alt: float, left: Callable[[], float]) -> None:
        # A loaded SITL sometimes takes the take-off and then disarms on the ground in HOLD (its
        # pre-flight auto-disarm): `arm_and_takeoff` arms and sends it again (takeoff_attempts)
        await self._call("takeoff", self.action.takeoff)
        self._begin_offboard_check()  # answered during the climb

    async def goto(self, lat: float, lon: float, rel_alt: float) -> None:
        """The position target in OFFBOARD (entering it when the vehicle is not in it yet) where the driver
        steers in OFFBOARD, else as a reposition; kept but not sent while a pilot's mode is reported."""
        home = self._home
        if home is None:
            raise MavlinkError(f"{self.name}: no home position yet, cannot convert to AMSL")
        self.target = Target(lat, lon, rel_alt)
        if self._pilot_has_it():
            return
        alt = home.alt_amsl + rel_alt
        self._begin_offboard_check()
        if self._offboard_ok and self._set_point(lat, lon, alt):
            if self._in_offboard() or await self._start_offboard():
                return
        await self.reposition(lat, lon, alt)
        self.steering = "reposition"

    def goto_nowait(self, lat: float, lon: float, rel_alt: float) -> bool:
        """In OFFBOARD (entered by `goto`): the new position target goes out at once, no answer awaited; False
        otherwise (use `goto`)."""
        home = self._home
        if home is None or not self._in_offboard():  # (a pilot's mode is not OFFBOARD: `goto` keeps the target)
            return False
        if not self._set_point(lat, lon, home.alt_amsl + rel_alt):
            return False
        self.target = Target(lat, lon, rel_alt)
        return True

    def reached(self, tolerance: float = 1.0) -> bool:
        """Within `tolerance` metres of the target horizontally and within the larger of it and
        PX4.reach_vertical_m vertically (PX4 SITL's altitude estimate wanders up to 1.9 m in a steady hover)."""
        pos, tgt = self.position, self.target
        if pos is None or tgt is None:
            return False
        memo = self._reached_memo
        if memo is not None and memo[0] is pos and memo[1] is tgt and memo[2] == tolerance:
            return memo[3]
        horizontal = distance_m(pos.lat, pos.lon, tgt.lat, tgt.lon)
        answer = horizontal <= tolerance and abs(pos.rel_alt - tgt.rel_alt) <= max(tolerance, PX4.reach_vertical_m)
        self._reached_memo = (pos, tgt, tolerance, answer)
        return answer

    def _pilot_has_it(self) -> bool:
        """A pilot's mode is reported: no target is sent (the controller marks the takeover itself)."""
        mode = self._mode
        if not PX4.is_pilot_mode(mode):
            self._pilot_warned = ""
            return False
        if self._pilot_warned != mode:
            self._pilot_warned = mode
            log.warning("%s: in %s, a pilot's mode: the position target is not sent", self.name, mode)
        return True

    def _in_offboard(self) -> bool:
        """The driver entered OFFBOARD and the vehicle still reports it."""
        return self._offboard_started and self._mode == "OFFBOARD"

    def _set_point(self, lat: float, lon: float, alt_amsl: float) -> bool:
        """Hand MAVSDK the OFFBOARD position target (AMSL, yaw as it is); it sends it now and repeats it at
        20 Hz. A blocking C call that waits for nothing from the vehicle. False when MAVSDK refuses it."""
        from mavsdk.plugins.offboard import PositionGlobalYaw

        if self._offboard is None:
            return False
        target = PositionGlobalYaw(lat, lon, alt_amsl, math.nan, PositionGlobalYaw.AltitudeType.AMSL)
        try:
            self._offboard._plugin.set_position_global(target)  # the blocking plugin under the asyncio one
        except Exception as exc:  # OffboardError: no system, connection error
            log.info("%s: MAVSDK did not take the OFFBOARD position target: %s", self.name, exc)
            return False
        return True

    async def _start_offboard(self) -> bool:
        """Ask for OFFBOARD (MAVSDK's `start`: the mode change, acknowledged); False when refused. After
        PX4.offboard_refusals refusals in a row the driver steers by reposition for good."""
        assert self._offboard is not None
        try:
            await self._call("offboard start", self._offboard.start)
        except MavlinkError as exc:
            self._offboard_refused += 1
            log.warning("%s: OFFBOARD refused (%s), repositioning instead", self.name, exc)
            if self._offboard_refused >= PX4.offboard_refusals:
                self._offboard_ok = False
                log.warning("%s: OFFBOARD refused %d times in a row: steering by reposition", self.name,
                            self._offboard_refused)  # fmt: skip
            return False
        if self.steering != "offboard":
            log.info("%s: in OFFBOARD", self.name)
        self._offboard_refused = 0
        self._offboard_started = True
        self.steering = "offboard"
        return True

    async def reposition(self, lat: float, lon: float, alt_amsl: float) -> None:
        """MAV_CMD_DO_REPOSITION as COMMAND_INT (what goto_location sends, but sent through MavlinkDirect:
        MAVSDK 4.1's own command sender aborts the process on an UNSUPPORTED_MAV_FRAME ack). The frames of
        descriptions.PX4 are tried in order until one is not refused for its frame; that one is kept."""
        frames = PX4.reposition_frames if self.reposition_frame is None else (self.reposition_frame,)
        for frame in frames:
            fields = dict(
                frame=frame, command=MAV.MAV_CMD_DO_REPOSITION, current=0, autocontinue=0,
                param1=-1.0, param2=float(MAV.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE), param3=0.0, param4=math.nan,
                x=round(lat * 1e7), y=round(lon * 1e7), z=float(alt_amsl),
            )  # fmt: skip
            result = await self.command_int("reposition", fields)
            if result == MAV.MAV_RESULT_ACCEPTED:
                if self.reposition_frame != frame:
                    log.info("%s: repositions in frame %s", self.name, _FRAME_NAMES.get(frame, frame))
                self.reposition_frame = frame
                return
            if result != REPOSITION_FRAME_REFUSED or frame == frames[-1]:
                tried = ", ".join(_FRAME_NAMES.get(f, str(f)) for f in frames[: frames.index(frame) + 1])
                raise CommandRejected("reposition", self.name, result_name(result), f"frame {tried}")
            log.info("%s: reposition in frame %s refused (%s)", self.name, _FRAME_NAMES.get(frame), result_name(result))

    async def command_int(self, what: str, fields: dict[str, Any]) -> int:
        """Send a COMMAND_INT (its fields but the target) through MavlinkDirect and wait for its COMMAND_ACK:
        the MAV_RESULT. Sent again after _COMMAND_ACK_S without one; CommandTimeout after the last try."""
        from mavsdk.plugins.mavlink_direct import MavlinkMessage

        if self.direct is None or self.sysid is None:
            raise MavlinkError(f"{self.name}: not connected, cannot send {what}")
        body = _json({"target_system": self.sysid, "target_component": 1, **fields})
        message = MavlinkMessage("COMMAND_INT", 0, 0, self.sysid, 1, body)
        async with self._command_lock:
            while not self._acks.empty():  # answers to earlier, given-up commands
                self._acks.get_nowait()
            for _attempt in range(_COMMAND_ATTEMPTS):
                try:
                    await self.direct.send_message(message)
                except Exception as exc:
                    raise MavlinkError(f"{self.name}: MAVSDK could not send {what}: {exc}") from None
                try:
                    return await asyncio.wait_for(self._ack_of(fields["command"]), _COMMAND_ACK_S)
                except TimeoutError:
                    continue
        raise CommandTimeout(what, self.name, _COMMAND_ATTEMPTS, _COMMAND_ACK_S)

    async def _ack_of(self, command: int) -> int:
        while True:
            ack = await self._acks.get()
            if ack.get("command") == command and ack.get("result") != MAV.MAV_RESULT_IN_PROGRESS:
                return int(ack["result"])

    # --- knowledge frames on the vehicle's link -------------------------------------------------------

    def write_frame(self, frame: bytes) -> bool:
        """A packed TUNNEL sent again through MAVSDK's MavlinkDirect, in order, without waiting. MAVSDK
        sends it from its own system and component ids (245/190 by default), unsigned: the frame's own
        ids and signature do not survive, the payload (which names its sender vehicle) does."""
        if self.direct is None:
            return False
        try:
            msgs = self._parser.parse_buffer(frame) or []
        except Exception:  # not one whole MAVLink frame
            return False
        tunnels = [m for m in msgs if m.get_type() == "TUNNEL"]
        for m in tunnels:
            fields = dict(
                target_system=m.target_system, target_component=m.target_component,
                payload_type=m.payload_type, payload_length=m.payload_length,
                payload=list(m.payload[: m.payload_length]),
            )  # fmt: skip
            try:
                self._outbox.put_nowait(fields)
            except asyncio.QueueFull:
                return False
        return bool(tunnels)

    async def _send_frames(self) -> None:
        from mavsdk.plugins.mavlink_direct import MavlinkMessage

        while True:
            fields = await self._outbox.get()
            message = MavlinkMessage("TUNNEL", 0, 0, fields["target_system"], fields["target_component"], _json(fields))
            try:
                await self.direct.send_message(message)
                self.frames_sent += 1
            except Exception as exc:  # the link going away; the bus has the knowledge all the same
                log.info("%s: MAVSDK did not send a knowledge frame: %s", self.name, exc)

    async def land(self) -> None:
        self._offboard_started = False
        await self._call("land", self.action.land)

    async def rtl(self) -> None:
        self._offboard_started = False
        await self._call("return_to_launch", self.action.return_to_launch)

    async def resume(self) -> None:
        # Hold stops a return or a landing; PX4 then accepts repositions (goto) in flight
        self.target = None
        await self.set_mode(PX4.command_mode)

    async def _send_fence(self, vertices: list[tuple[float, float]]) -> None:
        """PX4's inclusion geofence through MAVSDK's geofence plugin. PX4 enforces it as its GF_ACTION says
        (default Hold) and ignores repositions outside it."""
        from mavsdk.asyncio.plugins.geofence import FenceType, GeofenceAsync, GeofenceData, Point, Polygon

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

    @property
    def on_ground(self) -> bool:
        return self._landed_state == "ON_GROUND"
