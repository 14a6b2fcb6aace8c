"""Choosing moves in the field: every policy on the agents' beliefs, as in the simulator.

The controller has no simulator state: each agent knows only its Knowledge (explored cells, phi and
obstacles where explored, the last known cells of the others and whether they hover, reported
targets). `FieldPolicy` builds the Beliefs of the searching agents of the process from their
Knowledge (swarmctl.knowledge.model.beliefs_from_knowledge, the counterpart of SearchEnv.beliefs) and
hands them to the very policy object the simulator evaluates (swarmctl.policy): `ddql:PATH[:options]`
and `ddql-greedy:PATH` (the Q-network, one forward pass for all agents of the process, observed with
the settings stored in the checkpoint: window, rho, sigma2, fov), `la:N`, `frontier`, `lawnmower`
(its lanes planned from the first beliefs and kept), `random`, and `pattern:NAME` (a search pattern's
routes, swarmctl.policy.routes: the plan gives them, `set_routes`, from the grid and `[mission] lkp`).
The oracle reads the truth: it is not a policy and cannot fly.

Inference runs on one CPU thread (swarmctl.policy.threads; SWARMCTL_THREADS changes it for fly, agent
and demo).

Hovering is the controller's HOVER state, so the agents asked to choose never hover themselves. When
an agent on a target parks there is the hover rule's call (`FieldPolicy.parks`): `defer` unless the
policy spec names another with `:hover=` or the network was trained under a search recipe's rule, so
nobody parks while the swarm knows fewer targets than it has vehicles. Under `no` (the recipe's) nobody
parks on the way: the swarm holds once every vehicle sits on a target of its own (Rounds).
With `[mission] on_find = "mark"` nobody hovers on a target: every target found is reported and done,
so the policy is given beliefs without them (`targets_done`): no known target, and the value near each
removed as a taken target's is (swarmctl.world.taken), so planners and the network search on for
others instead of flying back to it.

Planners are given the mission's search probability (`set_search`, swarmctl.mission.probability): each
searching agent's Beliefs carry the density the prior leaves after the team's passes with the detector's
pod, so the coordinated planner goes where the probability is. The learned policies ignore the prior
(their networks were trained on the unexplored map).
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Collection
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from swarmctl.errors import InputError
from swarmctl.knowledge.model import PHI_TOLERANCE, Knowledge, beliefs_from_knowledge
from swarmctl.policy.ddql import DDQLPolicy
from swarmctl.policy.hover import DEFER, HOVER_RULES, parking
from swarmctl.policy.registry import is_route_spec, make_decider, make_route_policy
from swarmctl.policy.routes import RoutePolicy
from swarmctl.policy.threads import set_inference_threads
from swarmctl.world.beliefs import Beliefs, ObservationSettings
from swarmctl.world.taken import remove_taken_targets

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.mission.probability import SearchProbability

FIELD_POLICIES = (
    "coordinated, ddql:PATH[:options], ddql-greedy:PATH, la:N, frontier, lawnmower, random, pattern:NAME (with lkp)"
)


def obs_digest(obs) -> str:
    """The digest a step record keeps of a ddql observation (3, F, F): sha1 of its bytes, 16 hex digits."""
    return hashlib.sha1(obs.tobytes()).hexdigest()[:16]


@dataclass
class Choice:
    move: int
    obs_digest: str | None = None
    q: list[float] | None = None
    by: str | None = None  # "frontier" when ddql's straggler=frontier took the move from the network


class FieldPolicy:
    """One policy for every agent of a process; `choose` decides for all of them at once. The model is
    loaded once, here."""

    def __init__(self, spec: str, seed: int = 0, hover: str | None = None):
        self.spec = spec.strip()
        self.seed = int(seed)
        set_inference_threads()  # before the model is loaded: SWARMCTL_THREADS, default one thread
        if self.spec == "oracle":
            raise InputError(
                f"policy {self.spec!r} cannot fly a mission: it reads the hidden targets; use one of {FIELD_POLICIES}"
            )
        self.policy = make_route_policy(self.spec) if is_route_spec(self.spec) else make_decider(self.spec)
        self._routes_given = False
        # a mission parks on a target as its spec's `:hover=` says, else as `hover` says (a recording's
        # rule, for replay --verify), else as the network was trained (a search recipe's rule: it flies as
        # trained), else it defers (swarmctl.policy.hover)
        trained = self.policy.trained_hover if isinstance(self.policy, DDQLPolicy) else None
        rule = self.policy.hover if re.search(r":hover=", self.spec) else (hover or trained or DEFER)
        if not isinstance(rule, str) or rule not in HOVER_RULES:  # (a spec's rule is a name, never a bool)
            raise InputError(f"hover rule {rule!r} is unknown: use one of {', '.join(HOVER_RULES)}")
        self.hover = rule
        self.policy.hover = self.hover
        self.hold: int | None = None
        self.search: SearchProbability | None = None
        if isinstance(self.policy, DDQLPolicy):
            self.settings = self.policy.field_settings(PHI_TOLERANCE)
        else:
            self.settings = ObservationSettings(phi_tolerance=PHI_TOLERANCE)
        self._started = False

    @property
    def fov(self) -> float:
        """The sensing radius (cells) the policy expects: the model's trained fov, 3 for planners."""
        return self.settings.fov

    @property
    def window(self) -> int:
        return self.settings.window

    @property
    def weights_sha256(self) -> str | None:
        """The hash of the network's weights (swarmctl.policy.checkpoint); None for planners."""
        return self.policy.info["weights_sha256"] if isinstance(self.policy, DDQLPolicy) else None

    @property
    def forward(self) -> str | None:
        """What runs the network (torch or onnx, swarmctl.policy.forward); None for planners."""
        return self.policy.forward.name if isinstance(self.policy, DDQLPolicy) else None

    def recorded(self) -> dict:
        """What the recording's mission line keeps so that `swarmctl replay --verify` rebuilds this policy."""
        return dict(
            seed=self.seed, weights_sha256=self.weights_sha256, forward=self.forward, hover=self.hover, hold=self.hold
        )

    def set_hold(self, hold: int | None) -> None:
        """The targets the mission is to hold (its finish line's N), when fewer than its vehicles: the
        swarm parks once it knows that many (None: one a vehicle)."""
        self.hold = None if hold is None else int(hold)
        self.policy.hold = self.hold

    def set_search(self, search: SearchProbability | None) -> None:
        """The mission's search probability, whose density the planners' beliefs carry (not the networks')."""
        self.search = search

    @property
    def uses_prior(self) -> bool:
        """Whether the policy weighs cells by the prior (planners) or ignores it (ddql)."""
        return not isinstance(self.policy, DDQLPolicy)

    def parks(self, known_targets: int, vehicles: int, out_of_touch: int = 0) -> bool:
        """Whether an agent on a free target it knows parks there now (HOVER), the swarm of `vehicles`
        knowing `known_targets` targets, `out_of_touch` of its teammates not heard from lately
        (Knowledge.out_of_touch): the hover rule (`defer` unless the spec names another)."""
        return bool(parking(self.hover, known_targets, vehicles, self.hold, out_of_touch))

    def beliefs(
        self,
        knowledges: list[Knowledge],
        step: int = 0,
        vehicles: int | None = None,
        targets_done: bool = False,
        in_touch: Collection[int] = (),
    ) -> Beliefs:
        """The Beliefs of the searching agents whose Knowledge is given, at mission step `step`, in a swarm
        of `vehicles` (default: as many as the knowledges name), observed with this policy's settings;
        with `targets_done` (on_find = "mark") the known targets are left out (`without_targets`);
        `in_touch`: the vehicles heard now whatever their reports say (beliefs_from_knowledge)."""
        beliefs = beliefs_from_knowledge(knowledges, vehicles, self.settings, step, in_touch=in_touch)
        if targets_done:
            beliefs = without_targets(beliefs)
        return with_density(beliefs, self.search) if self.search is not None and self.uses_prior else beliefs

    @property
    def follows_routes(self) -> bool:
        """A search pattern's routes (pattern:NAME): the plan gives them (`set_routes`) before the start."""
        return isinstance(self.policy, RoutePolicy)

    def set_routes(self, routes: list[np.ndarray]) -> None:
        """Each vehicle's route of cells (routes[v]: (L, 2), v its index in the mission)."""
        if not isinstance(self.policy, RoutePolicy):
            raise TypeError(f"policy {self.spec!r} follows no routes")
        self.policy.set_routes(routes)
        self._routes_given = True

    def start(self, beliefs: Beliefs) -> None:
        """Start the policy on the mission's first beliefs (its seed; lawnmower plans its lanes); once."""
        if self.follows_routes and not self._routes_given:
            raise InputError(
                f"policy {self.spec!r}: its routes come from the mission's grid and [mission] lkp; "
                "fly it from its mission file"
            )
        if not self._started:
            self.policy.reset(beliefs, self.seed)
            self._started = True

    def decide(self, beliefs: Beliefs) -> list[Choice]:
        """A move for every decider of `beliefs` (a batch of one); the first call starts the policy."""
        self.start(beliefs)
        if not isinstance(self.policy, DDQLPolicy):
            return [Choice(int(m)) for m in self.policy.act(beliefs)[0]]
        d = self.policy.decide(beliefs)
        # Python floats from tolist() are float(v) of each float32, rounded as before
        return [
            Choice(m, obs_digest(o), [round(v, 4) for v in qv], "frontier" if by else None)
            for m, o, qv, by in zip(d.moves[0].tolist(), d.obs[0], d.q[0].tolist(), d.by_frontier[0].tolist())
        ]

    def choose(
        self, knowledges: list[Knowledge], step: int = 0, vehicles: int | None = None, targets_done: bool = False
    ) -> list[Choice]:
        """Moves for the searching agents whose Knowledge is given (`beliefs`, then `decide`)."""
        if not knowledges:
            return []
        return self.decide(self.beliefs(knowledges, step, vehicles, targets_done))


def with_density(beliefs: Beliefs, search: SearchProbability) -> Beliefs:
    """`beliefs` whose every decider weighs the cells by the search's density, passes and pod (the team's)."""
    shape = beliefs.explored.shape
    density, passes = search.density(), search.team_passes()
    return Beliefs(
        beliefs.explored,
        lambda: beliefs.phi_hat,
        lambda: beliefs.obstacles,
        lambda: beliefs.targets,
        beliefs.positions,
        beliefs.hovering,
        beliefs.me,
        beliefs.episodes,
        beliefs.step,
        beliefs.settings,
        step_limit=beliefs.step_limit,
        density=np.broadcast_to(density, shape),
        passes=np.broadcast_to(passes, shape),
        pod=search.pod,
        heard=beliefs.heard,
    )


def without_targets(beliefs: Beliefs, cells: set[tuple[int, int]] | None = None) -> Beliefs:
    """`beliefs` with every known target done (on_find = "mark": found, reported, not to be flown back
    to), or only those of `cells` (finds the operator rejected): not in `targets`, and phi_hat without
    the value they explain, removed as a taken target's (swarmctl.world.taken.remove_taken_targets; what
    other, unknown targets raise stays). Values stay on the quantised levels, so the recorded inputs
    decide the same again (replay --verify)."""
    targets = beliefs.targets
    done = targets
    if cells is not None:
        w, h = targets.shape[-2], targets.shape[-1]
        chosen = np.zeros((w, h), dtype=bool)
        for x, y in cells:
            if 0 <= x < w and 0 <= y < h:
                chosen[x, y] = True
        done = targets & chosen
    if not np.logical_or.reduce(done, axis=None):
        return beliefs
    s = beliefs.settings
    phi_hat = remove_taken_targets(beliefs.phi_hat, beliefs.explored, done, s.sigma2, s.phi_cutoff, s.phi_tolerance)
    return Beliefs(
        beliefs.explored,
        phi_hat,
        beliefs.obstacles,
        targets & ~done,
        beliefs.positions,
        beliefs.hovering,
        beliefs.me,
        beliefs.episodes,
        beliefs.step,
        s,
        step_limit=beliefs.step_limit,
        density=lambda: beliefs.density,  # the search's density, when the beliefs carry one
        pod=beliefs.pod,
        heard=beliefs.heard,
    )
