"""One vehicle's agent: its state machine and what the controller keeps about it.

The states and the transitions between them are explicit (`TRANSITIONS`); `Agent.enter` refuses any
other. What the vehicle's own reports call for (its link lost or back, a pilot taking it over, a low
battery) is decided by `Agent.next_state`, a pure function of what the agent knows; the controller
carries out the side effects (cancel a rejoin, send the vehicle home) and the swarm-level ones
(hovering needs to know what the others hold: swarmctl.mission.rounds).

    new -> connect -> preflight -> takeoff -> search <-> hover
    search / hover / rejoin -> lost -> rejoin -> search        (link loss and return)
    lost -> override                                           (back in a mode a pilot chose meanwhile)
    search / hover -> override                                 (a pilot's mode, or not commanded:
                                                                swarmctl.mission.watch)
    search -> low battery                                      (sent home: swarmctl.mission.energy)
    low battery -> rejoin -> search                            (landed and disarmed with a fresh battery)
    low battery -> override                                    (armed in a pilot's mode: it stays the pilot's)
    any of them -> failed; any but ended -> ended              (the end action was given)
"""

from __future__ import annotations

import asyncio
import time
from enum import StrEnum
from typing import TYPE_CHECKING, Any

from swarmctl.mavlink.codec import distance_m
from swarmctl.mavlink.limits import RESUME_ABOVE_M
from swarmctl.mission.energy import ChargeLog, home_check

if TYPE_CHECKING:
    from swarmctl.knowledge.exchange import KnowledgeExchange
    from swarmctl.knowledge.model import Knowledge
    from swarmctl.mavlink.codec import Endpoint
    from swarmctl.mission.detector import SensorFeed
    from swarmctl.mission.energy import HomeCheck
    from swarmctl.mission.spec import VehicleSpec


FRESH_RISE = 20  # % a landed vehicle's charge must rise above its lowest to count as a fresh battery


class State(StrEnum):
    """An agent's state; the value is what the recording writes."""

    NEW = "new"
    CONNECT = "connect"
    PREFLIGHT = "preflight"
    TAKEOFF = "takeoff"
    SEARCH = "search"
    HOVER = "hover"
    LOST = "lost"
    REJOIN = "rejoin"
    OVERRIDE = "override"
    LOW_BATTERY = "low battery"
    FAILED = "failed"
    ENDED = "ended"


_ACTIVE = {State.CONNECT, State.PREFLIGHT, State.TAKEOFF, State.SEARCH, State.HOVER, State.REJOIN}
# the states in which a vehicle is on its way to the search or in it: the hover rule counts it in touch
IN_TOUCH = frozenset(_ACTIVE)
TRANSITIONS: dict[State, frozenset[State]] = {
    State.NEW: frozenset({State.CONNECT}),
    State.CONNECT: frozenset({State.PREFLIGHT}),
    State.PREFLIGHT: frozenset({State.TAKEOFF}),
    State.TAKEOFF: frozenset({State.SEARCH}),
    State.SEARCH: frozenset({State.HOVER, State.LOST, State.OVERRIDE, State.LOW_BATTERY}),
    State.HOVER: frozenset({State.SEARCH, State.LOST, State.OVERRIDE}),  # search: the operator rejected the find
    State.LOST: frozenset({State.REJOIN, State.OVERRIDE}),
    State.REJOIN: frozenset({State.SEARCH, State.LOST}),
    State.OVERRIDE: frozenset(),
    State.LOW_BATTERY: frozenset({State.REJOIN, State.OVERRIDE}),  # a fresh battery; a pilot flying it
    State.FAILED: frozenset(),
    State.ENDED: frozenset(),
}
for _state in State:  # failure from any active state; the end action from anything but the end
    TRANSITIONS[_state] |= ({State.FAILED} if _state in _ACTIVE else frozenset()) | (
        frozenset() if _state is State.ENDED else {State.ENDED}
    )


class IllegalTransition(RuntimeError):
    """A transition the state machine does not have (a bug in the controller, never bad input)."""


class Agent:
    """One vehicle's controller: its Vehicle, Knowledge, exchange, sensor feed, state and counters."""

    def __init__(
        self,
        index: int,
        spec: VehicleSpec,
        vehicle: Any,  # a Vehicle; a connect.NotConnected until it is connected (duck-typed: a few fields)
        exchange: KnowledgeExchange,
        feed: SensorFeed,
        detector: Endpoint | str | None = None,
    ):
        self.index, self.spec, self.vehicle = index, spec, vehicle
        self.exchange, self.feed = exchange, feed
        self.detector = detector  # "mavlink" or a local socket (Endpoint); None: sensing from position only
        self.visited: dict[tuple[int, int], int] = {}  # cells the vehicle reached -> the step it last did
        self.sensor_dropped = 0  # report entries outside the footprints of the cells it reached
        self.unexpected_reports = False  # reports came although the mission gives it no detector
        self.knowledge: Knowledge = exchange.knowledge
        self.state = State.NEW
        self.cell: tuple[int, int] | None = None
        self.steps = 0
        self.refused = 0
        self.timeouts = 0
        self.end_action: str | None = None
        self.end_state: str | None = None
        self.error: str | None = None
        self.status: str | None = None  # the latest preflight note (Launch.note): what the vehicle says
        self.notes: dict[str, float] = {}  # preflight note -> when it was last shown (time.monotonic())
        self.failsafes: dict | None = None  # kind -> failsafes.Failsafe, once read at preflight (failsafes.py)
        self.saw_loss = False  # the link was lost since the agent last looked (even briefly)
        self.pilot_since: float | None = None  # when the vehicle was first seen in a pilot's mode
        self.lost_at: float | None = None  # when its link was last judged lost (time.monotonic())
        self.override_reason: str | None = None  # override: "pilot" or "not commanded" (swarmctl.mission.watch)
        self.watch_from: tuple[int, int] | None = None  # the cell held at the last off-course check
        self.watch_pos: tuple[float, float] | None = None  # lat, lon at the last check it passed
        # the watch's last path, kept while a flight is checked against it: its ends in metres from the
        # cell's centre, the position last measured and its metres off it (swarmctl.mission.watch.deviation)
        self.watch_path: list | None = None
        self.off_course = 0  # rounds in a row the vehicle was off course
        self.climbed = False  # at the mission altitude since it was first seen commanded
        self.alarm: str | None = None  # what the live table shows (off course)
        self.sent_home = False  # the operator sent it home (swarmctl.mission.web): its end action is rtl
        self._accepted = 0
        self.rejoin_task: asyncio.Task | None = None
        self.charges = ChargeLog()  # its battery reports against its seconds of flight (swarmctl.mission.energy)
        self.charge_clock: str | None = None  # what those seconds are: "vehicle" (its own clock) or "odometer"
        self.lowest: int | None = None  # the lowest charge it reported since it was sent home on low battery

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def here(self) -> tuple[int, int]:
        """Its cell, where it must be known: a vehicle searching, guarded or sensing has one (`cell` is
        None only before its first position)."""
        assert self.cell is not None, f"{self.name}: no cell yet"
        return self.cell

    @property
    def live(self) -> bool:
        return self.state in (State.SEARCH, State.HOVER, State.REJOIN)

    @property
    def targets_known(self) -> int:
        return len(self.knowledge.targets)

    def enter(self, state: State) -> bool:
        """Move to `state`; True when it is a change. IllegalTransition for a transition that is not in
        TRANSITIONS (staying in a state is always allowed)."""
        if state is self.state:
            return False
        if state not in TRANSITIONS[self.state]:
            raise IllegalTransition(f"{self.name}: no transition from {self.state} to {state}")
        self.state = state
        return True

    def next_state(
        self, low_battery: int, now: float | None = None, reserve: float | None = None, relaunch_at: int | None = None
    ) -> tuple[State, dict[str, Any]] | None:
        """The transition the vehicle's own reports call for, with what to record; None: none.

        Link lost (now, or briefly since the agent last looked) -> lost; back -> rejoin; a pilot's mode
        for the autopilot's debounce time -> override (reason "pilot"); while searching, a battery below
        `low_battery` %, or (with `reserve`) below what its return takes plus `reserve` % -> low battery
        (`home_check`); sent home on low battery, landed and disarmed with a fresh battery of at least
        `relaunch_at` % (None: never) -> rejoin (`fresh_battery`)."""
        lost = self.vehicle.lost
        now = time.monotonic() if now is None else now
        if self.state in (State.SEARCH, State.HOVER, State.REJOIN) and (lost or self.saw_loss):
            self.saw_loss = False
            self.lost_at = now
            self.status = f"link lost at cell {self.cell}: its own failsafe has it"
            return State.LOST, {"last_cell": self.cell}
        if self.state is State.LOST and not lost:
            found = self.found_on_return(now)
            info, mode = self.vehicle.autopilot_info, self.vehicle.mode
            if self.vehicle.armed and info is not None and info.is_pilot_mode(mode) and mode not in info.failsafe_modes:
                # flying in a mode a person chose while the link was down: theirs, never taken back (one on
                # the ground, disarmed, is in its boot or landed mode, and takes off again to rejoin)
                self.override_reason = "pilot"
                self.status = f"{self.describe_return(found)}; left to the pilot"
                return State.OVERRIDE, {"reason": "pilot", **found}
            self.status = f"{self.describe_return(found)}; rejoining"
            return State.REJOIN, found
        if self.state in (State.SEARCH, State.HOVER) and self.pilot_has_it(now):
            self.override_reason = "pilot"
            return State.OVERRIDE, {"mode": self.vehicle.mode, "reason": "pilot"}
        battery = self.battery()
        if self.state is State.SEARCH and battery is not None:
            if reserve is None:
                if battery < low_battery:
                    return State.LOW_BATTERY, {"battery": battery}
                return None
            check = self.home_check(battery, low_battery, reserve)
            if check.go:
                self.lowest = battery
                return State.LOW_BATTERY, check.record()
        if self.state is State.LOW_BATTERY and self.flown_by_pilot(now):
            self.override_reason = "pilot"
            return State.OVERRIDE, {"mode": self.vehicle.mode, "reason": "pilot"}
        if self.state is State.LOW_BATTERY and relaunch_at is not None and battery is not None:
            if self.fresh_battery(battery, relaunch_at):
                self.charges.clear()  # the rate of the old battery says nothing of the new one
                self.lowest = None
                self.status = f"fresh battery ({battery} %): taking off to rejoin"
                return State.REJOIN, {"relaunch": True, "battery": battery}
        return None

    def home_check(self, battery: int, floor: int, reserve: float) -> HomeCheck:
        """The energy rule on what the vehicle reports: its distance to home, its height, its speeds and
        its measured consumption (only the floor where its position, home or speeds are not known)."""
        v = self.vehicle
        pos, home = v.position, getattr(v, "home", None)
        limits = getattr(v, "limits", None)
        if pos is None or home is None or limits is None:
            return home_check(battery, floor, reserve)
        away = distance_m(pos.lat, pos.lon, home.lat, home.lon)
        return home_check(battery, floor, reserve, self.charges.rate(), away, max(0.0, pos.rel_alt), limits)

    def flown_by_pilot(self, now: float) -> bool:
        """Sent home on low battery, it is armed in a pilot's mode other than its own failsafes' (a pilot
        flies it home or keeps it): it is the pilot's from then on, never relaunched."""
        info = self.vehicle.autopilot_info
        if info is None or not self.vehicle.armed or self.vehicle.mode in info.failsafe_modes:
            self.pilot_since = None
            return False
        return self.pilot_has_it(now)

    def fresh_battery(self, battery: int, needed: int) -> bool:
        """Sent home on low battery, it reports a fresh one: on the ground and disarmed, its link up, at
        least `needed` % and FRESH_RISE % above the lowest it reported since (a battery recovering its
        voltage at rest, or the noise of a report, is no new battery)."""
        self.lowest = battery if self.lowest is None else min(self.lowest, battery)
        v = self.vehicle
        if v.lost or v.armed or battery < needed or battery < self.lowest + FRESH_RISE:
            return False
        pos = v.position
        return pos is not None and pos.rel_alt < RESUME_ABOVE_M

    def sample_charge(self) -> None:
        """The battery's report against the vehicle's seconds, while it flies for the search: its own clock,
        or where its driver reports none its odometer at its flight speed (swarmctl.mission.energy)."""
        if not self.live:
            return
        battery = self.battery()
        if battery is None:
            return
        seconds = getattr(self.vehicle, "clock_s", None)
        clock = "vehicle"
        if seconds is None:
            limits = getattr(self.vehicle, "limits", None)
            if limits is None:
                return
            seconds, clock = self.distance / limits.speed, "odometer"
        if clock != self.charge_clock:  # seconds of one clock are no measure against the other's
            self.charges.clear()
            self.charge_clock = clock
        self.charges.add(seconds, float(battery))

    def found_on_return(self, now: float) -> dict[str, Any]:
        """What the vehicle reports as its link comes back (the rejoin's record): its mode, whether it is
        armed, its position (lat, lon, metres above home) and how long the link was lost."""
        v = self.vehicle
        pos = v.position
        found: dict[str, Any] = dict(mode=v.mode, armed=bool(v.armed))
        if pos is not None:
            found["position"] = [round(pos.lat, 7), round(pos.lon, 7), round(pos.rel_alt, 1)]
        if self.lost_at is not None:
            found["lost_s"] = round(now - self.lost_at, 1)
        return found

    @staticmethod
    def describe_return(found: dict[str, Any]) -> str:
        """found_on_return in words: "link back after 8.1 s: RTL, armed, 12 m above home"."""
        after = f" after {found['lost_s']:g} s" if "lost_s" in found else ""
        where = f", {found['position'][2]:g} m above home" if "position" in found else ""
        return f"link back{after}: {found['mode']}, {'armed' if found['armed'] else 'disarmed'}{where}"

    def pilot_has_it(self, now: float) -> bool:
        """The pilot took over: the vehicle reports a pilot's mode (its autopilot's is_pilot_mode), and
        has reported one for the autopilot's mode_debounce_s (a mode report may lag behind the vehicle)."""
        info = self.vehicle.autopilot_info
        if info is None or not info.is_pilot_mode(self.vehicle.mode):
            self.pilot_since = None
            return False
        if self.pilot_since is None:
            self.pilot_since = now
        return now - self.pilot_since >= info.mode_debounce_s

    def battery(self) -> int | None:
        try:
            return self.vehicle.battery_remaining
        except Exception:
            return None

    def link_text(self) -> str:
        try:
            return "lost" if self.vehicle.lost else "ok"
        except Exception:
            return "?"

    @property
    def distance(self) -> float:
        """3-D distance the vehicle has flown, metres: its driver's odometer counts every position report
        of the whole flight (the climb, the search, the return and the descent)."""
        return float(self.vehicle.distance_flown_m)

    def track(self) -> None:
        """Each round: the battery's report for the consumption (the odometer follows the telemetry itself:
        see `distance`)."""
        self.sample_charge()

    def received_since(self) -> int:
        """Knowledge messages accepted (decoded and admitted by the trust checks) since the last call."""
        total = self.exchange.merged()
        new, self._accepted = total - self._accepted, total
        return new
