"""What a vehicle takes from the knowledge channel: the checks a decoded message passes before it is
merged, one function for the exchange and the bus (`KnowledgeTrust.admit`).

Order on the wire (the exchange's UDP path; a faster TUNNEL parser must keep it): the MAVLink frame's
CRC, then its signature when the mission has a key (swarmctl.signing: verified before any state
changes), then the payload's validation (swarmctl.knowledge.codec), then `admit`:

    member     the sender index is a vehicle of the mission
    sysid      the frame's system id, where it is known (UDP: from the frame; the bus: the member's
               own), is that vehicle's system id
    step       the message's step does not run ahead of what the receiver can know. A sender not heard
               yet: at most FIRST_AHEAD steps past the receiver's own step (`now`: the latest step it
               published; loose, so an agent that started late still hears the others). A sender
               heard: at most its step credit past its newest accepted step; the credit is at most
               STEP_AHEAD, a step ahead spends one, and it comes back at STEP_RATE per step of the
               receiver and STEP_RATE_S per second of its clock (onboard agents count steps each on
               their own, one hovering steps faster than one flying, and one in preflight does not
               step at all: a sender may lead by a few steps and step faster, never 2^32 at once, and
               one that fell behind the credit is believed again as it comes back). Older steps are
               not refused here (a vehicle repeats its finds with the step it made them) but checked
               against the sender's track (speed)
    speed      the position it reports is reachable from the sender's newest accepted one (by step): at
               most one cell per step (Manhattan: vehicles move N/E/S/W) plus SPEED_SLACK cells, by the
               steps between them, either way (a vehicle set down elsewhere after a link loss is believed
               again once the steps since allow the jump; an agent restarted counts from step 0 again,
               from where its vehicle was last heard, and is believed at once). An old step is allowed a
               jump as large as its age: what `footprint` bounds is the cells and targets it can bring
    footprint  a DETECTION's targets lie inside the sender's sensor footprint round the position it
               reports (the disc of radius fov cells, plus FOOTPRINT_SLACK): a vehicle vouches only for
               targets it saw itself, and repeats them with the step and cell it saw them from. A
               DELTA's cells lie where they can have been sensed: a delta (own cells) inside the reach
               of the sender's own track, the message's position included; a repair or push (flag
               repair: cells of any vehicle) inside the reach of any vehicle's track, this receiver's
               own positions included, and before the first position heard of a vehicle anywhere it
               can have flown since step 0. The reach of a track entry is the footprint disc (fov +
               FOOTPRINT_SLACK) widened by half the steps to its neighbours in the track (where the
               vehicle was in between, unheard: lost messages, steps it did not publish).

A message failing one of them is dropped whole, counted in `rejected[reason]`, and the first of each
reason is logged (logger `swarmctl.knowledge`, WARNING). Without a member list (`members=None`, tools
and tests of the codec) every sender index is taken and system ids are not compared; without `fov`
detections and deltas are not placed.

Tables fed from the wire are bounded: `_track` holds one entry per member (at most 256 sender ids
without a member list), each at most TRACK positions (one per step; past TRACK the older half is
thinned to every other one, so the track keeps its first position and its reach only widens);
`_clock` one per member; `rejected` one per reason.
"""

from __future__ import annotations

import bisect
import logging
import time
from collections import Counter
from collections.abc import Callable, Mapping

import numpy as np

from swarmctl.knowledge.model import Delta, Detection, Report

log = logging.getLogger("swarmctl.knowledge")

REASONS = ("member", "sysid", "step", "speed", "footprint")
SPEED_SLACK = 2  # cells beyond one per step a reported position may be from the track
FOOTPRINT_SLACK = 1.0  # cells beyond the sensor radius a detected target or a sensed cell may lie
STEP_AHEAD = 16  # steps a message may lead the receiver's own step (a sender not heard) or a sender's newest
STEP_RATE = 4  # step credit a heard sender regains per step of the receiver
STEP_RATE_S = 8.0  # and per second of the receiver's clock (a receiver that does not step, in preflight)
FIRST_AHEAD = 4096  # steps the first message of a sender not heard yet may lead the receiver's own step
TRACK = 64  # accepted positions kept per sender


class _Track:
    """A sender's accepted positions, by step (one per step), at most TRACK of them."""

    __slots__ = ("steps", "cells")

    def __init__(self) -> None:
        self.steps: list[int] = []
        self.cells: list[tuple[int, int]] = []

    def add(self, step: int, cell: tuple[int, int]) -> bool:
        """Record `cell` at `step` (the first position of a step is kept); True when it changed."""
        i = bisect.bisect_left(self.steps, step)
        if i < len(self.steps) and self.steps[i] == step:
            return False
        self.steps.insert(i, step)
        self.cells.insert(i, cell)
        if len(self.steps) > TRACK:  # thin the older half: its first entry stays
            half = len(self.steps) // 2
            del self.steps[1:half:2]
            del self.cells[1:half:2]
        return True

    def reach(self, radius: float, prehistory: bool) -> tuple[np.ndarray, np.ndarray]:
        """(E, 2) cells and (E,) radii: where what the vehicle sensed can lie (see the module docstring);
        with `prehistory` the first entry also reaches wherever the vehicle can have been since step 0."""
        s = np.asarray(self.steps, dtype=np.float64)
        gaps = np.diff(s) / 2.0
        widen = np.zeros(len(s))
        if len(s) > 1:
            widen[1:] = gaps
            widen[:-1] = np.maximum(widen[:-1], gaps)
        if prehistory and len(s):
            widen[0] = max(widen[0], s[0])
        return np.asarray(self.cells, dtype=np.float64).reshape(-1, 2), radius + widen


class KnowledgeTrust:
    """The acceptance checks of one receiver (an exchange, or the bus for all its members): see the
    module docstring. `members` maps each vehicle index of the mission to its system id; `fov` is the
    sensor radius in cells (the plan's). `now` is the receiver's own step (`advance`); `own` records
    the receiver's own positions (its track, for the reach of repairs)."""

    def __init__(
        self,
        members: Mapping[int, int] | None = None,
        fov: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.members = None if members is None else {int(k): int(v) for k, v in members.items()}
        self.fov = None if fov is None else float(fov)
        self.rejected: Counter[str] = Counter()
        self.now = 0
        self._track: dict[int, _Track] = {}  # sender -> accepted positions
        self._time = clock  # seconds, for the credit a receiver that does not step gives back
        self._clock: dict[int, tuple[int, float, int, float]] = {}  # sender -> (newest step, credit, then: step, s)
        self._reach: tuple[np.ndarray, np.ndarray] | None = None  # every track's reach (cache)

    def is_member(self, sender: int) -> bool:
        """Whether answers may go to `sender` (a vehicle of the mission)."""
        return self.members is None or sender in self.members

    def advance(self, step: int) -> None:
        """The receiver's own step is now `step` (it never goes back)."""
        self.now = max(self.now, int(step))

    def own(self, vehicle: int, step: int, cell: tuple[int, int] | None) -> None:
        """The receiver's own position at `step` (its own messages are never admitted: echoes)."""
        self.advance(step)
        if cell is not None and self._track.setdefault(int(vehicle), _Track()).add(int(step), (cell[0], cell[1])):
            self._reach = None

    def admit(self, message: Report, sysid: int | None = None) -> bool:
        """Whether `message` (decoded, from the frame of system `sysid` where known) may be merged; a
        refusal is counted by reason. An accepted position joins the sender's track."""
        reason = self._refusal(message, sysid)
        if reason is not None:
            if reason not in self.rejected:
                log.warning(
                    "knowledge: dropped a %s from vehicle %d (%s); further ones are only counted",
                    type(message).__name__,
                    message.sender,
                    reason,
                )
            self.rejected[reason] += 1
            clock = self._clock.get(message.sender)
            if reason == "step" and clock is not None:  # the credit there is, spent: a sender that fell
                # behind catches up at the rate credit comes back, so it is believed again, never faster
                credit = self._credit(clock)
                self._clock[message.sender] = (clock[0] + int(credit), credit % 1.0, self.now, self._time())
            elif reason == "step":  # first heard far ahead (an agent started very late): from FIRST_AHEAD on,
                # as for a sender heard, so the gap closes at the rate credit comes back
                self._clock[message.sender] = (self.now + FIRST_AHEAD, 0.0, self.now, self._time())
            return False
        sender, step = message.sender, message.step
        clock = self._clock.get(sender)
        if clock is None:
            self._clock[sender] = (step, float(STEP_AHEAD), self.now, self._time())
        elif step > clock[0]:
            self._clock[sender] = (step, self._credit(clock) - (step - clock[0]), self.now, self._time())
        if message.cell is not None and self._track.setdefault(sender, _Track()).add(step, message.cell):
            self._reach = None
        return True

    def _credit(self, clock: tuple[int, float, int, float]) -> float:
        _newest, credit, then, then_s = clock
        regained = STEP_RATE * max(0, self.now - then) + STEP_RATE_S * max(0.0, self._time() - then_s)
        return min(float(STEP_AHEAD), credit + regained)

    def _refusal(self, message: Report, sysid: int | None) -> str | None:
        sender, step = message.sender, message.step
        if self.members is not None:
            if sender not in self.members:
                return "member"
            if sysid is not None and self.members[sender] != sysid:
                return "sysid"
        clock = self._clock.get(sender)
        if clock is None:
            if step > self.now + FIRST_AHEAD:
                return "step"
        elif step > clock[0] and step - clock[0] > self._credit(clock):
            return "step"
        cell = message.cell
        track = self._track.get(sender)
        if cell is not None and track is not None and track.steps:
            # from the newest accepted position, by the steps between (either way: an agent restarted
            # counts its steps from 0 again, from where its vehicle was last heard)
            x, y = track.cells[-1]
            if abs(cell[0] - x) + abs(cell[1] - y) > abs(step - track.steps[-1]) + SPEED_SLACK:
                return "speed"
        if self.fov is None:
            return None
        radius = self.fov + FOOTPRINT_SLACK + 1e-9
        if isinstance(message, Detection):
            if cell is None:
                return "footprint"
            d = np.hypot(message.targets[:, 0] - cell[0], message.targets[:, 1] - cell[1])
            if d.size and float(d.max()) > radius:
                return "footprint"
        elif isinstance(message, Delta) and len(message):
            if not self._sensable(message, radius):
                return "footprint"
        return None

    def _sensable(self, delta: Delta, radius: float) -> bool:
        """Whether every cell of `delta` lies where it can have been sensed (the module docstring)."""
        cells = delta.cells
        if delta.cell is not None:  # most deltas: the footprint round the position they report
            cx, cy = delta.cell
            reach = radius * radius
            if len(cells) <= 64:  # a step's few new cells: in Python, cheaper than numpy's calls
                far = [(x, y) for x, y in cells.tolist() if (x - cx) ** 2 + (y - cy) ** 2 > reach]
                if not far:
                    return True
                cells = np.asarray(far, dtype=np.int64)
            else:
                near = (cells[:, 0] - cx) ** 2 + (cells[:, 1] - cy) ** 2 <= reach
                if near.all():
                    return True
                cells = cells[~near]
        cells = cells.astype(np.float64)
        if delta.repair:
            if self._reach is None:
                parts = [t.reach(radius, prehistory=True) for t in self._track.values() if t.steps]
                self._reach = (
                    (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]))
                    if parts
                    else (np.zeros((0, 2)), np.zeros(0))
                )
            where, radii = self._reach
        else:
            track = self._track.get(delta.sender)
            if track is None or not track.steps:
                return False
            if delta.cell is not None:  # its position now, with the steps since the newest entry
                track = _with(track, delta.step, delta.cell)
            where, radii = track.reach(radius, prehistory=False)
        if not len(where):
            return False
        d = np.hypot(cells[:, None, 0] - where[None, :, 0], cells[:, None, 1] - where[None, :, 1])
        return bool((d <= radii[None, :]).any(axis=1).all())

    def counters(self) -> dict[str, int]:
        """Rejections per reason (every reason, 0 included)."""
        return {r: self.rejected.get(r, 0) for r in REASONS}


def _with(track: _Track, step: int, cell: tuple[int, int]) -> _Track:
    """A copy of `track` with `cell` at `step` added."""
    out = _Track()
    out.steps, out.cells = list(track.steps), list(track.cells)
    i = bisect.bisect_left(out.steps, step)
    if not (i < len(out.steps) and out.steps[i] == step):
        out.steps.insert(i, step)
        out.cells.insert(i, cell)
    return out
