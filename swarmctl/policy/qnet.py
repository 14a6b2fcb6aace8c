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
head. `ScalesQNetwork` is the network of the scales variant (swarmctl.world.observe_scales): one small
convolutional tower shared by its three crops (1, 3 and 9 cells a pixel), their features and the
three scalars joined before the head. `make_network(variant, window)` builds the network a variant
needs.
"""

from __future__ import annotations

import torch
from torch import nn

from swarmctl.world.beliefs import GLOBAL_LOCAL_VARIANT, PAPER_VARIANT, SCALES_VARIANT, VARIANT_CHANNELS

ARCHITECTURE = "venturini2021-cnn"
GLOBAL_LOCAL_ARCHITECTURE = "global-local-cnn-v1"
SCALES_ARCHITECTURE = "scales-cnn-v1"
SCALE_COUNT = 3  # crops of the scales observation (swarmctl.world.observe_scales.CELLS_PER_PIXEL)
SCALE_SCALARS = 3  # its scalars, the last channels, each a constant plane


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


def halved(side: int) -> int:
    """Side after a 3x3 convolution of stride 2 and padding 1."""
    return (side + 1) // 2


def scales_tower(channels: int, widths: tuple[int, int, int]) -> nn.Sequential:
    """The convolutions every crop of the scales observation goes through, flattened."""
    a, b, c = widths
    return nn.Sequential(
        nn.Conv2d(channels, a, 3, padding=1),
        nn.ReLU(),
        nn.Conv2d(a, b, 3, stride=2, padding=1),
        nn.ReLU(),
        nn.Conv2d(b, c, 3, stride=2, padding=1),
        nn.ReLU(),
        nn.Flatten(),
    )


class ScalesQNetwork(nn.Module):
    """The scales variant on its (24, S, S) observation: channels 0-20 are three crops of 7 channels,
    each through one shared tower (Conv 7 -> 16, 3x3; Conv 16 -> 32, 3x3 stride 2; Conv 32 -> 32, 3x3
    stride 2; padding 1, ReLUs), the three flattened in scale order (the head tells the scales apart by
    where their features sit), joined by the scalars (one pixel of each of channels 21-23), then
    Linear(hidden) and Linear(5). 126,661 parameters and 2.45 MFLOPs for S = 11 (the paper's network:
    4.88 MFLOPs at F = 20)."""

    architecture = SCALES_ARCHITECTURE
    variant = SCALES_VARIANT
    in_channels = VARIANT_CHANNELS[SCALES_VARIANT]
    crop_channels = (in_channels - SCALE_SCALARS) // SCALE_COUNT

    def __init__(
        self, window: int = 11, n_actions: int = 5, widths: tuple[int, int, int] = (16, 32, 32), hidden: int = 128
    ):
        super().__init__()
        if window < 3:
            raise ValueError(f"window {window} is too small for the scales network: S must be >= 3")
        self.window = window
        self.tower = scales_tower(self.crop_channels, widths)
        self.crop_features = widths[2] * halved(halved(window)) ** 2
        features = SCALE_COUNT * self.crop_features + SCALE_SCALARS
        self.head = nn.Sequential(nn.Linear(features, hidden), nn.ReLU(), nn.Linear(hidden, n_actions))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """obs (N, 24, S, S) -> Q-values (N, 5)."""
        s = self.window
        crops = obs[:, : SCALE_COUNT * self.crop_channels].reshape(-1, self.crop_channels, s, s)
        features = self.tower(crops).reshape(-1, SCALE_COUNT * self.crop_features)
        scalars = obs[:, SCALE_COUNT * self.crop_channels :, 0, 0]
        result: torch.Tensor = self.head(torch.cat([features, scalars], dim=1))
        return result


QNet = QNetwork | GlobalLocalQNetwork | ScalesQNetwork  # the network of some observation variant (make_network)
NETWORKS: dict[str, type[QNet]] = {
    QNetwork.architecture: QNetwork,
    GlobalLocalQNetwork.architecture: GlobalLocalQNetwork,
    ScalesQNetwork.architecture: ScalesQNetwork,
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


def scales_forward_flops(
    window: int = 11, n_actions: int = 5, widths: tuple[int, int, int] = (16, 32, 32), hidden: int = 128
) -> int:
    """FLOPs of one forward pass of ScalesQNetwork for one observation, counted as forward_flops counts
    them: 2.45 M for S = 11."""
    a, b, c = widths
    crop = ScalesQNetwork.crop_channels
    side1, side2 = halved(window), halved(halved(window))
    tower = window * window * a * crop * 9 + side1 * side1 * b * a * 9 + side2 * side2 * c * b * 9
    features = SCALE_COUNT * c * side2 * side2 + SCALE_SCALARS
    return 2 * (SCALE_COUNT * tower + features * hidden + hidden * n_actions)
