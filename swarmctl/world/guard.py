"""The safety guard: one set of rules for the simulator's `--guard` and the controller, batched.

It has the last word on every move, whatever the policy said. A proposed cell is refused (the vehicle
stays where it is) when it is
  1. outside the grid,
  2. a blocked cell (in the field: outside the area, no-fly, building; in the simulator: an obstacle),
  3. more than one move away,
  4. a cell another vehicle holds now (whether or not it is leaving it this step), or
  5. a cell that a vehicle with a lower index (its order in the mission) is also moving to and may
     enter: contested cells go to the lowest index, the others stay.
A vehicle that stays is never refused. Setpoints are only ever built at the mission altitude
(`SafetyGuard.setpoint_altitude`).

Consequences the property tests check: no two vehicles end a step in one cell, nobody enters a cell
that was occupied at the start of the step, nobody leaves the grid or enters a blocked cell.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ACCEPTED, OUTSIDE, BLOCKED, TOO_FAR, HELD, CONTESTED = range(6)
REASONS = {
    OUTSIDE: "outside the grid",
    BLOCKED: "blocked cell",
    TOO_FAR: "more than one move",
    HELD: "held by another vehicle",
    CONTESTED: "another vehicle is moving there",
}


def guard_moves(pos: np.ndarray, proposed: np.ndarray, blocked: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Apply the rules to B batches of U vehicles at once.

    pos, proposed: (B, U, 2) int cells (proposed may lie anywhere, off the grid included); blocked:
    (B, W, H) or (W, H) bool. Returns (dest (B, U, 2), refused (B, U) int8: ACCEPTED or the reason
    code)."""
    pos = np.asarray(pos, dtype=np.int64)
    proposed = np.asarray(proposed, dtype=np.int64)
    blocked = np.asarray(blocked, dtype=bool)
    if blocked.ndim == 2:
        blocked = blocked[None]
    b, u = pos.shape[:2]
    w, h = blocked.shape[-2:]
    moving = (proposed != pos).any(-1)
    inside = (proposed >= 0).all(-1) & (proposed[..., 0] < w) & (proposed[..., 1] < h)
    px, py = np.clip(proposed[..., 0], 0, w - 1), np.clip(proposed[..., 1], 0, h - 1)
    bi = np.arange(b)[:, None] if blocked.shape[0] > 1 else np.zeros((b, 1), dtype=np.int64)
    hit = blocked[bi, px, py]
    far = np.abs(proposed - pos).sum(-1) > 1
    other = ~np.eye(u, dtype=bool)
    held = ((proposed[:, :, None, :] == pos[:, None, :, :]).all(-1) & other).any(-1)

    refused = np.zeros((b, u), dtype=np.int8)
    for code, rule in ((HELD, held), (TOO_FAR, far), (BLOCKED, hit), (OUTSIDE, ~inside)):  # last one wins
        refused[moving & rule] = code
    candidate = moving & (refused == ACCEPTED)
    same = (proposed[:, :, None, :] == proposed[:, None, :, :]).all(-1)  # (B, U, V): u and v want one cell
    earlier = np.tri(u, k=-1, dtype=bool)[None]  # v < u
    contested = (same & earlier & candidate[:, None, :]).any(-1)
    refused[candidate & contested] = CONTESTED
    dest = np.where((refused == ACCEPTED)[..., None], proposed, pos)
    return dest, refused


@dataclass
class GuardDecision:
    """One vehicle's guarded move: the cell it is sent to, and why its proposal was refused (None: it
    was not)."""

    cell: tuple[int, int]
    refused: str | None


class SafetyGuard:
    """The guard over one grid, as the controller uses it (a batch of one)."""

    def __init__(self, blocked: np.ndarray, altitude: float):
        self.blocked = np.asarray(blocked, dtype=bool)
        self.width, self.height = self.blocked.shape
        self.altitude = float(altitude)

    def guard_moves(self, current: np.ndarray, proposed: np.ndarray) -> list[GuardDecision]:
        """Guard the moves of all vehicles at once; current, proposed are (U, 2) cells in mission order."""
        current = np.asarray(current, dtype=np.int64).reshape(1, -1, 2)
        dest, refused = guard_moves(current, np.asarray(proposed, dtype=np.int64).reshape(1, -1, 2), self.blocked)
        return [GuardDecision((int(c[0]), int(c[1])), REASONS.get(int(r))) for c, r in zip(dest[0], refused[0])]

    def setpoint_altitude(self) -> float:
        """Every setpoint is sent at the mission altitude (relative to home)."""
        return self.altitude
