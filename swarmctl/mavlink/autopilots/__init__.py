"""The autopilots swarmctl flies, one module each: every firmware difference lives in its module."""

AUTOPILOT_NAMES = ("ardupilot", "px4")  # the values the mission file's `autopilot` key takes
