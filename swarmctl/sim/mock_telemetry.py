"""What a mock autopilot sends on its own: the heartbeat, the requested message streams and the
messages it answers requests with, built from its state (part of MockAutopilot, swarmctl.sim.autopilot)."""

from __future__ import annotations

import math
import time
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.mavlink.codec import offset_m, to_deg_e7
from swarmctl.sim.mock_base import MockBase

MAV = mavlink2

# SYS_STATUS sensor bits the mock reports (gyro, accel, mag, baro, GPS, motors, battery, pre-arm).
_SENSORS = (
    MAV.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | MAV.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | MAV.MAV_SYS_STATUS_SENSOR_3D_MAG
    | MAV.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | MAV.MAV_SYS_STATUS_SENSOR_GPS
    | MAV.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | MAV.MAV_SYS_STATUS_SENSOR_BATTERY
    | MAV.MAV_SYS_STATUS_PREARM_CHECK
)

# the messages it streams at a SET_MESSAGE_INTERVAL and sends at a request (MockTelemetry._build builds them)
STREAMABLE = frozenset(
    {
        MAV.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
        MAV.MAVLINK_MSG_ID_HOME_POSITION,
        MAV.MAVLINK_MSG_ID_SYS_STATUS,
        MAV.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
        MAV.MAVLINK_MSG_ID_BATTERY_STATUS,
        MAV.MAVLINK_MSG_ID_HEARTBEAT,
        MAV.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
        MAV.MAVLINK_MSG_ID_GPS_RAW_INT,
        MAV.MAVLINK_MSG_ID_EKF_STATUS_REPORT,
        MAV.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN,
        MAV.MAVLINK_MSG_ID_POSITION_TARGET_GLOBAL_INT,
    }
)
# POSITION_TARGET_GLOBAL_INT as ArduCopter sends it: the position only (every other field ignored)
_TARGET_POSITION_ONLY = 0xFFF8


class MockTelemetry(MockBase):
    """MockAutopilot's output side: the heartbeat each second and every stream when it is due (`_emit`,
    called after each physics step), and each message built from the vehicle's state (`_build`)."""

    def _emit(self, now: float) -> None:
        if now >= self.next_heartbeat:
            self.next_heartbeat = now + 1.0
            if now >= self._no_heartbeat_until:
                self.send_message(self._heartbeat())
                if self._console_after_heartbeat:  # SITL's "Init Gyro**" between its first heartbeats
                    self._write(self._console_after_heartbeat)
                    self._console_after_heartbeat = b""
        if not self.boot.has("streams"):
            return  # requests are kept; the streams start at "ArduPilot Ready"
        for msg_id, interval in list(self.intervals.items()):
            due = self.next_due.get(msg_id, 0.0)
            if now >= due:
                m = self._build(msg_id)
                if m is not None:  # nothing to report yet (no home): try again next tick
                    self.next_due[msg_id] = max(due + interval, now)
                    self.send_message(m)

    def _heartbeat(self) -> Any:
        base = self.personality.base_mode(self.custom_mode)
        if self.armed:
            base |= MAV.MAV_MODE_FLAG_SAFETY_ARMED
        status = (
            MAV.MAV_STATE_ACTIVE
            if self.armed
            else MAV.MAV_STATE_STANDBY
            if self.boot.has("standby")
            else self.personality.boot_status
        )
        if self.gcs_failsafe and self.armed:
            status = MAV.MAV_STATE_CRITICAL  # PX4 SITL: from the link loss until the link is back
        autopilot = self.personality.autopilot.mav_autopilot
        return self.mav.heartbeat_encode(MAV.MAV_TYPE_QUADROTOR, autopilot, base, self.custom_mode, status)

    def _reported_latlon(self) -> tuple[float, float]:
        if self._glitch is not None:
            n, e, until = self._glitch
            if time.monotonic() < until:
                return offset_m(self.lat, self.lon, n, e)
            self._glitch = None
        return self.lat, self.lon

    def _time_boot_ms(self) -> int:
        """Simulated milliseconds since boot: SITL's clock, which runs at its speed-up."""
        return int(self.sim_time * 1000) & 0xFFFFFFFF

    def _build(self, msg_id: int) -> Any:
        home_lat, home_lon, home_alt = self.home
        gps = self.boot.has("gps")
        if msg_id == MAV.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            if not gps and not self.personality.position_before_ready:
                return None
            if gps:
                lat, lon = self._reported_latlon()
                lat_i, lon_i = to_deg_e7(lat), to_deg_e7(lon)
            else:
                lat_i = lon_i = 0  # no GPS fix yet: ArduPilot reports zeros
            vn, ve, vd = self.vel
            hdg = int(math.degrees(math.atan2(ve, vn)) % 360 * 100) if (vn or ve) else 65535
            return self.mav.global_position_int_encode(
                self._time_boot_ms(),
                lat_i,
                lon_i,
                int(round((home_alt + self.rel_alt) * 1000)),
                int(round(self.rel_alt * 1000)),
                int(vn * 100),
                int(ve * 100),
                int(vd * 100),
                hdg,
            )
        if msg_id == MAV.MAVLINK_MSG_ID_HOME_POSITION:
            if not self.home_set:
                return None
            return self.mav.home_position_encode(
                to_deg_e7(home_lat),
                to_deg_e7(home_lon),
                int(round(home_alt * 1000)),
                0,
                0,
                0,
                [1.0, 0.0, 0.0, 0.0],
                0,
                0,
                0,
                int((time.monotonic() - self.boot_wall) * 1e6),
            )
        if msg_id == MAV.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN:
            if not self.home_set:
                return None
            t_us = int((time.monotonic() - self.boot_wall) * 1e6)
            return self.mav.gps_global_origin_encode(
                to_deg_e7(home_lat), to_deg_e7(home_lon), int(round(home_alt * 1000)), t_us
            )
        if msg_id == MAV.MAVLINK_MSG_ID_GPS_RAW_INT:
            lat, lon = self._reported_latlon() if gps else (0.0, 0.0)
            vn, ve, _vd = self.vel
            return self.mav.gps_raw_int_encode(
                int((time.monotonic() - self.boot_wall) * 1e6),
                MAV.GPS_FIX_TYPE_RTK_FIXED if gps else MAV.GPS_FIX_TYPE_NO_FIX,  # what SITL reports: 6
                to_deg_e7(lat),
                to_deg_e7(lon),
                int(round((home_alt + self.rel_alt) * 1000)) if gps else 0,
                121 if gps else 65535,
                200 if gps else 65535,
                int(math.hypot(vn, ve) * 100),
                int(math.degrees(math.atan2(ve, vn)) % 360 * 100) if (vn or ve) else 65535,
                10 if gps else 0,
            )
        if msg_id == MAV.MAVLINK_MSG_ID_EKF_STATUS_REPORT:
            return self.mav.ekf_status_report_encode(self.boot.ekf_flags(), 0.02, 0.03, 0.02, 0.01, 0.0)
        if msg_id == MAV.MAVLINK_MSG_ID_SYS_STATUS:
            health = _SENSORS
            if not self.armed and self._not_armable() is not None:  # always healthy when armed
                health &= ~MAV.MAV_SYS_STATUS_PREARM_CHECK
            if not gps:
                health &= ~MAV.MAV_SYS_STATUS_SENSOR_GPS
            volts = 4 * (3.5 + 0.7 * self.battery / 100.0)
            current = 1500 if self.rel_alt > 0.1 else (100 if self.armed else 50)
            return self.mav.sys_status_encode(
                _SENSORS, _SENSORS, health, 200, int(volts * 1000), current, int(self.battery), 0, 0, 0, 0, 0, 0
            )
        if msg_id == MAV.MAVLINK_MSG_ID_BATTERY_STATUS:
            cell_mv = int(1000 * (3.5 + 0.7 * self.battery / 100.0))
            return self.mav.battery_status_encode(
                0,
                MAV.MAV_BATTERY_FUNCTION_ALL,
                MAV.MAV_BATTERY_TYPE_LIPO,
                32767,
                [cell_mv] * 4 + [65535] * 6,
                1500 if self.rel_alt > 0.1 else 50,
                -1,
                -1,
                int(self.battery),
            )
        if msg_id == MAV.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
            return self.mav.extended_sys_state_encode(MAV.MAV_VTOL_STATE_UNDEFINED, self._landed_state())
        if msg_id == MAV.MAVLINK_MSG_ID_POSITION_TARGET_GLOBAL_INT:
            # ArduCopter reports the target its mode flies to (GUIDED: the last one taken), AMSL, and
            # nothing in a mode without one (GCS_MAVLINK_Copter::send_position_target_global_int)
            if self.target is None or not self.armed or self.mode_name not in self.personality.target_modes:
                return None
            lat, lon, rel_alt = self.target
            return self.mav.position_target_global_int_encode(
                self._time_boot_ms(),
                MAV.MAV_FRAME_GLOBAL,
                _TARGET_POSITION_ONLY,
                to_deg_e7(lat),
                to_deg_e7(lon),
                home_alt + rel_alt,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
            )
        if msg_id == MAV.MAVLINK_MSG_ID_HEARTBEAT:
            return self._heartbeat()
        if msg_id == MAV.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            p = self.personality
            return self.mav.autopilot_version_encode(
                p.capabilities, p.version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x5357_0000 + self.sysid
            )
        return None

    def _landed_state(self) -> int:
        if not self.armed and self.rel_alt <= 0.05:
            return MAV.MAV_LANDED_STATE_ON_GROUND
        if self.mode_name == "LAND" and self.vel[2] > 0:
            return MAV.MAV_LANDED_STATE_LANDING
        if self.target is not None and self.rel_alt < self.target[2] - 0.5 and self.vel[2] < 0 and self.rel_alt < 2.0:
            return MAV.MAV_LANDED_STATE_TAKEOFF
        return MAV.MAV_LANDED_STATE_IN_AIR if self.rel_alt > 0.05 else MAV.MAV_LANDED_STATE_ON_GROUND
