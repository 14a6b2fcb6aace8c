"""Knowledge: merge laws (idempotent, commutative, associative), newest position wins, own sensing,
and agreement with the simulator's value channel and observations."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.knowledge.model import Delta, Detection, Knowledge, Position, dequantise_phi, disc_cells, quantise_phi
from tests.helpers import make_env

W, H = 6, 5


@st.composite
def deltas(draw, width=W, height=H, senders=4):
    n = draw(st.integers(0, 8))
    cells = [(draw(st.integers(0, width - 1)), draw(st.integers(0, height - 1))) for _ in range(n)]
    cell = draw(st.one_of(st.none(), st.tuples(st.integers(0, width - 1), st.integers(0, height - 1))))
    return Delta(
        draw(st.integers(0, senders - 1)),
        draw(st.integers(0, 6)),
        cell,
        draw(st.booleans()),
        np.array(cells, dtype=np.int64).reshape(-1, 2),
        np.array(draw(st.lists(st.integers(0, 255), min_size=n, max_size=n)), dtype=np.uint8),
        np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)), dtype=bool),
    )


@st.composite
def detections(draw):
    n = draw(st.integers(1, 3))
    t = [(draw(st.integers(0, W - 1)), draw(st.integers(0, H - 1))) for _ in range(n)]
    return Detection(draw(st.integers(0, 3)), draw(st.integers(0, 6)), (0, 0), False, np.array(t))


reports = st.one_of(deltas(), detections())


@st.composite
def knowledges(draw):
    k = Knowledge(W, H, vehicle_id=draw(st.integers(0, 3)))
    for r in draw(st.lists(reports, max_size=4)):
        k.merge(r)
    return k


@given(knowledges())
def test_merge_is_idempotent(a):
    assert a.joined(a) == a
    b = a.copy()
    b.merge(a).merge(a)
    assert b == a


@given(knowledges(), knowledges())
def test_merge_is_commutative(a, b):
    assert a.joined(b) == b.joined(a)


@given(knowledges(), knowledges(), knowledges())
def test_merge_is_associative(a, b, c):
    assert a.joined(b).joined(c) == a.joined(b.joined(c))


@settings(max_examples=60)
@given(st.lists(reports, min_size=1, max_size=6), st.randoms(use_true_random=False))
def test_reports_in_any_order_and_repeated_give_the_same_knowledge(rs, rnd):
    in_order = Knowledge(W, H)
    for r in rs:
        in_order.merge(r)
    shuffled = rs + rs[: len(rs) // 2]  # some twice
    rnd.shuffle(shuffled)
    other = Knowledge(W, H)
    for r in shuffled:
        other.merge(r)
    assert other == in_order


@given(deltas(), deltas())
def test_a_position_is_replaced_only_by_a_newer_one(d1, d2):
    k = Knowledge(W, H)
    k.merge(d1).merge(d2)
    got = k.positions.get(d2.sender)
    if d1.sender == d2.sender:
        cands = [d.position for d in (d1, d2) if d.cell is not None]
        assert got == (max(cands, key=Position.order) if cands else None)
        if d1.cell is not None and d2.cell is not None and d1.step != d2.step:
            assert got.step == max(d1.step, d2.step)


def test_newest_position_wins_and_old_reports_do_not_move_a_vehicle_back():
    k = Knowledge(10, 10, vehicle_id=0)
    k.merge(Delta(3, 5, (4, 4)))
    k.merge(Delta(3, 2, (1, 1)))  # late, older
    assert k.positions[3] == Position(5, (4, 4), False)
    k.merge(Delta(3, 6, (4, 5), True))
    assert k.positions[3] == Position(6, (4, 5), True)
    k.merge(Delta(3, 6, (4, 3)))  # same step: the fixed tie-break keeps (4, 5)
    assert k.positions[3].cell == (4, 5)


def test_own_position_follows_the_vehicle_within_a_step_but_never_goes_back():
    k = Knowledge(10, 10, vehicle_id=1)
    k.set_position(4, (5, 5))
    k.set_position(4, (2, 2))  # same step, corrected (e.g. a guarded move): the vehicle knows best
    assert k.own_position == Position(4, (2, 2), False)
    k.set_position(3, (9, 9))
    assert k.own_position.cell == (2, 2)


def test_explored_cells_are_only_added_and_truth_combines_by_max():
    k = Knowledge(4, 4)
    k.merge(Delta(1, 0, None, cells=[(1, 1)], phi=[10], obstacle=[False]))
    k.merge(Delta(2, 0, None, cells=[(1, 1), (2, 2)], phi=[20, 30], obstacle=[True, False]))
    k.merge(Delta(1, 0, None, cells=[(1, 1)], phi=[5], obstacle=[False]))
    assert k.explored.sum() == 2 and k.phi_q[1, 1] == 20 and k.obstacle[1, 1] and k.phi_q[2, 2] == 30


def test_sense_queues_only_new_cells_and_take_delta_carries_the_position():
    k = Knowledge(20, 20, vehicle_id=2)
    k.set_position(4, (10, 10), on_target=True)
    phi = np.linspace(0, 1, 400).reshape(20, 20)
    assert k.sense_truth(phi, np.zeros((20, 20), bool)) == 29
    d = k.take_delta()
    assert (d.sender, d.step, d.cell, d.on_target, len(d)) == (2, 4, (10, 10), True, 29)
    assert np.array_equal(d.phi, quantise_phi(phi[d.cells[:, 0], d.cells[:, 1]]))
    k.set_position(5, (11, 10))
    assert k.sense_truth(phi, np.zeros((20, 20), bool)) == 7  # the disc moved one cell east
    assert len(k.take_delta()) == 7 and len(k.take_delta()) == 0


def test_cells_received_from_peers_are_not_published_again():
    k = Knowledge(10, 10, vehicle_id=0)
    k.merge(Delta(1, 1, (5, 5), cells=disc_cells((5, 5), 10, 10), phi=np.zeros(29), obstacle=np.zeros(29)))
    k.set_position(1, (5, 6))
    assert k.sense_truth(np.zeros((10, 10)), np.zeros((10, 10), bool)) == 7
    assert len(k.take_delta()) == 7


def test_quantisation_round_trip_is_within_half_a_step():
    phi = np.linspace(0, 1, 1001)
    assert np.abs(dequantise_phi(quantise_phi(phi)) - phi).max() <= 0.5 / 255 + 1e-7
    assert quantise_phi(1.0) == 255 and quantise_phi(0.0) == 0


def test_grid_checks():
    k = Knowledge(5, 5)
    with pytest.raises(ValueError):
        k.merge(Delta(1, 0, None, cells=[(5, 0)], phi=[1], obstacle=[False]))
    with pytest.raises(ValueError):
        k.merge(Knowledge(4, 5))
    with pytest.raises(ValueError, match="own cell"):
        k.observation()


def _env_and_knowledge(channel):
    env = make_env(
        12, targets=[(2, 2), (9, 9)], starts=[(1, 1), (6, 6)], obstacles=[(4, 4), (4, 5)], channel=channel, window=8
    )
    env.step(np.array([[2, 1]]))
    ks = []
    for v in range(2):
        k = Knowledge(12, 12, vehicle_id=v)
        x, y = np.nonzero(env.explored[0, v])
        k.sense(np.stack([x, y], 1), env.phi[0, x, y], env.obstacles[0, x, y])
        for u in range(2):
            if u == v or env.known_pos[0, v, u, 0] >= 0:
                k.merge_position(u, Position(1, tuple(env.pos[0, u] if u == v else env.known_pos[0, v, u])))
        ks.append(k)
    return env, ks


@pytest.mark.parametrize("channel", ["ideal", "none"])
def test_value_channel_and_observation_agree_with_the_simulator(channel):
    env, ks = _env_and_knowledge(channel)
    sim_value = env.beliefs().value_channel()[0]
    sim_obs = env.observe()[0]
    for v, k in enumerate(ks):
        assert np.abs(k.value_channel(env.cfg.rho) - sim_value[v]).max() <= 0.5 / 255 + 1e-6
        obs = k.observation(window=8, rho=env.cfg.rho)
        assert obs.shape == (3, 8, 8)
        assert np.array_equal(obs[:2], sim_obs[v, :2])
        assert np.abs(obs[2] - sim_obs[v, 2]).max() <= 0.5 / 255 + 1e-6


def test_a_target_learnt_later_raises_the_value_of_cells_explored_before_it():
    """Cells explored from the vehicle's position alone carry phi 0; the value channel computes phi on
    explored cells from the targets known, with the settings' sigma2 and cut-off, as the simulator's
    value map does, and leaves unexplored cells at 1."""
    from swarmctl.world.scenario import value_map

    k = Knowledge(12, 10, vehicle_id=0)
    k.set_position(1, (3, 3))
    cells = disc_cells((3, 3), 12, 10, 3.0)
    k.sense(cells, np.zeros(len(cells)), np.zeros(len(cells), bool))  # no detector: nothing reported
    before = k.value_channel()
    assert (before[k.explored] == 0).all() and (before[~k.explored] == 1).all()
    k.merge(Detection(1, 2, (5, 4), False, np.array([[5, 4]])))  # a peer found a target near them
    after = k.value_channel(sigma2=2.0)
    expected = value_map(np.array([[5, 4]]), 12, 10, sigma2=2.0)
    assert np.allclose(after[k.explored], expected[k.explored], atol=0.5 / 255, rtol=0)  # quantised as phi is
    assert (after[~k.explored] == 1).all()
    # where a detector reported the true phi, the known targets' value changes nothing (bit for bit)
    d = Knowledge(12, 10, vehicle_id=0)
    d.set_position(1, (3, 3))
    d.sense(cells, expected[cells[:, 0], cells[:, 1]], np.zeros(len(cells), bool))
    reported = d.value_channel(sigma2=2.0)
    d.add_targets([(5, 4)], 2)
    assert np.array_equal(d.value_channel(sigma2=2.0), reported)
    assert after[4, 4] > 0.7 and after[0, 3] == 0.0  # near the target raised, far from it still 0
    # a reported phi above the known targets' value is kept (a detector's phi near unseen targets)
    k.sense(np.array([[0, 3]]), np.array([0.5]), np.array([False]))
    assert abs(k.value_channel(sigma2=2.0)[0, 3] - 0.5) <= 1 / 255


@settings(max_examples=200)
@given(
    st.integers(1, 20),
    st.integers(1, 20),
    st.sampled_from([0.0, 1.0, 1.5, 2.0, 3.0, 4.2]),
    st.data(),
)
def test_disc_cells_are_the_discs_cells_on_the_grid_in_the_offsets_order(w, h, fov, data):
    """The footprint: every cell of the disc round `cell` that lies on the grid, in the simulator's
    offsets order, whether the disc is whole or cut by the grid's edge."""
    from swarmctl.world.scenario import fov_offsets

    cell = (data.draw(st.integers(0, w - 1)), data.draw(st.integers(0, h - 1)))
    every = np.asarray(cell) + fov_offsets(fov)
    on_grid = every[(every[:, 0] >= 0) & (every[:, 0] < w) & (every[:, 1] >= 0) & (every[:, 1] < h)]
    got = disc_cells(cell, w, h, fov)
    assert got.dtype == np.int64 and np.array_equal(got, on_grid)
    got[:] = -1  # a fresh array each time: the next caller's disc is untouched
    assert np.array_equal(disc_cells(cell, w, h, fov), on_grid)


@settings(max_examples=100)
@given(st.lists(st.tuples(st.integers(0, W - 1), st.integers(0, H - 1)), max_size=12), st.data())
def test_sense_counts_each_newly_explored_cell_once_and_queues_exactly_those(cells, data):
    """Own sensing with repeated cells (a footprint and a detector's report overlap): the count is of
    distinct new cells, and the next delta carries exactly them, in x, y order, with their max phi."""
    k = Knowledge(W, H, vehicle_id=0)
    k.set_position(1, (0, 0))
    known = data.draw(st.lists(st.tuples(st.integers(0, W - 1), st.integers(0, H - 1)), max_size=6))
    if known:
        k.sense(known, np.zeros(len(known)), np.zeros(len(known), bool))
        k.take_delta()
    phi = np.array(data.draw(st.lists(st.floats(0, 1), min_size=len(cells), max_size=len(cells))))
    new = sorted(set(cells) - set(known))
    assert k.sense(cells, phi, np.zeros(len(cells), bool)) == len(new)
    delta = k.take_delta()
    assert [tuple(c) for c in delta.cells.tolist()] == new
    for c, q in zip(delta.cells.tolist(), delta.phi):
        assert q == max(quantise_phi(p) for p, s in zip(phi, cells) if s == tuple(c))
    assert len(k.take_delta()) == 0
