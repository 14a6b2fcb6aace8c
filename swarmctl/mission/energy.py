"""When a searching vehicle must go home: the charge it needs to get there against the charge it has.

The charge needed is `reserve` % plus the vehicle's consumption (% per second) times the seconds of
its return from where it is (`FlightLimits.rtl_s`: climb to its return altitude, fly home at its
return speed, hover, land). Below `floor` % it goes home whatever the figures say.

Consumption is measured, not assumed: a least-squares slope of the vehicle's own battery reports over
its last `WINDOW_S` seconds of flight (noise and the steps of an integer percentage average out over
a window; a single report moves it little). Until the window spans `MIN_SPAN_S` the conservative
`PRIOR_RATE` is the least it is taken to be (a battery that drains faster shows it sooner, from
`EARLY_SPAN_S`); a charge that fell less than `MIN_DROP` % over the window is taken as one whole %
more than it fell. The seconds are the vehicle's own (its reports' time since boot, Vehicle.clock_s:
the clock the return is flown on, so the figures hold for a simulator running faster than the wall
clock too); where the driver reports no clock (PX4 through MAVSDK), its odometer at its flight speed
(Vehicle.distance_flown_m / speed), where hovering and waiting between moves drain without metres:
that counts against the rate and errs on the side of going home early.
Pure: no I/O.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from swarmctl.mavlink.limits import FlightLimits

PRIOR_RATE = 0.15  # % per second until measured: a full battery in 11 minutes, less than a search quadcopter's
WINDOW_S = 240.0  # seconds of flight the rate is measured over
MIN_SPAN_S = 45.0  # the measurement replaces the prior once its window spans this many seconds ...
MIN_DROP = 3.0  # ... and the charge fell this many % in it (a whole-% report: a few of its steps)
EARLY_SPAN_S = 10.0  # a faster drain than the prior counts from this many seconds (and MIN_DROP %)
MAX_SAMPLES = 2000  # reports kept at most (a vehicle that hovers adds them without seconds of flight)
MIN_RATE = 0.01  # % per second: a charge that does not fall is no free flight (a stuck or lagging report)


def consumption_rate(
    seconds: np.ndarray | list[float],
    charges: np.ndarray | list[float],
    prior: float = PRIOR_RATE,
    window: float = WINDOW_S,
) -> float:
    """% per second from reports (`seconds` of flight, increasing; `charges` in %): the least-squares
    slope over the last `window` seconds; at least `prior` while they span less than MIN_SPAN_S (just
    `prior` under EARLY_SPAN_S); over a full span with less than MIN_DROP % fallen, at most one whole %
    more than fell."""
    t = np.asarray(seconds, dtype=np.float64)
    c = np.asarray(charges, dtype=np.float64)
    if len(t) < 2:
        return prior
    keep = t >= t[-1] - window
    t, c = t[keep], c[keep]
    span, drop = float(t[-1] - t[0]), float(c.max() - c.min())
    if span < EARLY_SPAN_S:
        return prior
    if drop < MIN_DROP:
        return prior if span < MIN_SPAN_S else max(min(prior, (drop + 1.0) / span), MIN_RATE)
    measured = max(float(-np.polyfit(t - t[0], c, 1)[0]), MIN_RATE)
    return max(measured, prior) if span < MIN_SPAN_S else measured


@dataclass(frozen=True)
class HomeCheck:
    """The figures the rule decided on; `go`: the vehicle must go home now, `reason` "floor" (below the
    hard floor) or "energy" (the charge it needs to get home with its reserve)."""

    go: bool
    reason: str
    battery: float
    distance_m: float | None = None
    rate: float | None = None
    seconds_home: float | None = None
    needed: float | None = None

    def record(self) -> dict[str, float | str]:
        """What the `low battery` transition records."""
        out: dict[str, float | str] = {"battery": self.battery, "reason": self.reason}
        if self.distance_m is not None:
            out["distance_m"] = round(self.distance_m, 1)
        if self.rate is not None:
            out["rate"] = round(self.rate, 4)
        if self.seconds_home is not None:
            out["seconds_home"] = round(self.seconds_home, 1)
        if self.needed is not None:
            out["needed"] = round(self.needed, 1)
        return out


def home_check(
    battery: float,
    floor: float,
    reserve: float,
    rate: float | None = None,
    distance_m: float | None = None,
    height_m: float = 0.0,
    limits: FlightLimits | None = None,
) -> HomeCheck:
    """Whether a vehicle with `battery` % must go home: below `floor` %, or below `reserve` % plus `rate`
    (% per second) times its return from `distance_m` metres away and `height_m` metres up at `limits`.
    Without a distance, a rate or limits only the floor decides."""
    if distance_m is None or rate is None or limits is None:
        return HomeCheck(battery < floor, "floor", battery)
    seconds = limits.rtl_s(distance_m, height_m)
    needed = reserve + rate * seconds
    reason = "floor" if battery < floor else "energy"
    return HomeCheck(battery < floor or battery < needed, reason, battery, distance_m, rate, seconds, needed)


class ChargeLog:
    """A vehicle's battery reports against its seconds of flight, as long as the rate's window needs."""

    def __init__(self, window: float = WINDOW_S) -> None:
        self.window = window
        self.samples: deque[tuple[float, float]] = deque(maxlen=MAX_SAMPLES)

    def add(self, seconds: float, charge: float) -> None:
        """A report; one that says nothing new (the same charge within a second of flight) is not kept."""
        if self.samples:
            last_s, last_c = self.samples[-1]
            if seconds < last_s:  # a new odometer (a reconnected driver): start again
                self.samples.clear()
            elif charge == last_c and seconds - last_s < 1.0:
                return
        self.samples.append((seconds, charge))
        while len(self.samples) > 2 and self.samples[1][0] < seconds - self.window:
            self.samples.popleft()

    def clear(self) -> None:
        self.samples.clear()

    def rate(self, prior: float = PRIOR_RATE) -> float:
        if len(self.samples) < 2:
            return prior
        seconds, charges = zip(*self.samples)
        return consumption_rate(list(seconds), list(charges), prior, self.window)
