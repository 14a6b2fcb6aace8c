"""How the search stands against where the person is likely to be: the mission's prior, the detector's
probability of detection and the team's passes, and the probability of success (POS) they give.

The formulas are swarmctl.world.prior's: a pass over a cell is its entry into a vehicle's footprint
(the one the sensing step explores, swarmctl.mission.sensing): when a vehicle reaches a cell (its launch
cell included) the cells of the footprint there that the footprint it last looked from did not hold
gain a pass; staying adds none. After n passes a cell keeps prior * (1 - pod) ** n of its prior; POS
is 1 minus what the map keeps.

The passes counted are this process's vehicles' own. In onboard mode (one agent per process) the other
processes' vehicles' looks arrive only as explored cells in the agents' knowledge: a cell explored there
that none of this process's vehicles looked at counts as one pass.

POS is always computed against the mission's prior (uniform when it gives none) and pod, whatever the
policy: the coordinated planner and the other planners are given the density it leaves
(`Beliefs.density`), the learned policies ignore it.
"""

from __future__ import annotations

import numpy as np

from swarmctl.knowledge.model import disc_cells
from swarmctl.world import prior as search_prior

WEIGHT_DECIMALS = 8  # the prior event's weights
POS_DECIMALS = 4  # POS in step records and the summary


class SearchProbability:
    """The mission's prior (W, H), the detector's pod, the sensing radius `fov` (cells) and the team's pass
    counts, updated as vehicles arrive at cells (`look`) and, onboard, as the agents learn of cells
    explored by other processes (`note_explored`)."""

    def __init__(
        self, prior: np.ndarray | None, free: np.ndarray, pod: float, fov: float, source: str = "uniform"
    ) -> None:
        self.free = np.asarray(free, dtype=bool)
        self.pod = search_prior.check_pod(pod)
        self.prior = search_prior.uniform_prior(self.free) if prior is None else np.asarray(prior, dtype=np.float64)
        if self.prior.shape != self.free.shape:
            raise ValueError(f"prior of shape {self.prior.shape} on a grid of {self.free.shape}")
        self.fov = float(fov)
        self.source = source
        self.passes = np.zeros(self.free.shape, dtype=np.uint8)  # this process's vehicles' passes
        self._looked_from: dict[str, np.ndarray] = {}  # each vehicle's last footprint (W, H) bool
        self.explored_elsewhere = np.zeros(self.free.shape, dtype=bool)  # onboard: the others' explored cells

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.free.shape[0]), int(self.free.shape[1]))

    def look(self, cell: tuple[int, int], vehicle: str = "") -> None:
        """`vehicle` of this process has just reached `cell`: a pass over each cell of its footprint there
        that its last footprint did not hold."""
        w, h = self.shape
        c = disc_cells((int(cell[0]), int(cell[1])), w, h, self.fov)
        footprint = np.zeros(self.shape, dtype=bool)
        footprint[c[:, 0], c[:, 1]] = True
        before = self._looked_from.get(vehicle)
        entering = footprint if before is None else footprint & ~before
        self._looked_from[vehicle] = footprint
        self.passes = search_prior.add_passes(self.passes, entering)

    def note_explored(self, explored: np.ndarray) -> None:
        """Onboard: the cells explored in the agents' knowledge (other processes' vehicles' looks among them)."""
        self.explored_elsewhere |= np.asarray(explored, dtype=bool)

    def team_passes(self) -> np.ndarray:
        """(W, H) uint8 the passes counted: this process's, and one for a cell only other processes explored."""
        others = (self.explored_elsewhere & (self.passes == 0)).astype(np.uint8)
        return search_prior.add_passes(self.passes, others)

    def residual(self) -> np.ndarray:
        """(W, H) the probability each cell still holds the person (unnormalised)."""
        return search_prior.residual(self.prior, self.team_passes(), self.pod)

    def pos(self) -> float:
        """The probability of success so far (0 .. 1)."""
        return float(search_prior.pos(self.prior, self.team_passes(), self.pod))

    def density(self) -> np.ndarray:
        """(W, H) float32 the planners' exploration weight (swarmctl.world.prior.density)."""
        return search_prior.density(self.prior, self.team_passes(), self.pod, self.free)

    def prior_record(self) -> dict:
        """The recording's `prior` event: pod, the normalised prior (W lists of H floats) and its source."""
        weights = np.round(self.prior, WEIGHT_DECIMALS).tolist()
        return dict(pod=self.pod, weights=weights, source=self.source)

    def summary(self) -> dict:
        """What summary.json adds: the final POS and the team's pass counts (W lists of H ints)."""
        return dict(pos=round(self.pos(), POS_DECIMALS), passes=self.team_passes().tolist())

    def describe(self) -> str:
        """How the search is scored, in a line."""
        source = "a uniform prior" if self.source == "uniform" else f"the prior {self.source}"
        return f"POS against {source} with pod {self.pod:g}"
