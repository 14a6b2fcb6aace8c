"""The learned policy: the shared Q-network acting for every vehicle, batched.

`ddql:PATH` samples from softmax(Q / tau) with tau = 0.1 (the paper's "DDQL Soft"; it keeps stuck
vehicles from looping), `ddql-greedy:PATH` takes argmax Q. Options, appended as `:key=value`:

- `tau=T`: the softmax temperature (default 0.1);
- `taken=remove|keep`: the targets other vehicles sit on are removed from the value channel, as
  LA(n) removes them from its value map (default remove; keep is the paper's observation);
- `hover=yes|no`: a vehicle on a target that no lower-numbered vehicle holds stays there and every
  other vehicle moves: "stay" is only ever the hover, as in the controller's HOVER state. This is
  our answer to the paper's stragglers, vehicles that stop far from any target once the others have
  found theirs (default yes; no lets the network decide, as in the paper);
- `mask=yes|no`: moves off the map or into an obstacle the vehicle knows of are never chosen, as
  LA(n) scores them -inf (default yes; no as in the paper);
- `straggler=network|frontier`: who steers the last vehicle still searching once every other one
  hovers on a target. The paper names this straggler, far from anything its window shows on a big
  map, as its residual failure; `frontier` hands it to the frontier planner (nearest unexplored
  cell) until it finds a target (default network).

`ddql:PATH:taken=keep:hover=no:mask=no` is the paper's DDQL Soft.
"""

from __future__ import annotations

import re

import numpy as np
import torch

from swarmctl.errors import InputError
from swarmctl.policy.base import hovering
from swarmctl.policy.checkpoint import load_checkpoint
from swarmctl.policy.planners import FrontierPolicy
from swarmctl.world.env import SearchEnv
from swarmctl.world.moves import MOVES, STAY


def softmax_sample(q: np.ndarray, tau: float, rng: np.random.Generator) -> np.ndarray:
    """Sample one action per row from softmax(q / tau); q is (N, A)."""
    z = (q - q.max(axis=1, keepdims=True)) / tau
    p = np.exp(z)
    p /= p.sum(axis=1, keepdims=True)
    u = rng.random((q.shape[0], 1))
    return np.minimum((p.cumsum(axis=1) < u).sum(axis=1), q.shape[1] - 1)


def allowed_moves(pos: np.ndarray, hover_here: np.ndarray | None, blocked: np.ndarray | None) -> np.ndarray:
    """(B, U, 5) bool: the moves a vehicle may take.

    pos: (B, U, 2) cells. hover_here: (B, U) bool or None; where given, a vehicle that should hover
    may only stay and any other may not. blocked: (B, U, W, H) bool, the obstacles each vehicle knows
    of, or None; where given, moves into them or off the map are refused. Stay is always left to a
    vehicle with no move at all."""
    b, u = pos.shape[:2]
    allowed = np.ones((b, u, len(MOVES)), dtype=bool)
    if blocked is not None:
        w, h = blocked.shape[-2:]
        dest = pos[:, :, None, :] + MOVES[None, None]
        inside = (dest[..., 0] >= 0) & (dest[..., 0] < w) & (dest[..., 1] >= 0) & (dest[..., 1] < h)
        bi, ui = np.arange(b)[:, None, None], np.arange(u)[None, :, None]
        allowed &= inside & ~blocked[bi, ui, np.clip(dest[..., 0], 0, w - 1), np.clip(dest[..., 1], 0, h - 1)]
    if hover_here is not None:
        allowed[..., STAY] = hover_here
        allowed[hover_here] = np.arange(len(MOVES)) == STAY
    allowed[~allowed.any(-1), STAY] = True
    return allowed


def choose(q: np.ndarray, allowed: np.ndarray, tau: float | None, rng: np.random.Generator) -> np.ndarray:
    """Moves (B, U) from Q-values (B, U, 5): softmax(Q / tau) sampling (argmax when tau is None) over
    the allowed moves."""
    b, u, a = q.shape
    q = np.where(allowed, q, -np.inf)
    if tau is None:
        return q.argmax(axis=-1)
    return softmax_sample(q.reshape(b * u, a), tau, rng).reshape(b, u)


def env_allowed_moves(env: SearchEnv, hover: bool = True, mask: bool = True) -> np.ndarray:
    """(B, U, 5) bool: the moves the decision rules allow in a simulated world (allowed_moves with the
    world's hovering vehicles and each vehicle's known obstacles)."""
    return allowed_moves(env.pos, hovering(env) if hover else None, env.known_obstacles() if mask else None)


class DDQLPolicy:
    def __init__(
        self,
        path: str,
        tau: float | None = 0.1,
        name: str | None = None,
        remove_taken: bool = True,
        hover: bool = True,
        mask: bool = True,
        straggler_frontier: bool = False,
    ):
        self.path = path
        self.tau = tau
        self.remove_taken, self.hover, self.mask = remove_taken, hover, mask
        self.straggler_frontier = straggler_frontier
        self.name = name or f"ddql:{path}"
        self.net, self.info = load_checkpoint(path)
        self.rng = np.random.default_rng(0)
        self.frontier = FrontierPolicy()

    def reset(self, env: SearchEnv, rng: np.random.Generator) -> None:
        if env.cfg.window != self.net.window:
            raise InputError(
                f"{self.path}: the model was trained for {self.net.window} x {self.net.window} "
                f"observations, not {env.cfg.window} x {env.cfg.window}; use --window {self.net.window}"
            )
        self.rng = rng
        self.frontier.reset(env, rng.spawn(1)[0])  # its own stream: the network's draws stay as they were

    def q_values(self, obs: np.ndarray) -> np.ndarray:
        """Q-values (B, U, 5) for observations (B, U, 3, F, F)."""
        b, u = obs.shape[:2]
        with torch.inference_mode():
            q = self.net(torch.from_numpy(obs.reshape(b * u, *obs.shape[2:])))
        return q.numpy().reshape(b, u, -1)

    def act(self, env: SearchEnv) -> np.ndarray:
        obs = env.observe(self.remove_taken)  # its own observation: the world's setting may differ
        allowed = env_allowed_moves(env, self.hover, self.mask)
        moves = choose(self.q_values(obs), allowed, self.tau, self.rng)
        if self.straggler_frontier:
            last = last_searching(env)
            if last.any():
                moves = np.where(last, self.frontier.act(env), moves)
        return moves


def last_searching(env: SearchEnv) -> np.ndarray:
    """(B, U) bool: the vehicle is the only one not hovering on a target (the paper's straggler)."""
    hover = hovering(env)
    return ~hover & (hover.sum(axis=1, keepdims=True) == env.uavs - 1) & (env.uavs > 1)


def split_options(rest: str) -> tuple[str, str]:
    """`PATH:key=value:...` -> (PATH, ":key=value:..."), the options being those `ddql:` takes."""
    path = rest
    while (m := re.search(r":(tau|taken|hover|mask|straggler)=([^:]*)$", path)) is not None:
        path = path[: m.start()]
    return path, rest[len(path) :]


_CHOICES = {
    "taken": ("remove", "keep"),
    "hover": ("yes", "no"),
    "mask": ("yes", "no"),
    "straggler": ("network", "frontier"),
}


def make_ddql_policy(spec: str) -> DDQLPolicy:
    """Parse `ddql:PATH[:tau=T][:taken=remove|keep][:hover=yes|no][:mask=yes|no]
    [:straggler=network|frontier]` or `ddql-greedy:PATH[...]`, options in any order."""
    kind, _, rest = spec.partition(":")
    if not rest:
        raise InputError(f"--policy {spec!r}: give the checkpoint, as in {kind}:models/cluster-2uav.pt")
    path, suffix = split_options(rest)
    options = dict(re.findall(r":([a-z]+)=([^:]*)", suffix))
    tau: float | None = 0.1
    if "tau" in options:
        try:
            tau = float(options["tau"])
        except ValueError:
            tau = -1.0
        if not tau > 0:
            raise InputError(f"--policy {spec!r}: tau must be a number > 0, as in ddql:PATH:tau=0.1")
    for key, allowed in _CHOICES.items():
        if options.get(key, allowed[0]) not in allowed:
            raise InputError(
                f"--policy {spec!r}: {key} must be {' or '.join(allowed)}, as in ddql:PATH:{key}={allowed[1]}"
            )
    if kind == "ddql-greedy":
        tau = None
    return DDQLPolicy(
        path,
        tau=tau,
        name=spec,
        remove_taken=options.get("taken", "remove") == "remove",
        hover=options.get("hover", "yes") == "yes",
        mask=options.get("mask", "yes") == "yes",
        straggler_frontier=options.get("straggler", "network") == "frontier",
    )
