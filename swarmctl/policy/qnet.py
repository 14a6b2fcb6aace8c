"""The shared Q-network, exactly as the paper's operation counts pin it.

    Conv(3 -> 20, 3x3, padding 1)  -> 20 x 20 x 20, ReLU
    Conv(20 -> 20, 4x4, stride 1)  -> 17 x 17 x 20, ReLU
    Conv(20 -> 20, 4x4, stride 2)  -> 7 x 7 x 20 = 980, ReLU
    Linear(980 -> 64), ReLU
    Linear(64 -> 5)                -> Q-values for stay, N, E, S, W

76,509 parameters for F = 20. Other window sizes change only the first linear layer's input.

`GlobalLocalQNetwork` is the network of the global-local observation variant
(swarmctl.world.observe_global): the paper's convolutions on the local channels 0-2, a second
convolutional branch on the four pooled whole-map channels 3-6, their features joined before the
head. `make_network(variant, window)` builds the network a variant needs.
"""

from __future__ import annotations

import torch
from torch import nn

from swarmctl.world.beliefs import GLOBAL_LOCAL_VARIANT, PAPER_VARIANT

ARCHITECTURE = "venturini2021-cnn"
GLOBAL_LOCAL_ARCHITECTURE = "global-local-cnn-v1"


def conv_output_side(window: int) -> int:
    """Side of the last conv layer's output for an F x F input."""
    side = window  # 3x3, padding 1 keeps it
    side = side - 3  # 4x4, stride 1
    return (side - 4) // 2 + 1  # 4x4, stride 2


def check_window(window: int) -> None:
    """The paper's convolutions need a window of at least 8 cells."""
    if conv_output_side(window) < 1:
        raise ValueError(f"window {window} is too small for the network: F must be >= 8")


def paper_convolutions(channels: int) -> nn.Sequential:
    """The paper's three convolutions on the (3, F, F) window, flattened."""
    return nn.Sequential(
        nn.Conv2d(3, channels, 3, padding=1),
        nn.ReLU(),
        nn.Conv2d(channels, channels, 4, stride=1),
        nn.ReLU(),
        nn.Conv2d(channels, channels, 4, stride=2),
        nn.ReLU(),
        nn.Flatten(),
    )


class QNetwork(nn.Module):
    """The paper's network on its (3, F, F) observation."""

    architecture = ARCHITECTURE
    variant = PAPER_VARIANT
    in_channels = 3

    def __init__(self, window: int = 20, n_actions: int = 5, channels: int = 20, hidden: int = 64):
        super().__init__()
        check_window(window)
        self.window = window
        side = conv_output_side(window)
        self.features = paper_convolutions(channels)
        self.head = nn.Sequential(nn.Linear(channels * side * side, hidden), nn.ReLU(), nn.Linear(hidden, n_actions))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """obs (N, 3, F, F) -> Q-values (N, 5)."""
        result: torch.Tensor = self.head(self.features(obs))
        return result


class GlobalLocalQNetwork(nn.Module):
    """The global-local variant on its (7, F, F) observation: the paper's convolutions on channels 0-2
    (the local window), two strided convolutions on channels 3-6 (the whole map pooled to F x F around
    the vehicle), both flattened and joined, then Linear(hidden) and Linear(5). 196,045 parameters
    for F = 20."""

    architecture = GLOBAL_LOCAL_ARCHITECTURE
    variant = GLOBAL_LOCAL_VARIANT
    in_channels = 7

    def __init__(
        self, window: int = 20, n_actions: int = 5, channels: int = 20, global_channels: int = 16, hidden: int = 128
    ):
        super().__init__()
        check_window(window)
        self.window = window
        side = conv_output_side(window)
        self.local = paper_convolutions(channels)
        g = ((window + 1) // 2 + 1) // 2  # two 3x3 stride-2 convolutions with padding 1 halve it, rounding up
        self.whole = nn.Sequential(
            nn.Conv2d(4, global_channels, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(global_channels, global_channels, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.Conv2d(global_channels, global_channels, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.Flatten(),
        )
        features = channels * side * side + global_channels * g * g
        self.head = nn.Sequential(nn.Linear(features, hidden), nn.ReLU(), nn.Linear(hidden, n_actions))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """obs (N, 7, F, F) -> Q-values (N, 5)."""
        result: torch.Tensor = self.head(torch.cat([self.local(obs[:, :3]), self.whole(obs[:, 3:])], dim=1))
        return result


QNet = QNetwork | GlobalLocalQNetwork  # the network of some observation variant (make_network)
NETWORKS: dict[str, type[QNet]] = {
    QNetwork.architecture: QNetwork,
    GlobalLocalQNetwork.architecture: GlobalLocalQNetwork,
}
_BY_VARIANT = {cls.variant: cls for cls in NETWORKS.values()}


def make_network(variant: str = PAPER_VARIANT, window: int = 20) -> QNet:
    """The network an observation variant needs, freshly initialised."""
    return _BY_VARIANT[variant](window)


def parameter_count(net: nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())


def forward_flops(window: int = 20, n_actions: int = 5, channels: int = 20, hidden: int = 64) -> int:
    """FLOPs of one forward pass for one observation (2 per multiply-add, biases and ReLUs left out):
    4.88 M for F = 20 (the paper's count)."""
    side1, side2, side3 = window, window - 3, conv_output_side(window)
    macs = (
        side1 * side1 * channels * 3 * 3 * 3
        + side2 * side2 * channels * channels * 4 * 4
        + side3 * side3 * channels * channels * 4 * 4
        + channels * side3 * side3 * hidden
        + hidden * n_actions
    )
    return 2 * macs
