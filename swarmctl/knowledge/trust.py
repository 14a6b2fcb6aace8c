"""What a vehicle takes from the knowledge channel: the checks a decoded message passes before it is
merged, one function for the exchange and the bus (`KnowledgeTrust.admit`).

Order on the wire (the exchange's UDP path; a faster TUNNEL parser must keep it): the MAVLink frame's
CRC, then its signature when the mission has a key (swarmctl.signing: verified before any state
changes), then the payload's validation (swarmctl.knowledge.codec), then `admit`:

    member     the sender index is a vehicle of the mission
    sysid      the frame's system id, where it is known (UDP: from the frame; the bus: the member's
               own), is that vehicle's system id
    speed      the position the message reports is reachable from the sender's last accepted one: at
               most one cell per step (Manhattan: vehicles move N/E/S/W) plus SPEED_SLACK cells, by
               the messages' step numbers (a vehicle set down elsewhere after a link loss is believed
               again once the steps since allow the jump)
    footprint  a DETECTION's targets lie inside the sender's sensor footprint round the position it
               reports (the disc of radius fov cells, plus FOOTPRINT_SLACK): a vehicle vouches only for
               targets it saw itself, and repeats them with the step and cell it saw them from

A message failing one of them is dropped whole, counted in `rejected[reason]`, and the first of each
reason is logged (logger `swarmctl.knowledge`, WARNING). Without a member list (`members=None`, tools
and tests of the codec) every sender index is taken and system ids are not compared; without `fov`
detections are not placed.

Tables fed from the wire are bounded: `_last` holds one entry per member (at most 256 sender ids
without a member list); `rejected` one per reason.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Mapping

import numpy as np

from swarmctl.knowledge.model import Detection, Report

log = logging.getLogger("swarmctl.knowledge")

REASONS = ("member", "sysid", "speed", "footprint")
SPEED_SLACK = 2  # cells beyond one per step a reported position may be from the last one
FOOTPRINT_SLACK = 1.0  # cells beyond the sensor radius a detected target may lie


class KnowledgeTrust:
    """The acceptance checks of one receiver (an exchange, or the bus for all its members): see the
    module docstring. `members` maps each vehicle index of the mission to its system id; `fov` is the
    sensor radius in cells (the plan's)."""

    def __init__(self, members: Mapping[int, int] | None = None, fov: float | None = None):
        self.members = None if members is None else {int(k): int(v) for k, v in members.items()}
        self.fov = None if fov is None else float(fov)
        self.rejected: Counter[str] = Counter()
        self._last: dict[int, tuple[int, tuple[int, int]]] = {}  # sender -> newest (step, cell) accepted

    def is_member(self, sender: int) -> bool:
        """Whether answers may go to `sender` (a vehicle of the mission)."""
        return self.members is None or sender in self.members

    def admit(self, message: Report, sysid: int | None = None) -> bool:
        """Whether `message` (decoded, from the frame of system `sysid` where known) may be merged; a
        refusal is counted by reason. An accepted position becomes the sender's reference."""
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
            return False
        if message.cell is not None:
            last = self._last.get(message.sender)
            if last is None or message.step >= last[0]:
                self._last[message.sender] = (message.step, message.cell)
        return True

    def _refusal(self, message: Report, sysid: int | None) -> str | None:
        sender = message.sender
        if self.members is not None:
            if sender not in self.members:
                return "member"
            if sysid is not None and self.members[sender] != sysid:
                return "sysid"
        cell = message.cell
        if cell is not None:
            last = self._last.get(sender)
            if last is not None:
                step, (x, y) = last
                if abs(cell[0] - x) + abs(cell[1] - y) > abs(message.step - step) + SPEED_SLACK:
                    return "speed"
        if isinstance(message, Detection) and self.fov is not None:
            if cell is None:
                return "footprint"
            d = np.hypot(message.targets[:, 0] - cell[0], message.targets[:, 1] - cell[1])
            if d.size and float(d.max()) > self.fov + FOOTPRINT_SLACK + 1e-9:
                return "footprint"
        return None

    def counters(self) -> dict[str, int]:
        """Rejections per reason (every reason, 0 included)."""
        return {r: self.rejected.get(r, 0) for r in REASONS}
