"""Geofences: the polygon of a grid, its mission items, the upload to ArduPilot (pymavlink) and PX4
(MAVSDK) mock vehicles over loopback UDP, and what the mock does with a target outside it."""

from __future__ import annotations

import socket

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as MAV

from swarmctl.geo.areas import Area
from swarmctl.geo.fence import farthest_metres, fence_contains, fence_polygon
from swarmctl.geo.grid import GeoGrid, make_grid
from swarmctl.mavlink.autopilots.ardupilot import ArduPilotVehicle, fence_items
from swarmctl.mavlink.autopilots.px4 import PX4Vehicle
from swarmctl.mavlink.codec import offset_m
from swarmctl.mavlink.errors import CommandRejected, CommandTimeout, MavlinkError
from swarmctl.mavlink.network import MavlinkLink
from swarmctl.mavlink.vehicle import fence_vertices
from swarmctl.sim.fence import fence_polygons
from tests.geo_helpers import REPO, to_lonlat
from tests.mavlink_support import HOME, mock_vehicles, our_threads, run
from tests.mission_support import small_grid, wait_for

CHICAGO_GRID = REPO / "missions" / "chicago-loop" / "grid.npz"
# a 100 m square around the mock's home
SQUARE = [offset_m(HOME[0], HOME[1], n, e) for n, e in [(-50, -50), (-50, 50), (50, 50), (50, -50)]]


@pytest.fixture(autouse=True)
def no_leftover_threads():
    yield
    assert our_threads() == []


def e7(vertices):
    return [(round(lat * 1e7), round(lon * 1e7)) for lat, lon in vertices]


def free_cell_centres(grid: GeoGrid):
    xs, ys = np.nonzero(~grid.blocked)
    return zip(*grid.cells_to_latlon(xs, ys))


# --- the polygon -----------------------------------------------------------------------------------


def test_the_chicago_grid_is_fenced_by_its_area_and_a_cell_of_margin():
    grid = GeoGrid.load(CHICAGO_GRID)
    fence = fence_polygon(grid)
    assert 3 <= len(fence) <= 60
    assert all(fence_contains(fence, lat, lon) for lat, lon in free_cell_centres(grid))
    outline = grid.projection.geometry_to_metres(shapely.Polygon([(lon, lat) for lat, lon in fence]))
    area = grid.projection.geometry_to_metres(shapely.from_wkt(grid.area_wkt))
    assert outline.contains(area.buffer(grid.cell * 0.99))  # one cell of margin all round
    assert not outline.contains(area.buffer(grid.cell * 1.5))


def test_a_grid_without_its_area_is_fenced_round_its_free_cells():
    grid = small_grid()  # no area_wkt: 10 x 10 cells, a blocked 2 x 2 block in the middle
    fence = fence_polygon(grid)
    assert len(fence) == 4  # the outline of the free cells; the blocked block is not cut out
    assert all(fence_contains(fence, lat, lon) for lat, lon in free_cell_centres(grid))
    blocked = grid.cell_to_latlon(4, 4)
    assert fence_contains(fence, *blocked)


def test_an_area_with_hundreds_of_vertices_is_simplified_without_cutting_into_it():
    angles = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    radius = np.where(np.arange(400) % 2, 300.0, 600.0)  # a 200-point star
    star = shapely.Polygon(np.column_stack([radius * np.cos(angles), radius * np.sin(angles)]))
    grid, _ = make_grid(Area(to_lonlat(star)), cell=10.0)
    fence = fence_polygon(grid, max_vertices=40)
    assert 3 <= len(fence) <= 40
    assert all(fence_contains(fence, lat, lon) for lat, lon in free_cell_centres(grid))


def test_bad_fence_polygons_are_refused_and_a_closed_ring_is_opened():
    assert fence_vertices(SQUARE + [SQUARE[0]]) == SQUARE
    for bad in (
        SQUARE[:2],
        [SQUARE[0], SQUARE[1], SQUARE[0], SQUARE[2]],
        SQUARE[:3] + [(91.0, 0.0)],
        SQUARE[:3] + [(0.0, float("nan"))],
    ):
        with pytest.raises(ValueError):
            fence_vertices(bad)


# --- the mission items -----------------------------------------------------------------------------

latitudes = st.floats(-90, 90, allow_nan=False)
longitudes = st.floats(-180, 180, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(latitudes, longitudes), min_size=3, max_size=70, unique=True))
def test_fence_items_carry_every_vertex_to_1e7_degrees_and_the_count_in_param1(vertices):
    sender, receiver = MAV.MAVLink(None, 255, 190), MAV.MAVLink(None, 1, 1)
    items = fence_items(sender, 1, 1, vertices)
    wire = b"".join(m.pack(sender) for m in items)
    parsed = receiver.parse_buffer(wire)
    assert [m.get_type() for m in parsed] == ["MISSION_ITEM_INT"] * len(vertices)
    assert [m.seq for m in parsed] == list(range(len(vertices)))
    for m in parsed:
        assert m.param1 == len(vertices) and m.mission_type == MAV.MAV_MISSION_TYPE_FENCE
        assert m.command == MAV.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION and m.frame == MAV.MAV_FRAME_GLOBAL
    (back,) = fence_polygons(parsed)
    assert len(back) == len(vertices)
    for (lat, lon), (blat, blon) in zip(vertices, back):
        assert abs(lat - blat) <= 0.5e-7 + 1e-12 and abs(lon - blon) <= 0.5e-7 + 1e-12


# --- ArduPilot: the mission protocol over pymavlink ------------------------------------------------


async def ardupilot(link: MavlinkLink, **kw) -> ArduPilotVehicle:
    v = ArduPilotVehicle(link, 1, **kw)
    await v.connect(5)
    return v


def test_ardupilot_takes_the_fence_and_refuses_a_target_outside_it():
    inside = offset_m(HOME[0], HOME[1], 30.0, 0.0)
    outside = offset_m(HOME[0], HOME[1], 0.0, 80.0)

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")) as (m,):
                v = await ardupilot(link)
                await v.upload_fence(SQUARE)
                stored = m.state()
                await v.arm_and_takeoff(10.0, timeout=20)
                await v.goto(*outside, 10.0)
                await wait_for(lambda: m.state().fence_refused >= 1, 5, "the target to be refused")
                held = m.target
                await v.goto(*inside, 10.0)
                await v.wait_reached(0.05, 15)
                await v.close()
                return stored, held, m.state()

    stored, held, after = run(scenario())
    assert e7(stored.fence[0]) == e7(SQUARE) and stored.fence_enabled
    assert held is not None and fence_contains(SQUARE, held[0], held[1])  # it kept its own target
    assert after.fence_refused == 1 and after.mode == "GUIDED"
    assert fence_contains(SQUARE, after.lat, after.lon)


def test_a_vehicle_found_outside_its_fence_in_flight_returns_home():
    away = [offset_m(HOME[0], HOME[1], n, e) for n, e in [(200, 200), (200, 300), (300, 300)]]

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")) as (m,):
                m.params["FENCE_RADIUS"] = 500.0  # the circle round home holds the polygon (424 m away)
                v = await ardupilot(link)
                await v.arm_and_takeoff(10.0, timeout=20)
                await v.upload_fence(away)  # the vehicle is not inside this one
                await wait_for(lambda: v.mode == "RTL", 5, "the breach action")
                texts = [t for _, _, t in link.peers[1].statustexts]
                await v.close()
                return m.fence.breaches, texts

    breaches, texts = run(scenario())
    assert breaches == 1 and any("Fence breached" in t for t in texts)


def test_lost_mission_messages_are_sent_again():
    """The first request and the final ack are lost: the mock asks again by itself, and the driver
    sends the last item again, which the mock acknowledges again."""

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")) as (m,):
                v = await ardupilot(link, mission_timeout=0.3)
                m.drop_sent("MISSION_REQUEST_INT", 1)
                m.drop_sent("MISSION_ACK", 1)
                await v.upload_fence(SQUARE)
                await v.close()
                sent = [t for t, _, _ in m.received if t.startswith("MISSION_")]
                return m.state(), sent

    state, sent = run(scenario())
    assert e7(state.fence[0]) == e7(SQUARE) and state.fence_enabled
    # the count again (no request came), four items, and the last one again (no ack came)
    assert sent == ["MISSION_COUNT"] * 2 + ["MISSION_ITEM_INT"] * 5


def test_a_fence_too_big_for_the_vehicle_is_refused_with_its_reason():
    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")) as (m,):
                m.fence.max_items = 3
                v = await ardupilot(link)
                try:
                    with pytest.raises(CommandRejected) as err:
                        await v.upload_fence(SQUARE)
                finally:
                    await v.close()
                return str(err.value), m.state()

    message, state = run(scenario())
    assert message.startswith("vehicle 1: the fence upload was refused: NO_SPACE (")
    assert "Only 3 items are supported" in message  # the vehicle's STATUSTEXT
    assert state.fence == () and not state.fence_enabled


# a 800 m square round home: its corners are 565 m away, beyond ArduPilot's default 300 m circle fence
BIG = [offset_m(HOME[0], HOME[1], n, e) for n, e in [(-400, -400), (-400, 400), (400, 400), (400, -400)]]


@pytest.mark.parametrize(
    "params,needle",
    [
        (
            {},
            "FENCE_RADIUS is 300 m but the fence reaches 565 m from home, so the circle fence would cut the "
            "search area; set FENCE_RADIUS to at least 570 or take the circle (2) out of FENCE_TYPE (now 7)",
        ),
        (
            {"FENCE_TYPE": 3.0},
            "FENCE_TYPE is 3, without the polygon (4): the vehicle would not enforce the "
            "uploaded fence; set FENCE_TYPE to 7",
        ),
        ({"FENCE_TYPE": 5.0}, None),  # no circle
        ({"FENCE_RADIUS": 570.0}, None),
    ],
)
def test_the_vehicles_own_fence_settings_are_checked_before_the_upload(params, needle):
    assert farthest_metres(BIG, HOME[0], HOME[1]) == pytest.approx(565.7, abs=1.5)  # offset_m is a flat-earth step

    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")) as (m,):
                m.params.update(params)
                v = await ardupilot(link)
                await v.wait_ready(10)
                try:
                    if needle is None:
                        await v.upload_fence(BIG)
                        return None, m.state()
                    with pytest.raises(MavlinkError) as err:
                        await v.upload_fence(BIG)
                    return str(err.value), m.state()
                finally:
                    await v.close()

    message, state = run(scenario())
    if needle is None:
        assert e7(state.fence[0]) == e7(BIG) and state.fence_enabled
    else:
        assert message == f"vehicle 1: {needle}"
        assert state.fence == () and not state.fence_enabled  # nothing was uploaded


def test_a_silent_vehicle_ends_the_upload_with_a_timeout():
    async def scenario():
        async with MavlinkLink("udpin:127.0.0.1:0") as link:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{link.local_port}")) as (m,):
                v = await ardupilot(link, mission_timeout=0.2, retries=1)
                m.drop_sent("MISSION_REQUEST_INT", None)
                try:
                    with pytest.raises(CommandTimeout) as err:
                        await v.upload_fence(SQUARE)
                finally:
                    await v.close()
                return str(err.value)

    assert run(scenario()) == (
        "vehicle 1: no answer to the fence upload (waiting for a request for item 0) after 2 attempts (0.2 s each)"
    )


# --- PX4: MAVSDK's geofence plugin -----------------------------------------------------------------


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_px4_takes_the_fence_through_mavsdk_and_ignores_a_reposition_outside_it():
    port = free_udp_port()
    outside = offset_m(HOME[0], HOME[1], 0.0, 80.0)

    async def scenario():
        v = PX4Vehicle(f"udpin:127.0.0.1:{port}", arm_retry_period=0.2)
        try:
            with mock_vehicles(dict(sysid=1, connect=f"udpout:127.0.0.1:{port}", autopilot="px4")) as (m,):
                await v.connect(10)
                await v.upload_fence(SQUARE)
                stored = m.state()
                await v.arm_and_takeoff(10.0, timeout=20)
                await v.goto(*outside, 10.0)
                await wait_for(lambda: m.state().fence_refused >= 1, 5, "the reposition to be refused")
                return stored, m.state()
        finally:
            await v.close()

    stored, after = run(scenario(), timeout=60)
    assert e7(stored.fence[0]) == e7(SQUARE) and stored.fence_enabled
    assert after.mode == "HOLD" and fence_contains(SQUARE, after.lat, after.lon)
