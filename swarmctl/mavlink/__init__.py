"""swarmctl.mavlink: fly ArduPilot (pymavlink) and PX4 (MAVSDK) vehicles over MAVLink.

See docs/mavlink.md. The controller uses `Vehicle` (ArduPilotVehicle or PX4Vehicle) on one asyncio loop;
`Connector` picks the driver from what each vehicle reports (its firmware's `Autopilot` description).
Names are imported on first use, so `swarmctl` commands that never fly do not load pymavlink.
"""

from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "Autopilot": "autopilots.base",
    "autopilot_for_heartbeat": "autopilots.base",
    "autopilot_named": "autopilots.base",
    "AutopilotMismatch": "connect",
    "Connector": "connect",
    "ArduPilotVehicle": "autopilots.ardupilot",
    "PX4Vehicle": "autopilots.px4",
    "MavlinkLink": "network",
    "Vehicle": "vehicle",
    "Position": "vehicle",
    "Home": "vehicle",
    "Target": "vehicle",
    "MavlinkError": "errors",
    "CommandRejected": "errors",
    "CommandTimeout": "errors",
    "WaitTimeout": "errors",
    "load_signing_key": "codec",
    "offset_m": "codec",
    "parse_connection": "codec",
}
__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'swarmctl.mavlink' has no attribute {name!r}")
    return getattr(importlib.import_module(f"swarmctl.mavlink.{_WHERE[name]}"), name)
