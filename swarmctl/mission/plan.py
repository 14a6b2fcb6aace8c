"""The mission plan: a spec made concrete for one process, checked against its grid and its policy.

`make_plan` is the one step from a MissionSpec to what the controller flies. It

- loads the grid (the spec's grid file, or plans one from its area at the spec's altitude and cell
  size) and fills in what the spec left out: altitude and cell size from the grid, the sensor
  footprint from the policy's fov, knowledge push from the swarm's size;
- refuses a mission flying below the grid's planning altitude (the grid blocks only the buildings at
  least that tall) or with a cell size other than the grid's, and a footprint more than 0.25 cell
  from the fov the policy was trained with, and more expected targets than the grid has free cells;
- builds the policy once (loading its checkpoint): the plan keeps the object, the controller uses it;
  a search pattern (`pattern:NAME` with `lkp`) is planned here on the grid (swarmctl.geo.patterns) and
  its routes turned into routes of cells, the i-th vehicle of the file taking route i
  (`pattern_routes`);
- reads the `[mission] prior` file onto the grid (swarmctl.geo.prior), once;
- refuses an onboard plan (some vehicles only: `swarmctl agent`) without a `[knowledge] channel`: its
  agents share knowledge with the other processes' agents only through it.

The plan's spec is the resolved one: every value the controller reads is in it, once.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from swarmctl.errors import InputError
from swarmctl.geo.defaults import DEFAULT_ALTITUDE, DEFAULT_CELL
from swarmctl.knowledge.codec import MAX_CELLS, MAX_SIDE
from swarmctl.mavlink.codec import Endpoint
from swarmctl.mission.spec import PUSH_UP_TO, MissionSpec, MissionTable, parse_detector
from swarmctl.world.scenario import fov_offsets

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

    from swarmctl.geo.grid import GeoGrid
    from swarmctl.mission.decide import FieldPolicy
    from swarmctl.world.channel import Channel

FOOTPRINT_TOLERANCE = 0.25  # cells: how far the footprint may be from the policy's fov


@dataclass
class MissionPlan:
    """Everything the controller needs to fly: the resolved spec, the grid, the policy (built once) and
    what this process adds: the vehicles it flies (`only`, mission indices; None: all, the ground mode),
    their detectors, the seed of the policy's draws, the mission file (copied into the recording) and,
    for simulated swarms, the channel model of the in-process knowledge bus (None: ideal)."""

    spec: MissionSpec
    grid: GeoGrid
    policy: FieldPolicy
    signing_key: bytes | None = None
    # vehicle index -> its detector: ON_LINK (reports on its MAVLink link) or a local UDP socket
    detectors: dict[int, Endpoint | str] = field(default_factory=dict)
    only: list[int] | None = None
    seed: int = 0
    mission_file: Path | None = None
    bus_channel: Channel | None = None  # the channel model of the ground mode's bus; None: ideal
    prior: np.ndarray | None = None  # (W, H) the [mission] prior on the grid, summing to 1; None: uniform

    @property
    def onboard(self) -> bool:
        """This process flies some of the vehicles only (`swarmctl agent`): knowledge goes over the
        [knowledge] channel. Otherwise (ground mode) it flies every vehicle and shares in memory."""
        return self.only is not None

    @property
    def fov(self) -> float:
        """The sensing radius in cells: the footprint at the mission's cell size."""
        m = self.spec.mission
        assert m.footprint_m is not None and m.cell_size is not None, "make_plan resolves them"
        return float(m.footprint_m) / float(m.cell_size)

    @property
    def altitude(self) -> float:
        """The mission altitude in metres above home (the spec's, resolved by make_plan: a mission file
        may leave it out)."""
        altitude = self.spec.mission.altitude
        assert altitude is not None, "make_plan resolves the altitude"
        return altitude


def make_plan(
    spec: MissionSpec,
    *,
    grid: GeoGrid | None = None,
    policy: FieldPolicy | None = None,
    only: list[str] | None = None,
    detector: str | None = None,
    seed: int = 0,
    mission_file: Path | None = None,
) -> MissionPlan:
    """The plan for `spec`: `grid` and `policy` when the caller has them already (the demo), else
    loaded here; `only` keeps some vehicles by name (onboard mode: the mission must have a [knowledge]
    channel); `detector` ("mavlink" or udp:HOST:PORT) is the detector of every vehicle kept. Every
    refusal is an InputError naming the mission file."""
    where = str(mission_file) if mission_file is not None else "mission"
    socket = parse_detector(detector) if detector else None  # the command line before the file
    m = spec.mission
    grid = grid if grid is not None else load_grid(spec)
    altitude, cell = _check_grid(m, grid, where)
    if policy is None:
        policy = make_policy(m.policy, seed, where)
    footprint = _check_footprint(m.footprint_m, cell, policy, where)
    if m.lkp is not None:  # a search pattern's (the spec takes lkp with a pattern:NAME policy only)
        policy.set_routes(pattern_routes(m, grid, len(spec.vehicles), footprint / cell, where))
    _check_expected(m, grid, where)
    push = spec.knowledge.push if spec.knowledge.push is not None else len(spec.vehicles) <= PUSH_UP_TO
    resolved = spec.model_copy(
        update=dict(
            mission=m.model_copy(update=dict(altitude=altitude, cell_size=cell, footprint_m=footprint)),
            knowledge=spec.knowledge.model_copy(update=dict(push=push)),
        )
    )
    names = [v.name for v in spec.vehicles]
    for name in only or []:
        if name not in names:
            raise InputError(f"--vehicle {name!r} is not in {where}; use one of {', '.join(names)}")
    keep = [names.index(n) for n in only] if only else list(range(len(names)))
    if only and spec.knowledge.channel is None:
        raise InputError(
            f"{where}: [knowledge] channel is missing, and agents in separate processes (swarmctl agent) share "
            'knowledge only through it; add [knowledge] channel = "udpout:HOST:PORT" (a MAVLink router or '
            "telemetry mesh that forwards TUNNEL messages to every vehicle's agent), or fly every vehicle "
            "from one computer with swarmctl fly"
        )
    detectors = {i: d for i in keep if (d := spec.vehicles[i].detector) is not None}
    if socket is not None:
        detectors.update({i: socket for i in keep})
    key = None
    if m.signing_key is not None:
        from swarmctl.bounds import KEY_MAX_BYTES, read_limited
        from swarmctl.mavlink.codec import load_signing_key

        key_field = f"{where}: mission.signing_key"
        read_limited(m.signing_key, "signing key file", KEY_MAX_BYTES, key_field)  # before it is read whole
        key = load_signing_key(m.signing_key, field=key_field)
    prior = None
    if m.prior is not None:
        from swarmctl.geo.prior import load_prior

        prior = load_prior(m.prior, grid)
    return MissionPlan(
        resolved,
        grid,
        policy,
        key,
        detectors,
        keep if only else None,
        seed=seed,
        mission_file=mission_file,
        prior=prior,
    )


def _check_expected(m: MissionTable, grid: GeoGrid, where: str) -> None:
    """expected_targets no more than the grid's free cells (a target a cell): else the finish line is
    never met."""
    free = int((~grid.blocked).sum())
    if m.expected_targets is not None and m.expected_targets > free:
        raise InputError(
            f"{where}: mission.expected_targets = {m.expected_targets}: the grid has {free} free cells, at most one "
            f"target each; write expected_targets = {free} at most, or leave it out (unknown)"
        )


def load_grid(spec: MissionSpec) -> GeoGrid:
    """The spec's grid file, or a grid planned from its area at its altitude and cell size."""
    from swarmctl.geo.grid import GeoGrid, make_grid

    m = spec.mission
    if m.grid is not None:
        return GeoGrid.load(m.grid)
    if m.area is None:
        raise ValueError("the spec names neither grid nor area: give make_plan the grid")
    from swarmctl.geo.buildings import load_buildings
    from swarmctl.geo.load import load_area

    buildings = load_buildings(m.buildings) if m.buildings is not None else None
    grid, _report = make_grid(
        load_area(m.area),
        cell=m.cell_size if m.cell_size is not None else DEFAULT_CELL,
        altitude=m.altitude if m.altitude is not None else DEFAULT_ALTITUDE,
        buildings=buildings,
    )
    return grid


def make_policy(text: str, seed: int, where: str) -> FieldPolicy:
    """The FieldPolicy for `text` (a checkpoint is loaded here); its InputError names the mission key."""
    from swarmctl.mission.decide import FieldPolicy

    try:
        return FieldPolicy(text, seed=seed)
    except InputError as exc:
        raise InputError(f"{where}: mission.policy: {exc}") from None


def check_grid_size(grid: GeoGrid, where: str) -> None:
    """A grid a mission can fly: no larger than the knowledge messages carry (swarmctl.knowledge.codec)."""
    if not (grid.width <= MAX_SIDE and grid.height <= MAX_SIDE and grid.width * grid.height <= MAX_CELLS):
        raise InputError(
            f"{where} is {grid.width} x {grid.height} cells, more than knowledge sharing carries "
            f"(at most {MAX_SIDE} a side and {MAX_CELLS:,} in all); re-plan it with a larger `swarmctl plan --cell`"
        )


def _check_grid(m: MissionTable, grid: GeoGrid, where: str) -> tuple[float, float]:
    """The altitude and cell size to fly: the mission's, checked against the grid's, or the grid's."""
    name = f"the grid {m.grid.name}" if m.grid is not None else "the grid"
    for key, what, value, option in (
        ("altitude", "an altitude", grid.altitude, "--altitude"),
        ("cell_size", "a cell size", grid.cell, "--cell"),
    ):
        lo, hi = MissionTable.bounds(key)
        if getattr(m, key) is None and not lo <= value <= hi:
            raise InputError(
                f"{where}: {name} has {what} of {value:g} m, outside the {lo:g} to {hi:g} m a mission takes; "
                f"re-plan it with `swarmctl plan ... {option} N` within that range"
            )
    check_grid_size(grid, f"{where}: {name}")
    altitude = float(grid.altitude) if m.altitude is None else m.altitude
    if altitude < grid.altitude:
        raise InputError(
            f"{where}: mission.altitude = {altitude:g} is below the {grid.altitude:g} m {name} was planned for "
            f"(buildings from {altitude:g} m to {grid.altitude:g} m tall are not blocked in it); re-plan with "
            f"`swarmctl plan ... --altitude {altitude:g}`, or fly at the grid's altitude (leave altitude out)"
        )
    if m.cell_size is not None and not math.isclose(m.cell_size, grid.cell, rel_tol=1e-9):
        raise InputError(
            f"{where}: mission.cell_size = {m.cell_size:g} differs from the {grid.cell:g} m cells of {name}; "
            f"leave cell_size out (it comes from the grid), or re-plan with `swarmctl plan ... --cell {m.cell_size:g}`"
        )
    return altitude, float(grid.cell)


def _check_footprint(footprint: float | None, cell: float, policy: FieldPolicy, where: str) -> float:
    """The footprint radius in metres: the policy's fov at this cell size, or the mission's when it
    is within FOOTPRINT_TOLERANCE cell of it."""
    fov = float(policy.fov)
    if footprint is None:
        return fov * cell
    if abs(footprint / cell - fov) > FOOTPRINT_TOLERANCE:
        raise InputError(
            f"{where}: mission.footprint_m = {footprint:g} is {footprint / cell:.2f} cells of {cell:g} m, but the "
            f"policy {policy.spec} was trained to sense {fov:g} cells; write footprint_m = {fov * cell:g} "
            f"(or leave it out), or fly a policy trained with a fov of {footprint / cell:.2f} cells"
        )
    return footprint


def pattern_routes(m: MissionTable, grid: GeoGrid, vehicles: int, fov: float, where: str) -> list[np.ndarray]:
    """The routes of cells of the mission's search pattern (policy pattern:NAME from lkp), one per vehicle
    in the file's order: the pattern's routes (swarmctl.geo.patterns.plan_pattern, track spacing
    spacing_m or the footprint's diameter) as the free cells their legs cross, then every free cell of
    the pattern's region that no route cell's footprint (radius `fov` cells) covers added to the route
    passing nearest it."""
    from swarmctl.geo.patterns import plan_pattern

    assert m.lkp is not None, "the spec refuses a pattern without lkp"
    lat, lon = m.lkp
    x, y = grid.latlon_to_cell(lat, lon)
    if not grid.in_grid(x, y):
        raise InputError(
            f"{where}: mission.lkp = [{lat:g}, {lon:g}] lies outside the grid; give LAT, LON of a point in the "
            "searched area"
        )
    pattern = m.policy.partition(":")[2].split(":")[0]
    spacing = m.spacing_m if m.spacing_m is not None else 2.0 * fov * grid.cell
    try:
        planned = plan_pattern(grid, pattern, (lat, lon), vehicles, spacing)
    except InputError as exc:  # its words are the command line's: say them in the mission file's
        why = re.sub(r"--uavs (\d+)", r"the \1 vehicle(s) listed", str(exc))
        why = why.replace("--lkp", "lkp").replace("a larger --spacing", "a larger spacing_m")
        raise InputError(f"{where}: mission.policy = {m.policy!r}: {why}") from None
    routes = [route_cells(grid, r.local) for r in planned.routes]
    cover(routes, planned.cells, grid.blocked, fov)
    return routes


def route_cells(grid: GeoGrid, local: list[tuple[float, float]]) -> np.ndarray:
    """(L, 2): the free cells a route crosses, in order (points along each leg every quarter cell, in the
    grid's frame in metres); blocked cells and cells off the grid are left out (a way round them is the
    policy's to find)."""
    xy = np.asarray(local, dtype=float).reshape(-1, 2)
    points = [xy[:1]]
    for a, b in zip(xy[:-1], xy[1:]):
        n = max(2, int(math.ceil(4.0 * float(np.hypot(*(b - a))) / grid.cell)) + 1)
        points.append(a + np.linspace(0.0, 1.0, n)[1:, None] * (b - a))
    cells = np.floor(np.concatenate(points) / grid.cell).astype(np.int64)
    keep = grid.in_grid(cells[:, 0], cells[:, 1])
    cells = cells[keep]
    cells = cells[~grid.blocked[cells[:, 0], cells[:, 1]]]
    if len(cells) == 0:
        return cells.reshape(0, 2)
    new = np.ones(len(cells), dtype=bool)
    new[1:] = (cells[1:] != cells[:-1]).any(1)
    result: np.ndarray = cells[new]
    return result


def cover(routes: list[np.ndarray], cells: np.ndarray, blocked: np.ndarray, fov: float) -> None:
    """Add to `routes` (in place) each of `cells` that no route cell's footprint covers: after the
    nearest cell of the nearest route, until every one is covered."""
    offsets = fov_offsets(fov)
    w, h = blocked.shape
    seen = np.zeros((w, h), dtype=bool)

    def sense(at: np.ndarray) -> None:
        around = (at[:, None, :] + offsets[None]).reshape(-1, 2)
        inside = (around[:, 0] >= 0) & (around[:, 0] < w) & (around[:, 1] >= 0) & (around[:, 1] < h)
        seen[around[inside, 0], around[inside, 1]] = True

    for r in routes:
        sense(r)
    for cx, cy in np.asarray(cells, dtype=np.int64).reshape(-1, 2).tolist():
        if seen[cx, cy] or blocked[cx, cy]:
            continue
        best = None
        for k, r in enumerate(routes):
            if len(r):
                d = np.hypot(r[:, 0] - cx, r[:, 1] - cy)
                i = int(np.argmin(d))
                if best is None or d[i] < best[0]:
                    best = (float(d[i]), k, i + 1)
        k, i = (best[1], best[2]) if best is not None else (0, 0)
        routes[k] = np.insert(routes[k], i, [cx, cy], axis=0)
        sense(np.array([[cx, cy]]))
