"""swarmctl.geo"""
