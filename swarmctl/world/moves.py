"""The five grid moves, in the paper's order. One table shared by simulator, planners and controller.

Axes (CONTRACTS): cell (x, y), x grows east, y grows north, (0, 0) is the south-west cell.
"""

import numpy as np

STAY, NORTH, EAST, SOUTH, WEST = range(5)
MOVE_NAMES = ("stay", "north", "east", "south", "west")
N_ACTIONS = 5

#: MOVES[a] is the (dx, dy) of action a.
MOVES = np.array([(0, 0), (0, 1), (1, 0), (0, -1), (-1, 0)], dtype=np.int64)
MOVES.setflags(write=False)
