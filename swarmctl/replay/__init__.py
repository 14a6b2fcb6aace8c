"""Offline replay of recorded missions and foreign telemetry logs (`swarmctl replay`)."""
