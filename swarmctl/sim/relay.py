"""A lossy UDP relay: a link that loses, delays, duplicates and reorders datagrams, over real sockets,
between two UDP endpoints of this machine (a vehicle and the controller, in either role).

    faults = LinkFaults(loss=0.2, delay=0.03, jitter=0.02, duplicate=0.02)
    with LossyRelay(("127.0.0.1", 14551), faults, seed=1) as relay:
        ... the vehicle sends to relay.address (mock-vehicle --connect udpout:127.0.0.1:PORT) ...

Whoever sends to `relay.address` is a client. Each client gets a socket of its own on the relay,
connected to the target: its datagrams go to the target from there, and what the target sends to that
socket goes back to the client, so the target sees one address per client, as it would see each
vehicle's radio. Either side of a MAVLink link may be the client: a mock vehicle's `udpout:` in front of
a mission's `udpin:` port (the mission file's set-up), or the controller's `udpout:` in front of a mock's
`udpin:` port (SimSwarm's).

Faults, for each direction on its own (`forward`: client to target; `back`: target to client), for each
datagram on its own: lost with probability `loss`; else delivered after `delay` +- `jitter` seconds
(uniform), and with probability `duplicate` a second time, after a delay of its own. Datagrams closer
together than the spread of the delay overtake each other: the link reorders.

Determinism: one random stream per (seed, client, direction) and four draws per datagram whatever its
fate, so the n-th datagram of a direction meets the same fate in every run with the same seed (when it
leaves depends on when it came). Clients are numbered in the order they are first heard.

Bounds: at most `max_clients` clients (later ones are refused and counted), at most MAX_HELD datagrams
held back at once (more are dropped and counted as overflow), datagrams up to 65,535 bytes.

Concurrency: one thread serves every socket (a selector; a socket pair wakes it to stop). `start()`
binds and starts it; `stop()` (or leaving the `with` block) stops it, joins it and closes every socket;
datagrams still held back are dropped. Counters are read with `counts()`.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import selectors
import socket
import threading
import time
from dataclasses import dataclass, field, replace

import numpy as np

log = logging.getLogger(__name__)

Address = tuple[str, int]

MAX_DELAY_S = 10.0  # a link that holds a datagram longer is down, not slow
MAX_HELD = 100_000  # datagrams held back at once (a flood at the largest delay stays bounded)
MAX_RELAY_CLIENTS = 64
DATAGRAM_MAX = 65535
RECEIVE_BUFFER = 1 << 21  # bytes the kernel queues for each socket of the relay while its thread is busy
READS_PER_TURN = 64  # datagrams read from one socket before the others get their turn


@dataclass(frozen=True)
class LinkFaults:
    """What one direction of the link does to each datagram (see the module docstring). Seconds and
    probabilities; ValueError naming the field for anything out of range."""

    loss: float = 0.0
    delay: float = 0.0
    jitter: float = 0.0
    duplicate: float = 0.0

    def __post_init__(self) -> None:
        for name in ("loss", "duplicate"):
            value = getattr(self, name)
            if not _number(value) or not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} = {value!r}: a probability is a number from 0 to 1")
        for name in ("delay", "jitter"):
            value = getattr(self, name)
            if not _number(value) or not 0.0 <= value <= MAX_DELAY_S:
                raise ValueError(f"{name} = {value!r}: give seconds from 0 to {MAX_DELAY_S:g}")
        if self.jitter > self.delay:
            raise ValueError(
                f"jitter = {self.jitter!r} is more than delay = {self.delay!r}: a delay cannot be negative; "
                "give a jitter of at most the delay"
            )

    def fate(self, draws: np.ndarray) -> tuple[float, ...]:
        """The delays (seconds) of the copies delivered of one datagram, from its four uniform draws in
        [0, 1): none when it is lost, two when it is duplicated."""
        if draws[0] < self.loss:
            return ()
        first = self.delay + self.jitter * (2.0 * float(draws[1]) - 1.0)
        if draws[2] < self.duplicate:
            return (first, self.delay + self.jitter * (2.0 * float(draws[3]) - 1.0))
        return (first,)

    def describe(self) -> str:
        """E.g. "loss 20 %, delay 30 +- 20 ms, 2 % duplicates"."""
        return (
            f"loss {self.loss * 100:g} %, delay {self.delay * 1000:g} +- {self.jitter * 1000:g} ms, "
            f"{self.duplicate * 100:g} % duplicates"
        )


def _number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


@dataclass
class DirectionCounts:
    """What one direction of the relay did, in datagrams."""

    received: int = 0
    lost: int = 0
    duplicated: int = 0  # datagrams delivered twice (each copy is in `sent`)
    sent: int = 0
    send_errors: int = 0  # the receiver's socket refused it (not listening yet, gone)
    overflow: int = 0  # dropped because MAX_HELD datagrams were held back already


@dataclass(frozen=True)
class RelayCounts:
    """A snapshot of what the relay did (`LossyRelay.counts()`)."""

    forward: DirectionCounts  # client to target
    back: DirectionCounts  # target to client
    clients: int  # clients heard
    refused: int  # datagrams of clients beyond max_clients
    held: int  # datagrams held back now (in flight)


@dataclass
class _Client:
    address: Address
    index: int
    sock: socket.socket  # connected to the target
    streams: tuple[np.random.Generator, np.random.Generator]  # forward, back


@dataclass(order=True)
class _Held:
    due: float
    order: int
    back: bool = field(compare=False)
    client: _Client = field(compare=False)
    data: bytes = field(compare=False)


def _udp_socket() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)
    except OSError:  # the system's own limit stands
        pass
    return sock


def check_address(address: object, what: str, lowest_port: int = 1) -> Address:
    """(host, port) with a non-empty host and a port from `lowest_port` to 65535; ValueError otherwise."""
    if not (isinstance(address, tuple) and len(address) == 2):
        raise ValueError(f"{what} {address!r}: give (host, port)")
    host, port = address
    if not isinstance(host, str) or not host or not isinstance(port, int) or isinstance(port, bool):
        raise ValueError(f"{what} {address!r}: give (host, port) with a host name and a port number")
    if not lowest_port <= port <= 65535:
        raise ValueError(f"{what} {address!r}: the port must be from {lowest_port} to 65535")
    return host, port


class LossyRelay:
    """A UDP relay in front of `target` with `faults` on the way there and `back` (default: the same)
    on the way back; see the module docstring."""

    def __init__(
        self,
        target: Address,
        faults: LinkFaults | None = None,
        back: LinkFaults | None = None,
        *,
        seed: int = 0,
        listen: Address = ("127.0.0.1", 0),
        max_clients: int = MAX_RELAY_CLIENTS,
    ):
        self.target = check_address(target, "target")
        self.listen = check_address(listen, "listen", lowest_port=0)
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise ValueError(f"seed {seed!r}: give a whole number from 0")
        if not isinstance(max_clients, int) or isinstance(max_clients, bool) or not 1 <= max_clients <= 1024:
            raise ValueError(f"max_clients {max_clients!r}: give a whole number from 1 to 1024")
        self.faults = (faults or LinkFaults(), back or faults or LinkFaults())
        self.seed = seed
        self.max_clients = max_clients
        self._lock = threading.Lock()
        self._counts = (DirectionCounts(), DirectionCounts())  # forward, back
        self._clients: dict[Address, _Client] = {}
        self._refused = 0  # datagrams of clients beyond max_clients
        self._held: list[_Held] = []
        self._order = itertools.count()
        self._selector: selectors.BaseSelector | None = None
        self._sock: socket.socket | None = None
        self._wake: tuple[socket.socket, socket.socket] | None = None
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._target_ip = ""
        self.address: Address = ("", 0)

    # --- life cycle -----------------------------------------------------------------------------------

    def start(self) -> LossyRelay:
        """Bind the listening socket and start the thread; OSError (the port taken, a host that does not
        resolve) with nothing left open."""
        if self._thread is not None or self._stopping.is_set():
            raise RuntimeError("a relay starts once: make a new one")
        try:
            self._target_ip = socket.gethostbyname(self.target[0])
            self._sock = _udp_socket()
            self._sock.bind((socket.gethostbyname(self.listen[0]), self.listen[1]))
            self._sock.setblocking(False)
            self.address = self._sock.getsockname()
            self._wake = socket.socketpair()
            self._selector = selectors.DefaultSelector()
            self._selector.register(self._sock, selectors.EVENT_READ, (self._sock, None))
            self._selector.register(self._wake[0], selectors.EVENT_READ, None)
        except BaseException:
            self._close()
            raise
        self._thread = threading.Thread(target=self._run, name=f"lossy-relay {self.address[1]}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread, wait for it and close every socket (datagrams held back are dropped)."""
        self._stopping.set()
        if self._wake is not None:
            try:
                self._wake[1].send(b"\0")
            except OSError:
                pass
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(5.0)
        self._close()

    def _close(self) -> None:
        with self._lock:
            clients = list(self._clients.values())
            self._held.clear()
        for sock in [c.sock for c in clients] + [self._sock, *(self._wake or ())]:
            if sock is not None:
                sock.close()
        if self._selector is not None:
            self._selector.close()
            self._selector = None

    def __enter__(self) -> LossyRelay:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def port(self) -> int:
        return self.address[1]

    def sockets(self) -> list[socket.socket]:
        """Every socket the relay holds open."""
        with self._lock:
            clients = [c.sock for c in self._clients.values()]
        return [s for s in [self._sock, *(self._wake or ()), *clients] if s is not None and s.fileno() != -1]

    def forwarders(self) -> dict[Address, Address]:
        """Each client's address, and the address the relay forwards its datagrams from (the one the
        target sees, and answers)."""
        with self._lock:
            return {c.address: c.sock.getsockname() for c in self._clients.values() if c.sock.fileno() != -1}

    def counts(self) -> RelayCounts:
        """What the relay has done so far, read at once."""
        with self._lock:
            return RelayCounts(
                replace(self._counts[0]), replace(self._counts[1]), len(self._clients), self._refused, len(self._held)
            )

    # --- the thread -----------------------------------------------------------------------------------

    def _run(self) -> None:
        selector = self._selector
        assert selector is not None  # start() made it
        while not self._stopping.is_set():
            with self._lock:
                timeout = None if not self._held else max(0.0, self._held[0].due - time.monotonic())
            try:
                ready = selector.select(timeout)
            except (OSError, ValueError):  # closed under it: stopping
                return
            for key, _ in ready:
                if key.data is None:  # the wake-up: stop
                    return
                self._read(*key.data)
            self._deliver(time.monotonic())

    def _read(self, sock: socket.socket, client: _Client | None) -> None:
        """Up to READS_PER_TURN datagrams of one socket: the listening one (from clients) or a client's
        (from the target)."""
        for _ in range(READS_PER_TURN):
            try:
                data, source = sock.recvfrom(DATAGRAM_MAX)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # an ICMP error of an earlier send (nobody listening there): counted at the send
                continue
            now = time.monotonic()
            if client is None:
                sender = self._client(source)
                if sender is not None:
                    self._hold(sender, False, data, now)
            else:
                self._hold(client, True, data, now)

    def _client(self, source: Address) -> _Client | None:
        """The client of this address, made when first heard (None: refused, one client too many)."""
        client = self._clients.get(source)
        if client is not None:
            return client
        if len(self._clients) >= self.max_clients:
            with self._lock:
                self._refused += 1
                first = self._refused == 1
            if first:
                log.warning("relay %s: more than %d clients; %s refused", self.address, self.max_clients, source)
            return None
        sock = _udp_socket()
        try:
            sock.connect((self._target_ip, self.target[1]))  # replies from the target only
            sock.setblocking(False)
        except OSError:
            sock.close()
            raise
        index = len(self._clients)
        streams = (
            np.random.default_rng([self.seed, index, 0]),
            np.random.default_rng([self.seed, index, 1]),
        )
        client = _Client(source, index, sock, streams)
        with self._lock:
            self._clients[source] = client
        assert self._selector is not None
        self._selector.register(sock, selectors.EVENT_READ, (sock, client))
        return client

    def _hold(self, client: _Client, back: bool, data: bytes, now: float) -> None:
        faults = self.faults[back]
        delays = faults.fate(client.streams[back].random(4))
        with self._lock:
            counts = self._counts[back]
            counts.received += 1
            if not delays:
                counts.lost += 1
                return
            if len(delays) > 1:
                counts.duplicated += 1
            for d in delays:
                if len(self._held) >= MAX_HELD:
                    counts.overflow += 1
                    continue
                heapq.heappush(self._held, _Held(now + d, next(self._order), back, client, data))

    def _deliver(self, now: float) -> None:
        """Send every datagram whose time has come. Only this thread takes from the heap: a datagram
        stays held until it is sent and counted, so that `counts()` never misses one on its way."""
        while True:
            with self._lock:
                if not self._held or self._held[0].due > now:
                    return
                held = self._held[0]
            try:
                if held.back:
                    assert self._sock is not None
                    self._sock.sendto(held.data, held.client.address)
                else:
                    held.client.sock.send(held.data)
                ok = True
            except OSError:  # nobody listening there (yet, or any more): as a radio would, it is gone
                ok = False
            with self._lock:
                if not self._held:  # cleared by close
                    return
                heapq.heappop(self._held)
                counts = self._counts[held.back]
                if ok:
                    counts.sent += 1
                else:
                    counts.send_errors += 1
