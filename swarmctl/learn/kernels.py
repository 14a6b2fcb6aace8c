"""The trainer's kernels: its networks run faster on one CPU thread, with the same parameters
(state dict keys and shapes unchanged, so checkpoints and the inference path are untouched) and the
same numbers, bit for bit, as the plain modules on this machine.

Measured on one thread, in CPU time, on a busy 2-core AMD EPYC (min of 7 rounds):

- `keep_freed_memory`: glibc hands the top of its heap back to the kernel as soon as more than 128 KB
  lies free there, so the gradient steps page-faulted their megabyte-sized activations back in: about
  1,500 page faults a joint step of the bench's setting, a tenth of the loop's CPU time in the kernel.
- `fuse_conv_relu` (swarmctl.policy.fused): every convolution and the ReLU after it as one oneDNN
  primitive, so the activation is not written out and read back: 0.16, 0.36 and 0.08 ms less for the
  three convolutions at 64 rows (0.91, 4.26 and 0.84 ms apart), in each of a joint step's four forwards.
- `twin_forward`: the online and the target network on the same o' in one pass (the first convolution
  with both networks' filters, the others as two-group convolutions): 9.96 ms against 10.59 for the
  two passes at 64 rows.
"""

from __future__ import annotations

import ctypes
import platform

import torch
from torch import nn

from swarmctl.policy.fused import ConvReLU, conv_relu, fuse_conv_relu
from swarmctl.policy.qnet import QNetwork

__all__ = ["ConvReLU", "conv_relu", "fuse_conv_relu", "keep_freed_memory", "twin_forward"]

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # mallopt parameters (malloc.h)


def keep_freed_memory() -> bool:
    """Make glibc keep freed memory in the process (mmap only above 32 MB, trim the heap only past
    1 GB free) so a gradient step's activations reuse pages already mapped; process-wide. Returns
    whether it applied (False off glibc)."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    libc = ctypes.CDLL(None)
    return bool(libc.mallopt(_M_MMAP_THRESHOLD, 32 << 20)) and bool(libc.mallopt(_M_TRIM_THRESHOLD, 1 << 30))


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
        assert isinstance(b, nn.Conv2d) and a.bias is not None and b.bias is not None  # the same architecture
        assert not isinstance(a.padding, str)  # numbers: the paper's convolutions
        weight, bias = torch.cat([a.weight, b.weight]), torch.cat([a.bias, b.bias])
        x = conv_relu(x, weight, bias, list(a.stride), list(a.padding), groups=1 if i == 0 else 2)
    half = x.shape[1] // 2
    return online.head(x[:, :half].flatten(1)), target.head(x[:, half:].flatten(1))
