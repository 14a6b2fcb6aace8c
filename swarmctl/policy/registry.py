"""Policy specs as users type them: `random`, `la:4`, `lawnmower`, `frontier`, `oracle`,
`ddql:PATH[:options]` (swarmctl.policy.ddql), `ddql-greedy:PATH`."""

from __future__ import annotations

from swarmctl.errors import InputError
from swarmctl.policy.lookahead import LookAhead
from swarmctl.policy.oracle import OracleBound
from swarmctl.policy.planners import FrontierPolicy, LawnmowerPolicy, RandomPolicy

POLICY_HELP = (
    "random, la:N (N = 1..6), lawnmower, frontier, oracle, "
    "ddql:PATH[:tau=T][:taken=..][:hover=..][:mask=..][:straggler=..], ddql-greedy:PATH"
)


def make_policy(spec: str):
    """Build the policy a spec names; InputError with the accepted forms otherwise."""
    spec = spec.strip()
    name, _, arg = spec.partition(":")
    if name == "random" and not arg:
        return RandomPolicy()
    if name == "lawnmower" and not arg:
        return LawnmowerPolicy()
    if name == "frontier" and not arg:
        return FrontierPolicy()
    if name == "oracle" and not arg:
        return OracleBound()
    if name == "la":
        try:
            depth = int(arg or "4")
        except ValueError:
            depth = -1
        if not 1 <= depth <= 6:
            raise InputError(f"--policy {spec!r}: the look-ahead depth must be an integer 1..6, as in la:4")
        return LookAhead(depth)
    if name in ("ddql", "ddql-greedy"):
        try:
            from swarmctl.policy.ddql import make_ddql_policy
        except ImportError as exc:  # pragma: no cover - the learned policy ships with the trainer
            raise InputError(f"--policy {spec!r}: the learned policy is not available ({exc})") from None
        return make_ddql_policy(spec)
    raise InputError(f"--policy {spec!r} is unknown: use one of {POLICY_HELP}")
