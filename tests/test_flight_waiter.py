"""One waiter for a round's flights (swarmctl.mission.flight.Flight.fly_all): each vehicle's outcome and its
own timeout, the driver's resends while waiting, a driver that must wait for its goto, stop and link loss."""

from __future__ import annotations

import asyncio
import time
from types import SimpleNamespace

import pytest

from swarmctl.mavlink.errors import MavlinkError
from swarmctl.mission.flight import Flight
from tests.mavlink_support import run
from tests.mission_support import small_grid


class FakeVehicle:
    """Reaches its target `arrive_after` seconds after it was sent (None: never); `answers` False: its
    driver waits for an answer to each position target (as PX4's does), so it has no goto_nowait."""

    def __init__(self, arrive_after: float | None, answers: bool = True):
        self.arrive_after, self.answers = arrive_after, answers
        self.lost = False
        self.position = None
        self.sent: float | None = None
        self.target = None
        self.kept = 0
        self.fix_waker = None

    def goto_nowait(self, lat: float, lon: float, rel_alt: float) -> bool:
        if not self.answers:
            return False
        self.target, self.sent = (lat, lon, rel_alt), time.monotonic()
        return True

    async def goto(self, lat: float, lon: float, rel_alt: float) -> None:
        await asyncio.sleep(0.05)  # the vehicle's answer
        self.target, self.sent = (lat, lon, rel_alt), time.monotonic()

    def reached(self, tolerance: float) -> bool:
        if self.sent is None or self.arrive_after is None:
            return False
        return time.monotonic() - self.sent >= self.arrive_after

    async def keep_going(self) -> None:
        self.kept += 1


def controller() -> Flight:
    """The flight part alone: a grid, the guard's altitude, the reach tolerance and the stop flag; no
    crew, recorder or finish line (fly_all needs none of them), and a watch that sees nobody off course."""
    return Flight(
        small_grid(),
        SimpleNamespace(setpoint_altitude=lambda: 40.0),
        fov=1.0,
        limits=SimpleNamespace(reach_tolerance=1.0),
        timing=SimpleNamespace(sense_timeout=1.0),
        rec=None,
        state=SimpleNamespace(stopping=False, step=0),
        crew=None,
        watch=SimpleNamespace(off_course=lambda a, cell: False),
        finish=None,
    )


def agent(name: str, vehicle: FakeVehicle):
    return SimpleNamespace(name=name, vehicle=vehicle, cell=(0, 0), watch_from=None)  # not watched: no course


def test_each_flight_ends_on_its_own_arrival_or_timeout():
    c = controller()
    fast, never, answering = FakeVehicle(0.1), FakeVehicle(None), FakeVehicle(0.2, answers=False)
    moves = [(agent("fast", fast), (1, 0)), (agent("never", never), (0, 1)), (agent("px4", answering), (2, 0))]

    async def scenario():
        started = time.monotonic()
        out = await c.fly_all(moves, 0.6)
        return out, time.monotonic() - started

    (reached, took) = run(scenario())
    assert reached == [True, False, True]
    assert 0.6 <= took < 1.2  # the waiter ends with the last one: the timeout of the one that never arrives
    assert fast.target == (*c.grid.cell_to_latlon(1, 0), 40.0) and answering.target is not None
    assert never.kept >= 5  # its driver was given the chance to resend while it waited


def test_stop_and_link_loss_end_the_wait_at_once_and_count_as_no_timeout():
    c = controller()
    lost, stopped = FakeVehicle(None), FakeVehicle(None)

    async def scenario():
        async def trouble():
            await asyncio.sleep(0.1)
            lost.lost = True
            await asyncio.sleep(0.1)
            c.state.stopping = True

        started = time.monotonic()
        helper = asyncio.ensure_future(trouble())
        out = await c.fly_all([(agent("lost", lost), (1, 1)), (agent("stopped", stopped), (2, 2))], 30.0)
        await helper
        return out, time.monotonic() - started

    reached, took = run(scenario())
    assert reached == [True, True] and took < 1.0


def test_a_blocked_cell_is_refused_before_any_target_goes_out():
    c = controller()
    ok = FakeVehicle(0.0)
    blocked = tuple(int(v) for v in next(zip(*c.grid.blocked.nonzero())))

    with pytest.raises(MavlinkError, match="blocked cell"):
        run(c.fly_all([(agent("ok", ok), (0, 0)), (agent("bad", FakeVehicle(0.0)), blocked)], 1.0))
    assert ok.target is None


def test_an_arrival_is_seen_at_its_position_report_not_at_the_next_poll(monkeypatch):
    """With the timers' poll an hour apart, the flights still end at the position reports that show
    them arrived (the drivers set `fix_waker`); the waker is handed back afterwards."""
    import swarmctl.mission.flight as flight

    monkeypatch.setattr(flight, "POLL_S", 3600.0)
    c = controller()
    first, second = FakeVehicle(None), FakeVehicle(None)

    async def report(v: FakeVehicle) -> None:
        while v.fix_waker is None:  # the flight has started
            await asyncio.sleep(0)
        v.arrive_after = 0.0  # it is there: the driver has the report ...
        v.fix_waker.set()  # ... and says so

    async def scenario():
        reports = asyncio.gather(report(first), report(second))
        moves = [(agent("a", first), (1, 0)), (agent("b", second), (0, 1))]
        out = await asyncio.wait_for(c.fly_all(moves, 7200.0), 60)
        await reports
        return out

    assert run(scenario()) == [True, True]
    assert first.fix_waker is None and second.fix_waker is None


def test_the_waker_wakes_its_waiter_keeps_a_set_made_between_waits_and_times_out():
    from swarmctl.mavlink.vehicle import Waker

    async def scenario():
        waker = Waker()
        timed_out = await waker.wait(0.0)
        waker.set()  # nobody waits: kept for the next wait
        kept = await waker.wait(3600.0)
        loop = asyncio.get_running_loop()
        loop.call_soon(waker.set)
        woken = await asyncio.wait_for(waker.wait(3600.0), 60)
        again = await waker.wait(0.0)  # the set was used up
        return timed_out, kept, woken, again

    assert run(scenario()) == (False, True, True, False)


def test_both_drivers_wake_the_flights_at_a_position_report_and_not_at_one_without_a_position():
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    from swarmctl.mavlink.autopilots.ardupilot import ArduPilotVehicle
    from swarmctl.mavlink.autopilots.px4 import PX4Vehicle
    from swarmctl.mavlink.vehicle import Waker

    sender = mavlink2.MAVLink(None, srcSystem=7, srcComponent=1)
    parser = mavlink2.MAVLink(None)

    def global_position(lat_e7: int, lon_e7: int):
        frame = sender.global_position_int_encode(0, lat_e7, lon_e7, 40000, 40000, 0, 0, 0, 0).pack(sender)
        return parser.decode(bytearray(frame))

    def px4_position(lat: float, lon: float):
        return SimpleNamespace(latitude_deg=lat, longitude_deg=lon, relative_altitude_m=40.0, absolute_altitude_m=220.0)

    ardupilot = ArduPilotVehicle(SimpleNamespace(), 7)
    px4 = PX4Vehicle("udpin:127.0.0.1:14999", sysid=8)
    reports = [
        (ardupilot, lambda: ardupilot._on_position(global_position(0, 0)), False),  # no position yet
        (ardupilot, lambda: ardupilot._on_position(global_position(418_800_000, -876_300_000)), True),
        (px4, lambda: px4._on_position(px4_position(float("nan"), 0.0)), False),
        (px4, lambda: px4._on_position(px4_position(41.88, -87.63)), True),
    ]

    async def scenario():
        woken = []
        for vehicle, report, _ in reports:
            vehicle.fix_waker = Waker()
            report()
            woken.append(await vehicle.fix_waker.wait(0.0))
        return woken

    assert run(scenario()) == [wakes for _, _, wakes in reports]
