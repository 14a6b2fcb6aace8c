"""swarmctl: a MAVLink drone-swarm search mission controller driven by a shared deep Q-network."""

__version__ = "0.1.0"
