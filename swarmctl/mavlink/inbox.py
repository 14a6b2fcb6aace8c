"""The loop's side of every MAVLink link on one asyncio event loop: one `Inbox` per loop
(`inbox_for`). It reads the UDP links' sockets at its drains, takes what stream links' reader threads
hand over, delivers each link's messages to that link's listeners and each batch listener (the
recorder's tap) once per drain, and watches every open link's heartbeats from one timer. The links
themselves are swarmctl.mavlink.network's `MavlinkLink`.
"""

from __future__ import annotations

import asyncio
import logging
import selectors
import socket
import threading
import time
import weakref
from collections.abc import Callable
from typing import Protocol

from swarmctl.mavlink.codec import Endpoint

log = logging.getLogger("swarmctl.mavlink.network")  # the links' log: what a user filters on

GATHER_S = 0.005  # a loop woken by a reader (or a UDP socket) takes what has come in this long after
WATCHDOG_S = 0.1  # how often the links' heartbeats are checked for link loss
READ_BATCH = 64  # datagrams a UDP link reads at most in one drain before the loop's other work gets its turn
# Bytes parsed at most in one drain, per UDP link and in all (a datagram counts up to its first
# transport.MAX_DATAGRAM_PARSE bytes, what parsing it costs): once a link has had its share, what it has
# queued waits for the next drain, so a flood of big datagrams costs a bounded time a drain. 64 of the
# largest MAVLink 2 frames (280 bytes) are 17,920 bytes: an autopilot's traffic stays under both.
LINK_DRAIN_BYTES = 32768
DRAIN_BYTES = 131072


class Link(Protocol):
    """What the inbox uses of a link: a swarmctl.mavlink.network.MavlinkLink (described here, not imported:
    that module imports this one)."""

    @property
    def endpoint(self) -> Endpoint: ...

    @property
    def read_bytes(self) -> int: ...  # what the last datagram read cost to parse

    @property
    def _batch_listeners(self) -> tuple[Callable[[list], None], ...]: ...

    def _read_datagram(self) -> list | None: ...

    def _deliver(self, msgs: list) -> list: ...

    def _check_heartbeats(self, now: float) -> None: ...

    def remove_listener(self, callback: Callable[[list], None]) -> None: ...


class Inbox:
    """The loop's side of every link on it. What the links' readers parse is handed to the loop in
    one callback: a reader appends (link, messages) and wakes the loop only when no drain is pending; the
    drain runs GATHER_S later and hands each link's messages, in their order, to that link's listeners,
    then each batch listener once with the messages of all the links it listens to (so the loop is woken
    a few hundred times a second at most, not once per datagram, and the recorder's tap is called once
    per drain, not once per link). And one timer checks every open link's heartbeats every WATCHDOG_S
    (not a task per link).

    UDP links have no reader: their sockets sit in one selector of the inbox, whose descriptor the loop
    watches. When a datagram arrives the loop stops watching it and schedules a drain, and the drain
    first reads every socket that is ready (up to READ_BATCH datagrams each: _read_ready), then delivers, then
    watches again: the loop wakes once per drain, not once per datagram."""

    def __init__(self, loop: asyncio.AbstractEventLoop):
        self._loop = weakref.ref(loop)  # not a strong one: the loop is the key of its inbox in _inboxes
        self._items: list[tuple[Link, list]] = []
        self._lock = threading.Lock()
        self._scheduled = False
        self._links: dict[Link, None] = {}  # open links, in the order they were opened
        self._watchdog: asyncio.TimerHandle | None = None
        self._sockets: selectors.DefaultSelector | None = None  # the UDP links' sockets (data: the link)
        self._watching = False  # the loop watches self._sockets
        self._check_failed: weakref.WeakSet[Link] = weakref.WeakSet()  # links whose watchdog check failed

    def read(self, link: Link, sock: socket.socket) -> bool:
        """Read `sock` (a UDP link's) at each drain; False where this platform's selectors cannot be
        watched by the loop (the link then keeps a reader thread)."""
        if self._sockets is None:
            sockets = selectors.DefaultSelector()
            if not hasattr(sockets, "fileno"):  # select() only: nothing the loop could watch
                sockets.close()
                return False
            self._sockets = sockets
        self._sockets.register(sock, selectors.EVENT_READ, link)
        self._watch()
        return True

    def unread(self, sock: socket.socket) -> None:
        if self._sockets is None:
            return
        self._sockets.unregister(sock)
        if not self._sockets.get_map():
            self._unwatch()
            self._sockets.close()
            self._sockets = None

    def _watch(self) -> None:
        loop = self._loop()
        if not self._watching and self._sockets is not None and loop is not None and not loop.is_closed():
            loop.add_reader(self._sockets.fileno(), self._readable)
            self._watching = True

    def _unwatch(self) -> None:
        loop = self._loop()
        if self._watching and self._sockets is not None and loop is not None and not loop.is_closed():
            loop.remove_reader(self._sockets.fileno())
        self._watching = False

    def _readable(self) -> None:
        """On the loop: a UDP link has datagrams; read at the next drain, unwatched until then."""
        self._unwatch()
        self.put(None, [], on_loop=True)

    def put(self, link: Link | None, msgs: list, on_loop: bool = False) -> None:
        """From a reader thread (or, with on_loop, from the loop's own thread; link None: only a drain
        scheduled). RuntimeError when the loop is closed."""
        with self._lock:
            if link is not None:
                self._items.append((link, msgs))
            if self._scheduled:
                return
            self._scheduled = True
        loop = self._loop()
        try:
            if loop is None:
                raise RuntimeError("the event loop is gone")
            if on_loop:
                loop.call_later(GATHER_S, self._drain)
            else:
                loop.call_soon_threadsafe(loop.call_later, GATHER_S, self._drain)
        except RuntimeError:
            with self._lock:
                self._scheduled = False
            raise

    def _drain(self) -> None:
        if self._sockets is not None:
            read = self._read_ready()
            self._watch()
        else:
            read = []
        with self._lock:
            items, self._items = self._items, []
            self._scheduled = False
        items += read
        batches: dict[Link, list] = {}
        for link, msgs in items:
            if link in batches:
                batches[link] += msgs
            else:
                batches[link] = msgs
        shared: dict[Callable[[list], None], list] = {}  # batch listener -> the messages of its links
        for link, msgs in batches.items():
            accepted = link._deliver(msgs)
            if accepted:
                for cb in dict.fromkeys(link._batch_listeners):  # each once, even if added twice
                    if cb in shared:
                        shared[cb] += accepted
                    else:
                        shared[cb] = list(accepted)
        for cb in call_batch_listeners(shared):  # reported; not called again, on any link of the loop
            for link in {**self._links, **batches}:
                link.remove_listener(cb)

    def _read_ready(self) -> list[tuple[Link, list]]:
        """The ready UDP sockets' datagrams, parsed, per link in their order: in passes of one datagram
        from each socket the selector finds ready, until none is, so no read comes back empty (a failed
        recvfrom cost more than the datagram's parse in a 50-vehicle flight); at most READ_BATCH passes,
        LINK_DRAIN_BYTES parsed per link and DRAIN_BYTES in all, so a flooded link cannot hold up the loop
        (the rest waits for the next drain)."""
        assert self._sockets is not None
        got: dict[Link, list] = {}
        stopped: set[Link] = set()  # closing, ready with nothing to read, or had its share: not read again
        spent: dict[Link, int] = {}  # bytes parsed per link
        left = DRAIN_BYTES
        select = self._sockets.select
        for _ in range(READ_BATCH):
            ready = [key.data for key, _ in select(0)]
            if not ready or stopped.issuperset(ready):
                break
            for link in ready:
                if link in stopped:
                    continue
                msgs = link._read_datagram()
                if msgs is None:
                    stopped.add(link)
                    continue
                cost = link.read_bytes
                total = spent[link] = spent.get(link, 0) + cost
                if total >= LINK_DRAIN_BYTES:
                    stopped.add(link)
                if msgs:
                    if link in got:
                        got[link] += msgs
                    else:
                        got[link] = msgs
                left -= cost
                if left <= 0:
                    return list(got.items())
        return list(got.items())

    def watch(self, link: Link) -> None:
        self._links[link] = None
        if self._watchdog is None:
            self._watchdog = asyncio.get_running_loop().call_later(WATCHDOG_S, self._check)

    def unwatch(self, link: Link) -> None:
        self._links.pop(link, None)
        if not self._links and self._watchdog is not None:
            self._watchdog.cancel()
            self._watchdog = None

    def _check(self) -> None:
        now = time.monotonic()
        for link in list(self._links):
            try:
                link._check_heartbeats(now)
            except Exception as exc:  # one link's failure must not stop the watch of the others
                if link not in self._check_failed:  # one line a link, not ten a second
                    self._check_failed.add(link)
                    log.error("%s: the link watchdog failed: %s: %s", link.endpoint, type(exc).__name__, exc)
                    log.debug("the watchdog's traceback", exc_info=exc)
        self._watchdog = asyncio.get_running_loop().call_later(WATCHDOG_S, self._check) if self._links else None


def call_batch_listeners(batches: dict[Callable[[list], None], list]) -> list[Callable[[list], None]]:
    """Each batch listener with its messages; returns those that raised, each reported in one error line
    (no traceback: that is logged at DEBUG). A batch listener (the recorder's tap, the loss counter)
    takes the messages of several vehicles at once, so no one vehicle is judged silent for it (a
    per-message listener's failure silences its vehicle: MavlinkLink._listener_failed); the caller stops
    calling it instead, so it is reported once, not once a batch."""
    failed = []
    for cb, msgs in batches.items():
        try:
            cb(msgs)
        except Exception as exc:  # a listener's bug must not stop the link
            name = getattr(cb, "__qualname__", None) or type(cb).__name__
            log.error("MAVLink batch listener %s failed: %s: %s; it is not called again", name, type(exc).__name__, exc)
            log.debug("the listener's traceback", exc_info=exc)
            failed.append(cb)
    return failed


_inboxes: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, Inbox] = weakref.WeakKeyDictionary()


def inbox_for(loop: asyncio.AbstractEventLoop) -> Inbox:
    box = _inboxes.get(loop)
    if box is None:
        box = _inboxes[loop] = Inbox(loop)
    return box
