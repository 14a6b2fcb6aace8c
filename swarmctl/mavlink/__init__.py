"""swarmctl.mavlink"""
