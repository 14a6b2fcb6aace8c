"""The paper's search world: scenarios, the batched environment, observations, the channel model."""

from swarmctl.world.config import WorldConfig
from swarmctl.world.env import SearchEnv, StepInfo
from swarmctl.world.moves import MOVE_NAMES, MOVES, N_ACTIONS
from swarmctl.world.scenario import Scenario, generate_scenario, value_map

__all__ = [
    "WorldConfig",
    "SearchEnv",
    "StepInfo",
    "MOVES",
    "MOVE_NAMES",
    "N_ACTIONS",
    "Scenario",
    "generate_scenario",
    "value_map",
]
