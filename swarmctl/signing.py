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
"""

from __future__ import annotations

import functools
import hashlib
import hmac
import struct
import time
from collections.abc import Callable, Collection
from typing import Any

KEY_BYTES = 32
EPOCH_2015 = 1420070400  # MAVLink signing timestamps count 10 microsecond units from 2015-01-01 UTC
NEW_STREAM_SLACK = 6_000_000  # a new stream may be this far behind our clock: one minute, in 10 us units
_TIMESTAMP = struct.Struct("<IH")


def now_timestamp() -> int:
    """The current time as a MAVLink signing timestamp (10 us units since 2015-01-01 UTC)."""
    return int((max(time.time(), EPOCH_2015) - EPOCH_2015) * 100_000)


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
    elif timestamp + NEW_STREAM_SLACK < signing.timestamp:
        return False  # a new stream from long ago: a replay
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
) -> None:
    """Sign what `mav` sends with `key` (32 bytes) and accept only frames signed with it, verified by
    `check_signature`; `accept_unsigned` names message ids still taken unsigned (or is a callback
    (mav, msg_id) -> bool, as pymavlink's)."""
    if len(key) != KEY_BYTES:
        raise ValueError(f"a MAVLink signing key is {KEY_BYTES} bytes")
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
