"""The shared Q-network, exactly as the paper's operation counts pin it (PAPER.md).

    Conv(3 -> 20, 3x3, padding 1)  -> 20 x 20 x 20, ReLU
    Conv(20 -> 20, 4x4, stride 1)  -> 17 x 17 x 20, ReLU
    Conv(20 -> 20, 4x4, stride 2)  -> 7 x 7 x 20 = 980, ReLU
    Linear(980 -> 64), ReLU
    Linear(64 -> 5)                -> Q-values for stay, N, E, S, W

76,509 parameters for F = 20. Other window sizes change only the first linear layer's input.
"""

from __future__ import annotations

import torch
from torch import nn

ARCHITECTURE = "venturini2021-cnn"


def conv_output_side(window: int) -> int:
    """Side of the last conv layer's output for an F x F input."""
    side = window  # 3x3, padding 1 keeps it
    side = side - 3  # 4x4, stride 1
    return (side - 4) // 2 + 1  # 4x4, stride 2


class QNetwork(nn.Module):
    def __init__(self, window: int = 20, n_actions: int = 5, channels: int = 20, hidden: int = 64):
        super().__init__()
        if conv_output_side(window) < 1:
            raise ValueError(f"window {window} is too small for the network: F must be >= 8")
        self.window = window
        side = conv_output_side(window)
        self.features = nn.Sequential(
            nn.Conv2d(3, channels, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(channels, channels, 4, stride=1),
            nn.ReLU(),
            nn.Conv2d(channels, channels, 4, stride=2),
            nn.ReLU(),
            nn.Flatten(),
        )
        self.head = nn.Sequential(nn.Linear(channels * side * side, hidden), nn.ReLU(), nn.Linear(hidden, n_actions))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """obs (N, 3, F, F) -> Q-values (N, 5)."""
        return self.head(self.features(obs))


def parameter_count(net: nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())


def forward_flops(window: int = 20, n_actions: int = 5, channels: int = 20, hidden: int = 64) -> int:
    """FLOPs of one forward pass for one observation (2 per multiply-add, biases and ReLUs left out):
    4.88 M for F = 20 (PAPER.md)."""
    side1, side2, side3 = window, window - 3, conv_output_side(window)
    macs = (
        side1 * side1 * channels * 3 * 3 * 3
        + side2 * side2 * channels * channels * 4 * 4
        + side3 * side3 * channels * channels * 4 * 4
        + channels * side3 * side3 * hidden
        + hidden * n_actions
    )
    return 2 * macs
