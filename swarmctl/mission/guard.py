"""The safety guard: independent of the policy, it has the last word on every setpoint.

A proposed cell is refused (the vehicle stays) when it is outside the grid, a blocked cell (outside
the area, no-fly, building), more than one move away, a cell another vehicle holds, or a cell another
vehicle is moving to this step. Vehicles are decided in order, so an earlier vehicle's accepted cell
is claimed before later ones are checked. Setpoints are only ever built at the mission altitude.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

REASONS = (
    "outside the grid",
    "blocked cell",
    "more than one move",
    "held by another vehicle",
    "another vehicle is moving there",
)


@dataclass
class GuardDecision:
    cell: tuple[int, int]  # the cell the vehicle is sent to
    refused: str | None  # why the proposed cell was refused, None when accepted


class SafetyGuard:
    def __init__(self, blocked: np.ndarray, altitude: float):
        self.blocked = np.asarray(blocked, dtype=bool)
        self.width, self.height = self.blocked.shape
        self.altitude = float(altitude)

    def check(self, current: tuple[int, int], proposed: tuple[int, int], held: set, claimed: set) -> GuardDecision:
        """Decide one vehicle's move given the cells other vehicles hold and have claimed."""
        cx, cy = int(current[0]), int(current[1])
        px, py = int(proposed[0]), int(proposed[1])
        if (px, py) == (cx, cy):
            return GuardDecision((cx, cy), None)
        if not (0 <= px < self.width and 0 <= py < self.height):
            reason = REASONS[0]
        elif self.blocked[px, py]:
            reason = REASONS[1]
        elif abs(px - cx) + abs(py - cy) > 1:
            reason = REASONS[2]
        elif (px, py) in held:
            reason = REASONS[3]
        elif (px, py) in claimed:
            reason = REASONS[4]
        else:
            return GuardDecision((px, py), None)
        return GuardDecision((cx, cy), reason)

    def guard_moves(self, current: np.ndarray, proposed: np.ndarray) -> list[GuardDecision]:
        """Guard the moves of all vehicles at once; current, proposed are (U, 2) cells."""
        cells = [tuple(int(v) for v in c) for c in current]
        decisions: list[GuardDecision] = []
        claimed: set = set()
        for u, (cur, prop) in enumerate(zip(cells, proposed)):
            held = {c for j, c in enumerate(cells) if j != u}
            # a later vehicle's own stay claims its cell too: moving into it is "held"
            d = self.check(cur, tuple(int(v) for v in prop), held, claimed)
            decisions.append(d)
            claimed.add(d.cell)
        return decisions

    def setpoint_altitude(self) -> float:
        """Every setpoint is sent at the mission altitude (relative to home)."""
        return self.altitude
