"""A mock autopilot that speaks real MAVLink over a real socket (see autopilot.py)."""

from swarmctl.mavlink.mock.autopilot import MockAutopilot

__all__ = ["MockAutopilot"]
