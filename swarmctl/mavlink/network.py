"""The controller's MAVLink link on pymavlink, for asyncio.

Concurrency model: one asyncio event loop drives every vehicle. A UDP link's socket is read on the loop
itself: the sockets of all UDP links sit in one selector of the loop's `Inbox` (swarmctl.mavlink.inbox),
the loop watches that selector, and each drain of the inbox reads every socket that is ready (one
datagram from each ready socket a pass, passes until none is, up to READ_BATCH datagrams each) and
parses with pymavlink there; a stream link (TCP, serial) has a reader thread that blocks on its port and
parses there, handing the messages to the inbox (one `call_soon_threadsafe` per drain, not one per
read). The inbox delivers what every link has brought at once. UDP links have no thread because a thread
per vehicle cost more than the parsing: at 50 vehicles about 1,300 datagrams a second, each waking its
link's thread (docs/mavlink.md); nor a watch of their own, which woke the loop once per datagram. A
message goes only to the listeners registered for its type (or for every message), and batch listeners
(the recorder's tap) take the messages of the links they listen to a batch at a time (once per drain).
Everything else (state, waits, command retries, the 2 Hz heartbeat) runs as coroutines on the loop, and
one timer of the loop checks every link for link loss. Sending is a non-blocking datagram/serial write
under a lock. A slow or silent vehicle only makes its own coroutines wait, never the others.

Several vehicles may share one link: vehicles are told apart by system id, and every message the link
sends carries an explicit target_system/target_component (nothing relies on pymavlink's habit of
locking onto the first heartbeat's system id).

What the wire can make a link do is bounded (docs/security.md): with a key, each open link of the
process signs with a link id of its own and takes its signing timestamps from one clock
(swarmctl.signing.PROCESS_CLOCK), so a frame copied from one link onto another costs neither; a
`udpin` link answers only addresses that sent a frame signed with the key (without a key: a vehicle's
heartbeat), never one for an unsigned RADIO_STATUS; a datagram is parsed up to its first
MAX_DATAGRAM_PARSE bytes and a link reads at most inbox.LINK_DRAIN_BYTES a drain; link events
(`events`, `on_link_change`) are kept only for the system ids the link expects (`expect`; asked for
with `wait_heartbeat`, `peer`, a command), at most EVENTS_KEEP of them.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.errors import printable
from swarmctl.mavlink.codec import MAV_RESULT_NAMES, Endpoint, parse_connection
from swarmctl.mavlink.errors import CommandRejected, CommandTimeout, WaitTimeout
from swarmctl.mavlink.inbox import Inbox, call_batch_listeners, inbox_for
from swarmctl.mavlink.transport import (
    MAX_DATAGRAM_PARSE,
    Transport,
    UdpTransport,
    Unparsed,
    open_transport,
    parse_bytes,
)
from swarmctl.signing import PROCESS_CLOCK, setup_signing

log = logging.getLogger(__name__)

MAV = mavlink2
# Messages a signing controller still accepts unsigned (radio status comes from the radio itself).
_UNSIGNED_OK = {MAV.MAVLINK_MSG_ID_RADIO_STATUS}
_RADIO_STATUS = MAV.MAVLINK_MSG_ID_RADIO_STATUS
_HEARTBEAT = MAV.MAVLINK_MSG_ID_HEARTBEAT
EVENTS_KEEP = 1000  # link events kept in MavlinkLink.events (the oldest go)
# a vehicle whose autopilot is silent this long is lost (MavlinkLink's lost_after, the replay's)
LOST_AFTER_S = 3.0
# The controller's heartbeat. ArduCopter's GCS failsafe (FS_GCS_TIMEOUT, 5 s by default) counts only the
# heartbeats of its GCS: at 1 Hz, on a link losing 20 % each way, one of 3 vehicles missed 5 s of them
# and returned home in a 90 s search (tools/lossy_links.py); at 2 Hz that takes 9 lost in a row.
HEARTBEAT_PERIOD_S = 0.5

# Signing link ids of the open links of this process: each signs as a stream of its own.
_link_ids: dict[int, object] = {}
_link_ids_lock = threading.Lock()
_shared_ids = itertools.count()


def _take_link_id(owner: object, wanted: int | None = None) -> int:
    """`wanted`, or else the lowest signing link id no open link of this process holds (a closed link's
    id is free again: its successor's timestamps, from the same clock, are newer than all it sent); held
    by `owner` until _free_link_id. With all 256 held the ids are shared (logged)."""
    with _link_ids_lock:
        if wanted is not None:
            _link_ids.setdefault(wanted, owner)
            return wanted
        for link_id in range(256):
            if link_id not in _link_ids:
                _link_ids[link_id] = owner
                return link_id
    link_id = next(_shared_ids) % 256  # in turn (id() of objects falls on a few values only)
    log.warning("more than 256 signing links open in this process: link id %d is shared", link_id)
    return link_id


def _free_link_id(link_id: int, owner: object) -> None:
    with _link_ids_lock:
        if _link_ids.get(link_id) is owner:
            del _link_ids[link_id]


def command_name(command: int) -> str:
    entry = MAV.enums["MAV_CMD"].get(command)
    return entry.name if entry is not None else f"MAV_CMD {command}"


MAX_DATAGRAM = 65535


class _Writer:
    """File-like object pymavlink's MAVLink.send() writes packed bytes to."""

    def __init__(self, transport: Transport):
        self.transport = transport

    def write(self, data: bytes) -> None:
        self.transport.write(bytes(data))


@dataclass
class Peer:
    """What the link knows about one vehicle (one system id)."""

    sysid: int
    compid: int = 1
    heartbeat: Any = None
    last_heartbeat: float = 0.0  # time.monotonic()
    last_heard: float = 0.0  # the last frame of its autopilot component (its heartbeat or any other)
    lost: bool = False
    announced: bool = False  # its "seen" event has been given (events start with it)
    messages: dict[str, Any] = field(default_factory=dict)
    received_at: dict[str, float] = field(default_factory=dict)
    statustexts: deque = field(default_factory=lambda: deque(maxlen=50))
    command_lock: asyncio.Lock = field(default_factory=asyncio.Lock)

    def texts_since(self, started: float) -> str:
        """The STATUSTEXTs received since `started` (time.monotonic()), joined: why a vehicle refused."""
        return "; ".join(t for (ts, _sev, t) in self.statustexts if ts >= started)


@dataclass
class LinkStats:
    received: int = 0
    sent: int = 0
    bad_data: int = 0
    console_bytes: int = 0  # an autopilot's boot text on a stream link (SITL's SERIAL0), not bad data
    unknown: int = 0  # frames of message ids the dialect does not have (pymavlink checks neither CRC nor signature)
    dropped_bytes: int = 0  # bytes of datagrams past their first MAX_DATAGRAM_PARSE, not parsed (one bad_data each)


CONSOLE_KEEP = 4096  # bytes of console text kept on the link (`MavlinkLink.console`)


class MavlinkLink:
    """One MAVLink connection (UDP, TCP or serial) carrying one or more vehicles.

    Use it as ``async with MavlinkLink("udpin:0.0.0.0:14550") as link: ...``.
    """

    def __init__(
        self,
        connection: str | Endpoint,
        *,
        system_id: int = 255,
        component_id: int = 190,
        signing_key: bytes | None = None,
        accept_unsigned: bool = False,
        heartbeat_type: int = MAV.MAV_TYPE_GCS,
        heartbeat_period: float = HEARTBEAT_PERIOD_S,
        lost_after: float = LOST_AFTER_S,
        link_id: int | None = None,
        expect: Iterable[int] = (),
    ):
        self.endpoint = connection if isinstance(connection, Endpoint) else parse_connection(connection)
        if signing_key is not None and len(signing_key) != 32:
            raise ValueError("a MAVLink signing key is 32 bytes")
        if link_id is not None and not 0 <= link_id <= 255:
            raise ValueError(f"a MAVLink signing link id is 0..255, not {link_id}")
        self.system_id, self.component_id = system_id, component_id
        self.signing_key, self.accept_unsigned = signing_key, accept_unsigned
        self.heartbeat_type, self.heartbeat_period, self.lost_after = (heartbeat_type, heartbeat_period, lost_after)
        self.link_id = link_id  # signing link id; None: the lowest one free in this process, taken at open()
        self._own_link_id: int | None = None
        self.peers: dict[int, Peer] = {}
        self.stats = LinkStats()
        self.expected: set[int] = set()  # system ids the link reports events of (expect())
        # (monotonic time, sysid, "seen"|"lost"|"back"), of expected system ids, the last EVENTS_KEEP
        self.events: deque[tuple[float, int, str]] = deque(maxlen=EVENTS_KEEP)
        self._listeners: tuple[Callable[[Any], None], ...] = ()  # for every message
        self._typed: dict[str, tuple[Callable[[Any], None], ...]] = {}  # message type -> its listeners
        self._batch_listeners: tuple[Callable[[list], None], ...] = ()
        self._route: dict[str, tuple[Callable[[Any], None], ...]] = {}  # message type -> all its listeners
        self._link_callbacks: list[Callable[[int, str], None]] = []
        # system id -> why it is silent: a listener failed on its message (_listener_failed); its messages
        # reach no listener, peer or waiter again, and it stays lost
        self.silenced: dict[int, str] = {}
        self._failed_listeners: set[str] = set()  # the listeners reported (one line each)
        self._waiters: list[tuple[Callable[[Any], bool], asyncio.Future]] = []
        self._bad_logged = -1e9
        self.console = b""  # the first CONSOLE_KEEP bytes of console text (see _console_text)
        self._framed = False  # a valid MAVLink frame has arrived
        self.read_bytes = 0  # what the last datagram read cost to parse (_read_datagram)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None  # a stream link's reader
        self._reading: socket.socket | None = None  # a UDP link's socket, read by the inbox's drains
        self._tasks: list[asyncio.Task] = []
        self._transport: Transport | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._inbox: Inbox | None = None
        self.mav: Any = None
        for sysid in expect:
            self.expect(sysid)

    # --- life cycle ---------------------------------------------------------------------------------

    async def open(self) -> MavlinkLink:
        self._loop = asyncio.get_running_loop()
        self._inbox = inbox_for(self._loop)
        self._transport = open_transport(self.endpoint)
        self.mav = MAV.MAVLink(_Writer(self._transport), srcSystem=self.system_id, srcComponent=self.component_id)
        self.mav.robust_parsing = True
        try:
            if self.signing_key is not None:
                unsigned = (lambda _mav, _mid: True) if self.accept_unsigned else _UNSIGNED_OK
                link_id = self._own_link_id = _take_link_id(self, self.link_id)
                setup_signing(
                    self.mav, self.signing_key, link_id=link_id, accept_unsigned=unsigned, clock=PROCESS_CLOCK
                )
            if isinstance(self._transport, UdpTransport) and self._inbox.read(self, self._transport.sock):
                self._reading = self._transport.sock
            else:
                self._thread = threading.Thread(target=self._reader, name=f"mavlink-rx {self.endpoint}", daemon=True)
                self._thread.start()
        except BaseException:  # nothing of a link that did not open is kept: its link id, its socket
            if self._own_link_id is not None:
                _free_link_id(self._own_link_id, self)
                self._own_link_id = None
            self._transport.close()
            raise
        self._tasks = [asyncio.create_task(self._heartbeat_loop())]
        self._inbox.watch(self)  # link loss: the loop's watchdog (_check_heartbeats)
        return self

    async def close(self) -> None:
        await cancel_tasks(self._tasks)
        self._tasks = []
        if self._inbox is not None:
            self._inbox.unwatch(self)
        self._stop.set()
        if self._reading is not None and self._inbox is not None:  # (read through the inbox)
            self._inbox.unread(self._reading)
            self._reading = None
        if self._thread is not None:
            await asyncio.get_running_loop().run_in_executor(None, self._thread.join, 2.0)
            self._thread = None
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        if self._own_link_id is not None:
            _free_link_id(self._own_link_id, self)
            self._own_link_id = None
        for _, fut in self._waiters:
            if not fut.done():
                fut.cancel()
        self._waiters.clear()

    async def __aenter__(self) -> MavlinkLink:
        return await self.open()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    @property
    def local_port(self) -> int | None:
        return getattr(self._transport, "local_port", None)

    # --- receiving ------------------------------------------------------------------------------------

    def _reader(self) -> None:
        assert self._transport is not None and self._inbox is not None
        while not self._stop.is_set():
            try:
                data = self._transport.read(0.1)
            except (OSError, ValueError):
                if self._stop.is_set():
                    return
                time.sleep(0.1)
                continue
            if not data:
                continue
            with self._lock:
                msgs = parse_bytes(self.mav, data, self._transport.datagrams)
            if isinstance(self._transport, UdpTransport) and self._transport.listen:
                self._answer(self._transport, msgs)
            if msgs:
                try:
                    self._inbox.put(self, msgs)
                except RuntimeError:  # loop closed while stopping
                    return

    def _read_datagram(self) -> list | None:
        """One queued datagram of a UDP link (on the loop, at a drain of the inbox: Inbox._read_ready),
        parsed (up to its first MAX_DATAGRAM_PARSE bytes: parse_bytes); None when the link is closing or
        has none after all. `read_bytes` is then what it cost to parse (the inbox's budget per drain).
        udpin: its sender is answered as `_answer` says."""
        transport = self._transport
        if self._stop.is_set() or not isinstance(transport, UdpTransport):
            return None
        try:
            data, source = transport.sock.recvfrom(MAX_DATAGRAM, socket.MSG_DONTWAIT)
        except (BlockingIOError, InterruptedError):
            return None
        except OSError:  # an ICMP error of an earlier send (a peer gone away): link loss, seen by heartbeats
            self.read_bytes = 0
            return []
        self.read_bytes = min(len(data), MAX_DATAGRAM_PARSE)
        transport.last_source = source
        with self._lock:
            parsed = parse_bytes(self.mav, data, True)
        if transport.listen:
            self._answer(transport, parsed)
        return parsed

    def _answer(self, transport: UdpTransport, msgs: list) -> None:
        """udpin: whether the sender of these messages (one datagram's) is answered from now on. A
        frame signed with the key adds (or refreshes) its address; on a link that takes unsigned frames
        a vehicle's HEARTBEAT does, of a system id the link expects (any, while it expects none), and
        other valid frames only refresh an address already answered. An unsigned RADIO_STATUS (taken
        unsigned: radios insert it) neither adds nor refreshes one, nor does anything on a signing link
        that is not signed with the key. The address is kept for the sender's system id when the link
        expects it (or expects none): the transport then drops other addresses first (accept_source)."""
        signed_only = self.signing_key is not None and not self.accept_unsigned
        expected = self.expected
        refresh = False
        for msg in msgs:
            header = msg._header
            mid = header.msgId
            if mid < 0:  # bad data, an unknown message id
                continue
            src = header.srcSystem
            if msg._signed:  # its signature checked: only a key holder could send it
                transport.accept_source(src if not expected or src in expected else None)
                return
            if signed_only or mid == _RADIO_STATUS:
                continue
            if mid == _HEARTBEAT and msg.autopilot != MAV.MAV_AUTOPILOT_INVALID:
                if not expected or src in expected:
                    transport.accept_source(src)
                    return
            refresh = True
        if refresh:
            transport.refresh_source()

    def _dispatch(self, msgs: list) -> None:
        """Messages of this link to their listeners, then to its batch listeners."""
        accepted = self._deliver(msgs)
        if accepted:
            for cb in call_batch_listeners(dict.fromkeys(self._batch_listeners, accepted)):
                self.remove_listener(cb)  # reported once: not called again

    def _deliver(self, msgs: list) -> list:
        """Messages of this link to its per-message listeners (and peers, waiters); the valid ones."""
        now = time.monotonic()
        stats, peers, route = self.stats, self.peers, self._route
        accepted = msgs
        for i, msg in enumerate(msgs):
            header = msg._header  # pymavlink's parsed header: msgId, srcSystem (get_srcSystem() without the call)
            if header.msgId < 0:  # BAD_DATA (-1) or a message id the dialect does not have (UNKNOWN_n, -2)
                if accepted is msgs:
                    accepted = msgs[:i]
                if isinstance(msg, MAV.MAVLink_unknown):
                    stats.unknown += 1  # not kept per id: the table would grow with every id a sender makes up
                elif not self._console_text(msg):
                    if isinstance(msg, Unparsed):
                        stats.dropped_bytes += msg.dropped
                    self._bad_data(msg, now)
                continue
            if accepted is not msgs:
                accepted.append(msg)
            self._framed = True
            stats.received += 1
            src, mtype = header.srcSystem, msg._type  # _type: what get_type() returns
            if self.silenced and src in self.silenced:
                continue  # recorded (the batch listeners have it), never followed again
            if mtype == "HEARTBEAT":
                self._heartbeat(msg, src, now)
            peer = peers.get(src)
            if peer is not None:
                if header.srcComponent == peer.compid and not peer.lost and peer.heartbeat is not None:
                    self._silent_since_heard(peer, now)
                    # any frame of its autopilot keeps the link up: with 1 Hz heartbeats alone, a link
                    # losing 20 % gave 3 false losses in a 90 s search of 3 vehicles (tools/lossy_links.py).
                    # A lost one is back only with a heartbeat: its mode and armed state are the heartbeat's,
                    # and the rejoin reads them.
                    if not peer.lost:
                        peer.last_heard = now
                peer.messages[mtype] = msg
                peer.received_at[mtype] = now
                if mtype == "STATUSTEXT":
                    peer.statustexts.append((now, msg.severity, printable(msg.text)))
            cbs = route.get(mtype)
            if cbs is None:
                cbs = self._routes(mtype)
            for cb in cbs:  # the listeners now (one may add another)
                try:
                    cb(msg)
                except Exception as exc:  # a listener's bug must not stop the link
                    self._listener_failed(cb, mtype, src, exc)
                    break
            else:
                if self._waiters:
                    self._check_waiters(msg)
        return accepted

    def _listener_failed(self, cb: Callable[[Any], None], mtype: str, src: int, exc: Exception) -> None:
        """A listener raised on a message of type `mtype` from system `src`: that vehicle is judged as the
        watchdog judges a silent one (lost, its "lost" event given), and kept so: what a listener of its
        messages cannot take, the controller cannot follow, so its messages reach no listener, peer or
        waiter again (its heartbeats do not bring it back; the recording still has them). One error line
        per listener and vehicle (no traceback: that is logged at DEBUG), never one per message."""
        name = getattr(cb, "__qualname__", None) or type(cb).__name__
        why = f"{name} failed on its {mtype}: {type(exc).__name__}: {exc}"
        self.silenced[src] = why
        if src in self.expected or name not in self._failed_listeners:
            self._failed_listeners.add(name)
            log.error(
                "%s: MAVLink listener %s failed on %s from system %d: %s: %s; vehicle %d is treated as "
                "silent (lost, left to its failsafe) from now on",
                self.endpoint,
                name,
                mtype,
                src,
                type(exc).__name__,
                printable(str(exc)),
                src,
            )
            log.debug("the listener's traceback", exc_info=exc)
        peer = self.peers.get(src)  # none: it is lost already (is_lost)
        if peer is not None and not peer.lost:
            peer.lost = True
            if src in self.expected:
                self._link_event(peer, "lost")

    def _routes(self, mtype: str) -> tuple[Callable[[Any], None], ...]:
        """The listeners of one message type, in the order they are called (those for every message
        first), kept in `_route` until a listener is added or removed."""
        cbs = self._route[mtype] = self._listeners + self._typed.get(mtype, ())
        return cbs

    def _bad_data(self, msg: Any, now: float) -> None:
        self.stats.bad_data += 1
        if now - self._bad_logged > 5.0:  # logged, but at most once per 5 s per link
            self._bad_logged = now
            log.warning(
                "rejected bad MAVLink data on %s (%d so far): %s",
                self.endpoint,
                self.stats.bad_data,
                getattr(msg, "reason", ""),
            )

    def _heartbeat(self, msg: Any, src: int, now: float) -> None:
        if msg.autopilot == MAV.MAV_AUTOPILOT_INVALID:
            return  # another ground station or companion; not a vehicle
        peer = self.peers.get(src)
        if peer is None:
            peer = self.peers[src] = Peer(sysid=src)
        first = peer.heartbeat is None
        if not first and msg.get_srcComponent() == peer.compid:
            self._silent_since_heard(peer, now)
        peer.compid = msg.get_srcComponent()
        peer.heartbeat, peer.last_heartbeat, peer.last_heard = msg, now, now
        if first or peer.lost:  # its "back" (or first, "seen") event
            peer.lost = False
            if src in self.expected:
                self._link_event(peer, "back")

    def _silent_since_heard(self, peer: Peer, now: float) -> None:
        """A frame of a vehicle not heard for more than lost_after: it was lost, whether or not the watchdog
        ran meanwhile. A process stopped or starved that long reads the frames its socket kept as it runs
        again, maybe before the watchdog's turn: the vehicle's GCS failsafe has acted on the silence all the
        same, and the controller must see the loss (then, with a heartbeat, the vehicle back) to rejoin it
        rather than take the failsafe's mode for a pilot's."""
        if not peer.lost and peer.heartbeat is not None and now - peer.last_heard > self.lost_after:
            peer.lost = True
            if peer.sysid in self.expected:
                self._link_event(peer, "lost")

    def _check_waiters(self, msg: Any) -> None:
        for pred, fut in list(self._waiters):
            if fut.done():
                continue
            try:
                if pred(msg):
                    fut.set_result(msg)
            except Exception as exc:
                fut.set_exception(exc)

    def _console_text(self, msg: Any) -> bool:
        """True when these bad bytes are the autopilot's console text: on a stream link (TCP, serial),
        before its first valid frame or while a vehicle on it still reports MAV_STATE_BOOT (ArduCopter
        SITL prints 152 bytes on SERIAL0 before its first heartbeat and 12 more between the first two).
        They are counted in stats.console_bytes and kept in `console`, not reported as bad data."""
        if self._transport is None or self._transport.datagrams:
            return False
        booting = any(
            p.heartbeat is not None and p.heartbeat.system_status == MAV.MAV_STATE_BOOT for p in self.peers.values()
        )
        if self._framed and not booting:
            return False
        data = bytes(msg.get_msgbuf())
        if not self.stats.console_bytes:
            log.info("console text before MAVLink on %s (the autopilot booting)", self.endpoint)
        self.stats.console_bytes += len(data)
        self.console = (self.console + data)[:CONSOLE_KEEP]
        return True

    def add_listener(self, callback: Callable[[Any], None], types: Iterable[str] | None = None) -> None:
        """Call callback(msg) on the event loop for every message received, or (`types`) for the
        messages of those types only."""
        self._route = {}
        if types is None:
            self._listeners += (callback,)
            return
        for t in types:
            self._typed[t] = self._typed.get(t, ()) + (callback,)

    def add_batch_listener(self, callback: Callable[[list], None]) -> None:
        """Call callback(msgs) on the event loop with the valid messages received, a batch at a time (in
        the order they came, each message once; after the per-message listeners have seen them). A
        callback added to several links of one event loop (the recorder's tap) is called once per drain
        of the loop's inbox with all of their messages, link after link, each link's in their order."""
        self._batch_listeners += (callback,)

    def remove_listener(self, callback: Callable[[Any], None]) -> None:
        """Stop calling callback (whichever way it was added)."""

        def without(cbs: tuple) -> tuple:  # the first time it was added there
            for i, cb in enumerate(cbs):
                if cb == callback:
                    return cbs[:i] + cbs[i + 1 :]
            return cbs

        self._route = {}
        self._listeners = without(self._listeners)
        self._batch_listeners = without(self._batch_listeners)
        self._typed = {t: left for t, cbs in self._typed.items() if (left := without(cbs))}

    def on_link_change(self, callback: Callable[[int, str], None]) -> None:
        """Call callback(sysid, event) with event "seen", "lost" or "back", for the system ids the link
        expects (`expect`)."""
        self._link_callbacks.append(callback)

    def expect(self, sysid: int) -> None:
        """Report link events of vehicle `sysid` (in `events` and to `on_link_change`'s callbacks): from
        its first heartbeat ("seen", at once if it has been heard), then "lost" and "back". Heartbeats of
        other system ids keep their peers up to date but give no events, so that a sender making up
        system ids cannot fill the list or the recording. Called by wait_heartbeat and peer (every
        command and parameter read) for the vehicle they name."""
        if sysid in self.expected:
            return
        self.expected.add(sysid)
        peer = self.peers.get(sysid)
        if peer is not None and peer.heartbeat is not None and not peer.lost:
            self._link_event(peer, "seen")

    def _link_event(self, peer: Peer, event: str) -> None:
        """An event of an expected vehicle; its first is "seen", and nothing is lost before it."""
        if not peer.announced:
            if event == "lost":
                return
            event, peer.announced = "seen", True
        sysid = peer.sysid
        self.events.append((time.monotonic(), sysid, event))
        log.info("vehicle %d: %s", sysid, event)
        for cb in list(self._link_callbacks):
            try:
                cb(sysid, event)
            except Exception:
                log.exception("link-change callback failed")

    async def wait_message(self, predicate: Callable[[Any], bool], timeout: float) -> Any:
        """The next received message for which predicate(msg) is true; asyncio.TimeoutError if none."""
        fut: asyncio.Future = asyncio.get_running_loop().create_future()
        entry = (predicate, fut)
        self._waiters.append(entry)
        try:
            return await asyncio.wait_for(fut, timeout)
        finally:
            if entry in self._waiters:
                self._waiters.remove(entry)

    async def wait_until(self, condition: Callable[[], bool], timeout: float, what: str, vehicle: str) -> None:
        """Wait until condition() holds (re-checked on every message and every 0.2 s)."""
        deadline = time.monotonic() + timeout
        while not condition():
            left = deadline - time.monotonic()
            if left <= 0:
                raise WaitTimeout(what, vehicle, timeout)
            try:
                await self.wait_message(lambda _m: condition(), min(left, 0.2))
            except TimeoutError:
                pass

    # --- link state ---------------------------------------------------------------------------------

    def peer(self, sysid: int) -> Peer:
        """What the link knows of vehicle `sysid` (which it expects from now on: `expect`)."""
        if sysid not in self.expected:
            self.expect(sysid)
        if sysid not in self.peers:
            self.peers[sysid] = Peer(sysid=sysid, lost=True)
        return self.peers[sysid]

    def is_lost(self, sysid: int) -> bool:
        p = self.peers.get(sysid)
        return p is None or p.lost or p.heartbeat is None

    async def wait_heartbeat(self, sysid: int, timeout: float = 10.0) -> Peer:
        self.expect(sysid)
        p = self.peers.get(sysid)
        if p is None or p.heartbeat is None or p.lost:
            await self.wait_until(lambda: not self.is_lost(sysid), timeout, "a HEARTBEAT", f"vehicle {sysid}")
        return self.peers[sysid]

    async def _heartbeat_loop(self) -> None:
        while True:
            self.send(
                self.mav.heartbeat_encode(self.heartbeat_type, MAV.MAV_AUTOPILOT_INVALID, 0, 0, MAV.MAV_STATE_ACTIVE)
            )
            await asyncio.sleep(self.heartbeat_period)

    def _check_heartbeats(self, now: float) -> None:
        """A vehicle whose autopilot has sent nothing (no heartbeat, no other frame) for more than
        lost_after is lost (called every WATCHDOG_S)."""
        for p in list(self.peers.values()):
            if not p.lost and p.heartbeat is not None and now - p.last_heard > self.lost_after:
                # _listener_failed judges a vehicle whose listener failed the same way
                p.lost = True
                if p.sysid in self.expected:
                    self._link_event(p, "lost")

    # --- sending --------------------------------------------------------------------------------------

    def send(self, msg: Any) -> None:
        """Pack (and sign, if a key is set) one message built with link.mav.<name>_encode(...)."""
        if self._transport is None:
            raise RuntimeError("the MAVLink link is not open")
        with self._lock:
            self.mav.send(msg)
        self.stats.sent += 1

    async def command(
        self,
        sysid: int,
        command: int,
        params: tuple[float, ...] = (),
        *,
        compid: int | None = None,
        timeout: float = 1.0,
        retries: int = 3,
        vehicle: str | None = None,
        use_int: bool = False,
        frame: int = 0,
    ) -> Any:
        """Send COMMAND_LONG (or COMMAND_INT) and wait for its COMMAND_ACK, resending on timeout.

        Returns the ACCEPTED ack. Raises CommandRejected on DENIED/FAILED/UNSUPPORTED/
        TEMPORARILY_REJECTED/CANCELLED (with the vehicle's latest STATUSTEXT as the reason) and
        CommandTimeout when no ack came after 1 + retries attempts.
        """
        name = command_name(command)
        who = vehicle or f"vehicle {sysid}"
        p = list(params) + [0.0] * (7 - len(params))
        peer = self.peer(sysid)
        target_comp = peer.compid if compid is None else compid
        async with peer.command_lock:
            started = time.monotonic()
            attempts = 1 + max(0, retries)
            for attempt in range(attempts):
                if use_int:
                    msg = self.mav.command_int_encode(
                        sysid, target_comp, frame, command, 0, 0, p[0], p[1], p[2], p[3], int(p[4]), int(p[5]), p[6]
                    )
                else:
                    msg = self.mav.command_long_encode(sysid, target_comp, command, min(attempt, 255), *p)
                self.send(msg)
                deadline = time.monotonic() + timeout
                while True:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        break
                    try:
                        ack = await self.wait_message(
                            lambda m: (
                                m.get_type() == "COMMAND_ACK" and m.get_srcSystem() == sysid and m.command == command
                            ),
                            left,
                        )
                    except TimeoutError:
                        break
                    if ack.result == MAV.MAV_RESULT_IN_PROGRESS:
                        deadline = time.monotonic() + timeout
                        continue
                    if ack.result == MAV.MAV_RESULT_ACCEPTED:
                        return ack
                    await asyncio.sleep(0.02)  # a STATUSTEXT saying why may trail the ack
                    raise CommandRejected(
                        name, who, MAV_RESULT_NAMES.get(ack.result, str(ack.result)), peer.texts_since(started - 0.05)
                    )
                log.info("%s: no ack to %s (attempt %d of %d)", who, name, attempt + 1, attempts)
            raise CommandTimeout(name, who, attempts, timeout)

    async def read_param(
        self, sysid: int, name: str, *, timeout: float = 1.0, retries: int = 3, vehicle: str | None = None
    ) -> float:
        """A parameter's value: PARAM_REQUEST_READ by name, answered by PARAM_VALUE, resent on timeout.
        CommandTimeout when no answer came after 1 + retries attempts."""
        who = vehicle or f"vehicle {sysid}"
        peer = self.peer(sysid)
        attempts = 1 + max(0, retries)

        def answer(m: Any) -> bool:
            if m.get_type() != "PARAM_VALUE" or m.get_srcSystem() != sysid:
                return False
            pid = m.param_id if isinstance(m.param_id, str) else m.param_id.decode(errors="replace")
            return pid.rstrip("\x00") == name

        for attempt in range(attempts):
            self.send(self.mav.param_request_read_encode(sysid, peer.compid, name.encode(), -1))
            try:
                return float((await self.wait_message(answer, timeout)).param_value)
            except TimeoutError:
                log.info("%s: no answer to reading %s (attempt %d of %d)", who, name, attempt + 1, attempts)
        raise CommandTimeout(f"reading parameter {name}", who, attempts, timeout)

    async def set_message_interval(self, sysid: int, message_id: int, rate_hz: float, **kw: Any) -> Any:
        interval_us = -1.0 if rate_hz <= 0 else 1e6 / rate_hz
        return await self.command(sysid, MAV.MAV_CMD_SET_MESSAGE_INTERVAL, (float(message_id), interval_us), **kw)


async def cancel_tasks(tasks: list[asyncio.Task]) -> None:
    """Cancel background tasks and wait until each has ended (errors they ended with are dropped)."""
    for t in tasks:
        t.cancel()
    for t in tasks:
        try:
            await t
        except (asyncio.CancelledError, Exception):
            pass
