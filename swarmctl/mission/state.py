"""What a mission is doing now: its step, outcome and clock, the stop flag, the tasks it started, and
the timings of its decision rounds. Every part of the controller reads and writes these here, and
nothing else of the others' (swarmctl.mission.controller builds the parts)."""

from __future__ import annotations

import asyncio
import logging
import time
import traceback
from collections.abc import Awaitable, Coroutine
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import numpy as np

from swarmctl.errors import InputError, printable
from swarmctl.mavlink.errors import MavlinkError

log = logging.getLogger(__name__)

T = TypeVar("T")

SETTLE_S = 5.0  # how long the commands in flight (a low-battery RTL) may finish at the end


@dataclass
class RoundTimes:
    """Per decision round, in seconds: the policy, the CPU time of the controller's loop thread and of
    the whole process (the loop, stream links' reader threads, any worker threads), the whole round,
    and the time spent waiting for vehicles to arrive and for detector reports."""

    decide: list[float] = field(default_factory=list)
    round: list[float] = field(default_factory=list)
    wait: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)
    process_cpu: list[float] = field(default_factory=list)

    def overhead_ms(self) -> dict:
        """Their means (ms), and the controller's own part of a round in wall time (the round minus its
        waits): mean and 95th percentile."""
        n = min(len(self.round), len(self.wait))
        if not n:
            return dict(rounds=0)
        rounds, waits = np.array(self.round[:n]), np.array(self.wait[:n])
        own = np.maximum(rounds - waits, 0.0)
        return dict(
            rounds=n,
            decide_mean=round(1000 * float(np.mean(self.decide)), 3),
            cpu_mean=round(1000 * float(np.mean(self.cpu)), 3),
            process_cpu_mean=round(1000 * float(np.mean(self.process_cpu)), 3),
            round_mean=round(1000 * float(rounds.mean()), 3),
            controller_mean=round(1000 * float(own.mean()), 3),
            controller_p95=round(1000 * float(np.percentile(own, 95)), 3),
        )


class MissionState:
    """The mission's step, outcome and clock; its stop flag (Ctrl-C, SIGTERM, a refusal), every task it
    started (kept until done), the rounds' timings, and the operator's pause and orders (the live page,
    swarmctl.mission.web)."""

    def __init__(self) -> None:
        self.step = 0
        self.outcome: str | None = None
        self.started = time.monotonic()
        self.search_started: float | None = None
        self.ended: float | None = None
        self.on_targets: list[tuple[int, int]] = []  # the cells hovered on when the search ended
        self.mission_error: InputError | None = None  # what stopped the mission: raised by Controller.run
        self.fault: dict[str, str] | None = None  # an unexpected error that stopped it (fault_record)
        self.times = RoundTimes()
        self.tasks: set[asyncio.Task] = set()  # every task started with spawn(), until it is done
        self._stop = asyncio.Event()
        self.held_since: float | None = None  # the operator paused the search then (None: not paused)
        self.held_total = 0.0  # seconds the search was paused before that
        self.holding = False  # the rounds hold now: the round under way when the pause came has ended
        self.orders: list[tuple[str, str]] = []  # (action, vehicle) the operator asked for, done at the next round
        # the operator's word on finds: a rejected one is no target for the policy, the hover rule, the finish line
        self.confirmed: set[tuple[int, int]] = set()
        self.rejected: set[tuple[int, int]] = set()

    # --- the clock ---------------------------------------------------------------------------------------
    def search_seconds(self) -> float:
        """Seconds since the search started (0.0 before it started); at the end, up to when it ended."""
        if self.search_started is None:
            return 0.0
        now = self.ended or time.monotonic()
        held = self.held_total + (now - self.held_since if self.held_since is not None else 0.0)
        return now - self.search_started - held

    # --- the operator's pause: the vehicles hold, and the clock and the time limit with them --------------
    @property
    def held(self) -> bool:
        return self.held_since is not None

    def hold(self) -> bool:
        """Pause the search (no setpoints until resume); False when it already was."""
        if self.held_since is not None:
            return False
        self.held_since = time.monotonic()
        return True

    async def while_held(self, poll: float = 0.1) -> None:
        """Return once the search is not paused (at once when it is not), or the mission is stopped."""
        while self.held and not self.stopping:
            await self.pause(poll)

    def judge(self, cell: tuple[int, int], confirmed: bool) -> None:
        """The operator's word on a find: confirmed, or rejected (no longer a target for this process's
        policy, hover rule and finish line; a vehicle hovering on it searches again)."""
        (self.confirmed if confirmed else self.rejected).add(cell)
        (self.rejected if confirmed else self.confirmed).discard(cell)

    def resume(self) -> bool:
        """Resume the search; False when it was not paused."""
        if self.held_since is None:
            return False
        self.held_total += time.monotonic() - self.held_since
        self.held_since = None
        return True

    # --- stopping ----------------------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask the mission to end now: end actions follow, the recording is closed."""
        self._stop.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def fail(self, exc: InputError) -> None:
        """Bad input found while flying (the mission file or a vehicle must change): the mission stops
        and Controller.run raises the first such error."""
        if self.mission_error is None:
            self.mission_error, self.outcome = exc, "failed"
        self.stop()

    async def until_stopped(self, coro: Awaitable[T]) -> T | None:
        """Await coro unless the mission is stopped first (then coro is cancelled; None)."""
        task = asyncio.ensure_future(coro)
        stopper = asyncio.ensure_future(self._stop.wait())
        try:
            await asyncio.wait({task, stopper}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stopper.cancel()
        if not task.done():
            await cancel(task)
            return None
        return task.result()

    async def pause(self, seconds: float) -> None:
        """Wait `seconds`, or less if the mission is stopped."""
        try:
            await asyncio.wait_for(self._stop.wait(), seconds)
        except TimeoutError:
            pass

    # --- tasks -------------------------------------------------------------------------------------------
    def spawn(self, coro: Coroutine[object, None, T], name: str) -> asyncio.Task[T]:
        """Start a task the mission keeps until it is done (cancelled and awaited at the end)."""
        task = asyncio.ensure_future(coro)
        task.set_name(name)
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)
        return task

    async def settle_tasks(self, seconds: float = SETTLE_S) -> None:
        """Let the tasks in flight finish for `seconds` at most, cancel the rest, and wait until every
        task is done."""
        pending = [t for t in self.tasks if not t.done()]
        if pending:
            _, late = await asyncio.wait(pending, timeout=seconds)
            for t in late:
                await cancel(t)


FAULT_TEXT_CHARS = 300  # a fault's message, as recorded (the whole traceback goes to fault.txt)


def fault_record(exc: BaseException, part: str) -> dict[str, str]:
    """What the recording says of an unexpected error: the part it stopped, the innermost place in
    swarmctl it was raised (`file:line in function`), and `Type: message` on one line."""
    where = "?"
    for frame in reversed(traceback.extract_tb(exc.__traceback__)):
        path = Path(frame.filename)
        if "swarmctl" in path.parts:
            where = f"{'/'.join(path.parts[path.parts.index('swarmctl') :])}:{frame.lineno} in {frame.name}"
            break
    message = printable(" ".join(str(exc).split()))[:FAULT_TEXT_CHARS]
    return dict(part=part, where=where, error=f"{type(exc).__name__}: {message}" if message else type(exc).__name__)


async def quietly(coro: Awaitable[object]) -> None:
    """Await a command whose failure is only worth a log line (e.g. the low-battery RTL)."""
    try:
        await coro
    except (TimeoutError, MavlinkError) as exc:
        log.warning("%s", exc)


async def cancel(task: asyncio.Future) -> None:
    """Cancel a task and wait for it to finish (whatever it raises on the way out)."""
    task.cancel()
    try:
        await task
    except (asyncio.CancelledError, Exception):
        pass
