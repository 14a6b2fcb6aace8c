"""The knowledge of many agents in stacked arrays, merged for all of them at once.

    stack = KnowledgeStack(50, 50, 50)           # 50 agents on a 50 x 50 grid
    kn = stack.knowledge(3)                      # agent row 3: a Knowledge whose arrays are views
    stack.merge_batch(messages, receivers)       # deltas and detections into every receiver, vectorised

Every `swarmctl.knowledge.model.Knowledge` keeps its state in one row of a stack's arrays
(swarmctl.knowledge.arrays.StackArrays, which a KnowledgeStack is): explored, phi_q and
obstacle (N, W, H), the positions it knows (N, 256: one column per vehicle id, each an int64 key that
orders like Position.order(); -1 unknown), the earliest step of each target cell it knows (N, W, H;
NEVER where none) and the cells it sensed itself and has not published yet (pending). The stack also
holds each row's exchange bookkeeping for the push rule (learned_at, noted: KnowledgeExchange), so one
round's step of every agent of a process is a few array operations (swarmctl.knowledge.stepping). A
Knowledge made on its own holds arrays of one row; the agents of a ground-mode process
(swarmctl.knowledge.bus with a stack) hold one row each of the same stack, so what the bus delivers to
all of them is merged in a few numpy operations instead of one Python merge per agent and message.
The merges are the same join (logical or, max, newest position, earliest target step), so the result
is exactly that of merging each message into each receiver one by one, in any order.
"""

from __future__ import annotations

import numpy as np

from swarmctl.knowledge.arrays import (
    MAX_IDS,
    MAX_SIDE,
    NEVER,
    UNKNOWN,
    StackArrays,
    key_cells,
    position_key,
    split_key,
)
from swarmctl.knowledge.model import Delta, Detection, Knowledge

# the keys and constants, defined with the arrays (swarmctl.knowledge.arrays), importable from here too
__all__ = ["MAX_IDS", "MAX_SIDE", "NEVER", "UNKNOWN", "KnowledgeStack", "key_cells", "position_key", "split_key"]


class KnowledgeStack(StackArrays):
    """The state of `rows` agents' knowledge of a width x height grid (see the module docstring)."""

    def __init__(self, rows: int, width: int, height: int, ids: int = MAX_IDS):
        super().__init__(rows, width, height, ids)
        self._views: dict[int, Knowledge] = {}

    def knowledge(self, row: int, vehicle_id: int | None = None) -> Knowledge:
        """The Knowledge of agent `row` (vehicle id `row` unless given); one per row."""
        if not 0 <= row < self.rows:
            raise ValueError(f"row {row} is outside a stack of {self.rows}")
        if row in self._views:
            raise ValueError(f"row {row} of the knowledge stack is taken already")
        kn = Knowledge(self.width, self.height, row if vehicle_id is None else vehicle_id, stack=(self, row))
        self._views[row] = kn
        return kn

    def merge_batch(self, messages: list[Delta | Detection], receivers: np.ndarray) -> None:
        """Merge each message i into the rows where receivers[i] (M, rows) is True, all at once: the
        same result as Knowledge.merge of each message into each of its receivers."""
        if not messages:
            return
        receivers = np.asarray(receivers, dtype=bool).reshape(len(messages), self.rows)
        senders = np.array([m.sender for m in messages], dtype=np.int64)
        keys = np.array(
            [UNKNOWN if m.cell is None else position_key(m.step, m.cell, m.on_target) for m in messages],
            dtype=np.int64,
        )
        mi, ri = np.nonzero(receivers)
        np.maximum.at(self.position, (ri, senders[mi]), keys[mi])
        deltas = [i for i, m in enumerate(messages) if isinstance(m, Delta)]
        detections = [i for i, m in enumerate(messages) if not isinstance(m, Delta)]
        delta_messages = [m for m in messages if isinstance(m, Delta)]  # in the order of `deltas`
        detection_messages = [m for m in messages if not isinstance(m, Delta)]  # of `detections`
        if deltas:
            cells = [m.cells for m in delta_messages]
            x, y, owner = self._cells(cells, deltas)
            ci, ri = np.nonzero(receivers[owner])
            if ci.size:
                xs, ys = x[ci], y[ci]
                phi = np.concatenate([m.phi for m in delta_messages])
                obstacle = np.concatenate([m.obstacle for m in delta_messages])
                self.explored[ri, xs, ys] = True
                np.maximum.at(self.phi_q, (ri, xs, ys), phi[ci])
                hit = obstacle[ci]
                self.obstacle[ri[hit], xs[hit], ys[hit]] = True
        if detections:
            x, y, owner = self._cells([m.targets for m in detection_messages], detections)
            steps = np.array([m.step for m in detection_messages], dtype=np.int64)
            ci, ri = np.nonzero(receivers[owner])
            if ci.size:
                np.minimum.at(self.target_step, (ri, x[ci], y[ci]), steps[np.searchsorted(detections, owner[ci])])

    def _cells(self, parts: list[np.ndarray], index: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """x, y of the concatenated (K_i, 2) cell lists and the message index each cell came from."""
        cells = np.concatenate(parts).reshape(-1, 2)
        if cells.size and (
            (cells < 0).any() or (cells[:, 0] >= self.width).any() or (cells[:, 1] >= self.height).any()
        ):
            raise ValueError(f"cells outside the {self.width} x {self.height} grid")
        owner = np.repeat(np.asarray(index, dtype=np.int64), [len(p) for p in parts])
        return cells[:, 0], cells[:, 1], owner
