"""One thread for many mock vehicles on UDP (swarmctl.sim.autopilot's MockAutopilot.start(runner))."""

from __future__ import annotations

import logging
import selectors
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from swarmctl.mavlink.transport import UdpTransport

if TYPE_CHECKING:
    from swarmctl.sim.autopilot import MockAutopilot

log = logging.getLogger(__name__)


class MockRunner:
    """One thread for many mock vehicles on UDP (as 50 vehicles' threads each waking a hundred times a
    second cost a small machine more than the mocks' work): it waits on all their sockets at once, hands
    each datagram to its mock, and advances every mock at least every half tick, as a mock's own
    thread does. ``with MockRunner() as runner: mock.start(runner)``."""

    def __init__(self) -> None:
        self._sockets = selectors.DefaultSelector()
        self._mocks: dict[MockAutopilot, None] = {}
        self._lock = threading.RLock()  # held while the mocks are served: remove() waits for it
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def add(self, mock: MockAutopilot) -> MockRunner:
        assert isinstance(mock._transport, UdpTransport), "a MockRunner serves UDP mocks"
        with self._lock:
            self._sockets.register(mock._transport.sock, selectors.EVENT_READ, mock)
            self._mocks[mock] = None
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="mock-autopilots", daemon=True)
            self._thread.start()
        return self

    def remove(self, mock: MockAutopilot) -> None:
        with self._lock:
            if self._mocks.pop(mock, 1) is None:
                assert isinstance(mock._transport, UdpTransport)  # add() took only those; stop() keeps it till here
                self._sockets.unregister(mock._transport.sock)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        self._sockets.close()

    def __enter__(self) -> MockRunner:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                mocks = list(self._mocks)
            if not mocks:
                self._stop.wait(0.01)
                continue
            ready = self._sockets.select(min(m.tick for m in mocks) / 2)
            now = time.monotonic()
            with self._lock:
                for key, _ in ready:
                    if key.data in self._mocks:
                        self._serve(key.data, self._read, now)
                for mock in list(self._mocks):
                    self._serve(mock, self._advance, now)

    def _serve(self, mock: MockAutopilot, work: Callable[[MockAutopilot, float], None], now: float) -> None:
        try:
            work(mock, now)
        except Exception:  # one mock's failure stops that mock, as it would stop its own thread
            log.exception("mock vehicle %d stopped", mock.sysid)
            self.remove(mock)

    @staticmethod
    def _read(mock: MockAutopilot, now: float) -> None:
        """What the mock's socket holds, up to 64 datagrams (the rest at the next turn)."""
        transport = mock._transport
        assert transport is not None  # removed from the runner before it is closed
        for _ in range(64):
            try:
                data = transport.read(0)
            except (OSError, ValueError):
                return
            if not data:
                return
            mock._receive(data, now)

    @staticmethod
    def _advance(mock: MockAutopilot, now: float) -> None:
        mock._advance(now)
