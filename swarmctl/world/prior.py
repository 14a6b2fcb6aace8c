"""Where the missing person is likely to be, and how much of that the search has covered.

A prior is a probability per free cell (it sums to 1 over the free cells; blocked cells hold 0). The
detector sees a target in a pass over its cell with probability `pod`. A pass over a cell is its entry
into a vehicle's footprint: when the vehicle reaches a cell (its launch cell included), the cells of the
footprint there that were not in the footprint it looked from before gain a pass. A cell that stays in
the footprint as the vehicle moves on is still the same look, and staying adds none: a sweep past a
cell is one chance to see the person there, not one per frame. After n passes without a find, Bayes
leaves a cell the weight

    residual = prior * (1 - pod) ** n          (the posterior is residual / residual.sum())

and the probability of success so far, POS, is what the search would have found had the person been
anywhere the prior says:

    POS = sum(prior * (1 - (1 - pod) ** n)) = 1 - residual.sum()

With pod = 1 and a uniform prior, POS is the explored share of the free cells and `density` is 1 on
every unexplored cell and 0 on every explored one: the paper's "unexplored" map. Every function takes
any leading batch axes (..., W, H).
"""

from __future__ import annotations

import numpy as np

from swarmctl.errors import ScenarioError

MAX_PASSES = 255  # pass counts saturate (uint8): (1 - pod) ** 255 is 0 to float precision for pod >= 0.15


def normalise_prior(weights: np.ndarray, free: np.ndarray, name: str = "prior") -> np.ndarray:
    """(..., W, H) float64 probabilities over the free cells from non-negative weights: 0 on blocked
    cells, each map summing to 1. ScenarioError naming `name` for a weight that is negative or not
    finite, or a map whose free cells weigh nothing."""
    w = np.asarray(weights, dtype=np.float64)
    free = np.broadcast_to(np.asarray(free, dtype=bool), w.shape)
    if not np.isfinite(w).all():
        raise ScenarioError(f"{name}: every weight must be a finite number")
    if (w < 0).any():
        raise ScenarioError(f"{name}: weights must be >= 0 (found {float(w.min()):g})")
    w = np.where(free, w, 0.0)
    total = w.sum(axis=(-2, -1), keepdims=True)
    if (total <= 0).any():
        raise ScenarioError(f"{name}: the free cells carry no weight; give some cell a weight > 0")
    result: np.ndarray = w / total
    return result


def uniform_prior(free: np.ndarray) -> np.ndarray:
    """(..., W, H) every free cell equally likely: the paper's search, and POS's prior when none is given."""
    return normalise_prior(np.ones(np.shape(free)), free)


def check_pod(pod: float, name: str = "pod") -> float:
    """pod as a float in (0, 1]; ScenarioError otherwise."""
    pod = float(pod)
    if not (np.isfinite(pod) and 0.0 < pod <= 1.0):
        raise ScenarioError(f"{name} = {pod}: the probability of detection must be in (0, 1]")
    return pod


def residual(prior: np.ndarray, passes: np.ndarray, pod: float) -> np.ndarray:
    """(..., W, H) float64 the probability each cell still holds the person, unnormalised (module docstring)."""
    miss = 1.0 - check_pod(pod)
    n = np.asarray(passes)
    if miss == 0.0:  # 0 ** 0 is 1: an unseen cell keeps its prior, a seen one is cleared
        return np.where(n > 0, 0.0, np.asarray(prior, dtype=np.float64))
    if n.dtype == np.uint8:  # pass counts: one power per count, then a gather (the simulator's every step)
        gathered: np.ndarray = np.asarray(prior, dtype=np.float64) * miss_table(pod)[n]
        return gathered
    result: np.ndarray = np.asarray(prior, dtype=np.float64) * miss ** n.astype(np.float64)
    return result


def miss_table(pod: float) -> np.ndarray:
    """(MAX_PASSES + 1,) float64 (1 - pod) ** n for n = 0 .. MAX_PASSES: what n passes leave of a cell's prior."""
    table: np.ndarray = (1.0 - check_pod(pod)) ** np.arange(MAX_PASSES + 1, dtype=np.float64)
    return table


def pos(prior: np.ndarray, passes: np.ndarray, pod: float) -> np.ndarray:
    """(...) the probability of success so far: 1 - the residual left on the map (0 .. 1)."""
    left = residual(prior, passes, pod).sum(axis=(-2, -1))
    result: np.ndarray = np.clip(np.asarray(prior, dtype=np.float64).sum(axis=(-2, -1)) - left, 0.0, 1.0)
    return result


def density(prior: np.ndarray, passes: np.ndarray, pod: float, free: np.ndarray) -> np.ndarray:
    """(..., W, H) float32 the residual per cell in units of a uniform prior's cell (1 / free cells):
    1 on an unexplored cell and 0 on an explored one when the prior is uniform and pod is 1. The
    planners' exploration weight."""
    cells = np.maximum(np.asarray(free, dtype=bool).sum(axis=(-2, -1), keepdims=True), 1)
    result: np.ndarray = (residual(prior, passes, pod) * cells).astype(np.float32)
    return result


def add_passes(passes: np.ndarray, looks: np.ndarray) -> np.ndarray:
    """passes + looks (bool or counts), saturating at MAX_PASSES, as uint8."""
    total = np.asarray(passes, dtype=np.int64) + np.asarray(looks, dtype=np.int64)
    return np.minimum(total, MAX_PASSES).astype(np.uint8)


def hotspot_prior(free: np.ndarray, share: float, area: float, rng: np.random.Generator, spots: int = 2) -> np.ndarray:
    """(W, H) a prior that puts `share` of the probability in about `area` of the free cells: the
    free cells nearest `spots` random centres (grown by Euclidean distance, as a person's likely
    places cluster round a few features), the rest spread evenly over the other free cells."""
    free = np.asarray(free, dtype=bool)
    if not (0.0 < share < 1.0 and 0.0 < area < 1.0):
        raise ScenarioError(f"hotspot prior: share {share} and area {area} must be in (0, 1)")
    cells = np.argwhere(free)
    if len(cells) < 2:
        raise ScenarioError("hotspot prior: the map needs at least 2 free cells")
    centres = cells[rng.choice(len(cells), size=min(spots, len(cells)), replace=False)]
    d = np.min(np.linalg.norm(cells[:, None, :] - centres[None].astype(np.float64), axis=2), axis=1)
    hot_count = int(np.clip(round(area * len(cells)), 1, len(cells) - 1))
    hot = np.zeros(len(cells), dtype=bool)
    hot[np.argsort(d, kind="stable")[:hot_count]] = True
    w = np.zeros(free.shape, dtype=np.float64)
    w[cells[hot, 0], cells[hot, 1]] = share / hot_count
    w[cells[~hot, 0], cells[~hot, 1]] = (1.0 - share) / (len(cells) - hot_count)
    return normalise_prior(w, free)


def draw_cells(prior: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count, 2) distinct cells drawn from a (W, H) prior, without replacement (ScenarioError when it
    has fewer cells with weight)."""
    p = np.asarray(prior, dtype=np.float64).ravel()
    nonzero = int((p > 0).sum())
    if count > nonzero:
        raise ScenarioError(f"{count} targets cannot be drawn from a prior with {nonzero} cells of weight > 0")
    flat = rng.choice(p.size, size=count, replace=False, p=p / p.sum())
    return np.stack(np.divmod(flat, np.shape(prior)[1]), axis=1).astype(np.int64)
