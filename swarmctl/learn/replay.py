"""One replay memory shared by all vehicles: each vehicle's (o, a, r, o') is a sample.

The memory lives on the training device as torch tensors (`device="cuda"`: on the GPU, so a minibatch
never crosses to the host), and its minibatch indices come from a torch generator on that device,
seeded from the run's seed. Observations are stored as float16 (one-hot, small counts and values in
[-0.2, 1] are exact or within 1e-3), halving memory: 100,000 samples of 3 x 20 x 20 take 480 MB with
o and o'.

For a resumable run (`swarmctl train --resume`) the memory is saved beside the checkpoint with
`save(path)` and its small `state()` (size, cursor, generator, a fingerprint of the contents) goes in
the checkpoint; `load(path, state)` takes the file back only when it matches that state.
"""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path

import numpy as np
import torch


def _tensor(x, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    if isinstance(x, np.ndarray):
        x = torch.from_numpy(np.ascontiguousarray(x))
    return x.to(device=device, dtype=dtype)


class ReplayMemory:
    def __init__(self, capacity: int, obs_shape: tuple[int, ...], seed: int = 0, device: str | torch.device = "cpu"):
        self.capacity = capacity
        self.device = torch.device(device)
        self.obs = torch.zeros((capacity, *obs_shape), dtype=torch.float16, device=self.device)
        self.next_obs = torch.zeros((capacity, *obs_shape), dtype=torch.float16, device=self.device)
        self.actions = torch.zeros(capacity, dtype=torch.int64, device=self.device)
        self.rewards = torch.zeros(capacity, dtype=torch.float32, device=self.device)
        self.size = 0
        self.cursor = 0
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(int(np.random.SeedSequence([seed, 0xB0FF]).generate_state(1)[0]))

    def add(self, obs, actions, rewards, next_obs) -> None:
        """Add N samples (numpy arrays or tensors with a leading N axis), overwriting the oldest when full."""
        n = len(actions)
        idx = (self.cursor + torch.arange(n, device=self.device)) % self.capacity
        self.obs[idx] = _tensor(obs, self.device, torch.float16)
        self.next_obs[idx] = _tensor(next_obs, self.device, torch.float16)
        self.actions[idx] = _tensor(actions, self.device, torch.int64)
        self.rewards[idx] = _tensor(rewards, self.device, torch.float32)
        self.cursor = (self.cursor + n) % self.capacity
        self.size = min(self.size + n, self.capacity)

    def sample(
        self, batch: int, memory_format: torch.memory_format = torch.contiguous_format
    ) -> tuple[torch.Tensor, ...]:
        """A uniform minibatch (obs, actions, rewards, next_obs) on the memory's device, observations
        as float32 in `memory_format`."""
        idx = torch.randint(0, self.size, (batch,), device=self.device, generator=self.generator)
        as_f32 = lambda t: t[idx].to(dtype=torch.float32, memory_format=memory_format)  # noqa: E731
        return as_f32(self.obs), self.actions[idx], self.rewards[idx], as_f32(self.next_obs)

    def state(self) -> dict:
        """Size, cursor, the sampling generator's state and a fingerprint of the contents."""
        return {
            "capacity": self.capacity,
            "size": self.size,
            "cursor": self.cursor,
            "generator": self.generator.get_state(),
            "fingerprint": self._fingerprint(),
        }

    def _fingerprint(self) -> float:
        n = self.size
        return float(self.rewards[:n].double().sum() + self.actions[:n].double().sum() * 1e-3)

    def save(self, path: Path) -> None:
        """Write the samples held (atomically: a half-written file never replaces a good one)."""
        n = self.size
        tmp = Path(path).with_suffix(".tmp")
        torch.save(
            {
                "obs": self.obs[:n].cpu(),
                "next_obs": self.next_obs[:n].cpu(),
                "actions": self.actions[:n].cpu(),
                "rewards": self.rewards[:n].cpu(),
                "cursor": self.cursor,
            },
            tmp,
        )
        tmp.replace(path)

    def load(self, path: Path, state: dict) -> bool:
        """Take back the samples saved with `state` (checkpoint's); False when the file is missing,
        unreadable, or not the one the state describes (the memory is then left empty)."""
        path = Path(path)
        if not path.is_file() or state.get("capacity") != self.capacity:
            return False
        try:
            data = torch.load(path, map_location="cpu", weights_only=True)
            n = int(state["size"])
            if tuple(data["obs"].shape) != (n, *self.obs.shape[1:]) or data["cursor"] != state["cursor"]:
                return False
            self.obs[:n], self.next_obs[:n] = data["obs"].to(self.device), data["next_obs"].to(self.device)
            self.actions[:n], self.rewards[:n] = data["actions"].to(self.device), data["rewards"].to(self.device)
        except (
            OSError,
            RuntimeError,
            KeyError,
            TypeError,
            ValueError,
            EOFError,
            pickle.UnpicklingError,
            zipfile.BadZipFile,
        ):
            return False
        self.size, self.cursor = n, int(state["cursor"])
        if abs(self._fingerprint() - float(state["fingerprint"])) > 1e-6 * max(1.0, abs(state["fingerprint"])):
            self.size = self.cursor = 0
            return False
        self.generator.set_state(state["generator"])
        return True
