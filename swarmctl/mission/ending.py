"""The end of a mission for each vehicle still in contact: its end action (land, rtl, or hover: vehicles
hovering on a target hold there, the others return home; a vehicle sent home on low battery stays on
its way home), sent whatever else failed, and recorded."""

from __future__ import annotations

import asyncio
import logging
from typing import TYPE_CHECKING

from swarmctl.mavlink.errors import MavlinkError
from swarmctl.mission import timeouts
from swarmctl.mission.agent import Agent, State

if TYPE_CHECKING:
    from swarmctl.mission.crew import Crew
    from swarmctl.mission.recorder import Recorder
    from swarmctl.mission.spec import TimingTable

log = logging.getLogger(__name__)


class Ending:
    """End actions for the crew: the mission's `action` (land, rtl, hover), its altitude and `[timing]`
    (how long to wait for a landing), and where they are recorded."""

    def __init__(self, action: str, altitude: float, timing: TimingTable, rec: Recorder, crew: Crew):
        self.action, self.altitude, self.timing = action, altitude, timing
        self.rec, self.crew = rec, crew

    async def all(self) -> None:
        """Every agent's end action at once; an error after one vehicle's command is logged, and never
        keeps the others' from going out."""
        agents = self.crew.agents
        done = await asyncio.gather(*(self.end(a) for a in agents), return_exceptions=True)
        for a, result in zip(agents, done):
            if isinstance(result, Exception):  # after its command: only what was recorded of it
                log.error("%s: after the end action: %s: %s", a.name, type(result).__name__, result)

    async def end(self, a: Agent) -> None:
        """The agent's end action, its outcome in `a.end_state`."""
        if a.state in (State.FAILED, State.CONNECT, State.PREFLIGHT) and not a.vehicle.armed:
            a.end_state = a.state
            return
        silenced = a.vehicle.silenced
        if (a.state is State.LOST or a.vehicle.lost) and silenced is None:
            a.end_state = "lost (left to its failsafe)"
            self.rec.event("end_action", vehicle=a.name, action="none: link lost")
            return
        # a vehicle judged silent because a listener failed on its messages still hears us (its link is
        # up, so its GCS failsafe will not act): it is sent its end action all the same, unconfirmed
        if a.state is State.OVERRIDE:
            who = "pilot" if a.override_reason == "pilot" else f"taken over, {a.override_reason}"
            a.end_state = f"{who} ({a.vehicle.mode})"
            return
        action = self.action
        if action == "hover" and a.state is not State.HOVER:
            action = "rtl"  # only vehicles on a target hold; the others come home
        if a.state is State.LOW_BATTERY or a.sent_home:
            action = "rtl"
        a.end_action = action
        try:  # nothing the recording raises may keep the command from the vehicle
            self.rec.event("end_action", vehicle=a.name, action=action, cell=a.cell)
        except Exception as exc:
            log.error("%s: the end_action line was not recorded: %s: %s", a.name, type(exc).__name__, exc)
        try:
            if action == "land":
                await a.vehicle.land()
            elif action == "rtl":
                await a.vehicle.rtl()
            wait = timeouts.end(self.timing.end_timeout, a.vehicle, action, self.altitude)
            if action in ("land", "rtl") and wait > 0:
                await a.vehicle.wait_landed(wait)
                a.end_state = "landed at home" if action == "rtl" else "landed"
            elif action in ("land", "rtl"):  # end_timeout = 0: sent, its landing not waited for
                a.end_state = "returning home" if action == "rtl" else "landing"
            else:
                a.end_state = "hovering on target" if a.state is State.HOVER else "hovering"
        except (TimeoutError, MavlinkError) as exc:
            a.end_state = f"end action failed: {exc}"
            self.rec.event("end_action_failed", vehicle=a.name, error=str(exc))
        except Exception as exc:  # one vehicle's unexpected error must not cut the others' end actions short
            a.end_state = f"end action failed: unexpected {type(exc).__name__}: {exc}"
            log.error("%s: %s", a.name, a.end_state)
            self.rec.event("end_action_failed", vehicle=a.name, error=f"{type(exc).__name__}: {exc}")
        self.crew.enter(a, State.ENDED, end_state=a.end_state)
