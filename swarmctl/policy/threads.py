"""How many CPU threads inference uses: one, unless asked otherwise.

A decision at batch 1 is a few million multiply-adds; spreading it over threads costs more in
hand-offs than it saves, and on a machine whose cores are busy a second thread waits for a core
(the forward took 150 ms on two threads against 0.3 ms on one). So every inference path (`swarmctl
eval`, `bench`, the controller's FieldPolicy in `fly`, `agent` and `demo`) runs torch (and
onnxruntime, which takes its thread count from here) on one intra-op thread. `--threads` on eval
and bench, or the environment variable SWARMCTL_THREADS for fly, agent and demo, changes it.
Training keeps its own `--threads`.
"""

from __future__ import annotations

import os

import torch

from swarmctl.errors import InputError

ENV_VAR = "SWARMCTL_THREADS"
DEFAULT_THREADS = 1


def threads_from_env() -> int:
    """The thread count SWARMCTL_THREADS asks for (default 1); a bad value is an InputError."""
    text = os.environ.get(ENV_VAR, "").strip()
    if not text:
        return DEFAULT_THREADS
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise InputError(f"{ENV_VAR}={text!r}: give a whole number of threads >= 1, e.g. {ENV_VAR}=1")
    return n


def set_inference_threads(threads: int | None = None) -> int:
    """Run torch's CPU operators on `threads` intra-op threads (None: SWARMCTL_THREADS, default 1);
    returns the count. Also asks for one inter-op thread where torch still allows it."""
    n = threads_from_env() if threads is None else int(threads)
    if n < 1:
        raise InputError(f"--threads {n}: give a whole number of threads >= 1")
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    try:
        torch.set_num_interop_threads(1)
    except RuntimeError:  # already set, or parallel work has started: the intra-op count is what matters
        pass
    return n
