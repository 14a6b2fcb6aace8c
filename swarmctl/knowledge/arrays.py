"""The arrays behind every Knowledge, and the position keys they hold.

    arrays = StackArrays(1, 50, 50)              # one agent's rows of a 50 x 50 grid
    key = position_key(step, cell, on_target)   # orders like Position.order()

`StackArrays` holds the state of `rows` agents' knowledge: explored, phi_q and obstacle (N, W, H), the
positions each knows (N, 256: one int64 key per vehicle id, -1 unknown), the earliest step of each
target cell it knows (N, W, H; NEVER where none), the cells it sensed itself and has not published yet
(pending), and its exchange's push-rule bookkeeping (learned_at, noted). A
`swarmctl.knowledge.model.Knowledge` made on its own holds StackArrays of one row; the agents of a
ground-mode process hold one row each of a `swarmctl.knowledge.stack.KnowledgeStack` (these arrays,
with the rows' Knowledge views and the batch merge). Nothing here knows Knowledge, Delta or Detection,
so model.py and stack.py both build on it.
"""

from __future__ import annotations

import numpy as np

MAX_IDS = 256  # vehicle ids 0..255 (the codec's u8 sender)
UNKNOWN = -1  # a position key: no position known
NEVER = np.iinfo(np.int64).max  # a target step: no target known there


MAX_SIDE = 1 << 12  # cells per side a position key holds
_XY = 0xFFF


STEP_SHIFT = 25  # a position key's step is key >> STEP_SHIFT


def position_key(step: int, cell: tuple[int, int], on_target: bool) -> int:
    """An int64 that orders like Position.order(): step (< 2^38), then x, then y (< 4096), then
    on_target."""
    if not 0 <= int(step) < 1 << 38:
        raise ValueError(f"step {step} must be 0..2^38 - 1")
    return (int(step) << STEP_SHIFT) | (int(cell[0]) << 13) | (int(cell[1]) << 1) | int(bool(on_target))


def split_key(key: int) -> tuple[int, tuple[int, int], bool]:
    """The (step, cell, on_target) of a position key."""
    key = int(key)
    return key >> STEP_SHIFT, ((key >> 13) & _XY, (key >> 1) & _XY), bool(key & 1)


def key_cells(keys: np.ndarray) -> np.ndarray:
    """(..., 2) cells of an array of position keys (-1, -1 where unknown)."""
    cells = np.stack([(keys >> 13) & _XY, (keys >> 1) & _XY], axis=-1)
    return np.where((keys >= 0)[..., None], cells, -1)


class StackArrays:
    """The state of `rows` agents' knowledge of a width x height grid (see the module docstring)."""

    def __init__(self, rows: int, width: int, height: int, ids: int = MAX_IDS):
        if rows < 1:
            raise ValueError("a knowledge stack holds at least one agent")
        if not (1 <= width <= MAX_SIDE and 1 <= height <= MAX_SIDE):
            raise ValueError(f"grid {width} x {height} must have 1..{MAX_SIDE} cells a side")
        self.rows, self.width, self.height, self.ids = int(rows), int(width), int(height), int(ids)
        shape = (self.rows, self.width, self.height)
        self.explored = np.zeros(shape, dtype=bool)
        self.phi_q = np.zeros(shape, dtype=np.uint8)  # 0 where unexplored
        self.obstacle = np.zeros(shape, dtype=bool)  # False where unexplored
        self.position = np.full((self.rows, self.ids), UNKNOWN, dtype=np.int64)
        self.target_step = np.full(shape, NEVER, dtype=np.int64)
        self.pending = np.zeros(shape, dtype=bool)  # own finds not yet published (Knowledge.take_delta)
        # the push rule's bookkeeping of each row's exchange (swarmctl.knowledge.exchange): the step at
        # which each cell became known (NEVER: not yet), and where that was noted
        self.learned_at = np.full(shape, NEVER, dtype=np.int64)
        self.noted = np.zeros(shape, dtype=bool)
