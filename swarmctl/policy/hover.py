"""The hover rule: when a vehicle on a target parks there (the controller's HOVER state).

- `first`: a vehicle parks on the first target it reaches that nobody holds (the paper's rule, and
  the default of frontier, lawnmower, la:N and the networks trained with it);
- `defer`: no vehicle parks while the swarm knows fewer targets than it has vehicles (fewer free
  targets than searching vehicles): everyone explores until then, then the known targets are
  reached. Without it the last vehicle searches a big map alone (the paper's straggler);
- `no`: nobody parks (a search that marks its finds and goes on, `on_find = "mark"`).

The rule reads only the beliefs (targets known, the swarm's size, when each teammate was last heard)
and, in a mission whose finish line holds fewer targets than it flies vehicles (`expected_targets`),
that number (a policy's `hold`), so the simulator and the field apply it alike. With ideal sharing
`known targets >= vehicles` only ever turns true during a mission, so a vehicle that parks stays
parked, as HOVER does; over a lossy channel a teammate heard again counts again, and in the
simulator a parked vehicle may then leave its target where the controller's HOVER holds it.

Over a lossy channel a vehicle knows fewer targets than the swarm does, and with 10 vehicles on a
50 x 50 map the swarm's vehicles each waited for targets the others had found until the step limit
(docs/RESULTS.md, "When knowledge is lost"). So a teammate not heard from
in the last OUT_OF_TOUCH_STEPS steps is not counted among the vehicles the known targets must cover:
it may hold a target this vehicle never heard of, and nobody can wait for it. One never heard from
counts as heard at step 0 (the swarm sets out together); the controller counts the vehicles it flies
itself as heard while their links are up, taking off included (Beliefs.heard). With ideal sharing
every teammate is heard every step and the rule is unchanged. In the field a report's step is its
sender's round: a vehicle of another process that runs more than OUT_OF_TOUCH_STEPS rounds behind
counts as out of touch, and a vehicle gone home or down stops being counted once it stops reporting.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from swarmctl.world.beliefs import Beliefs

DEFER, FIRST, NO = "defer", "first", "no"
HOVER_RULES = (DEFER, FIRST, NO)
HOVER_ALIASES = {"yes": FIRST}  # ddql's older spelling
# steps without news after which `defer` stops counting a teammate: 5, 10 and 20 found all targets in 0.80,
# 0.83 and 0.73 of seed 0's 60 lossy 10-vehicle searches (docs/RESULTS.md); the longer of the two best
# forgives a radio's longer gaps
OUT_OF_TOUCH_STEPS = 10


def park_allowed(
    known_targets: npt.ArrayLike, vehicles: int, hold: int | None = None, out_of_touch: npt.ArrayLike = 0
) -> np.ndarray:
    """Whether a swarm of `vehicles` that knows `known_targets` targets (any shape) may park now
    under `defer`: it knows at least as many targets as it has vehicles in touch (`out_of_touch`:
    the teammates not heard from lately, same shape or a scalar), or as it is to hold (`hold`: a
    mission's expected_targets, when fewer)."""
    need = np.maximum(vehicles - np.asarray(out_of_touch), 1)
    if hold is not None:
        need = np.minimum(need, hold)
    result: np.ndarray = np.asarray(known_targets) >= need
    return result


def parking(
    rule: str, known_targets: npt.ArrayLike, vehicles: int, hold: int | None = None, out_of_touch: npt.ArrayLike = 0
) -> np.ndarray:
    """Whether a vehicle on a free target parks there now under `rule`, per belief holder."""
    known_targets = np.asarray(known_targets)
    if rule == FIRST:
        return np.ones(known_targets.shape, dtype=bool)
    if rule == NO:
        return np.zeros(known_targets.shape, dtype=bool)
    return park_allowed(known_targets, vehicles, hold, out_of_touch)


def swarm_parking(
    beliefs: Beliefs, rule: str, hold: int | None = None, rows: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """(B, U) bool, or (M,) for the deciders `rows` = (hb, hu): whether, as the decider knows the swarm,
    a vehicle on a free target parks there now under `rule` (the targets it knows, the teammates it is
    in touch with)."""
    hb, hu = rows if rows is not None else (slice(None), slice(None))
    known = beliefs.targets[hb, hu].sum((-2, -1))
    if rule != DEFER:
        return parking(rule, known, beliefs.vehicles)
    return park_allowed(known, beliefs.vehicles, hold, beliefs.out_of_touch(OUT_OF_TOUCH_STEPS)[hb, hu])


def parks(beliefs: Beliefs, rule: str, hold: int | None = None) -> np.ndarray:
    """(B, U) bool: the decider is on a target it holds and parks there now under `rule`."""
    here = beliefs.hovering_self
    if rule == FIRST or not here.any():
        return here
    result: np.ndarray = here & swarm_parking(beliefs, rule, hold)
    return result
