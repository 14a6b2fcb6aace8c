"""swarmctl.policy"""
