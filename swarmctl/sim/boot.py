"""The mock autopilot's boot: the stages a real one goes through before it can arm, in simulated time.

ArduCopter 4.7 SITL (notes in docs/mavlink.md, "What SITL showed") takes 41 s at x1 to be ready to arm
in GUIDED: its telemetry streams start at "ArduPilot Ready", the heartbeat leaves BOOT, the GPS gets a
fix (positions stop reading 0, 0), the EKF sets its origin (home, HOME_POSITION), the pre-arm checks
pass in STABILIZE, and only then does the EKF use the GPS (an absolute position: GUIDED can arm). The
personality gives each stage as a fraction of the time to that last one, `ready_after` (simulated
seconds, so the boot runs `speedup` times faster like the rest of the physics); the slow-EKF fault
moves the last one later alone.
"""

from __future__ import annotations

from collections.abc import Mapping

from pymavlink.dialects.v20 import ardupilotmega as MAV

STAGES = ("streams", "standby", "gps", "origin", "manual", "ready")  # in the order they are reached

# EKF_STATUS_REPORT flags as SITL reports them: initialising, then attitude, velocities and vertical
# position in constant-position mode (167), then horizontal position too, absolute and relative (831)
EKF_STARTING = MAV.EKF_UNINITIALIZED
EKF_NO_POSITION = (
    MAV.EKF_ATTITUDE | MAV.EKF_VELOCITY_HORIZ | MAV.EKF_VELOCITY_VERT | MAV.EKF_POS_VERT_ABS | MAV.EKF_CONST_POS_MODE
)
EKF_POSITION = (
    MAV.EKF_ATTITUDE
    | MAV.EKF_VELOCITY_HORIZ
    | MAV.EKF_VELOCITY_VERT
    | MAV.EKF_POS_HORIZ_REL
    | MAV.EKF_POS_HORIZ_ABS
    | MAV.EKF_POS_VERT_ABS
    | MAV.EKF_PRED_POS_HORIZ_REL
    | MAV.EKF_PRED_POS_HORIZ_ABS
)
EKF_ATTITUDE_AT = 0.14  # fraction of ready_after: SITL's EKF has attitude and velocities from 6 s of 41


class Boot:
    """Which stages a boot has reached. `stages` maps each stage but "ready" to its fraction of
    `ready_after`; `ekf_after` (None: `ready_after`) is when "ready" comes, never before "manual"."""

    def __init__(self, stages: Mapping[str, float], ready_after: float, ekf_after: float | None = None):
        self.ready_after = max(0.0, float(ready_after))
        self.times = {name: stages[name] * self.ready_after for name in STAGES[:-1]}
        ready = self.ready_after if ekf_after is None else max(0.0, float(ekf_after))
        self.times["ready"] = max(ready, max(self.times.values()))
        self.planned = dict(self.times)  # before any slow_boot
        self.reached: set[str] = set()
        self.sim_time = 0.0

    def advance(self, sim_time: float) -> list[str]:
        """Move to `sim_time` (seconds since boot); the stages reached now, in order."""
        self.sim_time = sim_time
        new = [s for s in STAGES if s not in self.reached and sim_time >= self.times[s]]
        self.reached.update(new)
        return new

    def slow_ekf(self, ekf_after: float) -> None:
        """The EKF uses the GPS only `ekf_after` simulated seconds after boot (not before "manual")."""
        self.times["ready"] = max(float(ekf_after), max(t for s, t in self.times.items() if s != "ready"))
        self.planned["ready"] = max(float(ekf_after), max(t for s, t in self.planned.items() if s != "ready"))
        if self.sim_time < self.times["ready"]:
            self.reached.discard("ready")

    def slow_boot(self, standby_after: float) -> None:
        """The initialisation ends (the heartbeat leaves BOOT) `standby_after` simulated seconds after
        boot, or as planned if that is later; the stages after it come no sooner than it. A second
        call moves the end again, earlier too (`slow_boot(sim_time)`: now)."""
        at = max(float(standby_after), self.planned["standby"])
        self.times["standby"] = at
        for stage in STAGES[STAGES.index("standby") + 1 :]:
            self.times[stage] = max(self.planned[stage], at)
        self.reached = {s for s in self.reached if self.sim_time >= self.times[s]}

    def has(self, stage: str) -> bool:
        return stage in self.reached

    def ekf_flags(self) -> int:
        """EKF_STATUS_REPORT.flags now."""
        if self.has("ready"):
            return EKF_POSITION
        return EKF_NO_POSITION if self.sim_time >= EKF_ATTITUDE_AT * self.ready_after else EKF_STARTING
