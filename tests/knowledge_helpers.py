"""Shared pieces of the knowledge tests: a swarm of exchanges around a radio, waiting on counters."""

from __future__ import annotations

import contextlib

import numpy as np

from swarmctl.knowledge.exchange import KnowledgeExchange
from swarmctl.knowledge.model import Knowledge, disc_cells
from swarmctl.sim.radio import Radio, wait_quiet
from swarmctl.world.channel import Channel
from swarmctl.world.moves import MOVES


def settle(radio: Radio, agents: list[KnowledgeExchange], timeout: float = 10.0) -> None:
    """Wait (on counters, with a timeout) until nothing is in flight; see radio.wait_quiet."""
    wait_quiet(radio, agents, timeout)


@contextlib.contextmanager
def swarm(
    n: int,
    size: int = 20,
    channel: Channel | None = None,
    seed: int = 0,
    mission_id: int = 7,
    push: bool = True,
    digest_every: int = 5,
    radio: Radio | None = None,
):
    """A radio (unless given) and n exchanges registered with it; everything closed on exit."""
    own_radio = radio is None
    radio = radio or Radio(channel, seed=seed)
    agents: list[KnowledgeExchange] = []
    try:
        for v in range(n):
            agents.append(
                KnowledgeExchange(
                    Knowledge(size, size, v), mission_id, radio.address, digest_every=digest_every, push=push
                )
            )
            radio.add_peer(agents[-1].address, system_id=v + 1)
        yield radio, agents
    finally:
        for a in agents:
            a.close()
        if own_radio:
            radio.close()


class Walkers:
    """Ground truth and random walks for n vehicles on a size x size grid (no obstacles in the way)."""

    def __init__(self, n: int, size: int, seed: int = 0):
        self.rng = np.random.default_rng(seed)
        self.size = size
        self.phi = self.rng.random((size, size))
        self.obstacle = self.rng.random((size, size)) < 0.1
        self.cells = [tuple(int(c) for c in self.rng.integers(0, size, 2)) for _ in range(n)]

    def move(self) -> None:
        for i, c in enumerate(self.cells):
            d = MOVES[self.rng.integers(0, 5)]
            self.cells[i] = (int(np.clip(c[0] + d[0], 0, self.size - 1)), int(np.clip(c[1] + d[1], 0, self.size - 1)))

    def sense(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c = disc_cells(self.cells[i], self.size, self.size)
        return c, self.phi[c[:, 0], c[:, 1]], self.obstacle[c[:, 0], c[:, 1]]

    def step_all(self, agents: list[KnowledgeExchange], step: int) -> None:
        for i, a in enumerate(agents):
            cells, phi, obs = self.sense(i)
            a.step(step, self.cells[i], False, cells, phi, obs)
