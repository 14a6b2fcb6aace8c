"""The scales observation: crops around the vehicle at 1, 3 and 9 cells a pixel, the same on every map.

The paper's window (swarmctl.world.observe) sees F cells and nothing beyond; the global-local variant
(swarmctl.world.observe_global) pools the whole map to F x F, so a pixel is 2 cells at M = 20 and 6.4
at M = 64 and no distance means the same on two maps. Here a pixel is always 1, 3 or 9 cells: three
S x S crops centred on the vehicle, S the window setting F (11 is the intended one: odd, so the
vehicle's cell is the centre of the centre pixel at every scale; 11 px x 9 cells covers 99 x 99 cells,
all of a 50-cell map from anywhere in it). An even S puts the vehicle in pixel S // 2, one pixel more
below it than above. Whatever the map size, the observation is (24, S, S).

Channels of each scale (scale i takes channels 7 i .. 7 i + 6), pooled over the cells of a pixel:

    0 unexplored   fraction of the pixel's cells not yet explored         mean  (off the map: 0)
    1 blocked      fraction known obstacle or off the map                 mean  (off the map: 1)
    2 free targets known targets no vehicle is believed to hover on       count (off the map: 0)
    3 searching    other vehicles at their believed cells, not hovering   count
    4 holding      other vehicles believed hovering on a target           count
    5 frontier     explored free cells 4-adjacent to an unexplored cell   max   (off the map: 0)
    6 distance     path steps from the vehicle to the pixel, searched on   -     (off the map: 1)
                   the pixels of the scale (below), / DISTANCE_CELLS, 1 when unreached or farther

Counts, not "any", where how many matters: three targets in a 9 x 9 pixel draw more than one. The
frontier is "any" (a frontier cell is a place to go; at 9 cells a pixel its fraction is tiny).

The distance is searched where it is seen and at the scale it is seen: per scale, a BFS from the
vehicle's pixel over a G x G grid of that scale's pixels, the crop and MARGIN pixels beyond it on
every side (G = S + 2 MARGIN, so a detour may leave the crop), a pixel passable when some cell of it
is open (on the map and not a known obstacle: unexplored cells pass), the vehicle's own pixel always.
A pixel reached in d steps reads d x cells less cells // 2 for each axis along which it lies off the
vehicle's pixel: on an open map that is the BFS distance to the pixel's nearest cell, at every scale.
At 1 cell a pixel it is the cell BFS round known obstacles within the G x G cells round the vehicle
(exact wherever the shortest path stays in them); at 3 and 9 cells a pixel an estimate (a pixel with
one open cell passes whole: on this simulator's rectangle maps, against the whole-map cell BFS's
nearest cell, the mean error is 0.1-0.2 cells and 90-97 % of the pixels read the same). The search
costs ~G^2 bits a scale a decider whatever the map, where a whole-map BFS cost the map's cells times
its depth.

Then three scalars, each a constant S x S plane (channels 21-23), so that one (24, S, S) tensor per
vehicle goes through the replay memory and the batching as the other variants' do; the network
(swarmctl.policy.qnet.ScalesQNetwork) reads one pixel of each and joins them to its head after the
convolutions:

    21 (free targets known - vehicles not believed hovering) / N, clipped to [-1, 1]
    22 steps left / step limit (Beliefs.step_limit; 1 when the beliefs do not know the limit)
    23 N / 10, N the swarm's vehicles

Everything comes from Beliefs (what each vehicle knows), batched over every decider, so the simulator
and the field, which both build Beliefs, observe the same tensor bit for bit; a decider's observation
never depends on the others in the batch (sums are of small integers, exact in float32; the paths a
few deciders take through Python give what the batched ones do). `remove_taken` does not apply: the
free-target channel already leaves out the targets vehicles hover on.

How it is computed, in numpy calls whose number does not grow with the batch: the four per-cell counts
(unexplored, open, free target, frontier) go one byte each into a uint32 and one summed-area table a
decider gives every pixel of every scale by four corners (summed_cells, pixel_sums); deciders whose
maps are the same (an episode's vehicles under ideal sharing) share one table (shared_rows). The
BFS of all deciders and scales runs on one Python integer, a bit a pixel (pixel_steps). For a few
deciders (Beliefs.crews) the vehicles and held targets are Python arithmetic.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from swarmctl.world.beliefs import Beliefs

CELLS_PER_PIXEL = (1, 3, 9)  # each 3 x the last
SCALE_CHANNELS = ("unexplored", "blocked", "free targets", "searching", "holding", "frontier", "distance")
SCALARS = ("free targets less searching vehicles", "steps left", "swarm size")
CHANNELS = len(CELLS_PER_PIXEL) * len(SCALE_CHANNELS) + len(SCALARS)
DISTANCE_CELLS = 100  # path cells that read 1
SWARM_UNIT = 10  # vehicles that read 1 in the swarm-size scalar
MARGIN = 2  # pixels each scale's path search sees beyond its crop on every side (detours out of view)
UNREACHED = 127  # the pixel steps of a pixel the search does not reach (7 bits; reads 1 at every scale)
SUMMED = ("unexplored", "open", "free targets", "frontier")  # the cell counts, one byte each of a uint32
SHARE_CELLS = 1 << 13  # deciders x cells from which deciders with the same maps share one summed table
SHARE_FEW = 16  # deciders up to which they always do (their maps compared in Python: cheap)
SCALES = np.array(CELLS_PER_PIXEL)
AREA = (SCALES * SCALES).astype(np.float32)[:, None, None]  # cells a pixel


@lru_cache(maxsize=8)
def pixel_edges(side: int, margin: int) -> np.ndarray:
    """(scales, G + 1) int64: the first cell of each of the G = side + 2 margin pixels of each scale
    along one axis, relative to the vehicle's cell, then the end of the last (the vehicle's cell is the
    middle of pixel side // 2 of the crop, pixel margin + side // 2 of the G)."""
    pixels = np.arange(side + 2 * margin + 1) - side // 2 - margin
    cells = SCALES[:, None]
    edges: np.ndarray = cells * pixels[None, :] - cells // 2
    edges.setflags(write=False)
    return edges


@lru_cache(maxsize=8)
def distance_values(side: int) -> tuple[np.ndarray, np.ndarray]:
    """A table (scales x (UNREACHED + 1) x S x S,) float32 of the distance channel's value of each crop
    pixel at each pixel steps: steps x cells less half a pixel (cells // 2) along each axis the pixel
    lies off the vehicle's (its nearest cell, as on an open map), / DISTANCE_CELLS, 1 at most; and the
    (scales, S, S) flat index of each scale and pixel in it at 0 steps (a step adds S x S)."""
    off = (np.arange(side) != side // 2).astype(np.int64)
    saved = (SCALES // 2)[:, None, None, None] * (off[:, None] + off[None, :])[None, None]
    steps = np.arange(UNREACHED + 1)[None, :, None, None]
    cells = np.clip(steps * SCALES[:, None, None, None] - saved, 0, DISTANCE_CELLS)
    table = (cells / np.float32(DISTANCE_CELLS)).astype(np.float32).reshape(-1)
    table.setflags(write=False)
    pixel = np.arange(side * side).reshape(side, side)
    index = np.arange(len(CELLS_PER_PIXEL))[:, None, None] * (UNREACHED + 1) * side * side + pixel
    index.setflags(write=False)
    return table, index


def free_targets(beliefs: Beliefs, targets: np.ndarray, deciders: np.ndarray) -> np.ndarray:
    """(D, W, H) bool: the known targets (D, W, H) of the `deciders` (D,) (flat over (B, U)) that no
    vehicle is believed to hover on (the deciders' own hovering included). Python writes on
    Beliefs.crews for a few deciders."""
    free = targets.copy()
    crews = beliefs.crews
    if crews is not None:
        for i, d in enumerate(deciders.tolist()):
            (x, y), holding, seen = crews[d]
            if holding:
                free[i, x, y] = False
            for ox, oy, hovering in seen:
                if hovering:
                    free[i, ox, oy] = False
        return free
    n = beliefs.batch * beliefs.deciders
    positions = beliefs.positions.reshape(n, -1, 2)[deciders]
    row, vehicle = np.nonzero(beliefs.hovering.reshape(n, -1)[deciders] & (positions[..., 0] >= 0))
    free[row, positions[row, vehicle, 0], positions[row, vehicle, 1]] = False
    return free


def summed_cells(explored: np.ndarray, obstacles: np.ndarray, free: np.ndarray) -> np.ndarray:
    """(N, W + 1, H + 1) uint32 summed-area table of the SUMMED counts, one byte each (open: not a known
    obstacle; frontier: explored, open, with an unexplored 4-neighbour on the map): entry [x, y] holds
    the counts of the cells [0, x) x [0, y). Counts overflow from byte to byte and wrap, but a pixel's
    four-corner difference is exact (arithmetic modulo 2^32; none of its counts is over 81 < 256, so
    nothing carries; the bytes are in the machine's order both ways)."""
    n, w, h = explored.shape
    table = np.zeros((n, w + 1, h + 1, len(SUMMED)), dtype=np.uint8)
    cells = table[:, 1:, 1:]
    unexplored = ~explored
    cells[..., 0] = unexplored
    np.logical_not(obstacles, out=cells[..., 1], casting="unsafe")
    cells[..., 2] = free
    near = np.zeros_like(unexplored)
    near[:, 1:] = unexplored[:, :-1]
    near[:, :-1] |= unexplored[:, 1:]
    near[:, :, 1:] |= unexplored[:, :, :-1]
    near[:, :, :-1] |= unexplored[:, :, 1:]
    near &= explored
    np.greater(near, obstacles, out=cells[..., 3], casting="unsafe")  # and not an obstacle
    result: np.ndarray = table.view(np.uint32)[..., 0]
    np.cumsum(result, axis=1, out=result)
    np.cumsum(result, axis=2, out=result)
    return result


def pixel_sums(table: np.ndarray, rows: np.ndarray, pos: np.ndarray, side: int, margin: int = MARGIN) -> np.ndarray:
    """(N, scales, G, G, 4) uint8: the SUMMED counts of the pixels of each decider's crops and of
    `margin` pixels beyond them on every side (G = side + 2 margin), from a summed_cells table (M, W +
    1, H + 1); rows (N,) the table's row of each decider, pos (N, 2) its cell. Four corners a pixel."""
    _, w1, h1 = table.shape
    edges = pos[:, :, None, None] + pixel_edges(side, margin)  # (N, 2, scales, G + 1)
    np.maximum(edges, 0, out=edges)
    xs = np.minimum(edges[:, 0], w1 - 1)  # on the map
    xs *= h1
    xs += (rows * (w1 * h1))[:, None, None]
    flat = xs[:, :, :, None] + np.minimum(edges[:, 1], h1 - 1)[:, :, None, :]
    corners = np.take(table.reshape(-1), flat)
    across = corners[:, :, 1:] - corners[:, :, :-1]
    sums = across[..., 1:] - across[..., :-1]
    grid = side + 2 * margin
    result: np.ndarray = sums.view(np.uint8).reshape(len(rows), len(CELLS_PER_PIXEL), grid, grid, len(SUMMED))
    return result


def _byte_cells() -> np.ndarray:
    """(256,) uint64: byte value v spread over 8 bytes, byte i holding bit i of v, in the machine's
    byte order, so that a view as uint8 reads one cell a byte."""
    spread: np.ndarray = np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1, bitorder="little")
    result: np.ndarray = spread.view(np.uint64)[:, 0]
    return result


BYTE_CELLS = _byte_cells()
PLANES = UNREACHED.bit_length()  # bit planes of a step count
PLANE_SHIFTS = np.arange(PLANES, dtype=np.uint64)[:, None]
STEP_BITS = [tuple(j for j in range(PLANES) if step >> j & 1) for step in range(UNREACHED + 1)]  # each count's planes


@lru_cache(maxsize=16)
def _source_bits(n: int, x: int, y: int, source: tuple[int, int]) -> int:
    """The bits of pixel_steps' grids (N, X + 2, Y + 2) set at `source` of every grid."""
    grid = np.zeros((n, x + 2, y + 2), dtype=bool)
    grid[:, source[0] + 1, source[1] + 1] = True
    return int.from_bytes(np.packbits(grid, axis=None, bitorder="little").tobytes(), "little")


def pixel_steps(passable: np.ndarray, source: tuple[int, int], limit: int = DISTANCE_CELLS) -> np.ndarray:
    """(N, X, Y) uint8: 4-connected steps from the cell `source` of each grid over the `passable` (N,
    X + 2, Y + 2) bool cells inside its one-cell border (the border does not pass; the source does,
    whatever `passable` says), UNREACHED where no path of fewer than `limit` steps exists (limit <=
    UNREACHED).

    All N grids are one Python integer, a bit a cell: a layer of the BFS is a few shifts, ORs and ANDs
    over all of them at once (tens of ns each on a few grids, where a numpy call costs ~1 us). Each
    layer's new cells are ORed into the bit planes of their step count; a table lookup per plane byte
    turns the planes into one count a byte."""
    n, x, line = passable.shape
    count = passable.size
    size = (count + 7) // 8
    reached = _source_bits(n, x - 2, line - 2, source)
    open_ = int.from_bytes(np.packbits(passable, axis=None, bitorder="little").tobytes(), "little") | reached
    unreached = open_ ^ reached
    planes = [0] * PLANES  # bit j of each cell's steps
    new = reached
    for step in range(1, limit):
        new = ((new << 1) | (new >> 1) | (new << line) | (new >> line)) & unreached
        if not new:
            break
        unreached ^= new
        for j in STEP_BITS[step]:
            planes[j] |= new
    missed = unreached | (((1 << count) - 1) ^ open_)  # UNREACHED: every bit set
    data = b"".join((plane | missed).to_bytes(size, "little") for plane in planes)
    spread = np.take(BYTE_CELLS, np.frombuffer(data, dtype=np.uint8).reshape(PLANES, size))
    spread <<= PLANE_SHIFTS
    steps: np.ndarray = np.bitwise_or.reduce(spread, axis=0).view(np.uint8)[:count]
    return steps.reshape(n, x, line)[:, 1:-1, 1:-1]


def pixel_distances(counts: np.ndarray, side: int, margin: int = MARGIN) -> np.ndarray:
    """(N, scales, S, S) float32: the distance channel of each crop, from pixel_sums' counts (G = S + 2
    margin pixels a side): a BFS from the vehicle's pixel over each scale's G x G pixels, a pixel
    passable where some cell of it is open (on the map, not a known obstacle); the pixel steps times
    the scale's cells, less half a pixel along each axis the pixel lies off the vehicle's (its nearest
    cell, as on an open map), / DISTANCE_CELLS, 1 at most and where unreached."""
    n, scales, grid = counts.shape[:3]
    passable = np.zeros((n * scales, grid + 2, grid + 2), dtype=bool)
    np.greater(counts[..., SUMMED.index("open")].reshape(n * scales, grid, grid), 0, out=passable[:, 1:-1, 1:-1])
    centre = margin + side // 2
    steps = pixel_steps(passable, (centre, centre)).reshape(n, scales, grid, grid)
    crop = slice(margin, margin + side)
    table, index = distance_values(side)
    result: np.ndarray = np.take(table, steps[:, :, crop, crop] * np.intp(side * side) + index)
    return result


def vehicle_channels(beliefs: Beliefs, obs: np.ndarray) -> None:
    """Write the searching and holding channels of every scale of the observations `obs` (N, 24, S, S):
    the other vehicles each decider knows of, counted per pixel. Python arithmetic on Beliefs.crews
    for a few deciders, a bincount for more."""
    n, side = obs.shape[0], obs.shape[2]
    scales, per_scale, half = len(CELLS_PER_PIXEL), len(SCALE_CHANNELS), side // 2
    searching = SCALE_CHANNELS.index("searching")  # then holding
    channels = obs[:, : scales * per_scale].reshape(n, scales, per_scale, side, side)[:, :, searching : searching + 2]
    crews = beliefs.crews
    if crews is not None:
        channels[...] = 0
        flat = obs.reshape(-1)
        for i, ((x, y), _, seen) in enumerate(crews):
            for ox, oy, holding in seen:
                for s, cells in enumerate(CELLS_PER_PIXEL):
                    px = (ox - x + half * cells + cells // 2) // cells
                    py = (oy - y + half * cells + cells // 2) // cells
                    if 0 <= px < side and 0 <= py < side:
                        flat[((i * CHANNELS + s * per_scale + searching + holding) * side + px) * side + py] += 1
        return
    positions = beliefs.positions.reshape(n, -1, 2)
    rel = positions - beliefs.pos.reshape(n, 1, 2)  # (N, V, 2)
    size = SCALES[:, None, None, None]
    pixel = np.floor_divide(rel + half * size + size // 2, size)  # (scales, N, V, 2)
    seen = beliefs.others.reshape(n, -1) & np.logical_and.reduce((pixel >= 0) & (pixel < side), axis=-1)
    kind = beliefs.hovering.reshape(n, -1).astype(np.int64)  # 1: holding
    scale = np.arange(scales)[:, None, None]
    flat_index = (((np.arange(n)[:, None] * scales + scale) * 2 + kind) * side + pixel[..., 0]) * side
    flat_index = flat_index + pixel[..., 1]
    counts = np.bincount(flat_index[seen], minlength=n * scales * 2 * side * side)
    channels[...] = counts.reshape(n, scales, 2, side, side)


def shared_rows(beliefs: Beliefs) -> np.ndarray:
    """(N,) the flat index of a decider with the same maps as each decider (explored, obstacles,
    targets, and the vehicles' believed cells and hovering, so the same free targets): the episode's
    first decider where they all equal its, else the decider itself. Bytes compared in Python for a
    few deciders (one numpy call costs more than comparing a map's bytes)."""
    b, u = beliefs.batch, beliefs.deciders
    grids = (beliefs.explored, beliefs.obstacles, beliefs.targets, beliefs.positions, beliefs.hovering)
    if b * u <= SHARE_FEW:
        flat = []
        for e in range(b):
            first = [grid[e, 0].tobytes() for grid in grids]
            flat += [e * u] + [
                e * u if all(grid[e, d].tobytes() == f for grid, f in zip(grids, first)) else e * u + d
                for d in range(1, u)
            ]
        return np.array(flat)
    rows = np.arange(b * u).reshape(b, u)
    same = np.ones((b, u - 1), dtype=bool)
    for grid in grids:
        same &= ~np.any((grid[:, 1:] != grid[:, :1]).reshape(b, u - 1, -1), axis=2)
    rows[:, 1:] = np.where(same, rows[:, :1], rows[:, 1:])
    result: np.ndarray = rows.reshape(-1)
    return result


def pixel_counts(beliefs: Beliefs) -> tuple[np.ndarray, np.ndarray]:
    """pixel_sums of every decider (N = B x U; S = beliefs.settings.window, margin MARGIN) and (N,) the
    free targets each knows. Deciders with the same maps share one summed table from SHARE_CELLS."""
    b, u, w, h = beliefs.explored.shape
    n = b * u
    maps = [grid.reshape(n, w, h) for grid in (beliefs.explored, beliefs.obstacles, beliefs.targets)]
    own = rows = np.arange(n)
    if u > 1 and (n <= SHARE_FEW or n * w * h >= SHARE_CELLS):
        shared = shared_rows(beliefs)
        own = np.flatnonzero(shared == rows)  # the deciders whose maps are summed
        if len(own) < n:
            maps, rows = [grid[own] for grid in maps], np.searchsorted(own, shared)
    free = free_targets(beliefs, maps[2], own)
    counts = pixel_sums(summed_cells(maps[0], maps[1], free), rows, beliefs.pos.reshape(n, 2), beliefs.settings.window)
    free_known: np.ndarray = free.reshape(len(free), -1).sum(axis=1)[rows]
    return counts, free_known


def observe_scales(beliefs: Beliefs) -> np.ndarray:
    """(B, U, 24, S, S) float32 observations of every decider (S = beliefs.settings.window)."""
    b, u = beliefs.batch, beliefs.deciders
    n, side, v = b * u, beliefs.settings.window, beliefs.vehicles
    scales, per_scale = len(CELLS_PER_PIXEL), len(SCALE_CHANNELS)
    counts, free_known = pixel_counts(beliefs)
    obs = np.empty((n, CHANNELS, side, side), dtype=np.float32)
    block = obs[:, : scales * per_scale].reshape(n, scales, per_scale, side, side)
    block[:, :, 6] = pixel_distances(counts, side)
    counts = counts[:, :, MARGIN : MARGIN + side, MARGIN : MARGIN + side]
    np.divide(counts[..., 0], AREA, out=block[:, :, 0])
    np.divide(AREA - counts[..., 1], AREA, out=block[:, :, 1])
    block[:, :, 2] = counts[..., 2]
    np.not_equal(counts[..., 3], 0, out=block[:, :, 5])
    vehicle_channels(beliefs, obs)
    searching = v - beliefs.hovering.reshape(n, v).sum(axis=1)
    limit = beliefs.step_limit
    scalar = obs[:, scales * per_scale :]
    surplus = np.maximum((free_known - searching) / v, -1.0)
    np.minimum(surplus, 1.0, out=surplus)
    scalar[:, 0] = surplus[:, None, None]
    scalar[:, 1] = 1.0 if limit is None else max(limit - beliefs.step, 0) / limit
    scalar[:, 2] = v / SWARM_UNIT
    return obs.reshape(b, u, CHANNELS, side, side)
