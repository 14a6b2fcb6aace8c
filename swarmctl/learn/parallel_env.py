"""The search world as a PettingZoo `ParallelEnv`, for training with other libraries.

    from swarmctl.learn.parallel_env import SearchParallelEnv
    env = SearchParallelEnv(WorldConfig(scenario="cluster", uavs=3), steps=40)
    observations, infos = env.reset(seed=0)
    while env.agents:
        actions = {a: policy(observations[a], infos[a]["action_mask"]) for a in env.agents}
        observations, rewards, terminations, truncations, infos = env.step(actions)

One episode of SearchEnv (batch 1) at a time; agents are "uav_0" ... "uav_{U-1}". Observations are
the paper's per-vehicle tensors (C x F x F float32, swarmctl.world.observe), actions the five moves
(stay, N, E, S, W). The world's reward; success (the world's finish line) terminates every agent, the
step limit truncates them. `infos[agent]["action_mask"]` (int8, 5) marks the moves the masks allow:
not off the map, not into a cell the vehicle knows to be blocked or held; no hover is forced (the hover
rule `no`, or the one given). Each reset without a seed plays the next episode of the last seed, so
episode i of seed s is the one `swarmctl eval --seed s` plays as its i-th.

Needs `pip install 'swarmctl[rl]'` (pettingzoo, gymnasium).
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from swarmctl.policy.base import allowed_moves
from swarmctl.policy.hover import HOVER_RULES, NO
from swarmctl.world.beliefs import VARIANT_CHANNELS
from swarmctl.world.config import WorldConfig
from swarmctl.world.env import SearchEnv
from swarmctl.world.moves import N_ACTIONS


class SearchParallelEnv(ParallelEnv):
    """U vehicles searching one episode of `world` for at most `steps` joint moves (module docstring)."""

    metadata = {"name": "swarmctl_search_v0", "render_modes": []}

    def __init__(
        self,
        world: WorldConfig | None = None,
        steps: int = 40,
        hover: str = NO,
        blocked: np.ndarray | None = None,
        render_mode: str | None = None,
    ):
        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r}: this environment does not render")
        if hover not in HOVER_RULES:
            raise ValueError(f"hover {hover!r} is unknown: use one of {', '.join(HOVER_RULES)}")
        if not 1 <= int(steps) <= 100_000:
            raise ValueError(f"steps {steps}: give 1..100000 joint moves")
        self.world = world or WorldConfig()
        self.steps, self.hover, self.blocked = int(steps), hover, blocked
        self.render_mode = None
        self.possible_agents = [f"uav_{i}" for i in range(self.world.uavs)]
        self.agents: list[str] = []
        self._env = SearchEnv(self.world, batch=1, stop_at_success=True, observations=False)
        self._seed, self._episode = 0, -1
        w = self.world
        self._obs_space = spaces.Box(
            low=-max(1.0, w.rho),
            high=float(max(w.uavs, w.targets, 1)),
            shape=(VARIANT_CHANNELS[w.variant], w.window, w.window),
            dtype=np.float32,
        )
        self._act_space = spaces.Discrete(N_ACTIONS)

    def observation_space(self, agent: str) -> spaces.Box:  # one object for every agent, as the API asks
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Discrete:
        return self._act_space

    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._seed, self._episode = int(seed), 0
        else:
            self._episode += 1
        self._env.reset(self._seed, [max(self._episode, 0)], self.blocked)
        self._t = 0
        self.agents = list(self.possible_agents)
        return self._observations(), self._infos()

    def step(self, actions: dict):
        if not self.agents:
            raise RuntimeError("the episode is over: call reset()")
        moves = np.zeros((1, len(self.possible_agents)), dtype=np.int64)
        for i, agent in enumerate(self.possible_agents):
            a = actions.get(agent, 0)
            if not self._act_space.contains(int(a)):
                raise ValueError(f"{agent}: action {a!r} is not one of 0..{N_ACTIONS - 1}")
            moves[0, i] = int(a)
        _, reward, success, _ = self._env.step(moves)
        self._t += 1
        done, cut = bool(success[0]), self._t >= self.steps
        observations, infos = self._observations(), self._infos()
        rewards = {a: float(reward[0, i]) for i, a in enumerate(self.possible_agents)}
        terminations = dict.fromkeys(self.possible_agents, done)
        truncations = dict.fromkeys(self.possible_agents, cut and not done)
        if done or cut:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def _observations(self) -> dict:
        obs = self._env.observe()[0]
        return {a: obs[i] for i, a in enumerate(self.possible_agents)}

    def _infos(self) -> dict:
        mask = allowed_moves(self._env.beliefs(), self.hover, True)[0].astype(np.int8)
        return {a: {"action_mask": mask[i]} for i, a in enumerate(self.possible_agents)}
