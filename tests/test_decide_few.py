"""The batch-1 decision path reads the swarm as Python ints (Beliefs.crews); on random beliefs it gives
the numpy reference's observations, allowed moves and taken-target test exactly."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.policy.base import _allowed_batched, allowed_moves
from swarmctl.policy.hover import HOVER_RULES, NO, parks
from swarmctl.world.beliefs import SMALL, Beliefs, ObservationSettings
from swarmctl.world.observe import _build_batched, build_observations, observe


def random_beliefs(seed: int, batch: int, deciders: int, vehicles: int, width: int, height: int, window: int):
    """Beliefs with random maps, some vehicles unknown, some hovering, vehicles sharing cells."""
    rng = np.random.default_rng(seed)
    shape = (batch, deciders, width, height)
    explored = rng.random(shape) < 0.5
    phi = np.where(explored, rng.choice([0.0, 0.3, 1.0], size=shape), 1.0).astype(np.float32)
    obstacles = explored & (rng.random(shape) < 0.2)
    targets = explored & ~obstacles & (phi == 1.0)
    cells = rng.integers(0, [width, height], size=(batch, deciders, vehicles, 2))
    shared = rng.random((batch, deciders, vehicles - 1, 1)) < 0.3  # on vehicle 0's cell
    cells[..., 1:, :] = np.where(shared, cells[..., :1, :], cells[..., 1:, :])
    me = np.stack([rng.permutation(vehicles)[:deciders] for _ in range(batch)])
    known = rng.random((batch, deciders, vehicles)) < 0.7
    known[np.arange(batch)[:, None], np.arange(deciders)[None, :], me] = True
    positions = np.where(known[..., None], cells, -1)
    hovering = rng.random((batch, deciders, vehicles)) < 0.4
    settings = ObservationSettings(window=window, sigma2=0.5)
    return Beliefs(explored, phi, obstacles, targets, positions, hovering, me, np.arange(batch), 3, settings)


@st.composite
def small_beliefs(draw):
    batch = draw(st.integers(1, 2))
    deciders = draw(st.integers(1, 4 if batch == 1 else 2))  # B x U x N <= SMALL with N >= U
    vehicles = draw(st.integers(deciders, max(deciders, SMALL // (batch * deciders))))
    window = draw(st.sampled_from([8, 9, 12, 20]))
    width, height = draw(st.integers(3, 26)), draw(st.integers(3, 26))
    return random_beliefs(draw(st.integers(0, 2**31 - 1)), batch, deciders, vehicles, width, height, window)


@settings(max_examples=300, deadline=None)
@given(small_beliefs(), st.booleans())
def test_the_few_deciders_observations_are_the_references_bit_for_bit(beliefs, remove_taken):
    assert beliefs.crews is not None
    s = beliefs.settings
    value = beliefs.value_channel(remove_taken)
    reference = _build_batched(value, beliefs.pos, beliefs.positions, beliefs.others, s.window, s.rho)
    fast = observe(beliefs, remove_taken)
    assert fast.dtype == reference.dtype and np.array_equal(fast, reference)
    arrays = build_observations(value, beliefs.pos, beliefs.positions, beliefs.others, s.window, s.rho)
    assert np.array_equal(arrays, reference)


@settings(max_examples=300, deadline=None)
@given(small_beliefs(), st.sampled_from(HOVER_RULES), st.booleans())
def test_the_few_deciders_rules_are_the_references(beliefs, rule, mask):
    fast = allowed_moves(beliefs, rule, mask)
    parked = None if rule == NO else parks(beliefs, rule)
    assert fast.dtype == bool and np.array_equal(fast, _allowed_batched(beliefs, parked, mask))
    assert beliefs.any_taken == bool((beliefs.targets & (beliefs.others_count > 0)).any())
    assert beliefs.any_obstacle == bool(beliefs.obstacles.any())


def test_beliefs_beyond_small_take_the_batched_path():
    beliefs = random_beliefs(0, 2, 3, 3, 12, 12, 8)  # 18 > SMALL
    assert beliefs.crews is None
    assert allowed_moves(beliefs).shape == (2, 3, 5)
