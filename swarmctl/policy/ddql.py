"""The learned policy: the shared Q-network acting for every vehicle, batched.

`ddql:PATH` samples from softmax(Q / tau) with tau = 0.1 (the paper's "DDQL Soft"; it keeps stuck
vehicles from looping), `ddql-greedy:PATH` takes argmax Q. Options, appended as `:key=value`:

- `tau=T`: the softmax temperature (default 0.1; 0 < T <= 100);
- `taken=remove|keep`: the targets other vehicles sit on are removed from the value channel, as
  LA(n) removes them from its value map (default remove; keep is the paper's observation);
- `hover=first|defer|no` (swarmctl.policy.hover; `yes` is `first`): with `first` a vehicle on a target
  that no lower-numbered vehicle holds stays there and every other vehicle moves: "stay" is only ever
  the hover, as in the controller's HOVER state (the default: the networks were trained so); `defer`
  parks only once the swarm knows as many targets as it has vehicles (before that a vehicle on a
  target moves on); `no` lets the network decide, as in the paper;
- `mask=yes|no`: moves off the map or into an obstacle the vehicle knows of are never chosen, as
  LA(n) scores them -inf (default yes; no as in the paper);
- `straggler=network|frontier`: who steers the last vehicle still searching once every other one
  hovers on a target. The paper names this straggler, far from anything its window shows on a big
  map, as its residual failure; `frontier` hands it to the frontier planner (nearest unexplored
  cell) until it finds a target (default network);
- `forward=auto|torch|onnx|onednn|onnx+onednn|torch+onednn`: what runs the network
  (swarmctl.policy.forward): `auto` (the default) runs calls of up to 6 rows on onnxruntime when it is
  installed (else plain torch) and larger batches on oneDNN's fused convolutions; `torch` is plain
  torch (the reference), `onnx` onnxruntime only (required), `onednn` oneDNN only; `A+onednn` names
  the split explicitly (a recording's forward is rebuilt by this name).

`ddql:PATH:taken=keep:hover=no:mask=no` is the paper's DDQL Soft. The observation settings (window,
rho, sigma2, ...) are the ones stored in the checkpoint's world config. A checkpoint that names the
rules it was trained under (`train["recipe"]`: `hover`, `mask`, `taken`, as swarmctl.learn.search_recipe
writes them) flies under them where the spec leaves an option out (`trained_rules`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace

import numpy as np

from swarmctl.errors import InputError
from swarmctl.policy.base import allowed_moves, choose
from swarmctl.policy.checkpoint import load_checkpoint
from swarmctl.policy.draws import SOFTMAX, Draws
from swarmctl.policy.forward import BACKENDS as FORWARD_BACKENDS
from swarmctl.policy.forward import make_forward
from swarmctl.policy.hover import FIRST, HOVER_ALIASES
from swarmctl.policy.planners import FrontierPolicy
from swarmctl.world.beliefs import Beliefs, ObservationSettings
from swarmctl.world.observe import observe


@dataclass
class Decision:
    """What the network decided for a batch of beliefs: moves (B, U), the observations (B, U, 3, F, F)
    and Q-values (B, U, 5) behind them, and which moves the frontier planner made (B, U) instead."""

    moves: np.ndarray
    obs: np.ndarray
    q: np.ndarray
    by_frontier: np.ndarray


class DDQLPolicy:
    """The shared Q-network with the decision rules its options ask for (module docstring)."""

    def __init__(
        self,
        path: str,
        tau: float | None = 0.1,
        name: str | None = None,
        remove_taken: bool | None = True,
        hover: bool | str | None = True,
        mask: bool | None = True,
        straggler_frontier: bool = False,
        forward: str = "auto",
    ):
        """remove_taken, hover, mask: None takes the checkpoint's trained rule (trained_rules), else the
        default above."""
        self.path = path
        self.tau = tau
        self.hold: int | None = None  # targets the mission holds, when fewer than its vehicles
        self.straggler_frontier = straggler_frontier
        self.name = name or f"ddql:{path}"
        self.net, self.info = load_checkpoint(path)
        rules = trained_rules(self.info, path)
        self.remove_taken = rules.get("taken", "remove") == "remove" if remove_taken is None else remove_taken
        trained = rules.get("hover", FIRST)
        # the rule a search recipe trained under (None: the paper's networks, trained under the forced hover)
        self.trained_hover: str | None = HOVER_ALIASES.get(trained, trained) if "hover" in rules else None
        self.hover: bool | str = HOVER_ALIASES.get(trained, trained) if hover is None else hover
        self.mask = rules.get("mask", "yes") == "yes" if mask is None else mask
        self.forward = make_forward(self.net, forward, key=self.info.get("weights_sha256"))
        # as it was trained (the window of the network itself)
        world = ObservationSettings.from_world(self.info["world"])
        self.settings = replace(world, window=self.net.window, variant=self.net.variant)
        self.seed = 0
        self.frontier = FrontierPolicy()

    def reset(self, beliefs: Beliefs, seed: int) -> None:
        self.seed = int(seed)
        self.frontier.reset(beliefs, seed)  # its own streams: the network's draws stay as they were

    def q_values(self, obs: np.ndarray) -> np.ndarray:
        """Q-values (B, U, 5) for observations (B, U, 3, F, F)."""
        b, u = obs.shape[:2]
        return self.forward(obs.reshape(b * u, *obs.shape[2:])).reshape(b, u, -1)

    def decide(self, beliefs: Beliefs) -> Decision:
        # observed in the network's own variant and window, whatever the world's (or another policy's) are:
        # `ddql:PATH` flies a model as it was trained, with no observation option to repeat
        seen, own = beliefs, {"variant": self.net.variant, "window": self.net.window}
        if any(getattr(beliefs.settings, k) != v for k, v in own.items()):
            seen = beliefs.with_settings(**own)
        obs = observe(seen, self.remove_taken)
        q = self.q_values(obs)
        u = Draws(self.seed, beliefs).deciders(SOFTMAX)
        moves = choose(q, allowed_moves(beliefs, self.hover, self.mask, self.hold), self.tau, u)
        by = np.zeros(moves.shape, dtype=bool)
        if self.straggler_frontier:
            last = beliefs.last_searching()
            batches = last.any(axis=1)
            if batches.any():
                frontier = self.frontier.act(beliefs.select(batches))
                moves[batches] = np.where(last[batches], frontier, moves[batches])
                by[batches] = last[batches]
        return Decision(moves, obs, q, by)

    def act(self, beliefs: Beliefs) -> np.ndarray:
        return self.decide(beliefs).moves

    def field_settings(self, phi_tolerance: float) -> ObservationSettings:
        """The observation settings the field builds beliefs with: the model's own."""
        return replace(self.settings, phi_tolerance=phi_tolerance)


def trained_rules(info: dict[str, object], path: str) -> dict[str, str]:
    """The rules a checkpoint was trained under, from its train["recipe"] (hover, mask, taken), each
    checked against the values its `ddql:` option takes; {} when it names none."""
    train = info.get("train")
    recipe = train.get("recipe") if isinstance(train, dict) else None
    if not isinstance(recipe, dict):
        return {}
    rules = {}
    for key in ("hover", "mask", "taken"):
        value = recipe.get(key)
        if value is None:
            continue
        if value not in _CHOICES[key]:
            raise InputError(f"{path}: train.recipe.{key} = {value!r} is not a rule ddql: takes; use an intact file")
        rules[key] = str(value)
    return rules


MAX_TAU = 100.0  # a softmax temperature beyond this is a uniform draw, and inf or NaN are no number


def split_options(rest: str) -> tuple[str, str]:
    """`PATH:key=value:...` -> (PATH, ":key=value:..."), the options being those `ddql:` takes."""
    path = rest
    while (m := re.search(r":(tau|taken|hover|mask|straggler|forward)=([^:]*)$", path)) is not None:
        path = path[: m.start()]
    return path, rest[len(path) :]


_CHOICES = {
    "taken": ("remove", "keep"),
    "hover": ("yes", "no", "first", "defer"),
    "mask": ("yes", "no"),
    "straggler": ("network", "frontier"),
    "forward": FORWARD_BACKENDS,
}


def make_ddql_policy(spec: str) -> DDQLPolicy:
    """Parse `ddql:PATH[:tau=T][:taken=remove|keep][:hover=yes|no][:mask=yes|no]
    [:straggler=network|frontier][:forward=auto|torch|onnx|...]` or `ddql-greedy:PATH[...]`, options in any order."""
    kind, _, rest = spec.partition(":")
    if not rest:
        raise InputError(f"--policy {spec!r}: give the checkpoint, as in {kind}:models/cluster-2uav.pt")
    path, suffix = split_options(rest)
    options: dict[str, str] = dict(re.findall(r":([a-z]+)=([^:]*)", suffix))
    tau: float | None = 0.1
    if "tau" in options:
        try:
            tau = float(options["tau"])
        except ValueError:
            tau = -1.0
        if not 0 < tau <= MAX_TAU:
            raise InputError(f"--policy {spec!r}: tau must be a number > 0 and <= {MAX_TAU:g}, as in ddql:PATH:tau=0.1")
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
        # an option left out: the checkpoint's trained rule, else the default (DDQLPolicy)
        remove_taken=options["taken"] == "remove" if "taken" in options else None,
        hover=HOVER_ALIASES.get(options["hover"], options["hover"]) if "hover" in options else None,
        mask=options["mask"] == "yes" if "mask" in options else None,
        straggler_frontier=options.get("straggler", "network") == "frontier",
        forward=options.get("forward", "auto"),
    )
