"""Bytes a vehicle sends in answer per byte it receives, per knowledge message kind (the table in
docs/security.md): swarmctl.knowledge.amplification over real UDP on 127.0.0.1.

    python tools/knowledge_amplification.py [--size 50] [--steps 50]
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from swarmctl.knowledge.amplification import KINDS, measure  # noqa: E402

SENDERS = (
    ("a stranger (index 7), unsigned channel", dict(member=False)),
    ("a member's index and sysid, unsigned channel", dict(member=True)),
    ("a member's index and sysid without the key, signed channel", dict(member=True, signed=True)),
    ("a member holding the key, signed channel (allowance)", dict(member=True, signed=True, sender_key=True)),
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=50, help="map side, cells")
    parser.add_argument("--steps", type=int, default=50, help="rounds (a digest period is 5)")
    args = parser.parse_args()
    logging.disable(logging.WARNING)  # the rejections' first-of-a-kind warnings
    print(f"{args.size} x {args.size} map, {args.steps} rounds; sent / received bytes (ratio)\n")
    print("| sender | per round | " + " | ".join(KINDS) + " |")
    print("|---|---|" + "---|" * len(KINDS))
    for label, kw in SENDERS:
        for per_step in (1, 20):
            cells = []
            for kind in KINDS:
                a = measure(kind, size=args.size, steps=args.steps, per_step=per_step, **kw)
                cells.append(f"{a.answered} / {a.received} ({a.ratio:.2f})")
            print(f"| {label} | {per_step} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
