"""The Q-network's forward pass at inference: eager torch (the reference), onnxruntime or fused oneDNN,
alone or split between two by a call's row count.

`make_forward(net, backend)` takes one of six BACKENDS: "torch" (eager torch), "onnx" (the network
exported to ONNX, run by onnxruntime: `pip install 'swarmctl[onnx]'`), "onednn" (torch on a
channels-last copy whose convolutions and ReLUs are fused oneDNN primitives: a torch built with oneDNN,
as the CPU wheels are), "onnx+onednn" and "torch+onednn" (calls of up to SPLIT_ROWS = 6 rows on the
first, larger ones on oneDNN), and "auto", which is not a forward of its own but picks one: the split
onnx+onednn, or torch+onednn (eager torch for the small calls) where onnxruntime is not installed; plain
onnx or torch only where torch lacks oneDNN. The forward it returns carries the name of what it picked.
Every forward takes observations (N, C, F, F) float32 as numpy (C: the network's in_channels, 3 for the
paper's variant) and returns Q-values (N, 5) float32, and runs large batches in chunks of CHUNK rows,
so the activations of a chunk stay in the CPU's cache.

Why onnxruntime: at batch 1 the network is call-bound. On one thread (2-core AMD EPYC, one run)
eager torch took 4.6x the network's FLOP time at batch 2, TorchScript frozen and optimised 3.8x,
torch.compile (inductor, frozen weights) 3.7x after 16 s of compiling, onnxruntime 2.0x with its
extended graph optimisations (2.3x with the NCHWc layout, which pads the 20 channels to 32).
onnxruntime's Q-values agree with torch's within 1e-5 (tests/test_fast_paths.py pins it); they are not
bit-identical, so a softmax draw that falls within about 1e-7 of a boundary may go the other way.

Why oneDNN for batches: past a few rows the network is compute-bound, and torch on channels-last
filters with each convolution and its ReLU as one oneDNN primitive (swarmctl.policy.fused) is the
fastest measured. One thread, min of 40 calls, 2-core Intel Xeon, us a row at 1 / 4 / 6 / 8 / 16 / 50
rows: onnxruntime 106 / 95 / 94 / 97 / 96 / 98, fused 281 / 112 / 95 / 84 / 70 / 56 (on the same
machine busy with other work, at 16 rows: 148 against 77). `auto` therefore runs
calls of up to SPLIT_ROWS rows on onnxruntime (eager torch without it) and larger ones on oneDNN: its
name says both ("onnx+onednn"), and a recording's forward is rebuilt by that name. The split depends
on the row count only, so the same batch gets the same numbers.
"""

from __future__ import annotations

import copy
import io
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from swarmctl.errors import InputError
from swarmctl.policy.fused import POINTWISE, fuse_conv_relu, to_memory_format
from swarmctl.policy.qnet import QNet

BACKENDS = ("auto", "torch", "onnx", "onednn", "onnx+onednn", "torch+onednn")
CHUNK = 64  # rows per forward call (one thread, 1,024 rows: torch 120 us a row in chunks of 64, 194 in
#              chunks of 256, 243 unchunked; onnxruntime 94-101 from 64 to 1,024)
SPLIT_ROWS = 6  # up to this many rows a call of the split forward runs on the small backend
SMALL_ROWS = 16  # up to this many rows a call runs on a kept output binding (OnnxForward._run_bound)
_EXPORTED: dict[str, bytes] = {}  # ONNX models by weights hash: one export per network per process


def onnx_available() -> bool:
    """Whether onnxruntime can be imported here."""
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        return False
    return True


class TorchForward:
    """Eager torch, the reference every other forward is compared against."""

    name = "torch"

    def __init__(self, net: QNet, chunk: int = CHUNK):
        self.net, self.chunk = net.eval(), chunk

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Q-values (N, 5) for observations (N, 3, F, F)."""
        x = torch.from_numpy(np.ascontiguousarray(obs, dtype=np.float32))
        with torch.inference_mode():
            if len(x) <= self.chunk:
                result: np.ndarray = self.net(x).numpy()
                return result
            return torch.cat([self.net(part) for part in x.split(self.chunk)]).numpy()


def export_onnx(net: QNet, key: str | None = None) -> bytes:
    """The network as an ONNX model with a free batch axis (cached under `key`, e.g. the weights hash)."""
    if key is not None and key in _EXPORTED:
        return _EXPORTED[key]
    buffer = io.BytesIO()
    example = torch.zeros(1, net.in_channels, net.window, net.window)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notice
        torch.onnx.export(
            net.eval(),
            (example,),
            buffer,  # type: ignore[arg-type]  # torch's annotation says a path; it writes to a file object too
            dynamo=False,
            input_names=["obs"],
            output_names=["q"],
            dynamic_axes={"obs": {0: "n"}, "q": {0: "n"}},
        )
    model = buffer.getvalue()
    if key is not None:
        _EXPORTED[key] = model
    return model


class OnnxForward:
    """The network exported to ONNX and run by onnxruntime on torch's intra-op thread count. Small calls
    share a kept output buffer, so one instance serves one thread at a time (as every caller here does)."""

    name = "onnx"

    def __init__(self, net: QNet, chunk: int = CHUNK, key: str | None = None):
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = torch.get_num_threads()
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")  # no busy-waiting threads
        self.session = ort.InferenceSession(export_onnx(net, key), options, providers=["CPUExecutionProvider"])
        self.chunk = chunk
        self._bound: dict[int, tuple[Any, np.ndarray]] = {}  # rows -> (binding, output buffer), for the small calls

    def _run_bound(self, x: np.ndarray) -> np.ndarray:
        """One call of up to SMALL_ROWS rows with the output bound to a buffer kept for that row count
        (the same session, so the same bits as session.run, without its per-call checks and output
        allocation)."""
        bound = self._bound.get(len(x))
        if bound is None:
            out = np.empty((len(x), self.session.get_outputs()[0].shape[1]), dtype=np.float32)
            binding = self.session.io_binding()
            binding.bind_output("q", "cpu", 0, np.float32, list(out.shape), out.ctypes.data)
            bound = self._bound[len(x)] = (binding, out)
        binding, out = bound
        binding.bind_cpu_input("obs", x)
        self.session.run_with_iobinding(binding)
        result: np.ndarray = out.copy()
        return result

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Q-values (N, 5) for observations (N, 3, F, F)."""
        x = np.ascontiguousarray(obs, dtype=np.float32)
        if len(x) <= SMALL_ROWS:
            return self._run_bound(x)
        run: Callable[[np.ndarray], np.ndarray] = lambda part: self.session.run(None, {"obs": part})[0]
        if len(x) <= self.chunk:
            result: np.ndarray = run(x)
            return result
        return np.concatenate([run(x[i : i + self.chunk]) for i in range(0, len(x), self.chunk)])


class OneDnnForward:
    """torch on a channels-last copy of the network whose convolutions and ReLUs are fused oneDNN
    primitives (swarmctl.policy.fused): the fastest forward for batches here."""

    name = "onednn"

    def __init__(self, net: QNet, chunk: int = CHUNK):
        self.net = fuse_conv_relu(to_memory_format(copy.deepcopy(net).eval(), torch.channels_last))
        self.chunk = chunk

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Q-values (N, 5) for observations (N, 3, F, F)."""
        x = torch.from_numpy(np.ascontiguousarray(obs, dtype=np.float32))
        with torch.inference_mode():
            parts = [self.net(part.contiguous(memory_format=torch.channels_last)) for part in x.split(self.chunk)]
            return (parts[0] if len(parts) == 1 else torch.cat(parts)).numpy()


class SplitForward:
    """Calls of up to `rows` rows on `small`, larger ones on `large` (module docstring)."""

    def __init__(self, small: TorchForward | OnnxForward, large: OneDnnForward, rows: int = SPLIT_ROWS):
        self.small, self.large, self.rows = small, large, rows
        self.name = f"{small.name}+{large.name}"

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Q-values (N, 5) for observations (N, 3, F, F)."""
        return self.small(obs) if len(obs) <= self.rows else self.large(obs)


Forward = TorchForward | OnnxForward | OneDnnForward | SplitForward


def onednn_available() -> bool:
    """Whether torch here runs convolutions and their ReLU as one oneDNN primitive."""
    return POINTWISE and torch.backends.mkldnn.is_available()


def make_forward(net: QNet, backend: str = "auto", key: str | None = None) -> Forward:
    """The forward for `backend` (module docstring); `key` caches the ONNX export (the weights hash)."""
    if backend not in BACKENDS:
        raise InputError(f"forward {backend!r}: choose one of {', '.join(BACKENDS)}")
    if "onnx" in backend and not onnx_available():
        raise InputError(f"forward={backend} needs onnxruntime: pip install 'swarmctl[onnx]', or use forward=torch")
    if "onednn" in backend and not onednn_available():
        raise InputError(f"forward={backend} needs a torch built with oneDNN (the CPU wheels); use forward=torch")
    if backend == "auto":
        first = "onnx" if onnx_available() else "torch"
        backend = f"{first}+onednn" if onednn_available() else first
    small_name, _, large_name = backend.partition("+")
    if small_name == "onednn":
        return OneDnnForward(net)
    small = TorchForward(net) if small_name == "torch" else OnnxForward(net, key=key)
    return SplitForward(small, OneDnnForward(net)) if large_name else small
