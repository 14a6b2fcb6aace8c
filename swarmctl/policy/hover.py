"""The hover rule: when a vehicle on a target parks there (the controller's HOVER state).

- `first`: a vehicle parks on the first target it reaches that nobody holds (the paper's rule, and
  the default of frontier, lawnmower, la:N and the networks trained with it);
- `defer`: no vehicle parks while the swarm knows fewer targets than it has vehicles (fewer free
  targets than searching vehicles): everyone explores until then, then the known targets are
  reached. Without it the last vehicle searches a big map alone (the paper's straggler);
- `no`: nobody parks (a search that marks its finds and goes on, `on_find = "mark"`).

The rule reads only the beliefs (targets known, the swarm's size) and, in a mission whose finish line
holds fewer targets than it flies vehicles (`expected_targets`), that number (a policy's `hold`), so
the simulator and the field apply it alike; `known targets >= vehicles` only ever turns true during a
mission, so a vehicle that parks stays parked, as HOVER does.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from swarmctl.world.beliefs import Beliefs

DEFER, FIRST, NO = "defer", "first", "no"
HOVER_RULES = (DEFER, FIRST, NO)
HOVER_ALIASES = {"yes": FIRST}  # ddql's older spelling


def park_allowed(known_targets: np.ndarray, vehicles: int, hold: int | None = None) -> np.ndarray:
    """Whether a swarm of `vehicles` that knows `known_targets` targets (any shape) may park now
    under `defer`: it knows at least as many targets as it has vehicles, or as it is to hold (`hold`:
    a mission's expected_targets, when fewer)."""
    need = vehicles if hold is None else min(hold, vehicles)
    return np.asarray(known_targets) >= need


def parking(rule: str, known_targets: npt.ArrayLike, vehicles: int, hold: int | None = None) -> np.ndarray:
    """Whether a vehicle on a free target parks there now under `rule`, per belief holder."""
    known_targets = np.asarray(known_targets)
    if rule == FIRST:
        return np.ones(known_targets.shape, dtype=bool)
    if rule == NO:
        return np.zeros(known_targets.shape, dtype=bool)
    return park_allowed(known_targets, vehicles, hold)


def parks(beliefs: Beliefs, rule: str, hold: int | None = None) -> np.ndarray:
    """(B, U) bool: the decider is on a target it holds and parks there now under `rule`."""
    here = beliefs.hovering_self
    if rule == FIRST or not here.any():
        return here
    if rule == NO:
        return np.zeros(here.shape, dtype=bool)
    result: np.ndarray = here & park_allowed(beliefs.targets.sum((2, 3)), beliefs.vehicles, hold)
    return result
