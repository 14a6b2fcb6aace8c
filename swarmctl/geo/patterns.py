"""Search patterns from a last known point (LKP), per IAMSAR, on a planned grid.

Every pattern is drawn in the grid's frame (metres along the grid's x and y axes, so a rotated grid
rotates its patterns with it), clipped to the area's free part (the area polygon less the squares of
its blocked cells: no-fly zones, holes, obstacles), and handed out to the swarm's vehicles:

- **expanding square**: from the LKP, legs of S, S, 2S, 2S, 3S, 3S ... with a right turn after each,
  the first leg along grid north, until the square covers every free cell. The spiral is cut into
  `uavs` consecutive stretches of about equal length (the first vehicle the innermost one) and each
  vehicle flies its stretch at an altitude of its own (stacked altitudes).
- **sector search**: from the LKP out a radius R, 120 degrees right, R (a chord), 120 degrees right,
  back through the LKP and on: three triangles, six legs through the LKP 60 degrees apart. The second
  pattern is the first turned by 30 degrees; with more patterns they are turned by 60/P degrees each,
  P chosen so that the legs through the LKP lie at most S apart at the radius R (R: the distance from
  the LKP to the farthest free cell). Patterns go round the vehicles, each vehicle at its own altitude.
- **parallel track** (creeping line): lanes S apart along the area's longer side, the first lane on the
  side nearest the LKP, flown back and forth. Each vehicle takes a contiguous block of lanes at the
  grid's altitude: the blocks are separate strips, so their lanes never meet. Should the ways round the
  area's gaps make two tracks meet (checked), the altitudes are stacked instead.

S, the track spacing, is the footprint's diameter unless given: 2 x fov cells x the cell size. Where
clipping leaves a free cell of the pattern's region further than S / 2 from every leg (an inlet
between two lanes, the far side of an obstacle) its centre is added as a waypoint by the shortest
detour that keeps the route's legs and start: out and back from the nearest point of a leg in the free
area, or on from the route's end (parallel track: of the vehicle whose strip holds it). Where the
straight way between two waypoints leaves the free area, the route goes round through free cells.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LineString, Point

from swarmctl.errors import InputError
from swarmctl.geo.grid import GeoGrid
from swarmctl.world.config import WorldConfig

STACK_STEP_M = 10.0  # vertical separation between vehicles flying stacked altitudes
# the highest a stacked vehicle may be given (metres above home): the usual limit for unmanned aircraft
# (120 m in the EU's open category, 400 ft in the US); a plan that would stack above it is refused
STACK_CEILING_M = 120.0
MAX_LEGS = 20_000  # legs of one pattern, before clipping
MAX_SECTOR_TURNS = 60  # sector patterns: at most one leg through the LKP every degree
MERGE_M = 0.01  # waypoints closer than this are one
INSIDE_M = 0.001  # a way this close to the free area is in it (points on its edge, rounded)
MAX_ROUNDS = 8  # fill and go round, again while going round leaves cells unseen
DEFAULT_FOV: float = WorldConfig.fov  # the footprint's radius in cells, the world's default

Point2 = tuple[float, float]


@dataclass
class VehicleRoute:
    """One vehicle's waypoints, (lat, lon) degrees, flown at `altitude` metres relative to home;
    `local` holds the same waypoints in the grid's frame (metres)."""

    name: str
    waypoints: list[Point2]
    local: list[Point2]
    altitude: float

    @property
    def length(self) -> float:
        """The route's length in metres, waypoint to waypoint."""
        xy = np.asarray(self.local, dtype=float).reshape(-1, 2)
        return float(np.hypot(*np.diff(xy, axis=0).T).sum()) if len(xy) > 1 else 0.0


@dataclass
class PatternPlan:
    """A pattern handed out to the vehicles: the routes, how they are kept apart (`split`), the
    pattern's legs before clipping (`legs`, grid frame, metres), and the free cells it covers."""

    pattern: str
    spacing: float
    routes: list[VehicleRoute]
    split: str
    legs: list[LineString]
    cells: np.ndarray  # (n, 2) int: the free cells of the pattern's region
    radius: float = 0.0  # sector search: R
    straight: int = 0  # ways between parts of the area no free cells join, flown straight


def default_spacing(grid: GeoGrid, fov: float = DEFAULT_FOV) -> float:
    """The footprint's diameter in metres: 2 x fov cells x the cell size."""
    return 2.0 * fov * grid.cell


class Frame:
    """The grid's frame: metres along the grid's axes from the corner of cell (0, 0)."""

    def __init__(self, grid: GeoGrid) -> None:
        self.grid = grid

    def from_latlon(self, lat, lon) -> tuple[np.ndarray, np.ndarray]:
        gx, gy = self.grid.metres_to_grid(*self.grid.projection.to_metres(lon, lat))
        return np.asarray(gx) * self.grid.cell, np.asarray(gy) * self.grid.cell

    def to_latlon(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        c = self.grid.cell
        lon, lat = self.grid.projection.to_lonlat(
            *self.grid.grid_to_metres(np.asarray(u, float) / c, np.asarray(v, float) / c)
        )
        return np.asarray(lat), np.asarray(lon)

    def geometry(self, lonlat_geom):
        """A lon/lat geometry in the grid's frame."""
        in_cells = self.grid.geometry_to_grid(self.grid.projection.geometry_to_metres(lonlat_geom))
        return affinity.scale(in_cells, self.grid.cell, self.grid.cell, origin=(0, 0))


def free_region(grid: GeoGrid, frame: Frame):
    """The area less its blocked cells, in the grid's frame: the runs of free cells of each column,
    as boxes, joined and cut to the area's polygon."""
    c = grid.cell
    boxes = []
    for x in range(grid.width):
        free = ~grid.blocked[x]
        edges = np.flatnonzero(np.diff(np.concatenate(([0], free.astype(np.int8), [0]))))
        for y0, y1 in zip(edges[::2], edges[1::2]):
            boxes.append(shapely.box(x * c, y0 * c, (x + 1) * c, y1 * c))
    cells = shapely.union_all(boxes)
    if grid.area_wkt:
        cells = cells.intersection(frame.geometry(shapely.from_wkt(grid.area_wkt)))
    return cells


def free_centres(grid: GeoGrid) -> tuple[np.ndarray, np.ndarray]:
    """The free cells (n, 2) and their centres (n, 2) in the grid's frame."""
    cells = np.argwhere(~grid.blocked)
    return cells, (cells + 0.5) * grid.cell


def expanding_square_legs(lkp: Point2, spacing: float, reach: float) -> list[LineString]:
    """IAMSAR expanding square: legs of S, S, 2S, 2S ... from `lkp`, first north, right turns, until
    the square reaches `reach` metres from the LKP along both axes."""
    headings = [(0.0, 1.0), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0)]  # north, east, south, west
    legs, (u, v), i = [], lkp, 0
    while True:
        n = i // 2 + 1
        du, dv = headings[i % 4]
        end = (u + du * n * spacing, v + dv * n * spacing)
        legs.append(LineString([(u, v), end]))
        u, v = end
        i += 1
        if n * spacing / 2 >= reach + spacing and i % 4 == 0:
            return legs
        if len(legs) > MAX_LEGS:
            raise InputError(f"the expanding square needs over {MAX_LEGS:,} legs; use a larger --spacing")


def sector_legs(lkp: Point2, radius: float, turn: float) -> list[LineString]:
    """One IAMSAR sector pattern: nine legs (six through the LKP, three chords), the first leg out
    along grid north turned `turn` degrees clockwise, 120-degree right turns."""

    def out(bearing: float) -> Point2:  # bearing clockwise from grid north
        a = math.radians(bearing)
        return (lkp[0] + radius * math.sin(a), lkp[1] + radius * math.cos(a))

    h = turn
    route = [lkp, out(h), out(h + 60), lkp, out(h + 240), out(h + 300), lkp, out(h + 120), out(h + 180), lkp]
    return [LineString([a, b]) for a, b in zip(route, route[1:])]


def parallel_legs(region, lkp: Point2, spacing: float) -> tuple[list[LineString], int]:
    """Lanes `spacing` apart along the region's longer side (grid axes), the first S / 2 in from the side
    nearest the LKP; returns the lanes in order from that side (all one way) and the axis across them."""
    umin, vmin, umax, vmax = region.bounds
    across = 1 if umax - umin >= vmax - vmin else 0  # lanes along u: they are stacked along v
    lo, hi = (vmin, vmax) if across else (umin, umax)
    count = max(1, math.ceil((hi - lo) / spacing - 1e-9))
    if count > MAX_LEGS:
        raise InputError(f"the parallel track needs {count:,} lanes, over {MAX_LEGS:,}; use a larger --spacing")
    offsets = lo + spacing * (np.arange(count) + 0.5)
    offsets = np.minimum(offsets, hi - spacing / 2) if count > 1 else np.array([(lo + hi) / 2])
    if abs(lkp[across] - hi) < abs(lkp[across] - lo):
        offsets = offsets[::-1]
    a0, a1 = (umin, umax) if across else (vmin, vmax)
    lanes = [LineString([(a0, w), (a1, w)] if across else [(w, a0), (w, a1)]) for w in offsets]
    return lanes, across


def clip(leg: LineString, region) -> list[list[Point2]]:
    """The parts of `leg` inside `region`, in the leg's direction, each as [start, end]."""
    inside = shapely.line_merge(shapely.union_all([g for g in shapely.get_parts(leg.intersection(region))]))
    parts = [g for g in shapely.get_parts(inside) if isinstance(g, LineString) and g.length > MERGE_M]
    parts.sort(key=lambda g: leg.project(Point(g.coords[0])))
    pieces = []
    for g in parts:
        a, b = g.coords[0], g.coords[-1]  # a part of a straight leg: its ends are enough
        if leg.project(Point(a)) > leg.project(Point(b)):
            a, b = b, a
        pieces.append([(float(a[0]), float(a[1])), (float(b[0]), float(b[1]))])
    return pieces


def join(pieces: list[list[Point2]]) -> list[Point2]:
    """The waypoints of pieces flown one after the other (a point repeated within MERGE_M kept once)."""
    out: list[Point2] = []
    for piece in pieces:
        for p in piece:
            if not out or math.dist(out[-1], p) > MERGE_M:
                out.append(p)
    return out


def _uncovered(route_xy: list[list[Point2]], centres: np.ndarray, radius: float) -> np.ndarray:
    """Which centres lie further than `radius` from every route's legs (a lone waypoint counts as a leg)."""
    parts = []
    for r in route_xy:
        if len(r) > 1:
            xy = np.asarray(r, dtype=float)
            parts += list(shapely.linestrings(np.stack([xy[:-1], xy[1:]], axis=1)))
        elif r:
            parts.append(Point(r[0]))
    if not parts:
        return np.ones(len(centres), bool)
    near, _ = shapely.STRtree(parts).query(
        shapely.points(centres), predicate="dwithin", distance=radius * (1 + 1e-9) + 1e-9
    )
    out = np.ones(len(centres), bool)
    out[near] = False
    return out


def _detour(route: list[Point2], p: Point2, region) -> tuple[float, int, list[Point2]]:
    """The shortest way to add `p` to `route` that keeps every leg it has and its start: on from the end,
    or out and back from the nearest point of a leg that lies in `region`. Returns (added length, index,
    waypoints to insert there)."""
    if not route:
        return 0.0, 0, [p]
    xy = np.asarray(route, dtype=float)
    q = np.asarray(p, dtype=float)
    best = (math.dist(route[-1], p), len(route), [p])  # the start stays: a pattern begins at the LKP
    if len(route) < 2:
        return best
    a, b = xy[:-1], xy[1:]
    ab = b - a
    t = np.clip(((q - a) * ab).sum(axis=1) / np.maximum((ab * ab).sum(axis=1), 1e-12), 0.0, 1.0)
    feet = a + t[:, None] * ab
    cost = 2 * np.hypot(*(feet - q).T)
    for i in np.argsort(cost):
        if cost[i] >= best[0]:
            break
        foot = (float(feet[i, 0]), float(feet[i, 1]))
        if region.distance(Point(foot)) > MERGE_M:  # a way between clipped pieces, outside the free area
            continue
        if math.dist(foot, route[i]) <= MERGE_M:
            return float(cost[i]), int(i) + 1, [p, route[i]]
        if math.dist(foot, route[i + 1]) <= MERGE_M:
            return float(cost[i]), int(i) + 2, [p, route[i + 1]]
        return float(cost[i]), int(i) + 1, [foot, p, foot]
    return best


def fill(routes: list[list[Point2]], centres: np.ndarray, radius: float, owner: np.ndarray | None, region) -> None:
    """Add the centres no leg covers as waypoints, each by the shortest detour of a route (of `owner[i]`'s
    route when owners are given) that keeps the legs it has, until every centre is within `radius` of a leg."""
    left = np.flatnonzero(_uncovered(routes, centres, radius))
    while len(left):
        i = int(left[0])
        p = (float(centres[i, 0]), float(centres[i, 1]))
        choices = [int(owner[i])] if owner is not None else range(len(routes))
        (_, where, points), k = min(((_detour(routes[k], p, region), k) for k in choices), key=lambda t: t[0][0])
        routes[k][where:where] = points
        j = where + points.index(p)
        near = routes[k][max(0, j - 1) : j + 2]  # the legs to and from p
        new = LineString(near) if len(near) > 1 else Point(p)
        hit = shapely.dwithin(new, shapely.points(centres[left]), radius * (1 + 1e-9) + 1e-9)
        hit[0] = True
        left = left[~hit]


def _nearest_free(grid: GeoGrid, centres: np.ndarray, cells: np.ndarray, p: Point2) -> tuple[int, int]:
    x, y = int(math.floor(p[0] / grid.cell)), int(math.floor(p[1] / grid.cell))
    if 0 <= x < grid.width and 0 <= y < grid.height and not grid.blocked[x, y]:
        return x, y
    k = int(np.argmin(np.hypot(*(centres - np.asarray(p)).T)))
    return int(cells[k, 0]), int(cells[k, 1])


def _walk(predecessors: np.ndarray, start: int, goal: int) -> list[int] | None:
    """The nodes from `start` to `goal` along a shortest-path tree rooted at `goal`, or None if unreachable."""
    if start != goal and predecessors[start] < 0:
        return None
    path = [start]
    while path[-1] != goal:
        path.append(int(predecessors[path[-1]]))
    return path


def _straighten(points: list[Point2], region) -> list[Point2]:
    """Drop the points of a path that a straight line within `region` can skip (greedy, forward)."""
    out, i = [points[0]], 0
    while i < len(points) - 1:
        j = i + 1
        while j + 1 < len(points) and region.covers(LineString([points[i], points[j + 1]])):
            j += 1
        out.append(points[j])
        i = j
    return out


def _free_graph(grid: GeoGrid, cells: np.ndarray):
    """The free cells as the nodes of a graph, each joined to its 4 free neighbours."""
    from scipy.sparse import coo_matrix

    index = np.full(grid.blocked.shape, -1, dtype=np.int64)
    index[cells[:, 0], cells[:, 1]] = np.arange(len(cells))
    rows, cols = [], []
    for dx, dy in ((1, 0), (0, 1)):
        a = index[: grid.width - dx, : grid.height - dy]
        b = index[dx:, dy:]
        both = (a >= 0) & (b >= 0)
        rows.append(a[both])
        cols.append(b[both])
    r, c = np.concatenate(rows), np.concatenate(cols)
    return coo_matrix((np.ones(len(r)), (r, c)), shape=(len(cells), len(cells))).tocsr()


def keep_inside(grid: GeoGrid, routes: list[list[Point2]], region) -> tuple[int, int]:
    """Where the straight way between two waypoints leaves the free area, go round through free cells
    (the shortest 4-connected path, straightened). Returns how many ways went round, and how many no free
    path joins (kept straight)."""
    from scipy.sparse.csgraph import breadth_first_order

    region = region.buffer(INSIDE_M)
    shapely.prepare(region)
    todo = [
        (k, i)
        for k, route in enumerate(routes)
        for i in range(len(route) - 1)
        if not region.covers(LineString([route[i], route[i + 1]]))
    ]
    if not todo:
        return 0, 0
    cells, centres = free_centres(grid)
    graph = _free_graph(grid, cells)
    node = {(int(x), int(y)): n for n, (x, y) in enumerate(cells)}
    trees: dict[int, np.ndarray] = {}
    ways: dict[tuple[int, int], list[Point2]] = {}
    stuck = 0
    for k, i in todo:
        a, b = routes[k][i], routes[k][i + 1]
        goal = node[_nearest_free(grid, centres, cells, b)]
        if goal not in trees:
            trees[goal] = breadth_first_order(graph, goal, directed=False, return_predecessors=True)[1]
        path = _walk(trees[goal], node[_nearest_free(grid, centres, cells, a)], goal)
        if path is None:
            stuck += 1
            continue
        middle = [(float(centres[n, 0]), float(centres[n, 1])) for n in path]
        ways[(k, i)] = _straighten([a, *middle, b], region)[1:-1]
    for k, i in sorted(ways, reverse=True):  # from the end, so the indices still hold
        routes[k][i + 1 : i + 1] = ways[(k, i)]
    return len(ways), stuck


def split_by_length(pieces: list[list[Point2]], parts: int) -> list[list[list[Point2]]]:
    """Consecutive groups of pieces, `parts` of them, of about equal length, the way from one piece to the
    next included (each group at least one piece)."""
    lengths = np.array(
        [LineString(p).length + (math.dist(pieces[i - 1][-1], p[0]) if i else 0.0) for i, p in enumerate(pieces)]
    )
    ends = np.cumsum(lengths)
    total = float(ends[-1]) if len(ends) else 0.0
    cuts = [0]
    for k in range(1, parts):
        j = int(np.searchsorted(ends, total * k / parts)) + 1
        j = min(max(j, cuts[-1] + 1), len(pieces) - (parts - k))
        cuts.append(j)
    cuts.append(len(pieces))
    return [pieces[a:b] for a, b in zip(cuts, cuts[1:])]


def _check(grid: GeoGrid, lkp_latlon: Point2, uavs: int, spacing: float) -> None:
    lat, lon = lkp_latlon
    if not (math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90 and -180 <= lon <= 180):
        raise InputError(f"--lkp {lat:g},{lon:g}: give a finite latitude (-90..90) and longitude (-180..180)")
    if not 1 <= uavs:
        raise InputError(f"--uavs {uavs}: give at least one vehicle")
    if not (math.isfinite(spacing) and spacing > 0):
        raise InputError(f"--spacing {spacing:g}: the track spacing must be a number of metres > 0")
    if grid.area_wkt and not shapely.from_wkt(grid.area_wkt).covers(Point(lon, lat)):
        raise InputError(
            f"--lkp {lat:g},{lon:g}: the last known point lies outside the area (or in a hole of it); "
            "give LAT,LON of a point inside it"
        )


def plan_pattern(
    grid: GeoGrid,
    pattern: str,
    lkp_latlon: Point2,
    uavs: int = 3,
    spacing: float | None = None,
    names: list[str] | None = None,
) -> PatternPlan:
    """Plan `pattern` ("expanding-square", "sector" or "parallel") from the LKP (lat, lon) for `uavs`
    vehicles with track spacing `spacing` metres (default: `default_spacing`); see the module docstring."""
    if pattern not in ("expanding-square", "sector", "parallel"):
        raise InputError(f"--pattern {pattern!r}: choose expanding-square, sector or parallel")
    spacing = default_spacing(grid) if spacing is None else float(spacing)
    _check(grid, lkp_latlon, uavs, spacing)
    names = names or [f"uav{k + 1}" for k in range(uavs)]
    frame = Frame(grid)
    u, v = frame.from_latlon(lkp_latlon[0], lkp_latlon[1])
    lkp = (float(u), float(v))
    region = free_region(grid, frame)
    cells, centres = free_centres(grid)
    if len(cells) == 0 or region.is_empty:
        raise InputError("every cell of the grid is blocked; no pattern can be flown")
    radius = spacing / 2
    offsets = centres - np.asarray(lkp)
    owner = None
    sector_r = 0.0
    if pattern == "expanding-square":
        reach = float(np.abs(offsets).max())
        legs = expanding_square_legs(lkp, spacing, reach)
        pieces = [p for leg in legs for p in clip(leg, region)]
        if len(pieces) < uavs:
            raise InputError(f"the expanding square has {len(pieces)} leg(s) in the area, fewer than --uavs {uavs}")
        routes = [join(group) for group in split_by_length(pieces, uavs)]
        altitudes = [grid.altitude + STACK_STEP_M * k for k in range(uavs)]
        split = _stacked("consecutive stretches of one spiral", altitudes)
    elif pattern == "sector":
        want = max(float(np.hypot(*offsets.T).max()), radius)
        step = 2 * math.degrees(math.asin(min(1.0, radius / want)))  # legs this far apart are S apart at R
        turns = max(2, math.ceil(60.0 / step - 1e-9))
        if turns > MAX_SECTOR_TURNS:
            turns = MAX_SECTOR_TURNS
            want = radius / math.sin(math.radians(60.0 / turns / 2))
        turns = math.ceil(turns / uavs) * uavs
        sector_r = want
        legs, routes = [], [[] for _ in range(uavs)]
        for j in range(turns):
            one = sector_legs(lkp, want, 60.0 * j / turns)
            legs += one
            routes[j % uavs] = join([routes[j % uavs], *[p for leg in one for p in clip(leg, region)]])
        inside = np.hypot(*offsets.T) <= want
        cells, centres = cells[inside], centres[inside]
        altitudes = [grid.altitude + STACK_STEP_M * k for k in range(uavs)]
        split = _stacked(f"{turns} sector patterns turned {60 / turns:.3g} deg apart, radius {want:.0f} m", altitudes)
    else:
        legs, across = parallel_legs(region, lkp, spacing)
        lane_pieces = [clip(leg, region) for leg in legs]
        used = [k for k, p in enumerate(lane_pieces) if p]
        if len(used) < uavs:
            raise InputError(f"the parallel track has {len(used)} lane(s) in the area, fewer than --uavs {uavs}")
        groups = split_by_length([[q for p in lane_pieces[k] for q in p] for k in used], uavs)
        routes, first = [], 0
        lane_owner = np.zeros(len(legs), dtype=np.int64)  # monotone: each vehicle's strip one interval
        offsets_across = np.array([leg.coords[0][across] for leg in legs])
        for k, group in enumerate(groups):
            lane_owner[used[first] :] = k
            block = used[first : first + len(group)]
            first += len(group)
            routes.append(join(_block_route(region, legs, lane_pieces, block, offsets_across, across, spacing)))
        nearest = np.abs(centres[:, across, None] - offsets_across[None, :]).argmin(axis=1)
        owner = lane_owner[nearest]
        altitudes = [grid.altitude] * uavs
        split = f"separate blocks of lanes, one per vehicle, all at {grid.altitude:g} m"
    stuck = keep_inside(grid, routes, region)[1]
    for _ in range(MAX_ROUNDS):  # a way round replaces a straight leg, whose cells the next fill sees again
        fill(routes, centres, radius, owner, region)
        rounded, stuck = keep_inside(grid, routes, region)
        if not rounded:
            break
    else:
        fill(routes, centres, radius, owner, region)  # every cell seen, even if a way is left straight
    if crossings(routes, altitudes):  # the strips keep lanes apart; this holds it for any area
        altitudes = [grid.altitude + STACK_STEP_M * k for k in range(uavs)]
        split = _stacked("blocks of lanes, whose ways round the area's gaps meet", altitudes)
    out = []
    for name, route, alt in zip(names, routes, altitudes):
        lat, lon = frame.to_latlon([p[0] for p in route], [p[1] for p in route])
        out.append(VehicleRoute(name, list(zip(lat.tolist(), lon.tolist())), route, alt))
    return PatternPlan(pattern, spacing, out, split, legs, cells, sector_r, stuck)


def _block_route(region, legs, lane_pieces, block, offsets_across, across: int, spacing: float):
    """A vehicle's lanes (indices `block`) flown back and forth, one part of its strip after the other: where
    the free area splits the strip (an obstacle, an inlet), each part's lanes are flown before the next's
    rather than crossing from one part to the other on every lane."""
    lo = float(offsets_across[block].min()) - spacing / 2
    hi = float(offsets_across[block].max()) + spacing / 2
    umin, vmin, umax, vmax = region.bounds
    strip = shapely.box(umin, lo, umax, hi) if across else shapely.box(lo, vmin, hi, vmax)
    parts = list(shapely.get_parts(region.intersection(strip)))
    by_part: dict[int, list[tuple[int, list[Point2]]]] = {}
    for order, lane in enumerate(block):
        for piece in lane_pieces[lane]:
            mid = Point((piece[0][0] + piece[-1][0]) / 2, (piece[0][1] + piece[-1][1]) / 2)
            part = min(range(len(parts)), key=lambda i: parts[i].distance(mid)) if parts else 0
            by_part.setdefault(part, []).append((order, piece))
    pieces: list[list[Point2]] = []
    for part in sorted(by_part, key=lambda i: min(o for o, _ in by_part[i])):
        lanes_here = sorted({o for o, _ in by_part[part]})
        for n, order in enumerate(lanes_here):
            here = [piece for o, piece in by_part[part] if o == order]
            pieces += here if n % 2 == 0 else [piece[::-1] for piece in here[::-1]]
    return pieces


def crossings(routes: list[list[Point2]], altitudes: list[float]) -> list[tuple[int, int]]:
    """The pairs of vehicles (indices) at one altitude whose tracks, waypoint to waypoint, meet."""
    tracks = [LineString(r) if len(r) > 1 else Point(r[0]) if r else Point() for r in routes]
    return [
        (a, b)
        for a in range(len(routes))
        for b in range(a + 1, len(routes))
        if altitudes[a] == altitudes[b] and tracks[a].intersects(tracks[b])
    ]


def _stacked(what: str, altitudes: list[float]) -> str:
    if altitudes[-1] > STACK_CEILING_M:
        raise InputError(
            f"{what} for {len(altitudes)} vehicles stacks them up to {altitudes[-1]:g} m, above "
            f"{STACK_CEILING_M:g} m; use fewer --uavs, a lower --altitude, or --pattern parallel"
        )
    if len(altitudes) == 1:
        return f"{what}, one vehicle at {altitudes[0]:g} m"
    return f"{what}, stacked altitudes {altitudes[0]:g}..{altitudes[-1]:g} m, {STACK_STEP_M:g} m apart"
