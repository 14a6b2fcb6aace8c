"""What a policy may know: each deciding vehicle's beliefs, never the hidden truth.

`Beliefs` is the one input of every policy (swarmctl.policy) and of the observation builder
(swarmctl.world.observe). The simulator builds it from its arrays (`SearchEnv.beliefs`), the
controller from each agent's Knowledge (`swarmctl.knowledge.model.beliefs_from_knowledge`); both end
in `Beliefs(...)`, whose checks and derived views are the same for both.

Shapes: B batches (episodes in the simulator, 1 in the field), U deciders per batch (the vehicles a
policy chooses moves for), N vehicles in the swarm (deciders are some of them: all in the
simulator, the searching agents of a process in the field), a W x H grid indexed [x, y].

`ObservationSettings` are the constants that turn beliefs into what a policy sees (sensing radius,
window, the obstacle weight rho, the value map's spread): a learned policy carries the ones it was
trained with in its checkpoint, so the field observes exactly as the simulator did.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields, replace
from functools import cached_property
from typing import Any

import numpy as np
import numpy.typing as npt

from swarmctl.world.moves import block_starts
from swarmctl.world.taken import remove_taken_targets

SMALL = 16  # deciders x vehicles up to which the decision rules read the swarm as Python ints (Beliefs.crews)

PAPER_VARIANT = "venturini2021"  # the paper's F x F, 3-channel observation

# a decider's own cell (x, y), whether it hovers, and the (x, y, hovering) of each other vehicle it knows of
Crew = tuple[Sequence[int], bool, Sequence[Sequence[int]]]
# a grid-sized field given to Beliefs: an array, a callable computing it when first read, or None
MapSource = npt.ArrayLike | Callable[[], npt.ArrayLike] | None
GLOBAL_LOCAL_VARIANT = "global-local-v1"  # the paper's window + the whole map pooled (world.observe_global)
SCALES_VARIANT = "scales-v1"  # crops at 1, 3 and 9 cells a pixel: a fixed metric scale (world.observe_scales)
# observation channels of each variant
VARIANT_CHANNELS = {PAPER_VARIANT: 3, GLOBAL_LOCAL_VARIANT: 7, SCALES_VARIANT: 24}


def silent_since(heard: np.ndarray, step: int, steps: int) -> np.ndarray:
    """bool, heard's shape: not heard from in the `steps` steps before `step` (`heard`: the step of the
    last report, -1 for none, which counts as heard at step 0: the swarm sets out together)."""
    result: np.ndarray = np.maximum(heard, 0) < step - steps
    return result


@dataclass(frozen=True)
class ObservationSettings:
    """How beliefs become an observation (the checkpoint's world config stores them)."""

    fov: float = 3.0  # zeta: sensing radius in cells (also what planners assume)
    window: int = 20  # F: observation window side
    rho: float = 0.2  # obstacle weight in the value channel
    sigma2: float = 1.0  # value-map spread (taken targets are removed with it)
    phi_cutoff: float = 0.01  # phi below this reads 0
    phi_tolerance: float = 1e-6  # how far a known phi may be from the exact one (quantised in the field)
    variant: str = PAPER_VARIANT  # the observation/network variant

    @classmethod
    def from_world(cls, world: Any, phi_tolerance: float = 1e-6) -> ObservationSettings:
        """The settings of a WorldConfig or of a checkpoint's stored world dict."""
        get: Callable[[str, Any], Any] = world.get if isinstance(world, dict) else lambda k, d: getattr(world, k, d)
        defaults = cls()
        kw = {f.name: get(f.name, getattr(defaults, f.name)) for f in fields(cls) if f.name != "phi_tolerance"}
        return cls(**kw, phi_tolerance=phi_tolerance)


def _one_map(arr: np.ndarray) -> bool:
    """Whether a (B, U, W, H) map is one map per batch, broadcast over its U > 1 deciders."""
    return arr.shape[1] > 1 and arr.strides[1] == 0


class Beliefs:
    """B x U deciders' knowledge (see the module docstring for the axes).

    explored (B, U, W, H) bool; phi_hat (B, U, W, H) float32, the known value phi where explored and 1
    elsewhere (the paper's optimism); obstacles (B, U, W, H) bool, known obstacles (False where
    unexplored); targets (B, U, W, H) bool, cells known to hold a target; positions (B, U, N, 2) int,
    where decider u believes vehicle n is (-1, -1 when unknown; its own row is its own cell); hovering
    (B, U, N) bool, u believes n hovers on a target (its own entry: it hovers); me (B, U) int, the
    decider's own index among the N vehicles; episodes (B,) int, the batches' episode ids (policy draws
    are keyed by them and by `step`); step_limit, the step the search ends at when the deciders know it
    (None: not known).

    The grid-sized fields (phi_hat, obstacles, targets) and `value` (the value channel without taken
    targets removed, computed from the other fields when not given) may be zero-argument callables:
    the simulator gives them so, and each is computed once, when a policy first reads it.

    density (B, U, W, H) float32, the planners' exploration weight: the probability left on each cell
    by the decider's prior and the passes it knows of, in units of a uniform prior's cell
    (swarmctl.world.prior.density); when not given, 1 where unexplored and 0 where explored (a uniform
    prior searched with a detector that never misses). passes (B, U, W, H) uint8, the passes the decider
    knows of, with the detector's `pod`: what `uniform_density` reads (when not given, explored cells
    count one pass). heard (B, U, N) int64: the step at which the decider last heard each vehicle's
    position (its own: now; -1: never), when the beliefs come over a lossy channel; None: every known
    position is current (ideal sharing). The hover rule reads it (`out_of_touch`); the controller marks
    the vehicles it flies itself and still hears over their links (taking off included) as heard now."""

    FIELDS = (
        "explored",
        "phi_hat",
        "obstacles",
        "targets",
        "positions",
        "hovering",
        "me",
        "episodes",
        "step",
        "step_limit",
        "heard",
    )
    _MAPS = {
        "phi_hat": np.float32,
        "obstacles": bool,
        "targets": bool,
        "value": np.float32,
        "density": np.float32,
        "passes": np.uint8,
    }

    def __init__(
        self,
        explored: npt.ArrayLike,
        phi_hat: MapSource,
        obstacles: MapSource,
        targets: MapSource,
        positions: npt.ArrayLike,
        hovering: npt.ArrayLike,
        me: npt.ArrayLike,
        episodes: npt.ArrayLike,
        step: int = 0,
        settings: ObservationSettings | None = None,
        value: MapSource = None,
        step_limit: int | None = None,
        density: MapSource = None,
        passes: MapSource = None,
        pod: float = 1.0,
        heard: npt.ArrayLike | None = None,
    ):
        self.explored = np.asarray(explored, dtype=bool)
        b, u, w, h = self.explored.shape
        self._maps = {
            "phi_hat": phi_hat,
            "obstacles": obstacles,
            "targets": targets,
            "value": value,
            "density": density,
            "passes": passes,
        }
        self._pod = float(pod)
        if not 0.0 < self._pod <= 1.0:
            raise ValueError(f"beliefs: the probability of detection {self._pod} is not in (0, 1]")
        self._ready: dict[str, np.ndarray] = {}  # the maps computed and checked already
        for name, given in self._maps.items():
            if given is not None and not callable(given):
                self._map(name)  # check it now
        self.positions = np.asarray(positions, dtype=np.int64)
        self.hovering = np.asarray(hovering, dtype=bool)
        self.me = np.asarray(me, dtype=np.int64)
        self.episodes = np.asarray(episodes, dtype=np.int64).reshape(b)
        self.step = int(step)
        self.step_limit = None if step_limit is None else int(step_limit)
        if self.step_limit is not None and self.step_limit < 1:
            raise ValueError(f"beliefs: step limit {self.step_limit} is not a positive number of steps")
        self.settings = settings or ObservationSettings()
        n = self.positions.shape[2] if self.positions.ndim == 4 else -1
        for name, arr, shape in (
            ("positions", self.positions, (b, u, n, 2)),
            ("hovering", self.hovering, (b, u, n)),
            ("me", self.me, (b, u)),
        ):
            if arr.shape != shape:
                raise ValueError(f"beliefs: {name} has shape {arr.shape}, expected {shape}")
        self.heard = None if heard is None else np.asarray(heard, dtype=np.int64)
        if self.heard is not None and self.heard.shape != (b, u, n):
            raise ValueError(f"beliefs: heard has shape {self.heard.shape}, expected {(b, u, n)}")
        if n < 1 or (self.me.size and (self.me.min() < 0 or self.me.max() >= n)):
            raise ValueError(f"beliefs: a decider's own index is outside the {n} vehicles")
        if self.positions.size:
            x_max, y_max = self.positions.reshape(-1, 2).max(0)
            if self.positions.min() < -1 or x_max >= w or y_max >= h:
                raise ValueError("beliefs: a known position lies outside the grid")
            if self.pos.min() < 0:
                raise ValueError("beliefs: every decider must know its own cell")

    def _map(self, name: str) -> np.ndarray:
        """A grid-sized field, computed (once) if it was given as a callable, and checked (once)."""
        ready = self._ready.get(name)
        if ready is not None:
            return ready
        given = self._maps[name]
        if callable(given):
            given = given()
        arr = np.asarray(given, dtype=self._MAPS[name])
        if arr.shape != self.explored.shape:
            raise ValueError(f"beliefs: {name} has shape {arr.shape}, expected {self.explored.shape}")
        self._maps[name] = self._ready[name] = arr
        return arr

    @property
    def phi_hat(self) -> np.ndarray:
        """(B, U, W, H) float32: the known phi where explored, 1 elsewhere. Shared: do not modify it."""
        return self._map("phi_hat")

    @property
    def obstacles(self) -> np.ndarray:
        """(B, U, W, H) bool: the obstacles the decider knows of."""
        return self._map("obstacles")

    @property
    def targets(self) -> np.ndarray:
        """(B, U, W, H) bool: the cells the decider knows to hold a target."""
        return self._map("targets")

    @property
    def density(self) -> np.ndarray:
        """(B, U, W, H) float32: the probability left on each cell in units of a uniform prior's cell (the
        class docstring); 1 where unexplored and 0 where explored when not given. Shared: do not modify it."""
        if self._maps["density"] is None:
            return self._unexplored
        return self._map("density")

    @property
    def pod(self) -> float:
        """The detector's probability of detection per pass (what `uniform_density` reads)."""
        return self._pod

    @property
    def uniform_density(self) -> np.ndarray:
        """(B, U, W, H) float32: `density` as a uniform prior would leave it after the passes the decider
        knows of, (1 - pod) ** passes: what a planner that ignores the prior weighs (1 where unexplored and
        0 where explored with pod 1). Shared: do not modify it."""
        if self._maps["passes"] is None or self.pod >= 1.0:
            return self._unexplored
        miss: np.ndarray = np.float32(1.0 - self.pod) ** np.arange(256, dtype=np.float32)
        result: np.ndarray = miss[self._map("passes")]
        return result

    @cached_property
    def _unexplored(self) -> np.ndarray:
        return (~self.explored).astype(np.float32)

    # --- sizes --------------------------------------------------------------------------------------
    @property
    def batch(self) -> int:
        result: int = self.explored.shape[0]
        return result

    @property
    def deciders(self) -> int:
        result: int = self.explored.shape[1]
        return result

    @property
    def vehicles(self) -> int:
        result: int = self.positions.shape[2]
        return result

    @property
    def width(self) -> int:
        result: int = self.explored.shape[2]
        return result

    @property
    def height(self) -> int:
        result: int = self.explored.shape[3]
        return result

    # --- derived views (computed once per Beliefs) ---------------------------------------------------
    @cached_property
    def _rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Index arrays (B, 1) and (1, U) over batches and deciders."""
        return np.arange(self.batch)[:, None], np.arange(self.deciders)[None, :]

    @cached_property
    def pos(self) -> np.ndarray:
        """(B, U, 2) each decider's own cell."""
        bi, ui = self._rows
        result: np.ndarray = self.positions[bi, ui, self.me]
        return result

    @cached_property
    def others(self) -> np.ndarray:
        """(B, U, N) bool: vehicle n is another vehicle whose position the decider knows."""
        n = np.arange(self.vehicles)
        result: np.ndarray = (self.positions[..., 0] >= 0) & (n[None, None, :] != self.me[..., None])
        return result

    @cached_property
    def crews(self) -> list[Crew] | None:
        """For a few deciders (B x U x N <= SMALL), flat over (B, U): each decider's own cell, whether
        it hovers, and the (x, y, hovering) of each other vehicle whose position it knows (`others`),
        as Python ints; None for more. At batch 1 a numpy call costs more than the arithmetic, so the
        decision rules and the observation's vehicle channels read these (same results)."""
        b, u, n, _ = self.positions.shape
        if b * u * n > SMALL:
            return None
        crews: list[Crew] = []
        for row, hover, me in zip(
            self.positions.reshape(b * u, n, 2).tolist(),
            self.hovering.reshape(b * u, n).tolist(),
            self.me.reshape(-1).tolist(),
        ):
            known = [(x, y, hv) for i, ((x, y), hv) in enumerate(zip(row, hover)) if i != me and x >= 0]
            crews.append((tuple(row[me]), hover[me], known))
        return crews

    def out_of_touch(self, steps: int) -> np.ndarray:
        """(B, U) int: the other vehicles the decider has not heard from in the last `steps` steps, one
        never heard from counting as heard at step 0 (the swarm sets out together); all zero without
        `heard` (ideal sharing)."""
        if self.heard is None:
            return np.zeros(self.me.shape, dtype=np.int64)
        others = np.arange(self.vehicles)[None, None, :] != self.me[..., None]
        silent = silent_since(self.heard, self.step, steps)
        result: np.ndarray = (silent & others).sum(-1)
        return result

    @cached_property
    def hovering_self(self) -> np.ndarray:
        """(B, U) bool: the decider hovers on a target (it stays there)."""
        bi, ui = self._rows
        result: np.ndarray = self.hovering[bi, ui, self.me]
        return result

    def _cell_counts(self, which: np.ndarray) -> np.ndarray:
        """(B, U, W, H) int: how many of the vehicles selected by `which` (B, U, N) are on each cell."""
        b, u, w, h = self.explored.shape
        if not which.any():
            return np.zeros((b, u, w, h), dtype=np.int64)
        bi, ui, ni = np.nonzero(which)
        flat = ((bi * u + ui) * w + self.positions[bi, ui, ni, 0]) * h + self.positions[bi, ui, ni, 1]
        return np.bincount(flat, minlength=b * u * w * h).reshape(b, u, w, h)

    @cached_property
    def others_count(self) -> np.ndarray:
        """(B, U, W, H) int: how many other vehicles the decider believes are on each cell."""
        return self._cell_counts(self.others)

    @cached_property
    def held(self) -> np.ndarray:
        """(B, U, W, H) bool: cells of the other vehicles the decider believes hover on a target. They
        stay there and the guard refuses every move into them, so planners go round them."""
        return self._cell_counts(self.others & self.hovering) > 0

    @cached_property
    def hover_cells(self) -> np.ndarray:
        """(B, U, W, H) bool: cells of every vehicle the decider believes hovers on a target, itself
        included: what the swarm's plan keeps every searching vehicle out of."""
        return self._cell_counts((self.positions[..., 0] >= 0) & self.hovering) > 0

    @cached_property
    def blocked(self) -> np.ndarray:
        """(B, U, W, H) bool: what the decider must not enter: known obstacles and held cells."""
        result: np.ndarray = self.obstacles | self.held
        return result

    @cached_property
    def taken(self) -> np.ndarray:
        """(B, U, W, H) bool: known targets on which the decider believes another vehicle is."""
        if not self.any_taken:
            return np.zeros(self.explored.shape, dtype=bool)
        return self.targets & (self.others_count > 0)

    @cached_property
    def any_taken(self) -> bool:
        """Whether any decider believes another vehicle sits on a target it knows (a gather at the
        others' cells, without building the grid-sized maps)."""
        b, u, w, h = self.explored.shape
        crews = self.crews
        if crews is not None:
            if not any(known for _, _, known in crews):
                return False
            targets, size = self.targets.reshape(-1), w * h
            cells = (i * size + x * h + y for i, (_, _, known) in enumerate(crews) for x, y, _ in known)
            return any(bool(targets[c]) for c in cells)
        if not np.logical_or.reduce(self.others, axis=None):
            return False
        rows = block_starts(b * u, w * h).reshape(b, u, 1)
        # an unknown position (-1, -1) reads some other cell here: `others` leaves it out
        cells = self.targets.reshape(-1)[rows + self.positions[..., 0] * h + self.positions[..., 1]]
        return bool(np.logical_or.reduce(cells & self.others, axis=None))

    @cached_property
    def any_obstacle(self) -> bool:
        """Whether any decider knows of an obstacle."""
        if self.crews is not None:  # a few maps: count_nonzero is the cheaper call there, reduce beyond
            return bool(np.count_nonzero(self.obstacles))
        return bool(np.logical_or.reduce(self.obstacles, axis=None))

    def phi_without_taken(self) -> np.ndarray:
        """phi_hat with the taken targets removed (swarmctl.world.taken), as LA(n) sees it."""
        s = self.settings
        if not self.any_taken:
            return self.phi_hat
        return remove_taken_targets(self.phi_hat, self.explored, self.taken, s.sigma2, s.phi_cutoff, s.phi_tolerance)

    def value_channel(self, remove_taken: bool = False) -> np.ndarray:
        """phi_hat - rho * omega_hat per decider (B, U, W, H) float32: unexplored cells read 1; with
        remove_taken the targets others sit on leave phi_hat first. The result may be shared: do not
        modify it."""
        if remove_taken and self.any_taken:
            base = self.phi_without_taken()
        elif self._maps["value"] is not None:
            return self._map("value")
        else:
            base = self.phi_hat
        if self.any_obstacle:
            obstacles, rho = self.obstacles, np.float32(self.settings.rho)
            if _one_map(base) and _one_map(obstacles):  # every decider reads the same maps: computed once
                return np.broadcast_to(base[:, :1] - rho * obstacles[:, :1], base.shape)
            return base - rho * obstacles
        return base

    def last_searching(self) -> np.ndarray:
        """(B, U) bool: the decider is the one vehicle not hovering on a target, by what it knows of the
        others (every other vehicle known and hovering): the paper's straggler."""
        others = np.arange(self.vehicles)[None, None, :] != self.me[..., None]
        all_hover = ((self.others & self.hovering) | ~others).all(-1)
        result: np.ndarray = ~self.hovering_self & all_hover & (self.vehicles > 1)
        return result

    def shared(self) -> np.ndarray:
        """(B,) bool: every decider of the batch holds the same maps as planners read them (explored
        cells, obstacles, targets) and the same picture of the swarm (ideal sharing): planning for the
        swarm may then be done once for the batch."""
        same = np.ones(self.batch, dtype=bool)
        maps = [self.explored, self.obstacles, self.targets, self.positions, self.hovering]
        maps += [self._map(name) for name in ("density", "passes") if self._maps[name] is not None]
        for arr in maps:
            same &= (arr == arr[:, :1]).reshape(self.batch, -1).all(1)
        return same

    def with_settings(self, **changes: Any) -> Beliefs:
        """The same beliefs under other observation settings (e.g. another variant); arrays are shared."""
        other = copy.copy(self)
        other.settings = replace(self.settings, **changes)
        other._maps, other._ready = dict(self._maps), dict(self._ready)
        if "rho" in changes:  # the value channel depends on it
            other._maps["value"] = None
            other._ready.pop("value", None)
        return other

    def select(self, batches: npt.ArrayLike) -> Beliefs:
        """The beliefs of some batches only (`batches`: bool mask or indices over B)."""
        idx = np.flatnonzero(batches) if np.asarray(batches).dtype == bool else np.asarray(batches)

        def part(name: str) -> Callable[[], np.ndarray] | None:
            return None if self._maps[name] is None else (lambda: self._map(name)[idx])

        return Beliefs(
            self.explored[idx],
            part("phi_hat"),
            part("obstacles"),
            part("targets"),
            self.positions[idx],
            self.hovering[idx],
            self.me[idx],
            self.episodes[idx],
            self.step,
            self.settings,
            part("value"),
            self.step_limit,
            part("density"),
            part("passes"),
            self.pod,
            None if self.heard is None else self.heard[idx],
        )
