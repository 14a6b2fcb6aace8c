"""The five grid moves, in the paper's order. One table shared by simulator, planners and controller.

Axes: cell (x, y), x grows east, y grows north, (0, 0) is the south-west cell.
"""

from functools import lru_cache

import numpy as np

STAY, NORTH, EAST, SOUTH, WEST = range(5)
MOVE_NAMES = ("stay", "north", "east", "south", "west")
N_ACTIONS = 5

#: MOVES[a] is the (dx, dy) of action a.
MOVES = np.array([(0, 0), (0, 1), (1, 0), (0, -1), (-1, 0)], dtype=np.int64)
MOVES.setflags(write=False)


@lru_cache(maxsize=16)
def move_table(width: int, height: int) -> np.ndarray:
    """(W * H, 5) int: the flat cell (x * H + y) each move leads to from each cell, -1 off the map."""
    x, y = np.divmod(np.arange(width * height), height)
    dx, dy = x[:, None] + MOVES[:, 0], y[:, None] + MOVES[:, 1]
    inside = (dx >= 0) & (dx < width) & (dy >= 0) & (dy < height)
    table = np.where(inside, dx * height + dy, -1)
    table.setflags(write=False)
    return table


@lru_cache(maxsize=16)
def cell_table(width: int, height: int) -> np.ndarray:
    """(W * H, 2) int: the (x, y) of each flat cell x * H + y."""
    table = np.stack(np.divmod(np.arange(width * height, dtype=np.int64), height), axis=-1)
    table.setflags(write=False)
    return table


@lru_cache(maxsize=64)
def block_starts(n: int, size: int) -> np.ndarray:
    """(n,) int: 0, size, 2 size, ...: where each of n blocks of `size` elements starts in a flat
    array (offsets for flat gathers and scatters over a batch; read-only)."""
    starts = np.arange(0, n * size, size)
    starts.setflags(write=False)
    return starts
