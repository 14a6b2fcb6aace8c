"""Sensing in the field: what a vehicle covers from the cell it reached, and what a detector adds.

Every step, on arrival, the agent explores its footprint: the disc of radius fov cells round the cell
the vehicle reached (cell centres, exactly the simulator's disc, swarmctl.world.scenario.fov_offsets;
fov is the plan's, `MissionPlan.fov`), whether or not a detector is attached. The obstacles there are
the grid's blocked cells (the controller knows the map) and the phi reported is 0: the value of
explored cells comes from the targets known (swarmctl.knowledge.model.beliefs_from_knowledge). Without
a detector the mission is a coverage search.

A detector only adds what it saw in a footprint: targets, and optionally phi and obstacles
(swarmctl.mission.detector: SensorReport). Reports are matched to where the vehicle has been, not taken
on trust:
- a report counts for the cell it names only if the vehicle reached that cell, and only within the
  footprint round it; the rest (a cell never reached, cells and targets outside the footprint) is
  dropped and counted (`Sensed.dropped`);
- a late report (after `[timing] sense_timeout`, or from a vehicle the mission gives no detector)
  counts when it arrives: its targets become known, and are shared, at the next round; its cells are
  explored already, and its phi and obstacles are merged into the agent's knowledge (not re-sent in
  deltas: the others compute the value near a target from the target itself).
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from swarmctl.knowledge.model import disc_cells
from swarmctl.world.scenario import fov_offsets

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.geo.grid import GeoGrid


def _none() -> np.ndarray:
    return np.zeros((0, 2), dtype=np.int64)


@dataclass
class Sensed:
    """What one agent senses in one round: cells with their phi and obstacle flag, target cells (each
    with the reached cell whose footprint it was reported in, `seen_from`), and how many report
    entries (cells and targets) were dropped."""

    cells: np.ndarray = field(default_factory=_none)  # (N, 2), may repeat a cell (merges take max / or)
    phi: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.float32))
    obstacle: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    targets: np.ndarray = field(default_factory=_none)  # (K, 2) distinct
    dropped: int = 0
    seen_from: np.ndarray = field(default_factory=_none)  # (K, 2): the cell each target was seen from


def footprint(cell: tuple[int, int], grid: GeoGrid, fov: float) -> np.ndarray:
    """(N, 2) cells of the footprint round `cell` that lie on the grid."""
    return disc_cells(cell, grid.width, grid.height, fov)


def footprints(grid: GeoGrid, fov: float, cells: list[tuple[int, int]]) -> list[Sensed]:
    """What `sense(grid, fov, cell, [], visited)` gives for each of `cells` (the footprint alone, with
    the grid's obstacles and phi 0), the footprints of all of them computed in one array operation."""
    if not cells:
        return []
    offsets = fov_offsets(float(fov))
    c = np.asarray(cells, dtype=np.int64).reshape(-1, 1, 2) + offsets  # (A, D, 2)
    x, y = c[..., 0], c[..., 1]
    inside = (x >= 0) & (x < grid.width) & (y >= 0) & (y < grid.height)
    blocked = np.asarray(grid.blocked, dtype=bool)[np.where(inside, x, 0), np.where(inside, y, 0)]
    zeros = np.zeros(offsets.shape[0], dtype=np.float32)
    out = []
    for i, keep in enumerate(inside):
        if keep.all():
            out.append(Sensed(c[i], zeros, blocked[i]))
        else:
            out.append(Sensed(c[i][keep], zeros[: int(keep.sum())], blocked[i][keep]))
    return out


def in_footprint(cells: np.ndarray, cell: tuple[int, int], grid: GeoGrid, fov: float) -> np.ndarray:
    """(N,) bool: which of `cells` (N, 2) lie in the footprint round `cell` (the grid's cells whose
    offset from `cell` is in the sensing disc, swarmctl.world.scenario.fov_offsets)."""
    d = cells - np.asarray(cell, dtype=np.int64)
    on_grid = (cells[:, 0] >= 0) & (cells[:, 0] < grid.width) & (cells[:, 1] >= 0) & (cells[:, 1] < grid.height)
    return on_grid & ((d * d).sum(axis=1) <= fov**2 + 1e-9)


def sense(
    grid: GeoGrid,
    fov: float,
    reached: tuple[int, int] | None,
    reports: Iterable[Any],
    visited: Collection[tuple[int, int]],
) -> Sensed:
    """The footprint round `reached` (None: the vehicle did not arrive anywhere new this round) with the
    grid's obstacles and phi 0, plus what `reports` (SensorReports) say within the footprints of cells
    in `visited` (the cells the vehicle reached, `reached` included)."""
    cells, phi, obstacle, targets, origins = [], [], [], [], []
    dropped = 0
    if reached is not None:
        c = footprint(reached, grid, fov)
        cells.append(c)
        phi.append(np.zeros(len(c), dtype=np.float32))
        obstacle.append(np.asarray(grid.blocked, dtype=bool)[c[:, 0], c[:, 1]])
    for r in reports:
        rc = np.asarray(r.cells, dtype=np.int64).reshape(-1, 2)
        rt = np.asarray(r.targets, dtype=np.int64).reshape(-1, 2)
        if tuple(r.cell) not in visited:
            dropped += len(rc) + len(rt)
            continue
        keep = in_footprint(rc, tuple(r.cell), grid, fov)
        dropped += int(len(keep) - np.count_nonzero(keep))
        rc = rc[keep]
        cells.append(rc)
        phi.append(np.asarray(r.phi, dtype=np.float32).reshape(-1)[keep])
        blocked = np.asarray(grid.blocked, dtype=bool)[rc[:, 0], rc[:, 1]]
        obstacle.append(np.asarray(r.obstacle, dtype=bool).reshape(-1)[keep] | blocked)
        if len(rt):
            keep_t = in_footprint(rt, tuple(r.cell), grid, fov)
            dropped += int(len(keep_t) - np.count_nonzero(keep_t))
            targets.append(rt[keep_t])
            origins.append(np.tile(np.asarray(r.cell, dtype=np.int64), (int(keep_t.sum()), 1)))
    if not cells:
        return Sensed(dropped=dropped)
    found, seen_from = _none(), _none()
    if any(len(t) for t in targets):  # np.unique(axis=0) is slow, even on nothing
        every, where = np.concatenate(targets).reshape(-1, 2), np.concatenate(origins).reshape(-1, 2)
        found, first = np.unique(every, axis=0, return_index=True)
        seen_from = where[first]
    return Sensed(
        np.concatenate(cells), np.concatenate(phi), np.concatenate(obstacle), found.reshape(-1, 2), dropped, seen_from
    )
