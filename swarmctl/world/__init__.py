"""swarmctl.world"""
