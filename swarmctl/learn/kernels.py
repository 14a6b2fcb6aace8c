"""Training-only kernels: the trainer's networks run faster on one CPU thread, with the same parameters
(state dict keys and shapes unchanged, so checkpoints and the inference path are untouched) and the
same numbers, bit for bit, as the plain modules on this machine.

Measured on one thread, in CPU time, on a busy 2-core AMD EPYC (min of 7 rounds):

- `keep_freed_memory`: glibc hands the top of its heap back to the kernel as soon as more than 128 KB
  lies free there, so the gradient steps page-faulted their megabyte-sized activations back in: about
  1,500 page faults a joint step of the bench's setting, a tenth of the loop's CPU time in the kernel.
- `fuse_conv_relu`: every convolution and the ReLU after it as one oneDNN primitive (the ReLU its
  post-op, `torch.ops.mkldnn._convolution_pointwise`, the kernel torch's own compiler fuses to), so
  the activation is not written out and read back: 0.16, 0.36 and 0.08 ms less for the three
  convolutions at 64 rows (0.91, 4.26 and 0.84 ms apart), in each of a joint step's four forwards.
- `twin_forward`: the online and the target network on the same o' in one pass (the first convolution
  with both networks' filters, the others as two-group convolutions): 9.96 ms against 10.59 for the
  two passes at 64 rows.
"""

from __future__ import annotations

import ctypes
import platform

import torch
import torch.nn.functional as F
from torch import nn

from swarmctl.policy.qnet import QNetwork

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # mallopt parameters (malloc.h)


def keep_freed_memory() -> bool:
    """Make glibc keep freed memory in the process (mmap only above 32 MB, trim the heap only past
    1 GB free) so a gradient step's activations reuse pages already mapped; process-wide. Returns
    whether it applied (False off glibc)."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    libc = ctypes.CDLL(None)
    return bool(libc.mallopt(_M_MMAP_THRESHOLD, 32 << 20)) and bool(libc.mallopt(_M_TRIM_THRESHOLD, 1 << 30))


_LAST = torch.channels_last
_POINTWISE = torch.backends.mkldnn.is_available() and hasattr(torch.ops.mkldnn, "_convolution_pointwise")


def _fusable(x: torch.Tensor, weight: torch.Tensor, groups: int = 1) -> bool:
    """Where torch's own convolution is oneDNN's too: float32 on the CPU with channels-last filters
    (contiguous filters take torch's native kernel for some small inputs, whose sums differ), and
    not the small single-row 3x3 case torch sends to its native kernel as faster (ConvParams::
    use_mkldnn: one row, one group, filters of 3 or less, at most 20,480 input values)."""
    cpu = x.device.type == "cpu" and x.dtype == torch.float32
    small = x.shape[0] == 1 and groups == 1 and min(weight.shape[-2:]) <= 3 and x.numel() <= 20480
    return (
        _POINTWISE and torch.backends.mkldnn.enabled and cpu and weight.is_contiguous(memory_format=_LAST) and not small
    )


def conv_relu(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None, stride, padding, groups: int = 1):
    """relu(conv2d(x)), in one oneDNN primitive where it gives torch's numbers (_fusable), without
    gradients."""
    if not _fusable(x, weight, groups):
        return F.relu(F.conv2d(x, weight, bias, stride, padding, groups=groups))
    return torch.ops.mkldnn._convolution_pointwise(x, weight, bias, padding, stride, [1, 1], groups, "relu", [], "")


class _ConvReLU(torch.autograd.Function):
    """conv_relu with the gradient autograd gives the two modules: ReLU's, then the convolution's."""

    @staticmethod
    def forward(ctx, x, weight, bias, stride, padding, groups):
        y = conv_relu(x, weight, bias, stride, padding, groups)
        ctx.save_for_backward(x, weight, y)
        ctx.conv = (stride, padding, groups, bias is not None)
        return y

    @staticmethod
    def backward(ctx, grad):
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
        return _ConvReLU.apply(x, self.weight, self.bias, list(self.stride), list(self.padding), self.groups)


def fuse_conv_relu(net: nn.Module) -> nn.Module:
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


def twin_forward(online: nn.Module, target: nn.Module, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Q-values of two networks of the paper's architecture on the same observations, without
    gradients, in one pass; other networks are called one after the other. Bit for bit the two
    calls' numbers where conv_relu is one primitive (the trainer's CPU networks, channels-last);
    elsewhere (a GPU) the grouped convolutions may round differently."""
    if not (isinstance(online, QNetwork) and isinstance(target, QNetwork)):
        return online(obs), target(obs)
    x = obs
    pairs = [(a, b) for a, b in zip(online.features, target.features) if isinstance(a, nn.Conv2d)]
    for i, (a, b) in enumerate(pairs):
        weight, bias = torch.cat([a.weight, b.weight]), torch.cat([a.bias, b.bias])
        x = conv_relu(x, weight, bias, list(a.stride), list(a.padding), groups=1 if i == 0 else 2)
    half = x.shape[1] // 2
    return online.head(x[:, :half].flatten(1)), target.head(x[:, half:].flatten(1))
