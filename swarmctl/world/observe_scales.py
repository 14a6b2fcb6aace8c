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
    6 distance     BFS steps from the vehicle over cells not known        min   (off the map: 1)
                   obstacles (unexplored ones pass), / DISTANCE_CELLS, 1 when unreachable or farther

Counts, not "any", where how many matters: three targets in a 9 x 9 pixel draw more than one. The
frontier is "any" (a frontier cell is a place to go; at 9 cells a pixel its fraction is tiny), the
distance the nearest cell's (how soon the vehicle can be in that pixel).

Then three scalars, each a constant S x S plane (channels 21-23), so that one (24, S, S) tensor per
vehicle goes through the replay memory and the batching as the other variants' do; the network
(swarmctl.policy.qnet.ScalesQNetwork) reads one pixel of each and joins them to its head after the
convolutions:

    21 (free targets known - vehicles not believed hovering) / N, clipped to [-1, 1]
    22 steps left / step limit (Beliefs.step_limit; 1 when the beliefs do not know the limit)
    23 N / 10, N the swarm's vehicles

Everything comes from Beliefs (what each vehicle knows), batched over every decider in numpy calls
whose number does not grow with the batch (one set per scale), so the simulator and the field,
which both build Beliefs, observe the same tensor bit for bit; a decider's observation never depends
on the others in the batch (sums are of small integers, exact in float32). `remove_taken` does not
apply: the free-target channel already leaves out the targets vehicles hover on.
"""

from __future__ import annotations

import numpy as np

from swarmctl.world.beliefs import Beliefs

CELLS_PER_PIXEL = (1, 3, 9)  # each 3 x the last, so each pixel is 3 x 3 of the last scale's (pyramid)
SCALE_CHANNELS = ("unexplored", "blocked", "free targets", "searching", "holding", "frontier", "distance")
SCALARS = ("free targets less searching vehicles", "steps left", "swarm size")
CHANNELS = len(CELLS_PER_PIXEL) * len(SCALE_CHANNELS) + len(SCALARS)
DISTANCE_CELLS = 100  # path steps that read 1 (the BFS stops there)
SWARM_UNIT = 10  # vehicles that read 1 in the swarm-size scalar
PAD = max(CELLS_PER_PIXEL)  # cells of fill round each map: the widest pixel off the map reads fill only
COUNT_FILL = np.array([0, 1, 0], dtype=np.uint8)  # unexplored, blocked, free targets: summed over a pixel
MOST_FILL = np.array([0, -DISTANCE_CELLS], dtype=np.int8)  # frontier, minus the path steps: their maximum
STOP_TEST = 4  # BFS layers between two tests for its end


def pixel_centres(pos: np.ndarray, side: int, cells: int) -> np.ndarray:
    """(N, side) the middle cell along one axis of each pixel of a crop of `side` pixels of `cells` cells
    centred on `pos` (N,): the vehicle's cell is the middle of pixel side // 2."""
    result: np.ndarray = pos[:, None] + cells * (np.arange(side) - side // 2)
    return result


def frontier_cells(explored: np.ndarray, obstacles: np.ndarray) -> np.ndarray:
    """(N, W, H) bool: explored cells not known obstacles with an unexplored 4-neighbour on the map."""
    unexplored = ~explored
    near = np.zeros_like(unexplored)
    near[:, 1:] |= unexplored[:, :-1]
    near[:, :-1] |= unexplored[:, 1:]
    near[:, :, 1:] |= unexplored[:, :, :-1]
    near[:, :, :-1] |= unexplored[:, :, 1:]
    result: np.ndarray = explored & ~obstacles & near
    return result


def path_steps(obstacles: np.ndarray, pos: np.ndarray, limit: int = DISTANCE_CELLS) -> np.ndarray:
    """(N, W, H) int16: 4-connected steps from `pos` (N, 2) round the known obstacles (unexplored cells
    pass, the map's edge does not), `limit` at `limit` steps and beyond and where no path is known.

    The BFS of swarmctl.world.paths.grid_distances on flat rows with a blocked border, counting the
    layers each cell has been reached in instead of writing each layer's cells, and testing for the
    end every STOP_TEST layers: fewer numpy calls a layer, which is what a layer costs at a few
    deciders (one run, 2 busy cores: 3 deciders on 50 x 50 maps 1.0 ms against grid_distances' 1.8, 192
    deciders 28 ms against 89)."""
    n, w, h = obstacles.shape
    if not np.logical_or.reduce(obstacles, axis=None):  # nothing in the way: the Manhattan distance
        dx = np.abs(np.arange(w)[None, :, None] - pos[:, 0, None, None])
        dy = np.abs(np.arange(h)[None, None, :] - pos[:, 1, None, None])
        manhattan: np.ndarray = np.minimum(dx + dy, limit).astype(np.int16)
        return manhattan
    line = h + 2
    padded = np.zeros((n, w + 2, line), dtype=bool)
    padded[:, 1:-1, 1:-1] = ~obstacles
    open_ = padded.reshape(n, -1)
    reached = np.zeros_like(open_)
    sources = (np.arange(n), (pos[:, 0] + 1) * line + pos[:, 1] + 1)
    reached[sources] = open_[sources] = True  # the vehicle's own cell passes, whatever is known of it
    grown = np.empty_like(reached)
    count = np.zeros(open_.shape, dtype=np.uint8)  # layers a cell was reached in, of `counted`
    counted, size = 0, -1
    for layer in range(limit):
        if layer % STOP_TEST == 0:
            now = int(np.count_nonzero(reached))
            if now == size:  # no cell reached since the last test: the later layers are all the same
                break
            size = now
        np.add(count, reached, out=count, casting="unsafe")
        counted += 1
        np.copyto(grown, reached)
        grown[:, 1:] |= reached[:, :-1]
        grown[:, :-1] |= reached[:, 1:]
        grown[:, line:] |= reached[:, :-line]
        grown[:, :-line] |= reached[:, line:]
        grown &= open_
        reached, grown = grown, reached
    np.add(count, reached, out=count, casting="unsafe")  # a cell first reached at layer d counts counted + 1 - d
    steps = np.where(count > 0, counted + 1 - count.astype(np.int16), limit).astype(np.int16)
    result: np.ndarray = steps.reshape(n, w + 2, line)[:, 1:-1, 1:-1]
    return result


def spread(level: np.ndarray, step: int, combine: np.ufunc) -> np.ndarray:
    """(N, C, X - 2 step, Y - 2 step): `combine` over the 3 x 3 cells `step` apart round each cell of
    `level` (N, C, X, Y); index i of the result is cell i + step of `level`."""
    along_x = combine(level[:, :, : -2 * step], level[:, :, step:-step])
    combine(along_x, level[:, :, 2 * step :], out=along_x)
    result: np.ndarray = combine(along_x[..., : -2 * step], along_x[..., step:-step])
    combine(result, along_x[..., 2 * step :], out=result)
    return result


def pyramid(layers: np.ndarray, combine: np.ufunc) -> list[np.ndarray]:
    """The padded layers (N, C, W + 2 PAD, H + 2 PAD) combined over each pixel size centred on each cell:
    1 cell (the layers), 3 x 3, and 9 x 9 (3 x 3 of the 3 x 3, 3 cells apart)."""
    three = spread(layers, 1, combine)
    return [layers, three, spread(three, 3, combine)]


def sampled(level: np.ndarray, xs: np.ndarray, ys: np.ndarray, cells: int) -> np.ndarray:
    """(N, S, S, C) the pyramid level of `cells` cells at the pixels centred on xs, ys (N, S). A centre
    farther off the map than the pixel's half is moved to the first wholly off it: fill only."""
    half = cells // 2
    w, h = level.shape[2] - 2 * PAD + 2 * half, level.shape[3] - 2 * PAD + 2 * half  # the map's
    ix = np.clip(xs, -half - 1, w + half) + PAD - half
    iy = np.clip(ys, -half - 1, h + half) + PAD - half
    result: np.ndarray = level[np.arange(len(level))[:, None, None], :, ix[:, :, None], iy[:, None, :]]
    return result


def vehicle_counts(beliefs: Beliefs, side: int) -> np.ndarray:
    """(N, scales, 2, S, S) float32: the other vehicles each decider knows of, per pixel of each
    scale: searching, holding."""
    n = beliefs.batch * beliefs.deciders
    positions = beliefs.positions.reshape(n, -1, 2)
    rel = positions - beliefs.pos.reshape(n, 1, 2)  # (N, V, 2)
    cells = np.array(CELLS_PER_PIXEL)[:, None, None, None]
    pixel = np.floor_divide(rel + (side // 2) * cells + cells // 2, cells)  # (scales, N, V, 2)
    seen = beliefs.others.reshape(n, -1) & np.logical_and.reduce((pixel >= 0) & (pixel < side), axis=-1)
    kind = beliefs.hovering.reshape(n, -1).astype(np.int64)  # 1: holding
    scale = np.arange(len(CELLS_PER_PIXEL))[:, None, None]
    flat = (((np.arange(n)[:, None] * len(CELLS_PER_PIXEL) + scale) * 2 + kind) * side + pixel[..., 0]) * side
    flat = flat + pixel[..., 1]
    counts = np.bincount(flat[seen], minlength=n * len(CELLS_PER_PIXEL) * 2 * side * side)
    result: np.ndarray = counts.astype(np.float32).reshape(n, len(CELLS_PER_PIXEL), 2, side, side)
    return result


def scalars(beliefs: Beliefs, free: np.ndarray) -> np.ndarray:
    """(N, 3) float32: the three scalars of the module docstring; free (N, W, H) the free targets."""
    n = free.shape[0]
    vehicles = beliefs.vehicles
    searching = np.count_nonzero(~beliefs.hovering.reshape(n, -1), axis=1)
    free_count = np.count_nonzero(free.reshape(n, -1), axis=1)
    surplus = np.clip((free_count - searching) / vehicles, -1.0, 1.0)
    limit = beliefs.step_limit
    left = 1.0 if limit is None else max(limit - beliefs.step, 0) / limit
    out = np.empty((n, len(SCALARS)), dtype=np.float32)
    out[:, 0] = surplus
    out[:, 1] = left
    out[:, 2] = vehicles / SWARM_UNIT
    return out


def observe_scales(beliefs: Beliefs) -> np.ndarray:
    """(B, U, 24, S, S) float32 observations of every decider (S = beliefs.settings.window)."""
    b, u, w, h = beliefs.explored.shape
    n, side = b * u, beliefs.settings.window
    explored = beliefs.explored.reshape(n, w, h)
    obstacles = beliefs.obstacles.reshape(n, w, h)
    free = (beliefs.targets & ~beliefs.hover_cells).reshape(n, w, h)
    pos = beliefs.pos.reshape(n, 2)
    counted = np.empty((n, len(COUNT_FILL), w + 2 * PAD, h + 2 * PAD), dtype=np.uint8)
    counted[...] = COUNT_FILL[:, None, None]
    inside = counted[:, :, PAD : PAD + w, PAD : PAD + h]
    np.logical_not(explored, out=inside[:, 0], casting="unsafe")
    inside[:, 1] = obstacles
    inside[:, 2] = free
    most = np.empty((n, len(MOST_FILL), w + 2 * PAD, h + 2 * PAD), dtype=np.int8)
    most[...] = MOST_FILL[:, None, None]
    inside = most[:, :, PAD : PAD + w, PAD : PAD + h]
    inside[:, 0] = frontier_cells(explored, obstacles)
    np.negative(path_steps(obstacles, pos), out=inside[:, 1], casting="unsafe")
    sums, maxima = pyramid(counted, np.add), pyramid(most, np.maximum)
    vehicles = vehicle_counts(beliefs, side)
    per_scale = len(SCALE_CHANNELS)
    obs = np.empty((n, CHANNELS, side, side), dtype=np.float32)
    for i, cells in enumerate(CELLS_PER_PIXEL):
        xs, ys = pixel_centres(pos[:, 0], side, cells), pixel_centres(pos[:, 1], side, cells)
        summed = sampled(sums[i], xs, ys, cells).transpose(0, 3, 1, 2)  # (N, 3, S, S)
        largest = sampled(maxima[i], xs, ys, cells).transpose(0, 3, 1, 2)  # (N, 2, S, S)
        block = obs[:, i * per_scale : (i + 1) * per_scale]
        np.divide(summed[:, :2], np.float32(cells * cells), out=block[:, :2], dtype=np.float32)
        block[:, 2] = summed[:, 2]
        block[:, 3:5] = vehicles[:, i]
        block[:, 5] = largest[:, 0]
        np.divide(largest[:, 1], np.float32(-DISTANCE_CELLS), out=block[:, 6], dtype=np.float32)
    obs[:, len(CELLS_PER_PIXEL) * per_scale :] = scalars(beliefs, free)[:, :, None, None]
    return obs.reshape(b, u, CHANNELS, side, side)
