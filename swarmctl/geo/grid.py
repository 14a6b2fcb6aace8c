"""The cell grid of a real area, and cell <-> latitude/longitude.

Frame: the area's local transverse Mercator projection (`swarmctl.geo.projection`), in metres.
The grid is a W x H block of square cells of side `cell` metres. Its x axis points east and y north
(arrays are indexed [x, y], (0, 0) is the south-west cell), unless the grid is rotated to
the area's main axis, in which case x points `rotation` degrees counter-clockwise from east. The
rotation is taken from the sides of the area's minimum rotated rectangle and folded into
(-45, 45] degrees, so x stays the axis closest to east and y the one closest to north.

The grid covers the (rotated) bounding box of the area and is centred on it. A cell is blocked when
its centre is outside the area, its centre is in (or on the edge of) a no-fly zone or a hole, or a
blocking building's footprint overlaps the cell square by a positive area (touching an edge does
not count); see `swarmctl.geo.buildings` for which buildings block.
"""

from __future__ import annotations

import json
import math
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely
from scipy import ndimage
from shapely import affinity

from swarmctl.errors import InputError
from swarmctl.geo.areas import Area
from swarmctl.geo.buildings import BuildingRule, BuildingSet
from swarmctl.geo.defaults import (
    CIRCLE_SEGMENTS,
    DEFAULT_ALTITUDE,
    DEFAULT_CELL,
    DEFAULT_MAX_CELLS,
    GRID_MAX_BYTES,
    MAX_ALTITUDE_M,
    MAX_CELL_M,
    MAX_GRID_CELLS,
    MAX_GRID_SIDE,
    METRES_PER_LEVEL,
    MIN_ALTITUDE_M,
    MIN_CELL_M,
)
from swarmctl.geo.projection import LocalProjection
from swarmctl.world.paths import largest_free_region

GRID_FORMAT = "swarmctl-grid"
GRID_VERSION = 1
EXTENT_TOLERANCE = 1e-3  # cells: a bounding box this much over a whole number of cells is not widened
OVERLAP_EPS = 1e-6  # cell areas: a building overlapping a cell by less only touches it


@dataclass
class GeoGrid:
    """A grid of square cells over a real area.

    `origin` is the south-west corner of cell (0, 0) in the projection's metres, `rotation` the
    angle of the x axis counter-clockwise from east in degrees, `blocked` a (width, height) bool
    array indexed [x, y]. `altitude` is the flight altitude in metres relative to home.
    `area_wkt` and `nofly_wkt` keep the area and its no-fly zones (lon/lat WKT) for geofencing.
    """

    proj: str
    origin: tuple[float, float]
    rotation: float
    cell: float
    blocked: np.ndarray
    altitude: float = DEFAULT_ALTITUDE
    area_name: str = ""
    buildings_name: str = ""
    area_wkt: str = ""
    nofly_wkt: str = ""
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.blocked = np.asarray(self.blocked, dtype=bool)
        self.projection = LocalProjection(self.proj)
        a = math.radians(self.rotation)
        self._cos, self._sin = math.cos(a), math.sin(a)

    @property
    def width(self) -> int:
        """Number of cells along x."""
        return int(self.blocked.shape[0])

    @property
    def height(self) -> int:
        """Number of cells along y."""
        return int(self.blocked.shape[1])

    @property
    def blocked_fraction(self) -> float:
        """Fraction of cells that are blocked."""
        return float(self.blocked.mean())

    # --- grid <-> local metres -------------------------------------------------------------
    def grid_to_metres(self, gx, gy):
        """Grid coordinates in cell units (cell (x, y) spans [x, x+1] x [y, y+1]) -> metres."""
        u = np.asarray(gx, dtype=float) * self.cell
        v = np.asarray(gy, dtype=float) * self.cell
        return (self.origin[0] + self._cos * u - self._sin * v, self.origin[1] + self._sin * u + self._cos * v)

    def metres_to_grid(self, e, n):
        """Metres in the projection -> grid coordinates in cell units (floats)."""
        de = np.asarray(e, dtype=float) - self.origin[0]
        dn = np.asarray(n, dtype=float) - self.origin[1]
        return ((self._cos * de + self._sin * dn) / self.cell, (-self._sin * de + self._cos * dn) / self.cell)

    def geometry_to_grid(self, geom_metres):
        """A shapely geometry in projection metres -> the same in grid cell units."""
        return shapely.transform(geom_metres, lambda xy: np.column_stack(self.metres_to_grid(xy[:, 0], xy[:, 1])))

    # --- cells <-> lat/lon -----------------------------------------------------------------
    def cells_to_latlon(self, x, y):
        """Vectorised: integer cell indices -> (lat, lon) arrays of the cell centres (degrees)."""
        e, n = self.grid_to_metres(np.asarray(x) + 0.5, np.asarray(y) + 0.5)
        lon, lat = self.projection.to_lonlat(e, n)
        return lat, lon

    def latlon_to_cells(self, lat, lon):
        """Vectorised: (lat, lon) in degrees -> (x, y) int arrays of the containing cells.

        Points outside the grid give indices outside [0, width) x [0, height): check with `in_grid`.
        """
        gx, gy = self.metres_to_grid(*self.projection.to_metres(lon, lat))
        return np.floor(gx).astype(np.int64), np.floor(gy).astype(np.int64)

    def cell_to_latlon(self, x: int, y: int) -> tuple[float, float]:
        """(lat, lon) of the centre of cell (x, y); the vehicle flies there at `altitude`. A cell of the
        grid is looked up in `centres` (the same values, converted once); one outside it is converted."""
        if 0 <= x < self.blocked.shape[0] and 0 <= y < self.blocked.shape[1]:
            lat, lon = self.centres()
            return lat[x][y], lon[x][y]
        lat, lon = self.cells_to_latlon(x, y)
        return float(lat), float(lon)

    def centres(self) -> tuple[list[list[float]], list[list[float]]]:
        """(lat, lon) of every cell's centre, degrees, as nested lists indexed [x][y] (Python floats, so a
        look-up costs no conversion): `cells_to_latlon` of all cells at once, kept until the grid's
        placement (projection, origin, rotation, cell size, shape) changes."""
        key = (self.proj, tuple(self.origin), self.rotation, self.cell, self.blocked.shape)
        cached = self.__dict__.get("_centres")
        if cached is None or cached[0] != key:
            xs, ys = np.meshgrid(np.arange(self.width), np.arange(self.height), indexing="ij")
            lat, lon = self.cells_to_latlon(xs, ys)
            cached = self._centres = (key, (lat.tolist(), lon.tolist()))
        return cached[1]

    def latlon_to_cell(self, lat: float, lon: float) -> tuple[int, int]:
        """The cell (x, y) containing (lat, lon); may lie outside the grid (see `in_grid`)."""
        x, y = self.latlon_to_cells(lat, lon)
        return int(x), int(y)

    def in_grid(self, x, y):
        """Whether cell indices lie inside the grid (vectorised)."""
        x, y = np.asarray(x), np.asarray(y)
        return (x >= 0) & (x < self.width) & (y >= 0) & (y < self.height)

    def corner_latlon(self):
        """(lat, lon) arrays of shape (width + 1, height + 1): the cell corners."""
        gx, gy = np.meshgrid(np.arange(self.width + 1), np.arange(self.height + 1), indexing="ij")
        lon, lat = self.projection.to_lonlat(*self.grid_to_metres(gx, gy))
        return lat, lon

    # --- connectivity ----------------------------------------------------------------------
    def free_regions(self) -> tuple[np.ndarray, int]:
        """Label the free cells by 4-connected region: (labels [x, y], number of regions)."""
        labels, n = ndimage.label(~self.blocked)
        return labels, int(n)

    def largest_free_region(self) -> np.ndarray:
        """Bool mask [x, y] of the largest 4-connected region of free cells (all False if none)."""
        return largest_free_region(self.blocked)

    # --- file ------------------------------------------------------------------------------
    def meta(self) -> dict:
        """Everything but the mask, as JSON-able values."""
        return {
            "format": GRID_FORMAT,
            "version": GRID_VERSION,
            "proj": self.proj,
            "origin": [float(self.origin[0]), float(self.origin[1])],
            "rotation_deg": float(self.rotation),
            "cell_size_m": float(self.cell),
            "altitude_m": float(self.altitude),
            "altitude_reference": "relative to home",
            "width": self.width,
            "height": self.height,
            "axes": "blocked[x, y]; x along the grid's x axis (east when rotation is 0), y north; (0, 0) south-west",
            "area_name": self.area_name,
            "buildings_name": self.buildings_name,
            "area_wkt": self.area_wkt,
            "nofly_wkt": self.nofly_wkt,
            "info": self.info,
        }

    def save(self, path: str | Path) -> Path:
        """Write the grid as a compressed .npz: `blocked` (bool [x, y]) and `meta` (a JSON string)."""
        path = Path(path)
        with path.open("wb") as fh:
            np.savez_compressed(fh, blocked=self.blocked, meta=np.array(json.dumps(self.meta())))
        return path

    @classmethod
    def load(cls, path: str | Path) -> GeoGrid:
        """Read a grid written by `save`, checking every field; a bad file raises InputError."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: grid file not found; create it with `swarmctl plan AREA --out DIR`")
        fix = "write it again with `swarmctl plan`"
        if path.stat().st_size > GRID_MAX_BYTES:
            raise InputError(f"{path}: over {GRID_MAX_BYTES // 2**20} MiB, too large for a grid file; {fix}")
        try:
            _check_members(path, fix)
            with np.load(path, allow_pickle=False) as data:
                blocked = np.asarray(data["blocked"])
                meta = json.loads(str(data["meta"]))
        except (OSError, ValueError, KeyError, EOFError, RecursionError, zipfile.BadZipFile, zlib.error) as exc:
            raise InputError(f"{path}: not a swarmctl grid file ({type(exc).__name__}); {fix}") from None
        if not isinstance(meta, dict) or meta.get("format") != GRID_FORMAT:
            raise InputError(f"{path}: not a swarmctl grid file (format is not {GRID_FORMAT!r}); {fix}")
        if meta.get("version") != GRID_VERSION:
            raise InputError(f"{path}: grid file version {meta.get('version')!r} is not {GRID_VERSION}; {fix}")
        try:
            origin = tuple(float(v) for v in meta["origin"])
            numbers = [float(meta[k]) for k in ("rotation_deg", "cell_size_m", "altitude_m")] + list(origin)
            shape = (int(meta["width"]), int(meta["height"]))
            proj = str(meta["proj"])
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{path}: grid file is missing or has a bad origin, size or projection; {fix}") from None
        if len(origin) != 2 or not all(math.isfinite(v) for v in numbers):
            raise InputError(f"{path}: grid file has a non-finite origin, rotation, cell size or altitude; {fix}")
        for key, value, lo, hi in (
            ("rotation_deg", numbers[0], -180.0, 180.0),
            ("cell_size_m", numbers[1], MIN_CELL_M, MAX_CELL_M),
            ("altitude_m", numbers[2], MIN_ALTITUDE_M, MAX_ALTITUDE_M),
            ("origin", max(abs(v) for v in origin), 0.0, 1e8),
        ):
            if not lo <= value <= hi:
                raise InputError(f"{path}: grid file's {key} {value:g} is outside {lo:g}..{hi:g}; {fix}")
        if blocked.dtype != bool or blocked.shape != shape or min(shape) < 1:
            raise InputError(f"{path}: grid mask is not a {shape[0]} x {shape[1]} bool array; {fix}")
        try:
            grid = cls(
                proj,
                origin,
                numbers[0],
                numbers[1],
                blocked,
                numbers[2],
                str(meta.get("area_name", "")),
                str(meta.get("buildings_name", "")),
                str(meta.get("area_wkt", "")),
                str(meta.get("nofly_wkt", "")),
                dict(meta.get("info") or {}),
            )
        except Exception as exc:  # pyproj.exceptions.CRSError and friends
            raise InputError(f"{path}: grid file has an unusable projection ({exc}); {fix}") from None
        return grid


def _check_members(path: Path, fix: str) -> None:
    """Refuse, before decompressing anything, a grid file whose mask is not a bool array of at most
    MAX_GRID_CELLS cells (MAX_GRID_SIDE a side) or whose meta is over GRID_MAX_BYTES."""
    with zipfile.ZipFile(path) as zf:
        with zf.open("blocked.npy") as fh:
            version = np.lib.format.read_magic(fh)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, _, dtype = read(fh)
        meta = zf.getinfo("meta.npy")
    if dtype != np.dtype(bool) or len(shape) != 2:
        raise InputError(f"{path}: grid mask is a {dtype} array of shape {shape}, not a 2-D bool array; {fix}")
    if max(shape) > MAX_GRID_SIDE or shape[0] * shape[1] > MAX_GRID_CELLS:
        raise InputError(
            f"{path}: grid of {shape[0]} x {shape[1]} cells, over the limits of {MAX_GRID_SIDE:,} a side and "
            f"{MAX_GRID_CELLS:,} in all; {fix}"
        )
    if meta.file_size > GRID_MAX_BYTES:
        raise InputError(f"{path}: grid metadata of {meta.file_size:,} bytes is too large; {fix}")


def grid_axes(outline_metres, rotate: bool) -> float:
    """The grid rotation in degrees: 0, or the main axis of the area folded into (-45, 45]."""
    if not rotate:
        return 0.0
    rect = shapely.minimum_rotated_rectangle(outline_metres)
    xy = np.asarray(rect.exterior.coords)
    edges = np.diff(xy, axis=0)
    longest = edges[int(np.argmax(np.hypot(edges[:, 0], edges[:, 1])))]
    angle = math.degrees(math.atan2(longest[1], longest[0]))
    folded = (angle + 45.0) % 90.0 - 45.0  # in [-45, 45)
    return 45.0 if folded == -45.0 else round(folded, 9)


def _cell_that_fits(width_m: float, height_m: float, max_cells: int) -> float:
    """The smallest round cell size (metres) whose grid stays within `max_cells`."""
    cell = math.sqrt(width_m * height_m / max_cells)
    for step in (0.1, 1, 5, 10, 50, 100, 1000):
        if cell < 10 * step or step == 1000:
            cell = math.ceil(cell / step) * step
            break
    while math.ceil(width_m / cell) * math.ceil(height_m / cell) > max_cells:
        cell += step
    return round(cell, 6)


def _check_not_degenerate(name: str, width_m: float, height_m: float, area_m2: float, cell: float) -> None:
    """Refuse an area narrower or shorter than one cell (along the grid's axes) or smaller than one cell's
    area: its grid would be a single cell, or a row of cells the area does not really cover (a 1 mm x 8 km
    sliver leaves half of a 1-cell-high row "free"). Such an area is almost always a typo in the coordinates."""
    slack = 1.0 - EXTENT_TOLERANCE  # an area of exactly one cell, give or take rounding, passes
    if width_m >= cell * slack and height_m >= cell * slack and area_m2 >= cell * cell * slack:
        return
    side = min(width_m, height_m, math.sqrt(max(area_m2, 0.0)))
    finer = math.floor(side * 100) / 100  # the largest cell, to the centimetre, that the area can hold
    if finer >= 0.01:
        fix = f"give a larger area (check its coordinates) or a --cell of at most {finer:g}"
    else:
        fix = "no --cell fits (the smallest is 0.01 m): give a larger area, and check its coordinates"
    raise InputError(
        f"{name}: the area measures {_length(width_m)} x {_length(height_m)} ({area_m2:.3g} square metres), "
        f"smaller than one {cell:g} m cell ({cell * cell:g} square metres); {fix}"
    )


def _length(metres: float) -> str:
    """A length for a message: km, m or mm, three significant figures."""
    if metres >= 1000:
        return f"{metres / 1000:.3g} km"
    return f"{metres:.3g} m" if metres >= 1 else f"{metres * 1000:.3g} mm"


@dataclass
class GridReport:
    """What went into the grid: blocked cells by reason, buildings by outcome, warnings."""

    outside: int = 0
    nofly: int = 0
    buildings: int = 0
    buildings_total: int = 0
    buildings_used: int = 0
    buildings_outside: int = 0
    buildings_blocking: int = 0  # obstacles: tall ones, and unknown ones under the "block" rule
    buildings_tall: int = 0  # height known and >= threshold
    buildings_low: int = 0  # height known and below the threshold
    unknown_height: int = 0
    unknown_rule: str = "block"
    threshold: float = DEFAULT_ALTITUDE
    warnings: list[str] = field(default_factory=list)


def make_grid(
    area: Area,
    cell: float = DEFAULT_CELL,
    altitude: float = DEFAULT_ALTITUDE,
    rotate: bool = False,
    buildings: BuildingSet | None = None,
    rule: BuildingRule | None = None,
    max_cells: int = DEFAULT_MAX_CELLS,
) -> tuple[GeoGrid, GridReport]:
    """Grid an area: size and place the grid, then block cells (see the module docstring)."""
    if not (isinstance(cell, (int, float)) and math.isfinite(cell) and cell > 0):
        raise InputError(f"cell size {cell!r} m: must be a number > 0, e.g. --cell 10")
    if not (math.isfinite(altitude) and altitude > 0):
        raise InputError(f"altitude {altitude!r} m: must be a number > 0, e.g. --altitude 40")
    rule = rule or BuildingRule(altitude=altitude)
    if rule.altitude != altitude:
        raise ValueError(f"the building rule's altitude {rule.altitude} differs from the grid's {altitude}")
    proj = LocalProjection.centred_on(area.geometry.bounds)
    outline_m = proj.geometry_to_metres(area.outline)
    rotation = grid_axes(outline_m, rotate)
    umin, vmin, umax, vmax = affinity.rotate(outline_m, -rotation, origin=(0, 0)).bounds
    _check_not_degenerate(area.name, umax - umin, vmax - vmin, float(outline_m.area), float(cell))
    w = max(1, math.ceil((umax - umin) / cell - EXTENT_TOLERANCE))
    h = max(1, math.ceil((vmax - vmin) / cell - EXTENT_TOLERANCE))
    if w * h > max_cells:
        raise InputError(
            f"{area.name}: the grid would be {w} x {h} = {w * h:,} cells of {cell:g} m "
            f"({(umax - umin) / 1000:.2f} x {(vmax - vmin) / 1000:.2f} km), over the limit of {max_cells:,}; "
            f"use a larger cell (e.g. --cell {_cell_that_fits(umax - umin, vmax - vmin, max_cells):g}), "
            "a smaller area, or raise --max-cells"
        )
    u0, v0 = (umin + umax - w * cell) / 2.0, (vmin + vmax - h * cell) / 2.0
    a = math.radians(rotation)
    origin = (math.cos(a) * u0 - math.sin(a) * v0, math.sin(a) * u0 + math.cos(a) * v0)
    grid = GeoGrid(
        proj.proj,
        origin,
        rotation,
        float(cell),
        np.zeros((w, h), bool),
        float(altitude),
        area_name=area.name,
        area_wkt=area.geometry.wkt,
    )
    report = GridReport(unknown_rule=rule.unknown, threshold=rule.threshold)

    cx, cy = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5, indexing="ij")
    outside = ~shapely.contains_xy(grid.geometry_to_grid(outline_m), cx, cy)
    zones_m = [proj.geometry_to_metres(z) for z in area.holes + area.nofly]
    zones_m += [
        shapely.Point(*proj.to_metres(c.lon, c.lat)).buffer(c.radius, CIRCLE_SEGMENTS) for c in area.nofly_circles
    ]
    nofly = np.zeros_like(outside)
    missed = []
    for i, zone in enumerate(zones_m):
        hit = shapely.intersects_xy(grid.geometry_to_grid(zone), cx, cy)
        if not hit.any() and zone.intersects(outline_m):
            missed.append(i)
        nofly |= hit
    if missed:
        report.warnings.append(
            f"{area.name}: {len(missed)} no-fly zone(s) or hole(s) cover no cell centre, so they block "
            "no cell; use a smaller --cell if vehicles must keep clear of them"
        )
    if zones_m:
        grid.nofly_wkt = shapely.union_all([proj.geometry_to_lonlat(z) for z in zones_m]).wkt
    nofly &= ~outside
    by_buildings = np.zeros_like(outside)
    if buildings is not None:
        grid.buildings_name = buildings.name
        by_buildings = _building_cells(grid, proj, area, buildings, rule, report) & ~outside & ~nofly
    grid.blocked = outside | nofly | by_buildings
    report.outside, report.nofly, report.buildings = int(outside.sum()), int(nofly.sum()), int(by_buildings.sum())
    grid.info = {
        "blocked_outside": report.outside,
        "blocked_nofly": report.nofly,
        "blocked_buildings": report.buildings,
        "building_rule": {
            "threshold_m": rule.threshold,
            "margin_m": rule.margin,
            "unknown_height": rule.unknown,
            "metres_per_level": METRES_PER_LEVEL,
            "coverage": "footprint overlaps cell area",
        },
    }
    return grid, report


def _building_cells(
    grid: GeoGrid, proj: LocalProjection, area: Area, bset: BuildingSet, rule: BuildingRule, report: GridReport
) -> np.ndarray:
    """Cells overlapped (by a positive area) by a blocking footprint; fills the building counts."""
    report.buildings_total = len(bset.buildings)
    report.warnings.extend(bset.warnings)
    if not bset.buildings:
        return np.zeros_like(grid.blocked)
    feet = np.array([grid.geometry_to_grid(proj.geometry_to_metres(b.geometry)) for b in bset.buildings])
    inside = shapely.intersects(feet, grid.geometry_to_grid(proj.geometry_to_metres(area.geometry)))
    heights = [b.height for b in bset.buildings]
    blocks = np.array([rule.blocks(h) for h in heights], dtype=bool)
    unknown = np.array([h is None for h in heights], dtype=bool)
    report.buildings_used = int(inside.sum())
    report.buildings_outside = int((~inside).sum())
    report.unknown_height = int((inside & unknown).sum())
    report.buildings_blocking = int((inside & blocks).sum())
    report.buildings_low = int((inside & ~blocks & ~unknown).sum())
    report.buildings_tall = int((inside & blocks & ~unknown).sum())
    if report.buildings_used == 0:
        report.warnings.append(
            f"{bset.name}: none of its {len(feet)} buildings lies in the area {area.name}; check that the "
            "file covers the area and stores [lon, lat] positions"
        )
    mask = np.zeros_like(grid.blocked)
    chosen = feet[inside & blocks]
    if len(chosen) == 0:
        return mask
    cx, cy = np.meshgrid(np.arange(grid.width), np.arange(grid.height), indexing="ij")
    boxes = shapely.box(cx.ravel(), cy.ravel(), cx.ravel() + 1, cy.ravel() + 1)
    cell_idx, foot_idx = shapely.STRtree(chosen).query(boxes, predicate="intersects")
    overlap = shapely.area(shapely.intersection(boxes[cell_idx], chosen[foot_idx])) > OVERLAP_EPS
    mask.ravel()[cell_idx[overlap]] = True
    return mask
