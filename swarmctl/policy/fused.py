"""Each convolution of a network and the ReLU after it as one oneDNN primitive (the ReLU its post-op,
`torch.ops.mkldnn._convolution_pointwise`, the kernel torch's own compiler fuses to), so the activation
is not written out and read back. The parameters stay those of the plain modules (state dict keys and
shapes unchanged), and so do the numbers, bit for bit, on the CPU where torch's own convolution is
oneDNN's (`_fusable`). The trainer's networks use it (swarmctl.learn.kernels), and so does the
inference forward for batches (swarmctl.policy.forward.OneDnnForward).
"""

from __future__ import annotations

from typing import Any, TypeVar

import torch
import torch.nn.functional as F
from torch import nn

_LAST = torch.channels_last
POINTWISE = torch.backends.mkldnn.is_available() and hasattr(torch.ops.mkldnn, "_convolution_pointwise")


def _fusable(x: torch.Tensor, weight: torch.Tensor, groups: int = 1) -> bool:
    """Where torch's own convolution is oneDNN's too: float32 on the CPU with channels-last filters
    (contiguous filters take torch's native kernel for some small inputs, whose sums differ), and
    not the small single-row 3x3 case torch sends to its native kernel as faster (ConvParams::
    use_mkldnn: one row, one group, filters of 3 or less, at most 20,480 input values)."""
    cpu = x.device.type == "cpu" and x.dtype == torch.float32
    small = x.shape[0] == 1 and groups == 1 and min(weight.shape[-2:]) <= 3 and x.numel() <= 20480
    return (
        POINTWISE
        and bool(torch.backends.mkldnn.enabled)
        and cpu
        and weight.is_contiguous(memory_format=_LAST)
        and not small
    )


def conv_relu(
    x: torch.Tensor,
    weight: torch.Tensor,
    bias: torch.Tensor | None,
    stride: list[int],
    padding: list[int],
    groups: int = 1,
) -> torch.Tensor:
    """relu(conv2d(x)), in one oneDNN primitive where it gives torch's numbers (_fusable), without
    gradients."""
    if not _fusable(x, weight, groups):
        return F.relu(F.conv2d(x, weight, bias, stride, padding, groups=groups))
    y: torch.Tensor = torch.ops.mkldnn._convolution_pointwise(
        x, weight, bias, padding, stride, [1, 1], groups, "relu", [], ""
    )
    return y


class _ConvReLU(torch.autograd.Function):
    """conv_relu with the gradient autograd gives the two modules: ReLU's, then the convolution's."""

    @staticmethod
    def forward(
        ctx: Any,  # torch's FunctionCtx, which carries the attributes set here
        x: torch.Tensor,
        weight: torch.Tensor,
        bias: torch.Tensor | None,
        stride: list[int],
        padding: list[int],
        groups: int,
    ) -> torch.Tensor:
        y = conv_relu(x, weight, bias, stride, padding, groups)
        ctx.save_for_backward(x, weight, y)
        ctx.conv = (stride, padding, groups, bias is not None)
        return y

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        x, weight, y = ctx.saved_tensors
        stride, padding, groups, has_bias = ctx.conv
        grad = torch.ops.aten.threshold_backward(grad, y, 0)
        gx, gw, gb = torch.ops.aten.convolution_backward(
            grad,
            x,
            weight,
            [weight.shape[0]] if has_bias else None,
            stride,
            padding,
            [1, 1],
            False,
            [0, 0],
            groups,
            [ctx.needs_input_grad[0], True, has_bias],
        )
        return gx, gw, gb, None, None, None


class ConvReLU(nn.Conv2d):
    """A Conv2d whose output goes through a ReLU, computed as one primitive (conv_relu). It adds no
    state to Conv2d: fuse_conv_relu turns Conv2d modules into ConvReLU in place."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not _fusable(x, self.weight, self.groups):
            return F.relu(super().forward(x))
        result: torch.Tensor = _ConvReLU.apply(  # type: ignore[no-untyped-call]  # torch's apply is untyped
            x, self.weight, self.bias, list(self.stride), list(self.padding), self.groups
        )
        return result


_M = TypeVar("_M", bound=nn.Module)


def to_memory_format(net: _M, memory_format: torch.memory_format, device: torch.device | None = None) -> _M:
    """`net.to(device, memory_format=memory_format)`: its parameters in that layout (on `device`, when
    given); torch's stubs lack the keyword, which Module.to takes."""
    args = () if device is None else (device,)
    moved: _M = net.to(*args, memory_format=memory_format)  # type: ignore[call-overload]
    return moved


def fuse_conv_relu(net: _M) -> _M:
    """In place: in every Sequential of `net`, a Conv2d (zero padding, no dilation) followed by a
    ReLU becomes a ConvReLU with the same parameters and the ReLU an Identity; the state dict keeps
    its keys and shapes. Returns `net`."""
    for seq in [m for m in net.modules() if isinstance(m, nn.Sequential)]:
        for i in range(len(seq) - 1):
            conv = seq[i]
            plain = type(conv) is nn.Conv2d and conv.padding_mode == "zeros" and conv.dilation == (1, 1)
            if plain and isinstance(conv.padding, tuple) and isinstance(seq[i + 1], nn.ReLU):
                conv.__class__ = ConvReLU
                seq[i + 1] = nn.Identity()
    return net
