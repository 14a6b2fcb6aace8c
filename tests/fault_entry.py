"""Faults injected into one part of the controller: `failing` wraps a function so that it raises from
its n-th call on, `parts` names what can be broken, and run as a script,

    python tests/fault_entry.py PART AT SWARMCTL-ARGS...

runs swarmctl with PART raising from its AT-th call (0: the call `parts` gives it; the SITL fault
scenario, tests/sitl_fly.py)."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any


class Injected(RuntimeError):
    """The fault: raised by a part on its n-th call."""


def failing(real: Callable[..., Any], at: int) -> Callable[..., Any]:
    """`real` (a function or coroutine function), raising Injected from its `at`-th call on."""
    import inspect

    calls = [0]

    def check() -> None:
        calls[0] += 1
        if calls[0] >= at:
            raise Injected(f"injected on call {calls[0]}")

    if inspect.iscoroutinefunction(real):

        async def wrapped_async(*args: Any, **kwargs: Any) -> Any:
            check()
            return await real(*args, **kwargs)

        return wrapped_async

    def wrapped(*args: Any, **kwargs: Any) -> Any:
        check()
        return real(*args, **kwargs)

    return wrapped


def parts() -> dict[str, tuple[Any, str, int]]:
    """part -> (the object, the attribute, the call that raises: in the search's first rounds)."""
    from swarmctl.mavlink.autopilots.ardupilot import ArduPilotVehicle
    from swarmctl.mission import flight
    from swarmctl.mission.decide import FieldPolicy
    from swarmctl.mission.recorder import Recorder
    from swarmctl.mission.rounds import Rounds

    return {
        "decision round": (Rounds, "decision_round", 3),
        "policy": (FieldPolicy, "decide", 3),
        "knowledge exchange": (flight, "step_all", 3),
        "recorder": (Recorder, "plain_event", 3),
        "driver": (ArduPilotVehicle, "goto_nowait", 6),  # after the take-off flights
    }


def inject(part: str, at: int | None = None) -> None:
    """Break `part` (at its own call number, or `at`)."""
    target, name, default = parts()[part]
    setattr(target, name, failing(getattr(target, name), default if at is None else at))


if __name__ == "__main__":
    from swarmctl.cli import main

    inject(sys.argv[1], int(sys.argv[2]) or None)
    sys.exit(main(sys.argv[3:]))
