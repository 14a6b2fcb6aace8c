"""Shared set-up for the MAVLink tests: mock vehicles that always stop, loops with a hard timeout."""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Iterator
from typing import Any

from swarmctl.sim.autopilot import MockAutopilot

HOME = (-35.363262, 149.165237, 584.0)  # ArduPilot's SITL default site (CMAC), as in the SITL log
FAST = dict(speedup=20.0, ready_after=2.0)


@contextlib.contextmanager
def mock_vehicles(*specs: dict[str, Any]) -> Iterator[list[MockAutopilot]]:
    """Start one MockAutopilot per spec (keyword arguments); stop them all whatever happens."""
    started: list[MockAutopilot] = []
    try:
        for spec in specs:
            kw = {"home": HOME, **FAST, **spec}
            started.append(MockAutopilot(**kw).start())
        yield started
    finally:
        for m in started:
            m.stop()


def run(coro: Any, timeout: float = 60.0) -> Any:
    """Run a coroutine on a fresh loop with an overall timeout."""

    async def bounded() -> Any:
        return await asyncio.wait_for(coro, timeout)

    return asyncio.run(bounded())


async def until(condition: Any, timeout: float = 5.0) -> None:
    """Wait on the loop until condition() is true; fail after `timeout` seconds."""
    deadline = asyncio.get_running_loop().time() + timeout
    while not condition():
        assert asyncio.get_running_loop().time() < deadline, "timed out"
        await asyncio.sleep(0.01)


def our_threads() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith(("mock-autopilot", "mavlink-rx"))]
