"""Choosing moves in the field: the policies that run on one vehicle's Knowledge alone.

The controller has no simulator state: each agent knows only its Knowledge (explored cells, phi and
obstacles where explored, the last known cells of the others, reported targets). Supported here:

- `ddql:PATH[:tau=T][:taken=remove|keep][:straggler=network|frontier]`, `ddql-greedy:PATH`: the
  Q-network on each agent's 3 x F x F observation (Knowledge.observation, the simulator's one
  observation builder, with the targets others hover on removed unless taken=keep), batched over the
  agents of the process in one forward pass; hovering is the controller's HOVER state; with
  straggler=frontier an agent that knows every other vehicle to hover on a target takes the
  frontier planner's move;
- `frontier`: the frontier planner (swarmctl.policy.planners) run by each agent on its own
  knowledge: known targets not held by a hovering vehicle are assigned nearest pair first, the
  others go to the nearest unexplored cell, spread apart by claims;
- `la:N`: the look-ahead planner run by each agent on its own knowledge (the vehicles it knows of
  enter as counts per cell; targets they sit on are removed from its value map, as in the simulator);
- `random`: uniform over the five moves.

`lawnmower` sweeps fixed lanes planned from every vehicle's start for the whole episode; it has no
per-agent form and is refused for missions (use it in `swarmctl eval`). `oracle` reads the truth.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from swarmctl.errors import InputError
from swarmctl.knowledge.model import PHI_TOLERANCE, Knowledge
from swarmctl.policy import planners
from swarmctl.policy.ddql import allowed_moves, choose
from swarmctl.policy.registry import make_policy
from swarmctl.world.config import WorldConfig
from swarmctl.world.moves import MOVES

FIELD_POLICIES = "ddql:PATH[:options], ddql-greedy:PATH, la:N, frontier, random"


@dataclass
class Choice:
    move: int
    obs_digest: str | None = None
    q: list[float] | None = None
    by: str | None = None  # "frontier" when ddql's straggler=frontier took the move from the network


def _blocked(kn: Knowledge) -> np.ndarray:
    """(W, H) bool: the obstacles the agent knows of, and the cells of the peers hovering on a target:
    those stay there and the guard refuses every move into them, so planners go round them."""
    blocked = kn.obstacle.copy()
    for p in kn.peers.values():
        if p.on_target and p.cell is not None:
            blocked[p.cell] = True
    return blocked


class _FieldView:
    """The attributes the frontier planner reads: batch 1, the given vehicles' cells in that order."""

    def __init__(self, kn: Knowledge, cells: list, targets: np.ndarray, window: int, fov: float):
        self.batch, self.uavs = 1, len(cells)
        self.width, self.height = kn.width, kn.height
        self.cfg = SimpleNamespace(window=window, fov=fov)
        self.pos = np.array(cells, dtype=np.int64).reshape(1, -1, 2)
        self.explored = np.broadcast_to(kn.explored, (1, self.uavs, kn.width, kn.height))
        self._obstacles = np.broadcast_to(_blocked(kn), (1, self.uavs, kn.width, kn.height))
        self.targets = np.asarray(targets, dtype=np.int64).reshape(1, -1, 2)

    def known_obstacles(self) -> np.ndarray:
        return self._obstacles


def _frontier_move(kn: Knowledge, rng: np.random.Generator, window: int, fov: float) -> int:
    """The frontier planner's move for this agent, from its own knowledge.

    The vehicles it knows of (itself included; those hovering on a target are done and left out) are
    taken in mission order, as the centralised planner would: known targets go nearest pair first,
    and the exploration claims of the vehicles before this one are respected. Only the distance maps
    the decision needs are computed."""
    own = kn.own_position
    me_id = kn.vehicle_id
    peers = {v: p.cell for v, p in kn.peers.items() if p.cell is not None and not p.on_target}
    order = sorted([me_id, *peers])
    cells = [own.cell if v == me_id else peers[v] for v in order]
    me = order.index(me_id)
    held = {p.cell for p in kn.peers.values() if p.on_target and p.cell is not None}
    targets = np.array([c for c in sorted(kn.targets) if c not in held], dtype=np.int64).reshape(-1, 2)
    has_target = np.zeros((1, len(cells)), dtype=bool)
    goal = None
    dist = None
    if len(targets):
        view = _FieldView(kn, cells, targets, window, fov)
        dist = planners._distances_from_vehicles(view)
        goals, has_target = planners._target_goals(view, dist)
        if has_target[0, me]:
            goal = goals[0, me]
    if goal is None:
        first = _FieldView(kn, cells[: me + 1], targets, window, fov)
        d = dist[:, : me + 1] if dist is not None else planners._distances_from_vehicles(first)
        explore, _ = planners._nearest_unexplored(first, d, ~has_target[:, : me + 1], rng, spread=2 * fov)
        goal = explore[0, me]
    alone = _FieldView(kn, [own.cell], targets, window, fov)
    return int(planners._navigate(alone, np.asarray(goal, dtype=np.int64).reshape(1, 1, 2), rng)[0, 0])


class _KnowledgeWorld:
    """One agent's Knowledge in the form LA(n) reads a SearchEnv: a batch of one with one vehicle, the
    others it knows of entering as counts per cell. phi is the quantised phi the codec carries.

    A vehicle hovering on a target will not move again and the guard refuses every move into its
    cell, so here that cell is an obstacle to plan round (in the simulator, where nothing refuses
    the move, LA(n) would pass through it)."""

    batch = uavs = 1
    phi_tolerance = PHI_TOLERANCE

    def __init__(self, kn: Knowledge):
        self.kn = kn
        self.width, self.height = kn.width, kn.height
        self.cfg = SimpleNamespace(sigma2=WorldConfig.sigma2, phi_cutoff=WorldConfig.phi_cutoff)  # the value map's
        self.explored = kn.explored[None, None]
        self.pos = np.array(kn.own_position.cell, dtype=np.int64).reshape(1, 1, 2)
        self.target_mask = np.zeros((1, kn.width, kn.height), dtype=bool)
        for cell in kn.targets:
            self.target_mask[(0, *cell)] = True

    def known_value(self) -> np.ndarray:
        return np.where(self.explored, self.kn.phi, np.float32(1.0))

    def known_obstacles(self) -> np.ndarray:
        return self.explored & _blocked(self.kn)

    def taken_targets(self) -> np.ndarray:
        return self.kn.taken_targets()[None, None]

    def others_count(self) -> np.ndarray:
        count = np.zeros((1, 1, self.width, self.height), dtype=np.int64)
        for p in self.kn.peers.values():
            if p.cell is not None:
                count[(0, 0, *p.cell)] += 1
        return count


class FieldPolicy:
    """One policy for every agent of a process; `choose` decides for all of them at once."""

    def __init__(self, spec: str, seed: int = 0, window: int = 20, fov: float = 3.0):
        self.spec = spec.strip()
        self.rng = np.random.default_rng(seed)
        self.window, self.fov = window, fov
        self.net = None
        self.tau: float | None = None
        kind = self.spec.partition(":")[0]
        if kind in ("ddql", "ddql-greedy"):
            from swarmctl.policy.ddql import make_ddql_policy

            p = make_ddql_policy(self.spec)
            if p.net.window != window:
                raise InputError(
                    f"policy {self.spec!r}: the model was trained for {p.net.window} x {p.net.window} "
                    f"observations, the controller builds {window} x {window}; use a model trained "
                    f"with --window {window}"
                )
            self.net, self.tau, self.kind = p, p.tau, "ddql"
        elif kind == "la":
            self.lookahead = make_policy(self.spec)
            self.lookahead.reset(None, self.rng)
            self.kind = "la"
        elif self.spec in ("frontier", "random"):
            self.kind = self.spec
        else:
            raise InputError(
                f"policy {self.spec!r} cannot fly a mission: use one of {FIELD_POLICIES} "
                "(lawnmower plans every vehicle's lanes at once; oracle reads the truth)"
            )

    def choose(self, knowledges: list[Knowledge]) -> list[Choice]:
        if not knowledges:
            return []
        if self.kind == "random":
            return [Choice(int(m)) for m in self.rng.integers(0, len(MOVES), size=len(knowledges))]
        if self.kind == "frontier":
            return [Choice(_frontier_move(kn, self.rng, self.window, self.fov)) for kn in knowledges]
        if self.kind == "la":
            return [Choice(int(self.lookahead.act(_KnowledgeWorld(kn))[0, 0])) for kn in knowledges]
        taken = self.net.remove_taken
        obs = np.stack([kn.observation(self.window, remove_taken=taken) for kn in knowledges])[None]  # (1, N, ...)
        q = self.net.q_values(np.ascontiguousarray(obs, dtype=np.float32))  # (1, N, 5)
        cells = np.array([kn.own_position.cell for kn in knowledges], dtype=np.int64)[None]
        # a searching agent is never on a free known target (it would hover): with hover it always moves
        hover_here = np.zeros(cells.shape[:2], dtype=bool) if self.net.hover else None
        blocked = (
            np.stack([_KnowledgeWorld(kn).known_obstacles()[0, 0] for kn in knowledges])[None]
            if self.net.mask
            else None
        )
        moves = choose(q, allowed_moves(cells, hover_here, blocked), self.tau, self.rng)[0]
        by = [None] * len(knowledges)
        if self.net.straggler_frontier:
            for i, kn in enumerate(knowledges):
                if _last_searching(kn):
                    moves[i], by[i] = _frontier_move(kn, self.rng, self.window, self.fov), "frontier"
        q = q[0]
        return [
            Choice(int(m), hashlib.sha1(o.tobytes()).hexdigest()[:16], [round(float(v), 4) for v in qv], b)
            for m, o, qv, b in zip(moves, obs[0], q, by)
        ]


def _last_searching(kn: Knowledge) -> bool:
    """Every other vehicle this agent knows of hovers on a target: it is the last one searching."""
    return bool(kn.peers) and all(p.on_target for p in kn.peers.values())
