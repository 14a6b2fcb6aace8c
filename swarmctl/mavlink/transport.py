"""Byte transports for MAVLink: UDP in/out, TCP client, serial. Blocking reads, for a link's reader thread
(a UDP link reads its socket on the event loop instead: swarmctl.mavlink.network).

`udpin` listens and answers the peers it has heard from (like a radio channel shared by several
vehicles): vehicles on one link tell messages apart by target_system, so nothing depends on which
socket address a vehicle used. An address is answered only once its owner, having parsed what came
from it, says so with `accept_source()` (the controller's link: a frame signed with the key, or
without a key a vehicle's heartbeat; never an unsigned RADIO_STATUS: MavlinkLink._answer), and
`refresh_source()` keeps an address answered without adding one. At most MAX_SOURCES addresses are
answered; when a new one comes, the one dropped is the least recently heard of those not known as a
vehicle's, else of a vehicle's with more addresses than one, else the least recently heard: so bytes
from spoofed ports neither make each write go to thousands of addresses nor push out the vehicles.
`udpout` sends to one address and reads answers on its own port.
"""

from __future__ import annotations

import select
import socket
import threading
from collections import OrderedDict
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav_module

from swarmctl.errors import InputError
from swarmctl.mavlink.codec import Endpoint, parse_connection

MAX_SOURCES = 32  # udpin: the addresses answered at once
# A datagram is parsed up to this many bytes (the rest is dropped, as one Unparsed bad-data message):
# autopilots send one frame, or a few, a datagram (a MAVLink 2 frame is at most 280 bytes), and one 65 KB
# datagram of 13-byte frames took 31 ms to parse.
MAX_DATAGRAM_PARSE = 8192


class Transport:
    datagrams = False  # True when every read() returns whole packets (UDP)

    def read(self, timeout: float) -> bytes:  # pragma: no cover - interface
        """Bytes received within timeout seconds (b'' if none)."""
        raise NotImplementedError

    def accept_source(self, vehicle: int | None = None) -> None:
        """Answer where the bytes last read came from (udpin); `vehicle`: the system id of a vehicle
        known to send from there."""

    def refresh_source(self) -> None:
        """The address of the bytes last read, if answered, stays answered as recently heard (udpin)."""

    def write(self, data: bytes) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - interface
        raise NotImplementedError


class UdpTransport(Transport):
    datagrams = True

    def __init__(self, ep: Endpoint):
        self.listen = ep.kind == "udpin"
        # No SO_REUSEADDR: on a UDP socket it lets the kernel hand a port already bound by another
        # such socket to a bind to port 0 (a udpout's own port landed on a udpin's, which then
        # answered itself), and lets a second program bind a listening port and split its traffic.
        # UDP has no TIME_WAIT, so a port closed is free again at once without it.
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.peers: list[tuple[str, int]] = []
        # udpin: the addresses answered, least recently heard first, each with its vehicle's system id (or None)
        self._sources: OrderedDict[tuple[str, int], int | None] = OrderedDict()
        self.last_source: tuple[str, int] | None = None
        self.evicted = 0  # udpin: addresses no longer answered because MAX_SOURCES newer ones were heard
        self._lock = threading.Lock()
        try:
            if self.listen:
                self.sock.bind((ep.host, ep.port))
            else:
                self.peers = [(socket.gethostbyname(ep.host), ep.port)]
                self.sock.bind(("0.0.0.0", 0))
        except OSError as exc:
            self.sock.close()
            raise InputError(
                f"connection {str(ep)!r}: cannot open the UDP socket ({exc.strerror}); "
                "check the host and that the port is free"
            ) from None
        self.local_port = self.sock.getsockname()[1]

    def read(self, timeout: float) -> bytes:
        r, _, _ = select.select([self.sock], [], [], timeout)
        if not r:
            return b""
        try:
            data, addr = self.sock.recvfrom(65535)
        except OSError:
            return b""
        self.last_source = addr
        return data

    def accept_source(self, vehicle: int | None = None) -> None:
        addr = self.last_source
        if not self.listen or addr is None:
            return
        with self._lock:
            sources = self._sources
            known = sources.get(addr, _ABSENT)
            if known is not _ABSENT:
                sources.move_to_end(addr)
                if vehicle is not None and known != vehicle:
                    sources[addr] = vehicle
                return
            sources[addr] = vehicle
            while len(sources) > MAX_SOURCES:
                del sources[self._evictable()]
                self.evicted += 1
            self.peers = list(sources)

    def _evictable(self) -> tuple[str, int]:
        """The address dropped for a new one: the least recently heard not known as a vehicle's; else of
        a vehicle with another address; else the least recently heard."""
        sources = self._sources
        count: dict[int, int] = {}
        for addr, vehicle in sources.items():
            if vehicle is None:
                return addr
            count[vehicle] = count.get(vehicle, 0) + 1
        for addr, vehicle in sources.items():
            if vehicle is not None and count[vehicle] > 1:  # (none is None here: the loop above returned)
                return addr
        return next(iter(sources))

    def refresh_source(self) -> None:
        addr = self.last_source
        if not self.listen or addr is None:
            return
        with self._lock:
            if addr in self._sources:
                self._sources.move_to_end(addr)

    def write(self, data: bytes) -> None:
        with self._lock:
            peers = list(self.peers)
        for addr in peers:
            try:
                self.sock.sendto(data, addr)
            except OSError:
                pass  # a peer gone away (ICMP unreachable) is link loss, seen by heartbeat timeout

    def close(self) -> None:
        self.sock.close()


class TcpTransport(Transport):
    def __init__(self, ep: Endpoint):
        try:
            self.sock = socket.create_connection((ep.host, ep.port), timeout=5.0)
        except OSError as exc:
            raise InputError(
                f"connection {str(ep)!r}: cannot connect ({exc.strerror or exc}); "
                "check that the vehicle or simulator listens on that TCP port"
            ) from None
        self.sock.setblocking(True)

    def read(self, timeout: float) -> bytes:
        r, _, _ = select.select([self.sock], [], [], timeout)
        if not r:
            return b""
        try:
            return self.sock.recv(65535)
        except OSError:
            return b""

    def write(self, data: bytes) -> None:
        try:
            self.sock.sendall(data)
        except OSError:
            pass

    def close(self) -> None:
        self.sock.close()


class SerialTransport(Transport):
    def __init__(self, ep: Endpoint):
        try:
            import serial  # pyserial, pulled in by pymavlink for serial links
        except ImportError:
            raise InputError(
                f"connection {str(ep)!r}: serial links need pyserial; install it with `pip install pyserial`"
            ) from None
        try:
            self.port = serial.Serial(ep.device, ep.baud, timeout=0)
        except (OSError, serial.SerialException) as exc:
            raise InputError(
                f"connection {str(ep)!r}: cannot open the serial device ({exc}); "
                "check the device path, the baud rate and permissions"
            ) from None

    def read(self, timeout: float) -> bytes:
        r, _, _ = select.select([self.port.fileno()], [], [], timeout)
        if not r:
            return b""
        return self.port.read(4096)

    def write(self, data: bytes) -> None:
        self.port.write(data)

    def close(self) -> None:
        self.port.close()


def parse_bytes(mav: Any, data: bytes, datagram: bool) -> list:
    """Parse received bytes with a pymavlink MAVLink object; never raises.

    Malformed input comes back as BAD_DATA messages. On a datagram link a packet never spans two
    datagrams, so bytes left over at the end of one (a truncated or bogus packet) are dropped as
    BAD_DATA instead of being glued to the next datagram, which would swallow valid packets.

    A datagram that is exactly one MAVLink 2 frame (what autopilots send) goes straight to pymavlink's
    own decode(), which checks the CRC and signature and builds the message, without the byte-stream
    state machine around it (a third of the parse's time); any other datagram, and every stream, goes
    through parse_buffer. Both paths give the same messages (tests/test_mavlink_parse.py).

    A datagram longer than MAX_DATAGRAM_PARSE is parsed up to that many bytes; the rest comes back as
    one `Unparsed` (BAD_DATA) message: so what one datagram costs is bounded.
    """
    if datagram and len(data) >= _V2_MIN and data[0] == _V2_MARKER and not mav.buf_len():
        flags = data[2]
        if flags & ~_V2_SIGNED == 0 and len(data) == data[1] + (_V2_SIGNED_OVERHEAD if flags else _V2_OVERHEAD):
            return [_decode_frame(mav, data)]
    if datagram and len(data) > MAX_DATAGRAM_PARSE:
        msgs = parse_stream(mav, data[:MAX_DATAGRAM_PARSE], True)
        mav.total_receive_errors += 1
        rest = len(data) - MAX_DATAGRAM_PARSE
        msgs.append(Unparsed(rest, f"a datagram of {len(data)} bytes: the {rest} past {MAX_DATAGRAM_PARSE} not parsed"))
        return msgs
    return parse_stream(mav, data, datagram)


class Unparsed(mav_module.MAVLink_bad_data):
    """The bytes of a datagram past MAX_DATAGRAM_PARSE, dropped unparsed (`dropped` of them): bad data."""

    def __init__(self, dropped: int, reason: str):
        super().__init__(bytearray(), reason)
        self.dropped = dropped


def parse_stream(mav: Any, data: bytes, datagram: bool) -> list:
    """parse_bytes without its fast path: every byte through pymavlink's parse_buffer."""
    try:
        msgs = mav.parse_buffer(data) or []
    except Exception as exc:  # pymavlink raises on some malformed input even in robust mode
        msgs = [_bad_data(mav, bytearray(data), str(exc))]
        _reset_parser(mav)
    if datagram and mav.buf_len() > 0:
        leftover = mav.buf[mav.buf_index :]
        _reset_parser(mav)
        msgs.append(_bad_data(mav, bytearray(leftover), "truncated packet at the end of a datagram"))
    return msgs


_V2_MARKER = mav_module.PROTOCOL_MARKER_V2
_V2_SIGNED = mav_module.MAVLINK_IFLAG_SIGNED
_V2_OVERHEAD = mav_module.HEADER_LEN_V2 + 2  # header and CRC around the payload
_V2_SIGNED_OVERHEAD = _V2_OVERHEAD + mav_module.MAVLINK_SIGNATURE_BLOCK_LEN
_V2_MIN = _V2_OVERHEAD + 1  # MAVLink 2 trims trailing zeros of a payload but keeps its first byte


def _decode_frame(mav: Any, data: bytes) -> Any:
    """One whole MAVLink 2 frame through pymavlink's decode(), with the counters and the error handling
    of its parse_char() in robust mode."""
    frame = bytearray(data)
    mav.total_bytes_received += len(frame)
    try:
        msg = mav.decode(frame)
    except mav_module.MAVError as reason:
        mav.total_receive_errors += 1
        msg = mav_module.MAVLink_bad_data(frame, reason.message)
    except Exception as exc:  # as parse_bytes: pymavlink raises more than MAVError on some input
        return _bad_data(mav, frame, str(exc))
    mav.total_packets_received += 1
    return msg


_ABSENT = object()


def valid_frame(msg: Any) -> bool:
    """A parsed message that is a whole frame of the dialect (not bad data, not an unknown message id,
    which pymavlink hands over without checking its CRC or signature)."""
    return msg.get_type() != "BAD_DATA" and not isinstance(msg, mav_module.MAVLink_unknown)


def _reset_parser(mav: Any) -> None:
    mav.buf = bytearray()
    mav.buf_index = 0
    mav.expected_length = mav_module.HEADER_LEN_V1 + 2
    mav.have_prefix_error = False


def _bad_data(mav: Any, data: bytearray, reason: str) -> Any:
    mav.total_receive_errors += 1
    return mav_module.MAVLink_bad_data(data, reason)


def open_transport(conn: str | Endpoint) -> Transport:
    ep = conn if isinstance(conn, Endpoint) else parse_connection(conn)
    if ep.kind in ("udpin", "udpout"):
        return UdpTransport(ep)
    if ep.kind == "tcp":
        return TcpTransport(ep)
    return SerialTransport(ep)
