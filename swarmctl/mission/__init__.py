"""swarmctl.mission"""
