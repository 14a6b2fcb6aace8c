"""A mock autopilot's flight: the physics step (boot stages, battery, the mode's motion, landing),
pre-arm checks and their texts, the geofence breach and the GCS failsafe (part of MockAutopilot,
swarmctl.sim.autopilot)."""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.mavlink.codec import distance_m, ne_m, offset_m
from swarmctl.sim.mock_base import MockBase

MAV = mavlink2

PREARM_DISPLAY_S = 30.0  # simulated seconds between two "PreArm: ..." texts with the same reason


class MockFlight(MockBase):
    """MockAutopilot's physics: `_step(dt, now)` advances the simulated vehicle by `dt` simulated
    seconds, with the lock held."""

    def _step(self, dt: float, now: float) -> None:
        self.sim_time += dt
        self.fence.tick(now)
        for stage in self.boot.advance(self.sim_time):
            if stage == "standby" and self.personality.boot_resets_mode and not self.armed:
                self.custom_mode = self.personality.custom_mode(self.personality.boot_mode)
                self.target = None
            for text in self.personality.stage_texts.get(stage, ()):
                self.statustext(text.format(alt=self.home[2]))
        self._prearm_texts()
        self._failsafe(now)
        if self.armed:
            self.battery = max(
                0.0, self.battery - dt * (self.battery_drain if self.rel_alt > 0.1 else self.battery_drain / 10)
            )
        if not self.armed:
            self.vel = (0.0, 0.0, 0.0)
            return
        mode = self.mode_name
        home_lat, home_lon, _ = self.home
        if mode == "LAND":
            self._move(self.lat, self.lon, 0.0, dt)
        elif mode == "RTL":
            away = distance_m(self.lat, self.lon, home_lat, home_lon)
            if away > 0.01 and self.rel_alt < self.rtl_alt - 0.01:
                self._move(self.lat, self.lon, self.rtl_alt, dt)
            elif away > 0.01:
                self._move(home_lat, home_lon, self.rel_alt, dt)
            else:
                self._move(home_lat, home_lon, 0.0, dt)
        elif self.target is not None and mode in self.personality.target_modes:
            self._move(*self.target, dt)
            if mode == self.personality.takeoff_mode and abs(self.rel_alt - self.target[2]) < 0.01:
                self.personality.takeoff_reached(self)
        else:
            self.vel = (0.0, 0.0, 0.0)
        self._fence_breach()
        if mode in ("LAND", "RTL") and self.rel_alt <= 0.0 and self.vel[2] >= 0:
            self.armed = False  # landed: disarm, as both autopilots do
            self.target = None
            self.vel = (0.0, 0.0, 0.0)
            self.statustext(self.personality.landed_text)
            if self.personality.landed_mode is not None:
                self.custom_mode = self.personality.custom_mode(self.personality.landed_mode)

    def _not_armable(self) -> str | None:
        """Why the vehicle could not arm now in its current mode (None: it could), as its pre-arm
        checks see it: a mode that needs a position needs "ready", another one the "manual" stage."""
        p = self.personality
        if not p.position_modes or self.mode_name in p.position_modes:
            return None if self.ready else p.not_ready_reason
        return None if self.boot.has("manual") else p.boot_reason

    def _prearm_texts(self) -> None:
        """The periodic pre-arm failure text ("PreArm: Need Position Estimate"), when the reason
        changes and again every PREARM_DISPLAY_S while it lasts, disarmed, once booted."""
        prefix = self.personality.prearm_prefix
        if prefix is None or self.armed or not self.boot.has("streams"):
            return
        reason = self._not_armable()
        shown, at = self._prearm_shown
        if reason is not None and (reason != shown or self.sim_time - at >= PREARM_DISPLAY_S):
            self.statustext(f"{prefix}: {reason}", MAV.MAV_SEVERITY_CRITICAL)
            self._prearm_shown = (reason, self.sim_time)
        elif reason is None:
            self._prearm_shown = (None, -math.inf)

    def _fence_breach(self) -> None:
        """Outside an enforced fence in flight: the breach action, once per breach: the personality's
        breach_mode (ArduPilot's FENCE_ACTION default, RTL; PX4's GF_ACTION default, Hold)."""
        f = self.fence
        if f.allows(self.lat, self.lon):
            f.breached = False
            return
        if f.breached or self.rel_alt <= 0.05:
            return
        f.breached = True
        f.breaches += 1
        if self.mode_name in ("RTL", "LAND"):
            return
        self._set_mode_name(self.personality.breach_mode)
        self.statustext(self.personality.breach_text, MAV.MAV_SEVERITY_CRITICAL)

    def _move(self, lat: float, lon: float, alt: float, dt: float) -> None:
        """Fly toward (lat, lon, alt): horizontal speed limit, climb and descent rates, exact arrival."""
        n, e = ne_m(self.lat, self.lon, lat, lon)
        dist = math.hypot(n, e)
        step = min(dist, self.speed * dt)
        if dist > 0 and step >= dist:
            self.lat, self.lon = lat, lon
        elif dist > 0:
            self.lat, self.lon = offset_m(self.lat, self.lon, n * step / dist, e * step / dist)
        dz = alt - self.rel_alt
        rate = self.climb_rate if dz > 0 else self.descent_rate
        dz_step = max(-rate * dt, min(rate * dt, dz))
        self.rel_alt = alt if abs(dz_step) >= abs(dz) else self.rel_alt + dz_step
        self.rel_alt = max(0.0, self.rel_alt)
        if dt > 0:
            self.vel = ((n * step / dist / dt) if dist else 0.0, (e * step / dist / dt) if dist else 0.0, -dz_step / dt)

    def _failsafe(self, now: float) -> None:
        """GCS failsafe: no controller heartbeat for the personality's loss timeout -> hold for its delay,
        then its action (ArduPilot RTL at once; PX4 NAV_DLL_ACT), or disarm on the ground. The mode stays
        when the heartbeats come back."""
        loss = self.personality.gcs_loss(self)
        if loss is None or self.last_gcs_heartbeat is None:
            self.gcs_failsafe = False
            return
        timeout, hold_s, action = loss
        silent_s = now - self.last_gcs_heartbeat
        if silent_s <= timeout:
            self.gcs_failsafe = False
            return
        if not self.gcs_failsafe:
            self.gcs_failsafe = True
            self._failsafe_done = False
            if self.armed and self.rel_alt <= 0.05:
                self.armed = False
                self.statustext("GCS Failsafe: disarming", MAV.MAV_SEVERITY_CRITICAL)
                self._failsafe_done = True
            elif self.armed and hold_s > 0 and self.mode_name not in ("RTL", "LAND"):
                self._set_mode_name(self.personality.autopilot.command_mode)
        if self._failsafe_done or silent_s < timeout + hold_s:
            return
        self._failsafe_done = True
        if self.armed and self.mode_name not in ("RTL", "LAND", action):
            self._set_mode_name(action)
            self.statustext(self.personality.failsafe_text, MAV.MAV_SEVERITY_CRITICAL)
