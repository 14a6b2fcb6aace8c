"""Plot a training run's metrics CSV (written next to the checkpoint by `swarmctl train`).

python tools/plot_training.py models/cluster-2uav.csv --out models/cluster-2uav.png [--la 0.87]
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("csv", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--la", type=float, help="LA(4) success rate to draw as a line")
    ap.add_argument("--title", default=None)
    args = ap.parse_args()
    rows = list(csv.DictReader(open(args.csv)))
    ep = [int(r["episodes"]) for r in rows]
    train_success = [float(r["train_success"]) for r in rows]
    evals = [(int(r["episodes"]), float(r["eval_success"])) for r in rows if r["eval_success"]]
    loss = [float(r["loss"]) for r in rows]
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(6.5, 5.5), sharex=True)
    a1.plot(ep, train_success, lw=0.8, alpha=0.6, label="training episodes (exploring, last 200)")
    a1.plot(*zip(*evals), "o-", label="held-out, softmax tau 0.1")
    if args.la is not None:
        a1.axhline(args.la, color="k", lw=1, ls="--", label="LA(4)")
    a1.set_ylabel("success rate")
    a1.set_ylim(0, 1)
    a1.legend(fontsize=8, loc="upper left")
    a1.set_title(args.title or args.csv.stem)
    a2.plot(ep, loss, lw=0.8)
    a2.set_ylabel("Huber loss (recent mean)")
    a2.set_xlabel("training episodes")
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
