"""swarmctl.learn"""
