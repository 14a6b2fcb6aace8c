"""The vehicles' own failsafes, read before anything takes off.

When the controller stalls or dies, what brings a vehicle home is its own GCS failsafe: the autopilot's
reaction when the controller's heartbeats stop (ArduCopter FS_GCS_ENABLE, PX4 NAV_DLL_ACT; both off by
default). Right after connecting, each vehicle's GCS failsafe parameter is read, with its battery
failsafe (BATT_FS_LOW_ACT, COM_LOW_BAT_ACT) and, when the mission uploads a fence, its geofence action
(FENCE_ACTION, GF_ACTION); what they say is shown and recorded as a preflight note. A vehicle whose GCS
failsafe is off (or cannot be read) stops the mission with one line naming the vehicle, the parameter,
its value and the fix (exit 2), unless the mission says `allow_no_failsafe = true` (then a warning). No
vehicle takes off before every vehicle's failsafe has been checked (or the vehicle has failed), so a
refusal comes before anything flies. Which parameter means what is in each firmware's description
(swarmctl/mavlink/autopilots/descriptions.py).
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from swarmctl.errors import InputError
from swarmctl.mavlink.errors import CommandTimeout, MavlinkError

if TYPE_CHECKING:
    from collections.abc import Callable

    from swarmctl.mavlink.vehicle import Vehicle
    from swarmctl.mission.agent import Agent
    from swarmctl.mission.crew import Crew
    from swarmctl.mission.plan import MissionPlan
    from swarmctl.mission.state import MissionState

log = logging.getLogger(__name__)

UNKNOWN = "unknown until connected"
GATE_POLL_S = 0.05  # how often a vehicle ready to take off looks whether every vehicle has been checked
# A failsafe parameter left unanswered is read this many times (each with the driver's own retries:
# ArduPilot 6 requests). Every firmware has them, so silence is the link's: at 20 % loss each way a
# round trip fails 36 % of the time, and 6 in a row (0.2 %) refused one demo in five over such links
# (tools/lossy_links.py, 2 failsafe reads of 3 vehicles); 18 in a row is 1e-8.
FAILSAFE_READS = 3


@dataclass(frozen=True)
class Failsafe:
    """One failsafe parameter as read from a vehicle: its value (None: not read, `error` says why) and
    what the vehicle does."""

    parameter: str
    value: float | None
    action: str
    off: bool
    error: str = ""

    def text(self) -> str:
        if self.value is None:
            return f"unknown ({self.parameter} not read: {self.error})"
        return f"{self.action} ({self.parameter} {self.value:g})"


async def read(vehicle: Any, fence: bool) -> dict[str, Failsafe]:
    """The vehicle's failsafes, by kind: "link" (the GCS failsafe), "battery" and, with `fence`, "fence";
    read all at once. A parameter that cannot be read is reported as not read (value None, off)."""
    info = vehicle.autopilot_info
    kinds = {"link": info.gcs_failsafe_parameter, "battery": info.battery_failsafe_parameter}
    if fence:
        kinds["fence"] = info.fence_failsafe_parameter
    kinds = {kind: name for kind, name in kinds.items() if name}
    answers = await asyncio.gather(*(_read(vehicle, n) for n in kinds.values()), return_exceptions=True)
    found: dict[str, Failsafe] = {}
    for (kind, name), answer in zip(kinds.items(), answers):
        if isinstance(answer, (MavlinkError, TimeoutError)):
            found[kind] = Failsafe(name, None, "unknown", True, str(answer) or type(answer).__name__)
        elif isinstance(answer, BaseException):
            raise answer
        else:
            value = float(answer)
            found[kind] = Failsafe(name, value, info.failsafe_action(name, value), info.failsafe_is_off(name, value))
    return found


async def _read(vehicle: Vehicle, name: str) -> float:
    """The parameter's value, read again (FAILSAFE_READS in all) while it goes unanswered."""
    for _ in range(FAILSAFE_READS - 1):
        try:
            return float(await vehicle.read_parameter(name))
        except CommandTimeout:
            log.info("%s: %s unanswered, reading it again", vehicle.name, name)
    return float(await vehicle.read_parameter(name))


def summary(found: dict[str, Failsafe]) -> str:
    """One line: what the vehicle does on link loss, low battery and (where read) a fence breach."""
    words = {"link": "on link loss", "battery": "on low battery", "fence": "on fence breach"}
    return "; ".join(f"{words[kind]}: {fs.text()}" for kind, fs in found.items())


def refusal(name: str, info: Any, link: Failsafe) -> str:
    """The one line a vehicle without a GCS failsafe is refused with: the vehicle, the parameter, its
    value, and the two fixes."""
    if link.value is None:
        what = f"{link.parameter} could not be read ({link.error}), so its GCS failsafe may be off"
    else:
        what = f"{link.parameter} is {link.value:g}: its GCS failsafe is off"
    return (
        f"{name}: {what} (nothing brings it home if swarmctl stops); {info.gcs_failsafe_fix}, or write "
        "allow_no_failsafe = true in [mission] to fly it anyway"
    )


async def check(a: Agent, fence: bool, allow_no_failsafe: bool, note: Callable[[str], None]) -> None:
    """Read the agent's vehicle's failsafes (with its fence's when the mission uploads one), show and
    record them (`note`: a preflight note), and refuse it (InputError, one line) when its GCS failsafe
    is off and the mission does not allow that."""
    found = await read(a.vehicle, fence)
    a.failsafes = found
    note(summary(found))
    link = found.get("link")
    if link is None or not link.off:
        return
    line = refusal(a.name, a.vehicle.autopilot_info, link)
    if not allow_no_failsafe:
        raise InputError(line)
    warning = f"warning: {a.name} flies without a GCS failsafe ({link.text()}; allow_no_failsafe = true)"
    log.warning("%s", warning)
    note(warning)


async def all_checked(crew: Crew, state: MissionState) -> None:
    """Wait until every agent's failsafes have been checked, or it has stopped trying (failed, ended),
    or the mission is stopping: no vehicle takes off before a refusal could stop the mission."""
    from swarmctl.mission.agent import State

    waiting = (State.NEW, State.CONNECT, State.PREFLIGHT)
    while not state.stopping and any(ag.failsafes is None and ag.state in waiting for ag in crew.agents):
        await asyncio.sleep(GATE_POLL_S)


def describe(plan: MissionPlan) -> list[str]:
    """What `swarmctl fly` shows before it asks: what each vehicle will do on link loss. The parameters
    are read only once connected, so this names them and says what preflight does."""
    allow = plan.spec.mission.allow_no_failsafe
    rule = (
        "allow_no_failsafe = true: a vehicle with it off flies, with a warning"
        if allow
        else "a vehicle with it off is refused before anything takes off (allow_no_failsafe = false)"
    )
    lines = [f"link loss: each vehicle's own GCS failsafe decides; preflight reads it, and {rule}"]
    from swarmctl.mavlink.autopilots.base import autopilot_named

    for i, v in enumerate(plan.spec.vehicles):
        if plan.only is not None and i not in plan.only:
            continue
        if v.autopilot is None:
            where = "its GCS failsafe (FS_GCS_ENABLE or NAV_DLL_ACT, as its heartbeat says)"
        else:
            where = autopilot_named(v.autopilot).gcs_failsafe_parameter
        lines.append(f"  vehicle {v.name} on link loss: {UNKNOWN} (preflight reads {where})")
    return lines
