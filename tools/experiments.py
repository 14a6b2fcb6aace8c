"""The paper's experiments, one sub-command each, regenerated from this repository.

    python tools/experiments.py --list
    python tools/experiments.py transfer [--fast] [--seed 0] [--out DIR] [--ray auto|ADDRESS] [--workers N]
    python tools/experiments.py chicago --set test_episodes=50         # change one parameter
    python tools/experiments.py all --fast                             # every experiment, seconds each
    python tools/experiments.py --report          # docs/RESULTS.md's sections from results/experiments/

Each experiment is a set of independent runs (training runs, evaluation runs, flown missions). Their
results go to DIR/runs/ one file per run as it finishes, and DIR/NAME.json (parameters, per-run
results, the table), DIR/NAME.png (the figure, the paper's claim beside ours) and DIR/NAME.md (the
table) are rewritten after each. A rerun skips the runs already done; a run that failed or was cut
is run again from the start. `--fast` runs a few episodes and a tiny training (what CI runs: never
a result). Runs execute in this process by default, in a pool with `--workers N`, or as tasks on a
Ray cluster with `--ray` (`pip install 'swarmctl[cluster]'`). Test episodes are `--seed`'s
episodes 0..E-1; training draws its episodes from a range no evaluation uses.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import matplotlib  # noqa: E402

matplotlib.use("Agg")

from tools.exp import EXPERIMENTS  # noqa: E402
from tools.exp.runs import LocalBackend, RayBackend, Store, run_all  # noqa: E402


def parameters(module, fast: bool, sets: list[str]) -> dict:
    """The preset's parameters with every --set KEY=VALUE (VALUE as JSON, else a string) applied."""
    p = json.loads(json.dumps(module.PRESETS["fast" if fast else "full"]))
    for item in sets:
        key, sep, value = item.partition("=")
        if not sep or key not in p:
            raise SystemExit(f"--set {item!r}: use KEY=VALUE with KEY one of {', '.join(p)}")
        try:
            p[key] = json.loads(value)
        except json.JSONDecodeError:
            p[key] = value
    return p


def write_outputs(module, out: Path, record: dict, results: dict) -> None:
    """NAME.json, NAME.png and NAME.md from the runs done so far."""
    summary = module.summarise(record["params"], record["seed"], results)
    if record["preset"] == "fast":
        summary["ours"] = "FAST MODE, NOT A RESULT: " + summary["ours"]
    record = {**record, "runs_done": len(results), "summary": summary, "runs": results}
    name = module.NAME
    (out / f"{name}.json").write_text(json.dumps(record, indent=1))
    module.figure(summary, out / f"{name}.png")
    (out / f"{name}.md").write_text(f"# {module.TITLE}\n\n{module.table(summary)}\n")


def run_experiment(module, args, log=print) -> dict:
    """Run one experiment's missing runs; returns the record written to NAME.json."""
    p = parameters(module, args.fast, args.set or [])
    out = args.out or (ROOT / ("runs/experiments-fast" if args.fast else "results/experiments") / module.NAME)
    if args.out and args.experiment == "all":
        out = args.out / module.NAME
    out.mkdir(parents=True, exist_ok=True)
    runs = module.runs(p, args.seed)
    command = "python tools/experiments.py " + " ".join(sys.argv[1:] if args.argv is None else args.argv)
    record = dict(
        experiment=module.NAME,
        title=module.TITLE,
        preset="fast" if args.fast else "full",
        params=p,
        seed=args.seed,
        runs_total=len(runs),
        paper=module.PAPER,
        command=command,
    )
    store = Store(out)
    backend = RayBackend(args.ray) if args.ray else LocalBackend(args.workers)
    t0 = time.time()
    results = run_all(runs, store, backend, lambda run, res: write_outputs(module, out, record, done(runs, store)), log)
    write_outputs(module, out, record, results)
    log(f"{module.NAME}: {len(results)} runs in {out} ({time.time() - t0:.0f} s this time)")
    return json.loads((out / f"{module.NAME}.json").read_text())


def done(runs, store: Store) -> dict:
    return {r.key: res for r in runs if (res := store.result(r)) is not None}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("experiment", nargs="?", choices=[*EXPERIMENTS, "all"])
    ap.add_argument("--list", action="store_true", help="list the experiments and their parameters")
    ap.add_argument("--fast", action="store_true", help="a few episodes, tiny training: seconds (CI)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the test episodes and of the training runs")
    ap.add_argument("--out", type=Path, help="output folder (default results/experiments/NAME)")
    ap.add_argument("--set", action="append", metavar="KEY=VALUE", help="change one parameter of the preset")
    ap.add_argument("--workers", type=int, default=1, help="local processes (1: in this process)")
    ap.add_argument("--ray", metavar="auto|ADDRESS", help="run on a Ray cluster (auto: the running one)")
    ap.add_argument("--report", action="store_true", help="rewrite docs/RESULTS.md's experiment sections")
    args = ap.parse_args(argv)
    args.argv = argv
    if args.report:
        from tools.exp.report import update

        update(ROOT / "docs/RESULTS.md", EXPERIMENTS, ROOT / "results/experiments", "../results/experiments")
        return {}
    if args.list or args.experiment is None:
        for name, module in EXPERIMENTS.items():
            print(f"{name}: {module.TITLE}\n  full: {json.dumps(module.PRESETS['full'])}")
        return {}
    if args.workers < 1:
        ap.error(f"--workers {args.workers} must be >= 1")
    names = list(EXPERIMENTS) if args.experiment == "all" else [args.experiment]
    return {name: run_experiment(EXPERIMENTS[name], args) for name in names}


if __name__ == "__main__":
    main()
