"""A grid for a log that came without one.

- Around the tracks (a foreign .tlog): the bounding box of every position, one cell of margin, gridded
  by swarmctl.geo.grid.make_grid with a round cell size that keeps the longer side near `cells` cells
  (at least 5 m). No cell is blocked: the log says nothing about obstacles.
- From swarmctl's TUNNEL frames (a swarmctl .tlog without its grid.npz): every knowledge payload says
  which cell its sender was in, and the vehicle's telemetry says where it was at that moment, so the
  grid's origin, cell size and rotation follow from a least-squares similarity fit of cell centres to
  positions (vehicles send from the centre of the cell they reached). Cells the payloads flag as
  obstacles are blocked.
"""

from __future__ import annotations

import math

import numpy as np
import shapely

from swarmctl.geo.areas import Area
from swarmctl.geo.grid import GeoGrid, make_grid
from swarmctl.geo.projection import LocalProjection

NICE_CELLS = (5, 10, 20, 25, 50, 100, 200, 250, 500, 1000, 2000, 5000)


def grid_around(lat: np.ndarray, lon: np.ndarray, cells: int = 60) -> GeoGrid:
    """A north-up grid over the positions' bounding box (see the module docstring)."""
    lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
    proj = LocalProjection.centred_on((lon.min(), lat.min(), lon.max(), lat.max()))
    e, n = proj.to_metres(lon, lat)
    side = max(float(np.ptp(e)), float(np.ptp(n)), 1.0)
    cell = next((c for c in NICE_CELLS if side / c <= cells), NICE_CELLS[-1])
    box = shapely.box(e.min() - cell, n.min() - cell, e.max() + cell, n.max() + cell)
    area = Area(proj.geometry_to_lonlat(box), name="the tracks' bounding box")
    grid, _ = make_grid(area, cell=float(cell), altitude=1.0)
    return grid


def grid_from_cells(
    lat: np.ndarray, lon: np.ndarray, x: np.ndarray, y: np.ndarray, width: int, height: int
) -> tuple[GeoGrid, float]:
    """The width x height grid whose cell centres best match the (x, y) cells reported at (lat, lon);
    returns it with the RMS residual in metres."""
    lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
    proj = LocalProjection.centred_on((lon.min(), lat.min(), lon.max(), lat.max()))
    e, n = proj.to_metres(lon, lat)
    u, v = np.asarray(x, dtype=float) + 0.5, np.asarray(y, dtype=float) + 0.5
    # e = oe + a u - b v ; n = on + b u + a v   (a = cell cos r, b = cell sin r)
    one, zero = np.ones_like(u), np.zeros_like(u)
    rows = np.vstack([np.column_stack([one, zero, u, -v]), np.column_stack([zero, one, v, u])])
    sol, *_ = np.linalg.lstsq(rows, np.concatenate([e, n]), rcond=None)
    oe, on, a, b = (float(s) for s in sol)
    cell = math.hypot(a, b)
    rotation = math.degrees(math.atan2(b, a))
    grid = GeoGrid(proj.proj, (oe, on), rotation, cell, np.zeros((width, height), dtype=bool), altitude=1.0)
    residual = rows @ sol - np.concatenate([e, n])
    return grid, float(np.sqrt(np.mean(residual[: u.size] ** 2 + residual[u.size :] ** 2)))
