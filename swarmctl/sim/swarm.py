"""A simulated swarm for the demo and the tests: mock autopilots over loopback UDP carrying a hidden
scenario in simulated detectors (or no detectors: a coverage search), and the MissionPlan that flies
them: in ground mode (every vehicle from one process, knowledge on the in-process bus, with the
swarm's channel model), or with the loopback radio as the knowledge channel of agents in separate
processes (`plan(..., radio=True)`).

The controller side is the real one: it talks to the mocks over UDP exactly as it would to real
vehicles and learns about targets only from the mocks' detector reports.
"""

from __future__ import annotations

import math
import socket
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from swarmctl.geo.fence import farthest_metres, fence_polygon
from swarmctl.mavlink.autopilots.base import autopilot_named
from swarmctl.mavlink.codec import Endpoint
from swarmctl.mission.plan import MissionPlan, make_plan
from swarmctl.mission.spec import DEMO_SETTINGS, ON_LINK, MissionSpec, VehicleSpec
from swarmctl.sim.autopilot import MockAutopilot
from swarmctl.sim.detector import FOV_CELLS, SimDetector
from swarmctl.sim.mock_runner import MockRunner
from swarmctl.sim.radio import Radio
from swarmctl.sim.relay import LinkFaults, LossyRelay
from swarmctl.world.channel import Channel

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.geo.grid import GeoGrid
    from swarmctl.mission.decide import FieldPolicy

HOME_AMSL = 180.0  # metres; the Chicago Loop is about 180 m above sea level


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _region(grid: GeoGrid) -> np.ndarray:
    free = grid.largest_free_region()
    if not free.any():
        raise ValueError("the grid has no free cell")
    return free


def start_cells(grid: GeoGrid, count: int) -> list[tuple[int, int]]:
    """Launch cells along the south edge of the largest free region, two cells apart where possible."""
    free = _region(grid)
    cells = sorted(((int(x), int(y)) for x, y in zip(*np.nonzero(free))), key=lambda c: (c[1], c[0]))
    chosen: list[tuple[int, int]] = []
    for spacing in (2, 1):
        chosen = []
        for c in cells:
            if all(abs(c[0] - o[0]) + abs(c[1] - o[1]) >= spacing for o in chosen):
                chosen.append(c)
                if len(chosen) == count:
                    return chosen
    raise ValueError(f"the grid's free region has room for {len(chosen)} vehicles, not {count}")


def hide_targets(
    grid: GeoGrid, count: int, seed: int, avoid: list[tuple[int, int]], min_distance: int = 6
) -> np.ndarray:
    """`count` distinct target cells in the largest free region, at least `min_distance` cells
    (Manhattan) from every launch cell, drawn with `seed`."""
    rng = np.random.default_rng(seed)
    free = _region(grid)
    xs, ys = np.nonzero(free)
    ok = np.ones(len(xs), dtype=bool)
    for ax, ay in avoid:
        ok &= (np.abs(xs - ax) + np.abs(ys - ay)) >= min_distance
    if ok.sum() < count:
        ok[:] = True
        for ax, ay in avoid:
            ok &= (xs != ax) | (ys != ay)
    idx = rng.choice(np.nonzero(ok)[0], size=count, replace=False)
    return np.stack([xs[idx], ys[idx]], axis=1).astype(np.int64)


@dataclass
class SimSwarm:
    """Mock vehicles (ArduPilot by default; "px4" entries in `autopilots` fly through MAVSDK) at
    distinct launch cells of `grid`, with `targets` hidden in their detectors (`carry_detectors=False`:
    no detectors, the mission is a coverage search). `channel` is the knowledge channel model: of the
    in-process bus in ground mode, of the loopback radio with `plan(..., radio=True)`."""

    grid: GeoGrid
    uavs: int = 3
    seed: int = 0
    speedup: float = 20.0
    altitude: float | None = None  # metres above home; None: the grid's
    fov: float | None = None  # the detectors' sensing radius in cells; None: the policy's, set by plan()
    mission_id: int = 7
    targets: np.ndarray | None = None
    autopilots: list[str] | None = None
    channel: Channel | None = None
    gcs_failsafe: float | None = 5.0
    # parameters every mock is given otherwise than its personality's defaults (e.g. FS_GCS_ENABLE=0 or
    # NAV_DLL_ACT=0: the GCS failsafe off, which preflight refuses unless allow_no_failsafe = true)
    params: dict[str, float] | None = None
    speed: float = 10.0  # m/s, a usual cruise speed for search quadcopters
    # the mock ArduPilots' FENCE_RADIUS (their circle fence round home); None: as a vehicle set up for
    # this area would have it, reaching the grid's fence from the launch cell (at least the default 300 m)
    fence_radius: float | None = None
    carry_detectors: bool = True
    pod: float = 1.0  # the detectors' probability of detection per pass (swarmctl.sim.detector), seeded by `seed`
    # each vehicle's MAVLink link through a LossyRelay with these faults each way (None: direct); the
    # relays' seeds follow the mocks'
    link_faults: LinkFaults | None = None
    mocks: list[MockAutopilot] = field(default_factory=list)
    relays: list[LossyRelay] = field(default_factory=list)
    detectors: list[SimDetector] = field(default_factory=list)
    specs: list[VehicleSpec] = field(default_factory=list)
    radio: Radio | None = None
    runner: MockRunner | None = None  # the one thread the UDP mocks run in
    _fence: list[tuple[float, float]] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.starts = start_cells(self.grid, self.uavs)
        if self.targets is None:
            self.targets = hide_targets(self.grid, self.uavs, self.seed, self.starts)
        self.targets = np.asarray(self.targets, dtype=np.int64).reshape(-1, 2)
        self.autopilots = list(self.autopilots or ["ardupilot"] * self.uavs)

    def start(self) -> SimSwarm:
        assert self.autopilots is not None and self.targets is not None  # set by __post_init__
        self.runner = MockRunner()
        try:
            for i, cell in enumerate(self.starts):
                lat, lon = self.grid.cell_to_latlon(*cell)
                autopilot = self.autopilots[i]
                sysid = i + 1
                detector = None  # a PX4's detector socket (an ArduPilot's reports come on its link)
                if autopilot_named(autopilot).own_connection:  # a PX4: MAVSDK on a UDP port of its own
                    port = free_udp_port()
                    connect, connection = f"udpout:127.0.0.1:{port}", f"udpin:127.0.0.1:{port}"
                    if self.link_faults is not None:  # the mock sends to the relay, the relay to MAVSDK
                        connect = f"udpout:127.0.0.1:{self._relay(('127.0.0.1', port), i).port}"
                    if self.carry_detectors:
                        detector = ("127.0.0.1", free_udp_port())
                else:
                    connect, connection = "udpin:127.0.0.1:0", None
                mock = MockAutopilot(
                    sysid=sysid,
                    connect=connect,
                    home=(lat, lon, HOME_AMSL),
                    autopilot=autopilot,
                    speedup=self.speedup,
                    ready_after=2.0,
                    gcs_failsafe_timeout=self.gcs_failsafe,
                    speed=self.speed,
                    seed=self._mock_seed(i),
                    params=self.params,
                )
                if "FENCE_RADIUS" in mock.params:  # ArduPilot's circle fence round home
                    mock.params["FENCE_RADIUS"] = self._fence_radius(lat, lon)
                if self.carry_detectors:
                    det = SimDetector(
                        self.grid,
                        self.targets,
                        i,
                        self.mission_id,
                        self.grid.altitude if self.altitude is None else self.altitude,
                        fov=FOV_CELLS if self.fov is None else self.fov,
                        udp=detector,
                        pod=self.pod,
                        seed=self.seed,
                    )
                    det.attach(mock)
                    self.detectors.append(det)
                mock.start(self.runner)
                self.mocks.append(mock)
                if connection is None:
                    mock_port = mock.local_port
                    assert mock_port is not None  # a started UDP mock
                    if self.link_faults is not None:  # the controller sends to the relay, the relay to the mock
                        mock_port = self._relay(("127.0.0.1", mock_port), i).port
                    connection = f"udpout:127.0.0.1:{mock_port}"
                if not self.carry_detectors:
                    sensor = None
                else:
                    sensor = ON_LINK if detector is None else f"udp:{detector[0]}:{detector[1]}"
                fields = dict(
                    name=f"uav{sysid}", connection=connection, sysid=sysid, autopilot=autopilot, detector=sensor
                )
                self.specs.append(VehicleSpec.model_validate(fields))  # the strings parsed as from a mission file
        except BaseException:
            self.stop()
            raise
        return self

    def _mock_seed(self, i: int) -> int:
        return self.seed * 1000 + i

    def _relay(self, target: tuple[str, int], i: int) -> LossyRelay:
        relay = LossyRelay(target, self.link_faults, seed=self._mock_seed(i))
        self.relays.append(relay)  # before it starts: stop() closes it whatever happens
        return relay.start()

    def _fence_radius(self, lat: float, lon: float) -> float:
        if self.fence_radius is not None:
            return float(self.fence_radius)
        if self._fence is None:
            self._fence = fence_polygon(self.grid)
        reach = farthest_metres(self._fence, lat, lon)
        return float(max(300, math.ceil(reach / 50.0) * 50))

    def plan(
        self, policy: FieldPolicy | str, base: MissionSpec | None = None, radio: bool = False, **settings: Any
    ) -> MissionPlan:
        """The plan that flies this swarm (see `sim_plan`): ground mode, knowledge on the in-process bus
        with the swarm's channel model; with `radio`, the loopback radio (started here, with that
        model) is the plan's knowledge channel, for controllers in separate processes (give each its
        `only`). The detectors then sense at the plan's altitude and fov."""
        assert self.mocks, "start() the swarm first"
        if self.altitude is not None:
            settings.setdefault("altitude", self.altitude)
        if self.fov is not None:
            settings.setdefault("footprint_m", self.fov * self.grid.cell)
        if self.pod != 1.0:  # the mission scores its search with the detectors' pod ([sensing] pod)
            settings.setdefault("pod", self.pod)
        if radio and self.radio is None:
            self.radio = Radio(self.channel or Channel("ideal"), seed=self.seed)
        plan = sim_plan(
            self.grid,
            self.specs,
            policy,
            channel=self.radio.address if radio and self.radio is not None else None,  # (started above)
            bus_channel=self.channel,
            base=base,
            seed=self.seed,
            mission_id=self.mission_id,
            **settings,
        )
        self.fov = plan.fov
        for d in self.detectors:
            d.altitude, d.fov = plan.altitude, plan.fov
        return plan

    def stop(self) -> None:
        for m in self.mocks:
            m.stop()
        if self.runner is not None:
            self.runner.stop()
        for d in self.detectors:
            d.close()
        for r in self.relays:
            r.stop()
        if self.radio is not None:
            self.radio.close()

    def __enter__(self) -> SimSwarm:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def sim_plan(
    grid: GeoGrid,
    vehicles: list[VehicleSpec],
    policy: FieldPolicy | str,
    /,
    *,
    channel: tuple[str, int] | None = None,
    bus_channel: Channel | None = None,
    base: MissionSpec | None = None,
    seed: int = 0,
    mission_id: int = 7,
    mission_file: Path | None = None,
    **settings: Any,
) -> MissionPlan:
    """The plan for simulated vehicles on `grid`: `base`'s settings (a mission file's; else the
    defaults) under DEMO_SETTINGS under `settings` (flat spec keys: time_limit, end_action, altitude,
    fence, grid: the grid's file, for the recording). Knowledge: on the in-process bus with
    `bus_channel` (None: ideal), and, with `channel` (the loopback radio's address), that address as
    the [knowledge] channel (the base's channel is not used: it is no address of this swarm). `policy`
    is a FieldPolicy or its spec string (built here, once)."""
    if isinstance(policy, str):
        from swarmctl.mission.decide import FieldPolicy

        policy = FieldPolicy(policy, seed=seed)
    own = dict(
        name=base.mission.name if base else "demo",
        id=mission_id,
        policy=policy.spec,
        channel=Endpoint("udpout", channel[0], int(channel[1])) if channel is not None else None,
        signing_key=None,  # the mock vehicles do not sign
    )
    if not policy.follows_routes:  # a base's pattern keys go with its pattern policy only
        own.update(lkp=None, spacing_m=None)
    where = str(mission_file) if mission_file is not None else "demo"
    spec = MissionSpec.build(vehicles, base, where, **{**DEMO_SETTINGS, **own, **settings})
    plan = make_plan(spec, grid=grid, policy=policy, seed=seed, mission_file=mission_file)
    plan.bus_channel = bus_channel
    return plan
