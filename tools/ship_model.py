"""Copy a trained checkpoint into models/ as it ships: the network, its world, rules and metadata, without
the trainer's state (target network, optimiser, random state) that only --resume needs.

    python tools/ship_model.py runs/search/search.best.pt models/search.pt
    python tools/ship_model.py runs/search/search.best.pt models/search.pt \\
        --change 11200 demo_share_end 0.1 0.5      # a schedule change made before checkpoints recorded it

The trainer's counters (`resume.progress`: stage openings, evaluations) stay for the model's card
(tools/search_card.py). The weights are not touched: the copy's sha256 is the source's. The copy must
load as `ddql:DST` does, and name no path of the machine that trained it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmctl.errors import InputError  # noqa: E402
from swarmctl.learn.search_recipe import SCHEDULE_FREE  # noqa: E402
from swarmctl.policy.checkpoint import load_checkpoint  # noqa: E402

MACHINE_PATHS = ("/tmp", "/work", "/home", "runs/")


def ship(src: Path, dst: Path, changes: list[dict[str, object]] | None = None) -> str:
    """Write `dst` from `src` (see the module's doc); returns the weights' sha256."""
    load_checkpoint(src)  # refuses a damaged or foreign file with its own message
    payload = torch.load(src, map_location="cpu", weights_only=True)
    progress = (payload.get("resume") or {}).get("progress")
    payload["resume"] = {"progress": progress} if progress is not None else None
    if changes:
        metadata = payload.setdefault("metadata", {})
        metadata["changes"] = [*metadata.get("changes", []), *changes]
    text = json.dumps({k: v for k, v in payload.items() if k != "state_dict"}, default=str)
    named = [p for p in MACHINE_PATHS if p in text]
    if named:
        raise InputError(f"{src}: its metadata names {', '.join(named)} (a path of the training machine); not shipped")
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_suffix(".tmp")
    torch.save(payload, tmp)
    tmp.replace(dst)
    _, info = load_checkpoint(dst)
    return str(info["weights_sha256"])


def change(episode: str, option: str, before: str, after: str) -> dict[str, object]:
    """One --change, its option and numbers checked."""
    if option not in SCHEDULE_FREE:
        raise InputError(f"--change ... {option} ...: OPTION is one of {', '.join(SCHEDULE_FREE)}")
    try:
        return {"episode": int(episode), "option": option, "from": float(before), "to": float(after)}
    except ValueError:
        raise InputError(
            f"--change {episode} {option} {before} {after}: give EPISODE as a whole number, FROM and TO as numbers"
        ) from None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src", type=Path, help="a checkpoint written by swarmctl train or train-search")
    ap.add_argument("dst", type=Path, help="where it ships, e.g. models/search.pt")
    ap.add_argument(
        "--change",
        nargs=4,
        action="append",
        metavar=("EPISODE", "OPTION", "FROM", "TO"),
        help="record a schedule change made on a resume before the trainer recorded them (repeatable)",
    )
    args = ap.parse_args(argv)
    try:
        changes = [change(*c) for c in args.change or []]
        sha = ship(args.src, args.dst, changes)
    except InputError as exc:
        print(f"ship_model: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.dst} (weights sha256 {sha})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
