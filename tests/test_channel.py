"""The packet-error model: calibration point, monotonic in distance, the extremes."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarmctl.world.channel import Channel, packet_error_probability


def test_half_the_packets_are_lost_at_110_m():
    assert packet_error_probability(110.0) == pytest.approx(0.5, abs=1e-6)


@given(st.floats(1.0, 2000.0), st.floats(1.0, 2000.0))
def test_loss_grows_with_distance(a, b):
    lo, hi = sorted((a, b))
    assert packet_error_probability(lo) <= packet_error_probability(hi) + 1e-12


def test_cell_size_sets_the_scale_10_m_and_20_m_cells():
    ten, twenty = Channel("model", 10.0), Channel("model", 20.0)
    assert ten.loss_probability(11.0) == pytest.approx(0.5, abs=1e-6)
    assert twenty.loss_probability(5.5) == pytest.approx(0.5, abs=1e-6)
    assert twenty.loss_probability(8.0) > ten.loss_probability(8.0)


def test_ideal_and_none_are_the_extremes():
    d = np.array([0.0, 3.0, 100.0])
    assert (Channel("ideal").loss_probability(d) == 0).all()
    assert (Channel("none").loss_probability(d) == 1).all()
    assert (Channel("fixed", loss=0.3).loss_probability(d) == 0.3).all()
