"""The learned policy: the shared Q-network acting for every vehicle, batched.

`ddql:PATH` samples from softmax(Q / tau) with tau = 0.1 (the paper's "DDQL Soft"; it keeps stuck
vehicles from looping), `ddql:PATH:tau=0.05` changes tau, `ddql-greedy:PATH` takes argmax Q.
"""

from __future__ import annotations

import numpy as np
import torch

from swarmctl.errors import InputError
from swarmctl.policy.checkpoint import load_checkpoint
from swarmctl.world.env import SearchEnv


def softmax_sample(q: np.ndarray, tau: float, rng: np.random.Generator) -> np.ndarray:
    """Sample one action per row from softmax(q / tau); q is (N, A)."""
    z = (q - q.max(axis=1, keepdims=True)) / tau
    p = np.exp(z)
    p /= p.sum(axis=1, keepdims=True)
    u = rng.random((q.shape[0], 1))
    return np.minimum((p.cumsum(axis=1) < u).sum(axis=1), q.shape[1] - 1)


class DDQLPolicy:
    needs_observations = True

    def __init__(self, path: str, tau: float | None = 0.1, name: str | None = None):
        self.path = path
        self.tau = tau
        self.name = name or f"ddql:{path}"
        self.net, self.info = load_checkpoint(path)
        self.rng = np.random.default_rng(0)

    def reset(self, env: SearchEnv, rng: np.random.Generator) -> None:
        if env.cfg.window != self.net.window:
            raise InputError(f"{self.path}: the model was trained for {self.net.window} x {self.net.window} "
                             f"observations, not {env.cfg.window} x {env.cfg.window}; use --window {self.net.window}")
        self.rng = rng

    def q_values(self, obs: np.ndarray) -> np.ndarray:
        """Q-values (B, U, 5) for observations (B, U, 3, F, F)."""
        b, u = obs.shape[:2]
        with torch.inference_mode():
            q = self.net(torch.from_numpy(obs.reshape(b * u, *obs.shape[2:])))
        return q.numpy().reshape(b, u, -1)

    def act(self, env: SearchEnv) -> np.ndarray:
        obs = env.last_observations if env.last_observations is not None else env.observe()
        q = self.q_values(obs)
        b, u, a = q.shape
        if self.tau is None:
            return q.argmax(axis=-1)
        return softmax_sample(q.reshape(b * u, a), self.tau, self.rng).reshape(b, u)


def make_ddql_policy(spec: str) -> DDQLPolicy:
    """Parse `ddql:PATH[:tau=T]` or `ddql-greedy:PATH`."""
    kind, _, rest = spec.partition(":")
    if not rest:
        raise InputError(f"--policy {spec!r}: give the checkpoint, as in {kind}:models/cluster-2uav.pt")
    tau: float | None = 0.1
    path = rest
    if ":tau=" in rest:
        path, _, value = rest.rpartition(":tau=")
        try:
            tau = float(value)
        except ValueError:
            tau = -1.0
        if not tau > 0:
            raise InputError(f"--policy {spec!r}: tau must be a number > 0, as in ddql:PATH:tau=0.1")
    if kind == "ddql-greedy":
        tau = None
    return DDQLPolicy(path, tau=tau, name=spec)
