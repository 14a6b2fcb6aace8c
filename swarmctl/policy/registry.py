"""Policy specs as users type them: `random`, `la:4`, `lawnmower`, `frontier`, `oracle`,
`ddql:PATH[:options]` (swarmctl.policy.ddql), `ddql-greedy:PATH`; and `pattern:NAME`, a search pattern's
routes (swarmctl.policy.routes), which only a mission builds: its routes come from the mission's grid
and last known point."""

from __future__ import annotations

from typing import TYPE_CHECKING, TypeAlias

from swarmctl.errors import InputError
from swarmctl.policy.coordinated import CoordinatedPolicy
from swarmctl.policy.hover import HOVER_ALIASES, HOVER_RULES
from swarmctl.policy.lookahead import LookAhead
from swarmctl.policy.oracle import OracleBound
from swarmctl.policy.planners import FrontierPolicy, LawnmowerPolicy, RandomPolicy
from swarmctl.policy.routes import ROUTE_PATTERNS, ROUTE_PREFIX, RoutePolicy

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.policy.ddql import DDQLPolicy  # imported when a spec asks for it (torch)

# a policy that moves vehicles (swarmctl.policy.base.Policy, with a hover rule and a hold): every one
# make_policy builds but the oracle bound
Decider: TypeAlias = (
    "RandomPolicy | LawnmowerPolicy | FrontierPolicy | CoordinatedPolicy | LookAhead | RoutePolicy | DDQLPolicy"
)

POLICY_HELP = (
    "coordinated, frontier, lawnmower, la:N (N = 1..6), random, oracle, "
    "ddql:PATH[:tau=T][:taken=..][:hover=..][:mask=..][:straggler=..], ddql-greedy:PATH; "
    "any but oracle takes :hover=defer|first|no; coordinated:prior=no weighs a uniform prior (ignores --prior)"
)


def _hover_option(spec: str, name: str, arg: str) -> tuple[str, str | None]:
    """`arg` without a trailing `hover=RULE` option (`la:4:hover=defer`, `frontier:hover=no`), and the rule."""
    head, sep, rule = arg.rpartition("hover=")
    if not sep or (head and not head.endswith(":")):
        return arg, None
    rule = HOVER_ALIASES.get(rule, rule)
    if rule not in HOVER_RULES:
        raise InputError(f"--policy {spec!r}: hover must be {', '.join(HOVER_RULES)}, as in {name}:hover=defer")
    return head[:-1] if head else "", rule


def make_policy(spec: str) -> Decider | OracleBound:
    """Build the policy a spec names; InputError with the accepted forms otherwise."""
    spec = spec.strip()
    name, _, arg = spec.partition(":")
    if name in ("ddql", "ddql-greedy", "oracle"):
        return _make(spec, name, arg)
    arg, rule = _hover_option(spec, name, arg)
    policy = _make(spec, name, arg)
    if rule is not None and not isinstance(policy, OracleBound):  # (the oracle takes no options)
        policy.hover = rule
        policy.name = spec
    return policy


def make_route_policy(spec: str) -> RoutePolicy:
    """The policy `pattern:NAME[:hover=RULE]` names, without routes yet (the mission gives them:
    RoutePolicy.set_routes); InputError for another spec or an unknown pattern."""
    spec = spec.strip()
    name, _, arg = spec.partition(":")
    arg, rule = _hover_option(spec, name, arg)
    if name != ROUTE_PREFIX or arg not in ROUTE_PATTERNS:
        forms = ", ".join(f"{ROUTE_PREFIX}:{p}" for p in ROUTE_PATTERNS)
        raise InputError(f"policy {spec!r} is not a search pattern: use one of {forms}")
    policy = RoutePolicy(name=spec)
    if rule is not None:
        policy.hover = rule
    return policy


def is_route_spec(spec: str) -> bool:
    """Whether `spec` names a search pattern's routes (pattern:NAME)."""
    return spec.strip().partition(":")[0] == ROUTE_PREFIX


def make_decider(spec: str) -> Decider:
    """make_policy for a policy that moves vehicles: InputError for the oracle, a bound that reads the
    hidden targets."""
    policy = make_policy(spec)
    if isinstance(policy, OracleBound):
        raise InputError(f"policy {spec!r} reads the hidden targets: it is a bound, not a policy that moves vehicles")
    return policy


def _make(spec: str, name: str, arg: str) -> Decider | OracleBound:
    if name == "random" and not arg:
        return RandomPolicy()
    if name == "lawnmower" and not arg:
        return LawnmowerPolicy()
    if name == "frontier" and not arg:
        return FrontierPolicy()
    if name == "coordinated" and arg in ("", "prior=yes", "prior=no"):
        return CoordinatedPolicy(name=spec, use_prior=arg != "prior=no")
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
    if name == ROUTE_PREFIX:
        raise InputError(
            f"--policy {spec!r}: a search pattern flies from a mission file, whose grid and "
            "[mission] lkp = [LAT, LON] give its routes; use swarmctl fly, or another policy here"
        )
    if name in ("ddql", "ddql-greedy"):
        try:
            from swarmctl.policy.ddql import make_ddql_policy
        except ImportError as exc:  # pragma: no cover - the learned policy ships with the trainer
            raise InputError(f"--policy {spec!r}: the learned policy is not available ({exc})") from None
        return make_ddql_policy(spec)
    raise InputError(f"--policy {spec!r} is unknown: use one of {POLICY_HELP}")
