"""The autopilots swarmctl flies, the one home of firmware differences.

base.py describes a firmware as questions (`Autopilot`) and finds the description a HEARTBEAT names
(`autopilot_for_heartbeat`, `autopilot_named`); descriptions.py answers them for ArduPilot and PX4;
ardupilot.py (pymavlink) and px4.py (MAVSDK) are the drivers that fly them. This module imports none of
them, so reading a mission file loads neither pymavlink nor MAVSDK.
"""

from typing import Literal, get_args

AutopilotName = Literal["ardupilot", "px4"]  # the values the mission file's `autopilot` key takes
AUTOPILOT_NAMES: tuple[str, ...] = get_args(AutopilotName)
