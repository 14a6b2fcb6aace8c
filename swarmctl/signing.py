"""MAVLink 2 signing for pymavlink objects, with each signed frame verified before any state changes.

    setup_signing(mav, key)                       # sign what mav sends, accept only frames signed with key
    setup_signing(mav, key, accept_unsigned={MAVLINK_MSG_ID_RADIO_STATUS})

Every MAVLink object of swarmctl that signs (the controller's links, the knowledge codec, the mock
autopilot) is set up here, so they share one verification. pymavlink's own `MAVLink.check_signature`
(2.4.x) records a stream's timestamp before it checks the signature: one forged frame with a stream's
(link id, system id, component id) and a timestamp of 2^48 - 2 makes every later correctly signed
frame of that stream look old, and the stream is lost for good. `check_signature` here checks the
signature first (in constant time) and records the timestamp only for a frame that carries the key's
signature; replay protection is kept (a stream's timestamps must increase, and a new stream may be at
most one minute behind our own clock, as the MAVLink specification says).

The timestamps table (`mav.signing.stream_timestamps`) therefore only grows with streams that hold the
key. Counters: pymavlink's own (`goodsig_count`, `badsig_count`, `reject_count`, `unsigned_count`).

Several MAVLink objects of one process that sign as the same system and component (the controller's
links: one per connection, every one system 255, component 190) must not sign as one stream: a frame
copied from one link onto another would be new to the vehicle there, and the timestamp it carries
would make that link's own frames look old. So each gets a `link_id` of its own (a stream is
(link id, system id, component id), at ArduPilot and PX4 as here), and they draw their timestamps
from one `SigningClock` (`clock=`): strictly increasing over all of them and never behind the wall
clock, so even where a receiver kept one timestamp for all of them, a frame copied from another link
is older than the next frame of the link's own.
"""

from __future__ import annotations

import functools
import hashlib
import hmac
import struct
import threading
import time
from collections.abc import Callable, Collection
from typing import Any

from pymavlink.dialects.v20.ardupilotmega import MAVLinkSigning

KEY_BYTES = 32
EPOCH_2015 = 1420070400  # MAVLink signing timestamps count 10 microsecond units from 2015-01-01 UTC
NEW_STREAM_SLACK = 6_000_000  # a new stream may be this far behind our clock: one minute, in 10 us units
_TIMESTAMP = struct.Struct("<IH")


def now_timestamp() -> int:
    """The current time as a MAVLink signing timestamp (10 us units since 2015-01-01 UTC)."""
    return int((max(time.time(), EPOCH_2015) - EPOCH_2015) * 100_000)


class SigningClock:
    """One source of signing timestamps for several MAVLink objects: every value handed out is at least
    the wall clock's (`now_timestamp`) and at least any value set (a frame sent: pymavlink adds 1 after
    signing; a newer timestamp received), so the frames of all of them carry increasing timestamps."""

    def __init__(self) -> None:
        self._last = 0
        self._lock = threading.Lock()

    def now(self) -> int:
        value = int((time.time() - EPOCH_2015) * 100_000)
        with self._lock:
            if value > self._last:
                self._last = value
                return value
            return self._last

    def advance(self, value: int) -> None:
        with self._lock:
            if value > self._last:
                self._last = value


PROCESS_CLOCK = SigningClock()  # the controller's links draw from this one (swarmctl.mavlink.network)


class _ClockedSigning(MAVLinkSigning):
    """pymavlink's signing state with its `timestamp` read from, and written to, a SigningClock."""

    def __init__(self, clock: SigningClock, state: MAVLinkSigning):
        self._clock = clock
        super().__init__()
        self.__dict__.update({k: v for k, v in vars(state).items() if k != "timestamp"})
        clock.advance(state.timestamp)

    @property
    def timestamp(self) -> int:
        return self._clock.now()

    @timestamp.setter
    def timestamp(self, value: int) -> None:
        self._clock.advance(value)


def check_signature(mav: Any, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
    """Whether a signed frame carries the signature of `mav`'s key and a timestamp newer than its
    stream's; only then is the stream's timestamp recorded (see the module docstring)."""
    signing = mav.signing
    digest = hashlib.sha256(bytes(signing.secret_key) + bytes(msgbuf[:-6])).digest()[:6]
    if not hmac.compare_digest(digest, bytes(msgbuf[-6:])):
        return False
    low, high = _TIMESTAMP.unpack(bytes(msgbuf[-12:-6]))
    timestamp = low + (high << 32)
    stream = (msgbuf[-13], src_system, src_component)
    last = signing.stream_timestamps.get(stream)
    if last is not None:
        if timestamp <= last:
            return False  # a replayed or reordered frame
    elif timestamp + NEW_STREAM_SLACK < now_timestamp():
        # a new stream from long ago: a replay. Against the wall clock, not signing.timestamp, which a
        # vehicle whose clock runs ahead pushes forward (on a shared clock, for every link)
        return False
    signing.stream_timestamps[stream] = timestamp
    signing.timestamp = max(signing.timestamp, timestamp)
    return True


def setup_signing(
    mav: Any,
    key: bytes,
    *,
    link_id: int = 0,
    sign_outgoing: bool = True,
    accept_unsigned: Collection[int] | Callable[[Any, int], bool] = (),
    clock: SigningClock | None = None,
) -> None:
    """Sign what `mav` sends with `key` (32 bytes) and accept only frames signed with it, verified by
    `check_signature`; `accept_unsigned` names message ids still taken unsigned (or is a callback
    (mav, msg_id) -> bool, as pymavlink's). `link_id` (0-255) is the link id of the frames it signs;
    with `clock` its timestamps come from that SigningClock (shared with the other objects on it)
    instead of a counter of its own."""
    if len(key) != KEY_BYTES:
        raise ValueError(f"a MAVLink signing key is {KEY_BYTES} bytes")
    if not 0 <= int(link_id) <= 255:
        raise ValueError(f"a MAVLink signing link id is 0..255, not {link_id}")
    if clock is not None and not isinstance(mav.signing, _ClockedSigning):
        mav.signing = _ClockedSigning(clock, mav.signing)
    s = mav.signing
    s.secret_key, s.sign_outgoing, s.link_id = bytes(key), sign_outgoing, int(link_id)
    s.timestamp = max(s.timestamp, now_timestamp())
    if callable(accept_unsigned):
        s.allow_unsigned_callback = accept_unsigned
    else:
        allowed = frozenset(accept_unsigned)
        s.allow_unsigned_callback = lambda _mav, msg_id: msg_id in allowed
    mav.check_signature = functools.partial(check_signature, mav)


def signing_counts(mav: Any) -> dict[str, int]:
    """What a signing MAVLink object has seen: good and bad signatures, frames refused (unsigned or
    wrongly signed, not allowed unsigned) and unsigned frames allowed."""
    s = mav.signing
    return dict(good=s.goodsig_count, bad=s.badsig_count, refused=s.reject_count, unsigned=s.unsigned_count)
