"""tools/controller_overhead.py's growth figures: the fitted exponent and the 50/3 ratio it prints
below its table."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from tools.controller_overhead import scaling


def rows(cpu: dict[int, float], runs: int = 2) -> list[dict]:
    key = "process_cpu_min" if runs > 1 else "process_cpu_mean"
    return [{"vehicles": n, key: c} for n, c in cpu.items()]


@given(
    scale=st.floats(0.1, 100.0),
    exponent=st.floats(0.2, 2.5),
    runs=st.sampled_from([1, 3]),
)
def test_a_power_law_gives_back_its_exponent_over_the_sizes_from_12(scale, exponent, runs):
    cpu = {n: scale * n**exponent for n in (12, 50, 200)}
    cpu[3] = 1000.0  # the smallest size is not fitted: it would bend the line
    got = scaling(rows(cpu, runs))
    assert got["sizes"] == [12, 50, 200]
    assert math.isclose(got["exponent"], exponent, rel_tol=1e-9, abs_tol=1e-9)
    assert math.isclose(got["ratio_50_3"], cpu[50] / 1000.0)


def test_the_table_of_one_day_fits_as_the_docs_say():
    got = scaling(rows({3: 6.929, 12: 9.692, 50: 18.396, 200: 73.133}))
    assert round(got["exponent"], 2) == 0.72
    assert round(got["ratio_50_3"], 2) == 2.65


def test_without_the_sizes_there_is_no_figure():
    got = scaling(rows({3: 7.0, 12: 10.0}))
    assert got["exponent"] is None and got["sizes"] == [] and got["ratio_50_3"] is None
    got = scaling(rows({50: 20.0, 200: 80.0}))
    assert math.isclose(got["exponent"], 1.0) and got["ratio_50_3"] is None
    assert scaling([{"vehicles": 50}])["exponent"] is None  # a size whose runs measured nothing
