"""The runs of an experiment, their results on disk, and where they execute.

An experiment is a list of independent runs (a training run, an evaluation run, a flown mission),
some of which need another's output (an evaluation needs its trained checkpoint). Every run is a
task name, JSON parameters and input files; `execute` runs it anywhere (this process, a local
process pool, a Ray worker on another machine): it receives its input files as bytes and returns its
result and its output files as bytes, so only the driver touches the output folder.

A run is done when OUT/runs/KEY.json holds its result for the same parameters; the driver writes
the run's output files first and that JSON last (atomically), so a run that failed or was cut has no
JSON and is run again from the start (same seed, same result). A rerun skips every done run.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Run:
    """One independent unit of work. `inputs` maps a name to a repository path ("models/x.pt") or to
    "@KEY", the checkpoint run KEY writes; task parameters name inputs as "{name}"."""

    key: str
    task: str
    params: dict
    inputs: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if "." in self.key or "/" in self.key:
            raise ValueError(f"run key {self.key!r}: no dots or slashes (it names files)")

    @property
    def needs(self) -> list[str]:
        """The runs whose outputs this one reads ("@KEY" is KEY.pt, "@KEY.ep250" its KEY.ep250.pt)."""
        return [v[1:].split(".")[0] for v in self.inputs.values() if v.startswith("@")]


def execute(task: str, params: dict, inputs: dict[str, bytes]) -> tuple[dict, dict[str, bytes]]:
    """Run one task where this is called: the inputs are written to a fresh folder and their names
    in the parameters replaced by paths there; returns (result, output files by suffix)."""
    from tools.exp import tasks

    with tempfile.TemporaryDirectory(prefix="swarmctl-run-") as tmp:
        folder = Path(tmp)
        paths = {}
        for filename, data in inputs.items():  # NAME.SUFFIX
            paths[Path(filename).stem] = folder / f"in-{filename}"
            paths[Path(filename).stem].write_bytes(data)
        t0 = time.time()
        result, outputs = tasks.TASKS[task](fill(params, {k: str(v) for k, v in paths.items()}), folder)
        result["run_wall_s"] = round(time.time() - t0, 1)
        return result, {suffix: Path(p).read_bytes() for suffix, p in outputs.items()}


def fill(value, names: dict[str, str]):
    """`value` with every "{name}" in its strings replaced by names[name] (lists and dicts walked)."""
    if isinstance(value, str):
        for k, v in names.items():
            value = value.replace("{" + k + "}", v)
        return value
    if isinstance(value, list):
        return [fill(v, names) for v in value]
    if isinstance(value, dict):
        return {k: fill(v, names) for k, v in value.items()}
    return value


class Store:
    """The runs' results under OUT/runs/: KEY.json (params, result) and KEY.SUFFIX outputs."""

    def __init__(self, out: Path):
        self.folder = out / "runs"
        self.folder.mkdir(parents=True, exist_ok=True)

    def output(self, key: str, suffix: str = "pt") -> Path:
        return self.folder / f"{key}.{suffix}"

    def result(self, run: Run) -> dict | None:
        """The stored result of `run`, or None when it is not done (or was done with other parameters)."""
        path = self.folder / f"{run.key}.json"
        if not path.exists():
            return None
        stored = json.loads(path.read_text())
        return stored["result"] if stored.get("params") == run.params and stored.get("task") == run.task else None

    def save(self, run: Run, result: dict, outputs: dict[str, bytes]) -> None:
        for suffix, data in outputs.items():
            _atomic_write(self.output(run.key, suffix), data)
        record = {"task": run.task, "params": run.params, "inputs": run.inputs, "result": result}
        _atomic_write(self.folder / f"{run.key}.json", json.dumps(record, indent=1).encode())

    def inputs(self, run: Run) -> dict[str, bytes]:
        """The run's input files as {NAME.SUFFIX: bytes}, from the repository or earlier runs' outputs."""
        out = {}
        for name, where in run.inputs.items():
            path = self.output(where[1:]) if where.startswith("@") else ROOT / where
            out[f"{name}{path.suffix}"] = path.read_bytes()
        return out


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".part")
    tmp.write_bytes(data)
    os.replace(tmp, path)


class LocalBackend:
    """Runs in this process (workers = 1) or in a pool of `workers` spawned processes."""

    def __init__(self, workers: int = 1):
        self.workers = workers
        self.pool = None
        if workers > 1:
            import multiprocessing as mp

            self.pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"))
        self.pending: dict = {}

    def submit(self, run: Run, inputs: dict[str, bytes]) -> None:
        if self.pool is None:
            self.pending[run.key] = execute(run.task, run.params, inputs)
        else:
            self.pending[self.pool.submit(execute, run.task, run.params, inputs)] = run.key

    def capacity(self) -> int:
        return max(1, self.workers)

    def next_done(self) -> tuple[str, tuple]:
        """(key, (result, outputs)) of a finished run, waiting for one."""
        if self.pool is None:
            key = next(iter(self.pending))
            return key, self.pending.pop(key)
        done, _ = wait(list(self.pending), return_when=FIRST_COMPLETED)
        future = done.pop()
        return self.pending.pop(future), future.result()

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)


class RayBackend:
    """Runs as Ray tasks of one CPU each on the cluster at `address` ("auto": the running cluster;
    a Ray instance this process already started is used as it is). The experiment code (tools/)
    travels with the job; the cluster's nodes need swarmctl installed (`pip install 'swarmctl[cluster]'`)
    and its repository's model files do not: every run receives its input files."""

    def __init__(self, address: str):
        try:
            import ray
        except ImportError:
            from swarmctl.errors import InputError

            raise InputError("--ray: ray is not installed; pip install 'swarmctl[cluster]'") from None
        import tools.exp

        ray.cloudpickle.register_pickle_by_value(tools.exp)
        if not ray.is_initialized():  # the task code (tools/) travels with the job
            ray.init(address=address, runtime_env={"py_modules": [str(ROOT / "tools")]}, log_to_driver=False)
        self.ray = ray
        self.remote = ray.remote(num_cpus=1, max_retries=2)(execute)
        self.pending: dict = {}

    def submit(self, run: Run, inputs: dict[str, bytes]) -> None:
        self.pending[self.remote.remote(run.task, run.params, inputs)] = run.key

    def capacity(self) -> int:
        return max(1, int(self.ray.cluster_resources().get("CPU", 1)))

    def next_done(self) -> tuple[str, tuple]:
        done, _ = self.ray.wait(list(self.pending), num_returns=1)
        return self.pending.pop(done[0]), self.ray.get(done[0])

    def close(self) -> None:
        for ref in self.pending:
            self.ray.cancel(ref)


def run_all(
    runs: Iterable[Run], store: Store, backend, on_done: Callable[[Run, dict], None], log=print
) -> dict[str, dict]:
    """Execute the runs not done yet (each once what it needs is done), calling on_done after each;
    returns every run's result by key."""
    runs = list(runs)
    by_key = {r.key: r for r in runs}
    results = {r.key: res for r in runs if (res := store.result(r)) is not None}
    if results:
        log(f"{len(results)} of {len(runs)} runs done already")
    waiting = [r for r in runs if r.key not in results]
    running: set[str] = set()
    try:
        while waiting or running:
            ready = [r for r in waiting if all(n in results for n in r.needs)]
            for r in ready[: max(0, backend.capacity() - len(running))]:
                waiting.remove(r)
                running.add(r.key)
                log(f"run {r.key} ({r.task})")
                backend.submit(r, store.inputs(r))
            if not running:
                missing = sorted({n for r in waiting for n in r.needs if n not in by_key})
                raise RuntimeError(f"runs wait for runs that do not exist: {missing}")
            key, (result, outputs) = backend.next_done()
            running.discard(key)
            store.save(by_key[key], result, outputs)
            results[key] = result
            on_done(by_key[key], result)
    finally:
        backend.close()
    return results
