"""Policy randomness keyed by (seed, episode, step, vehicle, stream): batch size never changes a draw.

Every random number a policy uses (tie-breaks, softmax sampling, random moves) is a pure function of
the policy's seed, the episode id, the step, the vehicle's index in the swarm, a stream id naming the
purpose, and the element's index: the counter-based generator of swarmctl.world.draws (SplitMix64
finalisers over the key, vectorised in numpy), which the world's message losses share on streams of
their own. So an episode plays the same whether it runs alone or in a batch of 500, in chunks or not,
and a vehicle planning another vehicle's move (the frontier planner's claims) draws the very numbers
that vehicle draws for itself. 53-bit uniforms in [0, 1).
"""

from __future__ import annotations

import numpy as np

from swarmctl.world.beliefs import Beliefs
from swarmctl.world.draws import (  # noqa: F401  (the generator's parts, for tests that check its two paths)
    _GOLDEN,
    SMALL,
    _key,
    _mix,
    _one_each_small,
    _uniform_small,
    uniform,
)

# one stream per purpose, so adding a draw in one place never shifts another's numbers
TIES, CLAIMS, NAVIGATE, SOFTMAX, RANDOM, LOOKAHEAD = range(1, 7)


class Draws:
    """The draws of one decision: bound to a policy seed and the beliefs' episodes, step and deciders."""

    def __init__(self, seed: int, beliefs: Beliefs):
        self.seed, self.episodes, self.step, self.me = int(seed), beliefs.episodes, beliefs.step, beliefs.me

    def deciders(self, stream: int, *shape: int) -> np.ndarray:
        """(B, U, *shape) uniforms, one set per decider."""
        if not shape and self.me.size <= SMALL:  # one draw per decider, few deciders: a decision at batch 1
            return _one_each_small(self.seed, self.episodes, self.step, self.me, stream)
        return uniform(self.seed, self.episodes, self.step, self.me, stream, shape)

    def vehicles(self, stream: int, n: int, *shape: int) -> np.ndarray:
        """(B, n, *shape) uniforms, one set per vehicle 0..n-1 of the swarm (the same numbers whoever
        draws them)."""
        ids = np.broadcast_to(np.arange(n), (len(self.episodes), n))
        return uniform(self.seed, self.episodes, self.step, ids, stream, shape)
