"""One vehicle's knowledge of the search grid, and the messages that change it.

`Knowledge` is the controller's view of the world (the simulator keeps the same state for B x U
vehicles in arrays; this is the batch-of-one form): which cells are explored, their value phi and
obstacle flag where explored, where each vehicle was last known to be, and the target cells reported
by detections. Arrays are indexed [x, y] (CONTRACTS.md).

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

from dataclasses import dataclass, field

import numpy as np

from swarmctl.world.beliefs import Beliefs, ObservationSettings
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


def disc_cells(cell: tuple[int, int], width: int, height: int, fov: float = 3.0) -> np.ndarray:
    """(N, 2) cells of the sensing disc of radius `fov` around `cell` that lie on the grid."""
    c = np.asarray(cell, dtype=np.int64) + fov_offsets(fov)
    inside = (c[:, 0] >= 0) & (c[:, 0] < width) & (c[:, 1] >= 0) & (c[:, 1] < height)
    return c[inside]


@dataclass(frozen=True)
class Position:
    """Where a vehicle was at `step`; `cell` is None when the vehicle did not know yet."""

    step: int
    cell: tuple[int, int] | None
    on_target: bool = False

    def order(self) -> tuple:
        """Total order used by merges: newest step first, then a fixed tie-break."""
        cell = self.cell if self.cell is not None else (-1, -1)
        return (self.step, cell[0], cell[1], self.on_target)


def _cells_array(cells) -> np.ndarray:
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

    def _same_report(self, other: object) -> bool:
        return type(self) is type(other) and (self.sender, self.step, self.cell, self.on_target) == (
            other.sender,
            other.step,
            other.cell,
            other.on_target,
        )


@dataclass(eq=False)
class Delta(Report):
    """Cells explored by `sender` (with their quantised phi and obstacle flag) and the sender's
    position at `step`. A delta with no cells is a position report."""

    cells: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    phi: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.uint8))
    obstacle: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def __post_init__(self) -> None:
        super().__post_init__()
        self.cells = _cells_array(self.cells)
        self.phi = np.asarray(self.phi, dtype=np.uint8).reshape(-1)
        self.obstacle = np.asarray(self.obstacle, dtype=bool).reshape(-1)
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


class Knowledge:
    """One vehicle's view of a width x height grid (see the module docstring for merge rules)."""

    def __init__(self, width: int, height: int, vehicle_id: int = 0):
        if width < 1 or height < 1:
            raise ValueError(f"grid {width} x {height} must have at least one cell")
        self.width, self.height, self.vehicle_id = int(width), int(height), int(vehicle_id)
        self.explored = np.zeros((self.width, self.height), dtype=bool)
        self.phi_q = np.zeros((self.width, self.height), dtype=np.uint8)  # 0 where unexplored
        self.obstacle = np.zeros((self.width, self.height), dtype=bool)  # False where unexplored
        self.positions: dict[int, Position] = {}
        self.targets: dict[tuple[int, int], int] = {}  # target cell -> earliest report step
        self._pending = np.zeros((self.width, self.height), dtype=bool)  # own finds not yet published

    # ----- views ------------------------------------------------------------------------------------
    @property
    def phi(self) -> np.ndarray:
        """phi (float32, [x, y]) where explored, 0 elsewhere; quantised like the codec carries it."""
        return dequantise_phi(self.phi_q)

    @property
    def own_position(self) -> Position | None:
        return self.positions.get(self.vehicle_id)

    @property
    def peers(self) -> dict[int, Position]:
        """Known positions of the other vehicles."""
        return {v: p for v, p in self.positions.items() if v != self.vehicle_id}

    def known_targets(self) -> np.ndarray:
        """(W, H) bool: cells known to hold a target (reported by a detection, or sensed with phi 1)."""
        mask = self.explored & (self.phi_q == PHI_LEVELS)
        for x, y in self.targets:
            mask[x, y] = True
        return mask

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
        return self.beliefs(settings=s).value_channel(remove_taken)[0, 0]

    def observation(self, window: int = 20, rho: float = 0.2, remove_taken: bool = False) -> np.ndarray:
        """The (3, F, F) observation of this vehicle (swarmctl.world.observe, from its Beliefs). Peers
        whose position is unknown are left out; the own position must be known."""
        s = ObservationSettings(window=window, rho=rho, phi_tolerance=PHI_TOLERANCE)
        return observe(self.beliefs(settings=s), remove_taken)[0, 0]

    # ----- own updates ------------------------------------------------------------------------------
    def set_position(self, step: int, cell: tuple[int, int], on_target: bool = False) -> None:
        """Record the own position: it replaces any stored one of the same step or older (the vehicle
        knows best where it is); an older step than the stored one is ignored."""
        self._check_cells(_cells_array([cell]))
        old = self.positions.get(self.vehicle_id)
        if old is None or int(step) >= old.step:
            self.positions[self.vehicle_id] = Position(int(step), (int(cell[0]), int(cell[1])), bool(on_target))

    def sense(self, cells, phi, obstacle) -> int:
        """Own observation of `cells` (N, 2) with their true phi (float) and obstacle flags.

        Returns how many of them were newly explored; those are queued for the next `take_delta`."""
        cells = _cells_array(cells)
        self._check_cells(cells)
        q = quantise_phi(np.asarray(phi, dtype=np.float64).reshape(-1))
        obs = np.asarray(obstacle, dtype=bool).reshape(-1)
        x, y = cells[:, 0], cells[:, 1]
        new = ~self.explored[x, y]
        self._apply(x, y, q, obs)
        self._pending[x[new], y[new]] = True
        return int(np.unique(x[new] * self.height + y[new]).size)

    def sense_truth(self, phi_map: np.ndarray, obstacle_map: np.ndarray, fov: float = 3.0) -> int:
        """Sense the disc of radius `fov` around the own cell from ground-truth maps (simulation)."""
        own = self.own_position
        if own is None or own.cell is None:
            raise ValueError(f"vehicle {self.vehicle_id} does not know its own cell yet: call set_position first")
        c = disc_cells(own.cell, self.width, self.height, fov)
        return self.sense(c, phi_map[c[:, 0], c[:, 1]], obstacle_map[c[:, 0], c[:, 1]])

    def take_delta(self) -> Delta:
        """A delta with the cells this vehicle explored itself since the last call, and its position."""
        x, y = np.nonzero(self._pending)
        self._pending[:] = False
        own = self.own_position or Position(0, None)
        return Delta(
            self.vehicle_id,
            own.step,
            own.cell,
            own.on_target,
            np.stack([x, y], axis=1),
            self.phi_q[x, y],
            self.obstacle[x, y],
        )

    def cells_delta(self, mask: np.ndarray) -> Delta:
        """A delta carrying every explored cell selected by `mask` (W, H) (repair answers)."""
        x, y = np.nonzero(mask & self.explored)
        own = self.own_position or Position(0, None)
        return Delta(
            self.vehicle_id,
            own.step,
            own.cell,
            own.on_target,
            np.stack([x, y], axis=1),
            self.phi_q[x, y],
            self.obstacle[x, y],
        )

    def add_targets(self, cells, step: int) -> None:
        for c in _cells_array(cells):
            self._check_cells(c[None])
            key = (int(c[0]), int(c[1]))
            self.targets[key] = min(self.targets.get(key, int(step)), int(step))

    # ----- merging ----------------------------------------------------------------------------------
    def merge(self, other: Delta | Detection | Knowledge) -> Knowledge:
        """Merge a received delta, detection or a whole other knowledge in place; returns self."""
        if isinstance(other, Knowledge):
            if (other.width, other.height) != (self.width, self.height):
                raise ValueError("cannot merge knowledge of different grid sizes")
            self._apply_mask(other.explored, other.phi_q, other.obstacle)
            for v, p in other.positions.items():
                self._merge_position(v, p)
            for c, s in other.targets.items():
                self.targets[c] = min(self.targets.get(c, s), s)
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
        k = Knowledge(self.width, self.height, self.vehicle_id)
        k.explored, k.phi_q, k.obstacle = self.explored.copy(), self.phi_q.copy(), self.obstacle.copy()
        k.positions, k.targets, k._pending = dict(self.positions), dict(self.targets), self._pending.copy()
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

    __hash__ = None  # mutable

    def __repr__(self) -> str:
        return (
            f"Knowledge(vehicle {self.vehicle_id}, {self.width} x {self.height}, "
            f"{int(self.explored.sum())} explored, {len(self.positions)} positions, {len(self.targets)} targets)"
        )

    # ----- internals --------------------------------------------------------------------------------
    def _check_cells(self, cells: np.ndarray) -> None:
        if cells.size and (
            (cells < 0).any() or (cells[:, 0] >= self.width).any() or (cells[:, 1] >= self.height).any()
        ):
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
        old = self.positions.get(vehicle)
        if old is None or position.order() > old.order():
            self.positions[vehicle] = position


def beliefs_from_knowledge(
    knowledges: list[Knowledge],
    vehicles: int | None = None,
    settings: ObservationSettings | None = None,
    step: int = 0,
    hovering: list[bool] | None = None,
    episode: int = 0,
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
    episode: the id that keys the policy's random draws with the step (a mission is episode 0).
    Each agent must know its own cell."""
    if not knowledges:
        raise ValueError("beliefs need at least one agent's knowledge")
    w, h = knowledges[0].width, knowledges[0].height
    ids = {k.vehicle_id for k in knowledges} | {v for k in knowledges for v in k.positions}
    n = max(ids) + 1 if vehicles is None else int(vehicles)
    if max(ids) >= n:
        raise ValueError(f"vehicle id {max(ids)} is outside a swarm of {n}")
    a = len(knowledges)
    positions = np.full((1, a, n, 2), -1, dtype=np.int64)
    hover = np.zeros((1, a, n), dtype=bool)
    for i, k in enumerate(knowledges):
        if (k.width, k.height) != (w, h):
            raise ValueError("beliefs of one batch share one grid")
        own = k.own_position
        if own is None or own.cell is None:
            raise ValueError(f"vehicle {k.vehicle_id} does not know its own cell yet: call set_position first")
        for v, p in k.positions.items():
            if p.cell is not None:
                positions[0, i, v] = p.cell
                hover[0, i, v] = p.on_target and v != k.vehicle_id
        hover[0, i, k.vehicle_id] = bool(hovering[i]) if hovering is not None else False
    settings = settings or ObservationSettings(phi_tolerance=PHI_TOLERANCE)
    explored = np.stack([k.explored for k in knowledges])[None]
    targets = np.stack([k.known_targets() for k in knowledges])[None]
    value = _known_value(targets[0], settings)
    phi_hat = np.stack(
        [np.where(k.explored, np.maximum(k.phi, v), np.float32(1.0)) for k, v in zip(knowledges, value)]
    )[None]
    obstacles = np.stack([k.explored & k.obstacle for k in knowledges])[None]
    me = np.array([[k.vehicle_id for k in knowledges]], dtype=np.int64)
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
    )


def _known_value(targets: np.ndarray, settings: ObservationSettings) -> list[np.ndarray]:
    """The value map of each agent's known targets ((A, W, H) bool), quantised as phi is (so where a
    detector reported the true phi, the max leaves it unchanged: quantising is monotone), computed once
    per distinct set (agents sharing knowledge mostly know the same targets)."""
    w, h = targets.shape[1:]
    maps: dict[bytes, np.ndarray] = {}
    out = []
    for mask in targets:
        cells = np.argwhere(mask)
        key = cells.tobytes()
        if key not in maps:
            maps[key] = dequantise_phi(quantise_phi(value_map(cells, w, h, settings.sigma2, settings.phi_cutoff)))
        out.append(maps[key])
    return out
