"""Per-autopilot drivers behind swarmctl.mavlink.vehicle.Vehicle: ardupilot.py (pymavlink), px4.py (MAVSDK)."""
