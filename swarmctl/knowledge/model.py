"""One vehicle's knowledge of the search grid, and the messages that change it.

`Knowledge` is the controller's view of the world (the simulator keeps the same state for B x U
vehicles in arrays; this is the batch-of-one form): which cells are explored, their value phi and
obstacle flag where explored, where each vehicle was last known to be, and the target cells reported
by detections. Arrays are indexed [x, y]. Its state is one row of a
swarmctl.knowledge.arrays.StackArrays: arrays of its own, or the swarmctl.knowledge.stack.KnowledgeStack
the agents of a ground-mode process share (merged for all of them at once).

phi is stored quantised to uint8 (`PHI_LEVELS` = 255 steps over [0, 1]) because that is how the
MAVLink codec carries it: a vehicle's own observations and those it received agree bit for bit.
The rounding error is at most 1/510, well below the value map's 0.01 cut-off.

Merge semantics (a join semilattice, so merging is idempotent, commutative and associative):
- explored cells are only ever added (logical or);
- a cell's phi and obstacle flag are fixed truth: reports are combined with max / or, which is
  deterministic even if two reports disagreed;
- a vehicle's position is replaced only by a report with a newer step; reports with equal steps are
  ordered by (x, y, on_target) so every vehicle picks the same one;
- a target cell keeps the earliest step at which it was reported.
"""

from __future__ import annotations

import functools
from collections.abc import Collection, Iterator, Mapping, MutableMapping
from dataclasses import dataclass, field
from typing import Any, Self, TypeGuard

import numpy as np
import numpy.typing as npt

from swarmctl.knowledge.arrays import (
    MAX_IDS,
    NEVER,
    STEP_SHIFT,
    UNKNOWN,
    StackArrays,
    key_cells,
    position_key,
    split_key,
)
from swarmctl.world.beliefs import Beliefs, ObservationSettings, silent_since
from swarmctl.world.observe import observe
from swarmctl.world.scenario import fov_offsets, value_map

PHI_LEVELS = 255
PHI_TOLERANCE = 0.5 / PHI_LEVELS + 1e-6  # how far a quantised phi may be from the exact one


def quantise_phi(phi: np.ndarray | float) -> np.ndarray:
    """phi in [0, 1] to uint8 0..255 (rounded; values outside [0, 1] are clipped)."""
    return np.rint(np.clip(np.asarray(phi, dtype=np.float64), 0.0, 1.0) * PHI_LEVELS).astype(np.uint8)


def dequantise_phi(q: np.ndarray | int) -> np.ndarray:
    """uint8 0..255 back to phi in [0, 1] as float32."""
    return (np.asarray(q, dtype=np.float32) / np.float32(PHI_LEVELS)).astype(np.float32)


@functools.lru_cache(maxsize=32)
def _disc(fov: float) -> tuple[np.ndarray, int]:
    """The disc's offsets (read-only) and its radius in whole cells."""
    offsets = fov_offsets(fov)
    return offsets, int(np.abs(offsets).max(initial=0))


def disc_cells(cell: tuple[int, int], width: int, height: int, fov: float = 3.0) -> np.ndarray:
    """(N, 2) cells of the sensing disc of radius `fov` around `cell` that lie on the grid."""
    offsets, r = _disc(float(fov))
    x, y = int(cell[0]), int(cell[1])
    c = offsets + np.array([x, y], dtype=np.int64)
    if r <= x < width - r and r <= y < height - r:  # the whole disc is on the grid
        return c
    inside = (c[:, 0] >= 0) & (c[:, 0] < width) & (c[:, 1] >= 0) & (c[:, 1] < height)
    return c[inside]


@dataclass(frozen=True)
class Position:
    """Where a vehicle was at `step`; `cell` is None when the vehicle did not know yet."""

    step: int
    cell: tuple[int, int] | None
    on_target: bool = False

    def order(self) -> tuple[int, int, int, bool]:
        """Total order used by merges: newest step first, then a fixed tie-break."""
        cell = self.cell if self.cell is not None else (-1, -1)
        return (self.step, cell[0], cell[1], self.on_target)


def _cells_array(cells: npt.ArrayLike) -> np.ndarray:
    arr = np.asarray(cells, dtype=np.int64)
    return arr.reshape(-1, 2) if arr.size else np.zeros((0, 2), dtype=np.int64)


@dataclass(eq=False)
class Report:
    """What every message carries: who sent it, at which step, and where the sender was then."""

    sender: int
    step: int
    cell: tuple[int, int] | None
    on_target: bool = False

    def __post_init__(self) -> None:
        if self.cell is not None:
            self.cell = (int(self.cell[0]), int(self.cell[1]))
        self.sender, self.step, self.on_target = int(self.sender), int(self.step), bool(self.on_target)

    @property
    def position(self) -> Position:
        return Position(self.step, self.cell, self.on_target)

    def _same_report(self, other: object) -> TypeGuard[Self]:
        return type(self) is type(other) and (self.sender, self.step, self.cell, self.on_target) == (
            other.sender,
            other.step,
            other.cell,
            other.on_target,
        )


@dataclass(eq=False)
class Delta(Report):
    """Cells explored by `sender` (with their quantised phi and obstacle flag) and the sender's
    position at `step`. A delta with no cells is a position report. `repair`: an answer to a digest or
    a request (the frame's repair flag), whose cells may be any the sender knows; otherwise the cells
    are the sender's own (what the trust checks place: swarmctl.knowledge.trust). Not compared."""

    cells: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    phi: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.uint8))
    obstacle: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    repair: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        self.cells = _cells_array(self.cells)
        self.phi = np.asarray(self.phi, dtype=np.uint8).reshape(-1)
        self.obstacle = np.asarray(self.obstacle, dtype=bool).reshape(-1)
        self.repair = bool(self.repair)
        if not len(self.cells) == len(self.phi) == len(self.obstacle):
            raise ValueError("Delta: cells, phi and obstacle must have the same length")

    def __len__(self) -> int:
        return len(self.cells)

    def __eq__(self, other: object) -> bool:
        return (
            self._same_report(other)
            and np.array_equal(self.cells, other.cells)
            and np.array_equal(self.phi, other.phi)
            and np.array_equal(self.obstacle, other.obstacle)
        )

    def split(self, max_cells: int) -> list[Delta]:
        """Chunks of at most `max_cells` cells, each a complete delta (same sender, step, position)."""
        if len(self) <= max_cells:
            return [self]
        return [
            Delta(
                self.sender,
                self.step,
                self.cell,
                self.on_target,
                self.cells[i : i + max_cells],
                self.phi[i : i + max_cells],
                self.obstacle[i : i + max_cells],
                self.repair,
            )
            for i in range(0, len(self), max_cells)
        ]

    @staticmethod
    def concat(parts: list[Delta]) -> Delta:
        """The inverse of `split` (parts in order)."""
        first = parts[0]
        return Delta(
            first.sender,
            first.step,
            first.cell,
            first.on_target,
            np.concatenate([p.cells for p in parts]),
            np.concatenate([p.phi for p in parts]),
            np.concatenate([p.obstacle for p in parts]),
            first.repair,
        )


@dataclass(eq=False)
class Detection(Report):
    """Target cells found by `sender` (by its detector, or by sensing a cell with phi = 1)."""

    targets: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))

    def __post_init__(self) -> None:
        super().__post_init__()
        self.targets = _cells_array(self.targets)

    def __eq__(self, other: object) -> bool:
        return self._same_report(other) and np.array_equal(self.targets, other.targets)


class PositionTable(MutableMapping[int, Position]):
    """A Knowledge's known positions, vehicle id -> Position, kept as keys in its stack row (ids in
    ascending order; a position without a cell is never stored)."""

    def __init__(self, row: np.ndarray):
        self._row = row

    def __getitem__(self, vehicle: int) -> Position:
        if not isinstance(vehicle, (int, np.integer)) or not 0 <= vehicle < self._row.size or self._row[vehicle] < 0:
            raise KeyError(vehicle)
        step, cell, on_target = split_key(self._row[vehicle])
        return Position(step, cell, on_target)

    def __setitem__(self, vehicle: int, position: Position) -> None:
        if position.cell is None:
            raise ValueError("a known position has a cell")
        if not 0 <= int(vehicle) < self._row.size:
            raise ValueError(f"vehicle id {vehicle} is outside 0..{self._row.size - 1}")
        self._row[int(vehicle)] = position_key(position.step, position.cell, position.on_target)

    def __delitem__(self, vehicle: int) -> None:
        self[vehicle]  # KeyError when unknown
        self._row[vehicle] = UNKNOWN

    def __iter__(self) -> Iterator[int]:
        return iter(np.flatnonzero(self._row >= 0).tolist())

    def __len__(self) -> int:
        return int(np.count_nonzero(self._row >= 0))

    def __repr__(self) -> str:
        return repr(dict(self.items()))


class TargetTable(MutableMapping[tuple[int, int], int]):
    """A Knowledge's known targets, cell (x, y) -> earliest report step, kept in its stack row (cells in
    x, y order)."""

    def __init__(self, steps: np.ndarray):
        self._steps = steps

    def _cell(self, cell: Any) -> tuple[int, int]:  # any key: a wrong one is a KeyError
        try:
            x, y = int(cell[0]), int(cell[1])
        except (TypeError, ValueError, IndexError):
            raise KeyError(cell) from None
        if not (0 <= x < self._steps.shape[0] and 0 <= y < self._steps.shape[1]):
            raise KeyError(cell)
        return x, y

    def __contains__(self, cell: object) -> bool:
        try:
            return bool(self._steps[self._cell(cell)] != NEVER)
        except KeyError:
            return False

    def __getitem__(self, cell: tuple[int, int]) -> int:
        step = self._steps[self._cell(cell)]
        if step == NEVER:
            raise KeyError(cell)
        return int(step)

    def __setitem__(self, cell: tuple[int, int], step: int) -> None:
        try:
            self._steps[self._cell(cell)] = int(step)
        except KeyError:
            raise ValueError(f"target cell {cell} is outside the grid") from None

    def __delitem__(self, cell: tuple[int, int]) -> None:
        self[cell]  # KeyError when unknown
        self._steps[self._cell(cell)] = NEVER

    def __iter__(self) -> Iterator[tuple[int, int]]:
        x, y = np.nonzero(self._steps != NEVER)
        return iter(zip(x.tolist(), y.tolist()))

    def __len__(self) -> int:
        return int(np.count_nonzero(self._steps != NEVER))

    def __repr__(self) -> str:
        return repr(dict(self.items()))


class Knowledge:
    """One vehicle's view of a width x height grid (see the module docstring for merge rules).

    Its state lives in one row of a swarmctl.knowledge.arrays.StackArrays: its own arrays of one row, or
    `stack=(stack, row)`, a row of the KnowledgeStack the agents of a process share (KnowledgeStack.knowledge).
    `explored`, `phi_q` and `obstacle` are views of that row, `positions` and `targets` mappings onto it."""

    def __init__(self, width: int, height: int, vehicle_id: int = 0, *, stack: tuple[StackArrays, int] | None = None):
        if width < 1 or height < 1:
            raise ValueError(f"grid {width} x {height} must have at least one cell")
        self.width, self.height, self.vehicle_id = int(width), int(height), int(vehicle_id)
        if self.vehicle_id < 0:
            raise ValueError(f"vehicle id {vehicle_id} must not be negative")
        if stack is None:
            stack = (StackArrays(1, self.width, self.height, ids=max(MAX_IDS, self.vehicle_id + 1)), 0)
        self._stack, self._row = stack
        st, row = stack
        if (st.width, st.height) != (self.width, self.height) or self.vehicle_id >= st.ids:
            raise ValueError("a knowledge's stack must hold its grid and its vehicle id")
        self.explored: np.ndarray = st.explored[row]
        self.phi_q: np.ndarray = st.phi_q[row]  # 0 where unexplored
        self.obstacle: np.ndarray = st.obstacle[row]  # False where unexplored
        self._position: np.ndarray = st.position[row]
        self._target_step: np.ndarray = st.target_step[row]
        self._pending: np.ndarray = st.pending[row]  # own finds not yet published

    @property
    def positions(self) -> PositionTable:
        """vehicle id -> its last known Position (a mapping onto the stack row)."""
        return PositionTable(self._position)

    @positions.setter
    def positions(self, value: Mapping[int, Position]) -> None:
        self._position[:] = UNKNOWN
        table = self.positions
        for v, p in dict(value).items():
            table[v] = p

    @property
    def targets(self) -> TargetTable:
        """target cell -> earliest report step (a mapping onto the stack row)."""
        return TargetTable(self._target_step)

    @targets.setter
    def targets(self, value: Mapping[tuple[int, int], int]) -> None:
        self._target_step[:] = NEVER
        table = self.targets
        for c, s in dict(value).items():
            table[c] = s

    # ----- views ------------------------------------------------------------------------------------
    @property
    def phi(self) -> np.ndarray:
        """phi (float32, [x, y]) where explored, 0 elsewhere; quantised like the codec carries it."""
        return dequantise_phi(self.phi_q)

    @property
    def own_position(self) -> Position | None:
        key = self._position[self.vehicle_id]
        if key < 0:
            return None
        step, cell, on_target = split_key(key)
        return Position(step, cell, on_target)

    @property
    def peers(self) -> dict[int, Position]:
        """Known positions of the other vehicles."""
        return {v: p for v, p in self.positions.items() if v != self.vehicle_id}

    def out_of_touch(self, step: int, vehicles: int, steps: int, in_touch: Collection[int] = ()) -> int:
        """How many of the other `vehicles` (ids 0..vehicles-1) this vehicle has no report from of step
        `step - steps` or later, one never heard from counting as heard at step 0 and the ids `in_touch`
        as heard now (as Beliefs.out_of_touch reads the beliefs beliefs_from_knowledge makes)."""
        keys = np.full(vehicles, UNKNOWN, dtype=np.int64)
        known = self._position[:vehicles]
        keys[: known.size] = known
        silent = silent_since(heard_steps(keys, step, in_touch), step, steps)
        if self.vehicle_id < vehicles:
            silent[self.vehicle_id] = False
        return int(silent.sum())

    def known_targets(self) -> np.ndarray:
        """(W, H) bool: cells known to hold a target (reported by a detection, or sensed with phi 1)."""
        known: np.ndarray = (self.explored & (self.phi_q == PHI_LEVELS)) | (self._target_step != NEVER)
        return known

    def beliefs(
        self,
        vehicles: int | None = None,
        settings: ObservationSettings | None = None,
        step: int = 0,
        hovering: bool = False,
    ) -> Beliefs:
        """This vehicle's beliefs as a batch of one decider (see beliefs_from_knowledge)."""
        return beliefs_from_knowledge([self], vehicles, settings, step, [hovering])

    def value_channel(
        self, rho: float = 0.2, remove_taken: bool = False, sigma2: float = 1.0, cutoff: float = 0.01
    ) -> np.ndarray:
        """phi_hat - rho * omega_hat, (W, H) float32: unexplored cells read 1 (the simulator's value
        channel, from the same Beliefs); with remove_taken the targets others sit on are removed."""
        s = ObservationSettings(rho=rho, sigma2=sigma2, phi_cutoff=cutoff, phi_tolerance=PHI_TOLERANCE)
        channel: np.ndarray = self.beliefs(settings=s).value_channel(remove_taken)[0, 0]
        return channel

    def observation(self, window: int = 20, rho: float = 0.2, remove_taken: bool = False) -> np.ndarray:
        """The (3, F, F) observation of this vehicle (swarmctl.world.observe, from its Beliefs). Peers
        whose position is unknown are left out; the own position must be known."""
        s = ObservationSettings(window=window, rho=rho, phi_tolerance=PHI_TOLERANCE)
        obs: np.ndarray = observe(self.beliefs(settings=s), remove_taken)[0, 0]
        return obs

    # ----- own updates ------------------------------------------------------------------------------
    def set_position(self, step: int, cell: tuple[int, int], on_target: bool = False) -> None:
        """Record the own position: it replaces any stored one of the same step or older (the vehicle
        knows best where it is); an older step than the stored one is ignored."""
        if not (0 <= int(cell[0]) < self.width and 0 <= int(cell[1]) < self.height):
            raise ValueError(f"cells outside the {self.width} x {self.height} grid")
        old = self._position[self.vehicle_id]
        if old < 0 or int(step) >= int(old) >> STEP_SHIFT:  # the stored step (stack.position_key)
            self._position[self.vehicle_id] = position_key(step, cell, on_target)

    def sense(self, cells: npt.ArrayLike, phi: npt.ArrayLike, obstacle: npt.ArrayLike) -> int:
        """Own observation of `cells` (N, 2) with their true phi (float) and obstacle flags.

        Returns how many of them were newly explored; those are queued for the next `take_delta`."""
        cells = _cells_array(cells)
        self._check_cells(cells)
        q = quantise_phi(np.asarray(phi, dtype=np.float64).reshape(-1))
        obs = np.asarray(obstacle, dtype=bool).reshape(-1)
        x, y = cells[:, 0], cells[:, 1]
        new = ~self.explored[x, y]
        self._apply(x, y, q, obs)
        if not new.any():
            return 0
        x, y = x[new], y[new]
        self._pending[x, y] = True
        return len(set((x * self.height + y).tolist()))  # cells may repeat

    def sense_truth(self, phi_map: np.ndarray, obstacle_map: np.ndarray, fov: float = 3.0) -> int:
        """Sense the disc of radius `fov` around the own cell from ground-truth maps (simulation)."""
        own = self.own_position
        if own is None or own.cell is None:
            raise ValueError(f"vehicle {self.vehicle_id} does not know its own cell yet: call set_position first")
        c = disc_cells(own.cell, self.width, self.height, fov)
        return self.sense(c, phi_map[c[:, 0], c[:, 1]], obstacle_map[c[:, 0], c[:, 1]])

    def take_delta(self) -> Delta:
        """A delta with the cells this vehicle explored itself since the last call, and its position."""
        delta = self._delta_of(self._pending)
        self._pending[:] = False
        return delta

    def cells_delta(self, mask: np.ndarray) -> Delta:
        """A delta carrying every explored cell selected by `mask` (W, H) (repair answers)."""
        return self._delta_of(mask & self.explored)

    def _delta_of(self, mask: np.ndarray) -> Delta:
        """The cells of `mask` (x, y order) with their phi and obstacle flags, and the own position."""
        cells = np.argwhere(mask)
        x, y = cells[:, 0], cells[:, 1]
        key = int(self._position[self.vehicle_id])
        step, cell, on_target = split_key(key) if key >= 0 else (0, None, False)
        return Delta(self.vehicle_id, step, cell, on_target, cells, self.phi_q[x, y], self.obstacle[x, y])

    def add_targets(self, cells: npt.ArrayLike, step: int) -> None:
        """Target cells reported at `step` (each keeps its earliest step)."""
        c = _cells_array(cells)
        self._check_cells(c)
        np.minimum.at(self._target_step, (c[:, 0], c[:, 1]), int(step))

    # ----- merging ----------------------------------------------------------------------------------
    def merge(self, other: Delta | Detection | Knowledge) -> Knowledge:
        """Merge a received delta, detection or a whole other knowledge in place; returns self."""
        if isinstance(other, Knowledge):
            if (other.width, other.height) != (self.width, self.height):
                raise ValueError("cannot merge knowledge of different grid sizes")
            self._apply_mask(other.explored, other.phi_q, other.obstacle)
            for v, p in other.positions.items():
                self._merge_position(v, p)
            np.minimum(self._target_step, other._target_step, out=self._target_step)
        elif isinstance(other, Delta):
            self._check_cells(other.cells)
            self._apply(other.cells[:, 0], other.cells[:, 1], other.phi, other.obstacle)
            self._merge_position(other.sender, other.position)
        elif isinstance(other, Detection):
            self.add_targets(other.targets, other.step)
            self._merge_position(other.sender, other.position)
        else:
            raise TypeError(f"cannot merge a {type(other).__name__} into Knowledge")
        return self

    def merge_position(self, vehicle: int, position: Position) -> None:
        """A position report alone (e.g. from a digest's header)."""
        self._merge_position(int(vehicle), position)

    def joined(self, other: Knowledge) -> Knowledge:
        """A new knowledge: self merged with other (self unchanged)."""
        return self.copy().merge(other)

    def copy(self) -> Knowledge:
        st = StackArrays(1, self.width, self.height, ids=self._position.size)
        k = Knowledge(self.width, self.height, self.vehicle_id, stack=(st, 0))
        for name in ("explored", "phi_q", "obstacle", "_position", "_target_step", "_pending"):
            getattr(k, name)[...] = getattr(self, name)
        return k

    def same_map(self, other: Knowledge) -> bool:
        """Same explored cells, phi and obstacles (positions and targets not compared)."""
        return (
            np.array_equal(self.explored, other.explored)
            and np.array_equal(self.phi_q, other.phi_q)
            and np.array_equal(self.obstacle, other.obstacle)
        )

    def __eq__(self, other: object) -> bool:
        """Equal views: same grid, map, positions and targets (whose view it is is not compared)."""
        if not isinstance(other, Knowledge):
            return NotImplemented
        return (
            (self.width, self.height) == (other.width, other.height)
            and self.same_map(other)
            and self.positions == other.positions
            and self.targets == other.targets
        )

    # mutable, so unhashable: a class that defines __eq__ and not __hash__ gets __hash__ = None

    def __repr__(self) -> str:
        return (
            f"Knowledge(vehicle {self.vehicle_id}, {self.width} x {self.height}, "
            f"{int(self.explored.sum())} explored, {len(self.positions)} positions, {len(self.targets)} targets)"
        )

    # ----- internals --------------------------------------------------------------------------------
    def _check_cells(self, cells: np.ndarray) -> None:
        if cells.size and (cells.min() < 0 or cells[:, 0].max() >= self.width or cells[:, 1].max() >= self.height):
            raise ValueError(f"cells outside the {self.width} x {self.height} grid")

    def _apply(self, x: np.ndarray, y: np.ndarray, q: np.ndarray, obs: np.ndarray) -> None:
        self.explored[x, y] = True
        np.maximum.at(self.phi_q, (x, y), np.asarray(q, dtype=np.uint8))
        np.logical_or.at(self.obstacle, (x, y), np.asarray(obs, dtype=bool))

    def _apply_mask(self, explored: np.ndarray, phi_q: np.ndarray, obstacle: np.ndarray) -> None:
        self.explored |= explored
        np.maximum(self.phi_q, np.where(explored, phi_q, 0).astype(np.uint8), out=self.phi_q)
        self.obstacle |= explored & obstacle

    def _merge_position(self, vehicle: int, position: Position) -> None:
        if position.cell is None:
            return
        if not 0 <= vehicle < self._position.size:
            raise ValueError(f"vehicle id {vehicle} is outside 0..{self._position.size - 1}")
        key = position_key(position.step, position.cell, position.on_target)
        if key > self._position[vehicle]:
            self._position[vehicle] = key


def heard_steps(keys: np.ndarray, step: int, in_touch: Collection[int] = ()) -> np.ndarray:
    """(..., N) the step of each vehicle's newest report in the position keys `keys` (-1: none), the
    ids `in_touch` (heard otherwise: the controller's own vehicles on their links) set to `step`."""
    heard: np.ndarray = np.where(keys >= 0, keys >> STEP_SHIFT, -1)
    heard[..., [v for v in in_touch if 0 <= v < keys.shape[-1]]] = step
    return heard


def beliefs_from_knowledge(
    knowledges: list[Knowledge],
    vehicles: int | None = None,
    settings: ObservationSettings | None = None,
    step: int = 0,
    hovering: list[bool] | None = None,
    episode: int = 0,
    in_touch: Collection[int] = (),
) -> Beliefs:
    """The Beliefs of the agents whose Knowledge is given (one batch, one decider each), as the
    simulator's SearchEnv.beliefs builds them from its arrays.

    phi_hat on an explored cell is the larger of the phi reported for it (a detector's, or 0 where the
    cell was explored from the vehicle's position alone) and the value map of the targets the agent
    knows (swarmctl.world.scenario.value_map with the settings' sigma2 and cut-off, quantised as phi
    is), as the simulator's value map is of its targets: a target learnt later raises the value of the
    cells explored before.

    vehicles: the swarm's size N (default: enough for every vehicle id the knowledges name);
    settings: the observation settings (default the paper's, with the quantised phi's tolerance);
    hovering: whether each agent itself hovers on a target (default: none do: they are searching);
    episode: the id that keys the policy's random draws with the step (a mission is episode 0);
    in_touch: the vehicle ids heard now whatever their reports say (`heard`: the controller's own
    vehicles on their links, taking off included).
    Each agent must know its own cell. When every agent knows the same maps (ideal sharing), the
    grid-sized fields are built once and are read-only broadcast views over the agents."""
    if not knowledges:
        raise ValueError("beliefs need at least one agent's knowledge")
    w, h = knowledges[0].width, knowledges[0].height
    if any((k.width, k.height) != (w, h) for k in knowledges):
        raise ValueError("beliefs of one batch share one grid")
    a = len(knowledges)
    me = np.array([k.vehicle_id for k in knowledges], dtype=np.int64)
    keys = stacked_field(knowledges, "position", UNKNOWN)
    known = keys >= 0
    named = np.flatnonzero(known.any(axis=0))
    top = max(int(me.max()), int(named[-1]) if named.size else -1)
    n = top + 1 if vehicles is None else int(vehicles)
    if top >= n:
        raise ValueError(f"vehicle id {top} is outside a swarm of {n}")
    lacking = np.flatnonzero(~known[np.arange(a), me])
    if lacking.size:
        raise ValueError(
            f"vehicle {knowledges[lacking[0]].vehicle_id} does not know its own cell yet: call set_position first"
        )
    if keys.shape[1] < n:
        keys = np.concatenate([keys, np.full((a, n - keys.shape[1]), UNKNOWN, dtype=np.int64)], axis=1)
    keys = keys[:, :n]
    positions = key_cells(keys)[None]
    heard = heard_steps(keys, step, in_touch)[None]
    hover = (keys >= 0) & (keys & 1).astype(bool)
    hover[np.arange(a), me] = np.asarray(hovering, dtype=bool) if hovering is not None else False
    hover = hover[None]
    settings = settings or ObservationSettings(phi_tolerance=PHI_TOLERANCE)
    names = ("explored", "phi_q", "target_step", "obstacle")
    rows = _one_shared_map(knowledges, names)
    same = rows is not None  # every agent knows the same map (ideal sharing): built once, read through views
    if rows is None:
        rows = [stacked_field(knowledges, name) for name in names]
    explored, phi_q, target_step, obstacle = rows
    targets = (explored & (phi_q == PHI_LEVELS)) | (target_step != NEVER)
    value = np.stack(_known_value(targets, settings))
    phi_hat = np.where(explored, np.maximum(dequantise_phi(phi_q), value), np.float32(1.0))
    maps = [explored, phi_hat, explored & obstacle, targets]
    if same:
        maps = [np.broadcast_to(m, (a, w, h)) for m in maps]
    explored, phi_hat, obstacles, targets = (m[None] for m in maps)
    me = me[None]
    return Beliefs(
        explored,
        phi_hat,
        obstacles,
        targets,
        positions,
        hover,
        me,
        np.array([episode], dtype=np.int64),
        int(step),
        settings,
        heard=heard,
    )


def stacked_field(knowledges: list[Knowledge], name: str, fill: int | None = None) -> np.ndarray:
    """(A, ...) the stack arrays `name` of the knowledges' rows: one gather when they share a stack."""
    stack = knowledges[0]._stack
    if all(k._stack is stack for k in knowledges):
        gathered: np.ndarray = getattr(stack, name)[[k._row for k in knowledges]]
        return gathered
    rows = [getattr(k._stack, name)[k._row] for k in knowledges]
    if fill is not None and len({r.size for r in rows}) > 1:  # position rows of different widths
        width = max(r.size for r in rows)
        rows = [np.concatenate([r, np.full(width - r.size, fill, dtype=r.dtype)]) for r in rows]
    return np.stack(rows)


def _one_shared_map(knowledges: list[Knowledge], names: tuple[str, ...]) -> list[np.ndarray] | None:
    """When two or more knowledges are rows of one stack holding the same arrays `names`: the first
    row of each, (1, W, H); None otherwise. Compared in place, without gathering the rows."""
    stack = knowledges[0]._stack
    if len(knowledges) < 2 or any(k._stack is not stack for k in knowledges):
        return None
    rows = [k._row for k in knowledges]
    out = []
    for name in names:
        arr = getattr(stack, name)
        first = arr[rows[0] : rows[0] + 1]
        if 2 * len(rows) >= len(arr):  # most of the stack: compare it all, then pick the rows
            equal = np.logical_and.reduce((arr == first).reshape(len(arr), -1), axis=1)[rows]
        else:
            equal = np.logical_and.reduce((arr[rows] == first).reshape(len(rows), -1), axis=1)
        if not np.logical_and.reduce(equal):
            return None
        out.append(first)
    return out


def _known_value(targets: np.ndarray, settings: ObservationSettings) -> list[np.ndarray]:
    """The value map of each agent's known targets ((A, W, H) bool), quantised as phi is (so where a
    detector reported the true phi, the max leaves it unchanged: quantising is monotone), computed once
    per distinct set (agents sharing knowledge mostly know the same targets)."""
    w, h = targets.shape[1:]
    maps: dict[bytes, np.ndarray] = {}
    out = []
    for mask in targets:
        key = mask.tobytes()
        if key not in maps:
            cells = np.argwhere(mask)
            maps[key] = dequantise_phi(quantise_phi(value_map(cells, w, h, settings.sigma2, settings.phi_cutoff)))
        out.append(maps[key])
    return out
