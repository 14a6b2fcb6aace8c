"""Agents that know the same maps (ideal sharing) get beliefs built once and broadcast: the same beliefs,
value channels, observations and allowed moves as each agent's own, built alone. The vehicle channel
counted cell by cell gives the per-vehicle count's observations."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.knowledge.model import PHI_TOLERANCE, Knowledge, beliefs_from_knowledge, position_key
from swarmctl.knowledge.stack import KnowledgeStack
from swarmctl.policy.base import allowed_moves
from swarmctl.world import observe as observing
from swarmctl.world.beliefs import ObservationSettings
from swarmctl.world.observe import observe
from swarmctl.world.taken import _remove, remove_taken_targets
from tests.test_decide_few import random_beliefs


def _shared_swarm(seed: int, n: int, w: int, h: int) -> list[Knowledge]:
    """n agents on one stack, every one holding the same explored cells, phi, obstacles, targets and
    positions of the swarm (some vehicles hovering, some sitting on a known target)."""
    rng = np.random.default_rng(seed)
    stack = KnowledgeStack(n, w, h, ids=n)
    agents = [Knowledge(w, h, i, stack=(stack, i)) for i in range(n)]
    cells = np.argwhere(rng.random((w, h)) < 0.6)
    phi = np.where(rng.random(len(cells)) < 0.08, 1.0, rng.random(len(cells)) * 0.9)
    obstacle = rng.random(len(cells)) < 0.1
    targets = cells[phi == 1.0]
    spots = [tuple(c) for c in rng.integers(0, (w, h), size=(n, 2)).tolist()]
    for j in range(min(len(targets), n // 2)):  # some vehicles on known targets
        spots[j] = tuple(targets[j].tolist())
    hovering = (rng.random(n) < 0.4).tolist()
    table = [position_key(2, cell, hv) for cell, hv in zip(spots, hovering)]
    for k in agents:
        k.sense(cells, phi, obstacle)
        if len(targets):
            k.add_targets(targets[:2], 1)
        k._position[:n] = table  # every agent knows every position (its own included) the same way
    return agents


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(2, 7), st.integers(8, 26), st.integers(8, 26))
def test_shared_beliefs_equal_each_agents_own(seed, n, w, h):
    agents = _shared_swarm(seed, n, w, h)
    s = ObservationSettings(window=10, phi_tolerance=PHI_TOLERANCE)
    shared = beliefs_from_knowledge(agents, n, s, 5)
    assert shared.phi_hat.strides[1] == 0  # the broadcast path is the one under test
    allowed = allowed_moves(shared)
    for remove in (False, True):
        value, obs = shared.value_channel(remove), observe(shared, remove)
        for i, k in enumerate(agents):
            alone = beliefs_from_knowledge([k], n, s, 5)
            for name in ("explored", "phi_hat", "obstacles", "targets", "positions", "hovering", "me"):
                assert np.array_equal(getattr(shared, name)[0, i], getattr(alone, name)[0, 0]), name
            assert np.array_equal(value[0, i], alone.value_channel(remove)[0, 0])
            assert np.array_equal(obs[0, i], observe(alone, remove)[0, 0])
            assert np.array_equal(allowed[0, i], allowed_moves(alone)[0, 0])


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(2, 6))
def test_removing_taken_targets_from_equal_maps_is_removing_them_from_each(seed, maps):
    rng = np.random.default_rng(seed)
    w, h = 9, 8
    phi = np.where(rng.random((w, h)) < 0.1, 1.0, rng.random((w, h))).astype(np.float32)
    explored = rng.random((w, h)) < 0.7
    phi[~explored] = 1.0
    taken = explored & (phi >= 1.0) & (rng.random((w, h)) < 0.5)
    phi[0, 0], explored[0, 0], taken[0, 0] = 1.0, True, True  # at least one taken target
    stack = [np.broadcast_to(a, (1, maps, w, h)) for a in (phi, explored, taken)]
    out = remove_taken_targets(*stack, 1.0, 0.01)
    each = _remove(*(np.ascontiguousarray(a[0]) for a in stack), 1.0, 0.01, 1e-6)
    assert out.shape == (1, maps, w, h) and np.array_equal(out[0], each)


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 3), st.integers(3, 9), st.integers(8, 30), st.sampled_from([8, 20]))
def test_the_vehicle_channel_counted_by_cell_is_the_per_vehicle_count(seed, batch, deciders, side, window):
    beliefs = random_beliefs(seed, batch, deciders, deciders + 3, side, side + 1, window)
    arrays = beliefs.value_channel(True), beliefs.pos, beliefs.positions, beliefs.others, window, beliefs.settings.rho
    kept, built = observing.DENSE, {}
    for dense in (0, 10**9):  # never, always
        observing.DENSE = dense
        try:
            built[dense] = observing._build_batched(*arrays)
        finally:
            observing.DENSE = kept
    assert built[0].dtype == built[10**9].dtype and np.array_equal(built[0], built[10**9])
