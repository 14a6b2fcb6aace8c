"""The off-course watch's kept path (swarmctl.mission.watch.deviation): the same figures as measuring
each position afresh, whatever the order of starts, cells, positions and last on-course points."""

from __future__ import annotations

from types import SimpleNamespace

from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.mavlink.codec import ne_m
from swarmctl.mavlink.vehicle import Position
from swarmctl.mission.watch import deviation, off_path_m
from tests.mission_support import small_grid

GRID = small_grid()


def fresh(start, cell, watch_pos, pos) -> tuple[float, float] | None:
    """The figures measured from nothing kept: the path's ends converted for this position alone."""
    below = 40.0 - pos.rel_alt
    if start is None:
        return 0.0, below
    lat, lon = GRID.cell_to_latlon(*cell)
    here = ne_m(lat, lon, pos.lat, pos.lon)
    starts = [GRID.cell_to_latlon(*start)] + ([watch_pos] if watch_pos is not None else [])
    return min(off_path_m(here, ne_m(lat, lon, *s)) for s in starts), below


cells = st.tuples(st.integers(0, 9), st.integers(0, 9))
metres = st.floats(-80.0, 80.0)
checks = st.lists(
    st.tuples(
        st.one_of(st.none(), cells),  # start
        cells,
        st.one_of(st.none(), st.tuples(metres, metres)),  # watch_pos, metres from the grid's first centre
        st.tuples(metres, metres, st.floats(0.0, 60.0)),  # the position
        st.booleans(),  # the same position report again (the same object)
    ),
    min_size=1,
    max_size=12,
)


@settings(max_examples=60, deadline=None)
@given(checks)
def test_the_kept_path_gives_the_figures_of_a_fresh_measurement(sequence):
    lat0, lon0 = GRID.cell_to_latlon(0, 0)
    vehicle = SimpleNamespace(position=None)
    agent = SimpleNamespace(vehicle=vehicle, watch_pos=None, watch_path=None)
    for start, cell, watch_m, (n, e, alt), again in sequence:
        agent.watch_pos = None if watch_m is None else (lat0 + watch_m[0] * 1e-5, lon0 + watch_m[1] * 1e-5)
        if not (again and vehicle.position is not None):
            vehicle.position = Position(lat0 + n * 1e-5, lon0 + e * 1e-5, alt, alt + 180.0)
        assert deviation(GRID, 40.0, agent, start, cell) == fresh(start, cell, agent.watch_pos, vehicle.position)


def test_no_position_no_figures():
    agent = SimpleNamespace(vehicle=SimpleNamespace(position=None), watch_pos=None, watch_path=None)
    assert deviation(GRID, 40.0, agent, (0, 0), (1, 0)) is None
