"""How much a vehicle may send in answer to its peers' digests and requests: a token bucket per peer.

The pull protocol answers small messages with bigger ones (a 35-byte digest lacking a chunk draws the
cells the receiver knows there, a request for a whole chunk draws up to 880 cells), so unbounded it
amplifies whatever reaches the channel. Here:

- only mission members get answers (the exchange answers only messages `KnowledgeTrust.admit` took);
- each member earns CREDIT (2) bytes of answers per byte received from it, any kind (a late joiner's
  own deltas, digests and requests earn it its repairs), and, on a signed channel, once per digest
  period REPAIR_ALLOWANCE bytes more if it was heard in the period that just ended (the allowance
  keeps a quiet vehicle that lost its requests converging); a bucket holds at most BUCKET_CAP bytes;
- an answer frame goes out only while the bucket holds its size; the rest is withheld and counted;
- each peer gets at most one push and one repair per digest chunk per digest period (what it asks for
  in one period, the protocol asks once), however many digests or requests arrive.

So a message earns at most twice its size in answers. The allowance is given only where members are
authenticated (a signing key): on an unsigned channel anyone can send as a member, and a fixed
allowance would let one 34-byte digest per period draw 512 bytes (measured: x5 at one digest a step;
with 2x alone, under 2 for every kind: docs/security.md).

Bounds: one bucket per member (at most 256), one `first` entry per (kind, member, chunk).
"""

from __future__ import annotations

from dataclasses import dataclass

CREDIT = 2.0  # bytes of answers per byte received from a member
REPAIR_ALLOWANCE = 512  # bytes per digest period for a member heard in the period before
BUCKET_CAP = 4096  # bytes a bucket holds at most


@dataclass
class _Bucket:
    tokens: float = 0.0
    heard: bool = False  # something from this peer arrived in the current period


class AnswerBudget:
    """The answer budgets of one vehicle (see the module docstring); `signed`: the channel is signed,
    so members get the repair allowance."""

    def __init__(
        self, signed: bool = False, credit: float = CREDIT, allowance: float = REPAIR_ALLOWANCE, cap: float = BUCKET_CAP
    ):
        self.credit, self.cap = float(credit), float(cap)
        self.allowance = float(allowance) if signed else 0.0  # see the module docstring
        self._buckets: dict[int, _Bucket] = {}
        self._period: int | None = None
        self._first: dict[tuple[str, int, int], int] = {}  # (kind, peer, chunk) -> period last answered
        self.withheld_frames = 0
        self.withheld_bytes = 0

    def received(self, peer: int, size: int) -> None:
        """`size` bytes from member `peer` arrived (call for admitted messages only)."""
        b = self._buckets.get(peer)
        if b is None:
            b = self._buckets[peer] = _Bucket()
        b.tokens = min(self.cap, b.tokens + self.credit * size)
        b.heard = True

    def period(self, index: int) -> None:
        """The vehicle's digest period is now `index`: a new one grants the allowance to the members
        heard in the last one."""
        if self._period is not None and index <= self._period:
            return
        self._period = index
        for b in self._buckets.values():
            if b.heard:
                b.tokens = min(self.cap, b.tokens + self.allowance)
            b.heard = False

    def first(self, kind: str, peer: int, chunk: int) -> bool:
        """Whether this is the first answer of `kind` to `peer` for `chunk` in this period (then noted)."""
        key = (kind, peer, chunk)
        now = -1 if self._period is None else self._period
        if self._first.get(key) == now:
            return False
        self._first[key] = now
        return True

    def spend(self, peer: int, size: int) -> bool:
        """Take `size` bytes from `peer`'s bucket for an answer frame; False (counted) when it holds less."""
        b = self._buckets.get(peer)
        if b is None or b.tokens < size:
            self.withheld_frames += 1
            self.withheld_bytes += size
            return False
        b.tokens -= size
        return True

    def tokens(self, peer: int) -> float:
        """What `peer`'s bucket holds now (bytes)."""
        b = self._buckets.get(peer)
        return 0.0 if b is None else b.tokens
