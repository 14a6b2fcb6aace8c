"""A datagram's parse: the fast path for a datagram that is one whole MAVLink 2 frame (pymavlink's
decode() without its byte-stream state machine) gives what parse_buffer gives, for valid frames,
signed or not, and for every corruption of them: the same messages, the same bad data with the same
reasons, the same counters."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.mavlink.transport import parse_bytes, parse_stream
from swarmctl.signing import setup_signing

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))


class _Frames:
    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.frames.append(bytes(data))


def _frame(kind: int, value: int, key: bytes | None) -> bytes:
    out = _Frames()
    mav = mavlink2.MAVLink(out, srcSystem=1 + value % 250, srcComponent=1)
    if key is not None:
        setup_signing(mav, key)
    if kind == 0:
        msg = mav.heartbeat_encode(2, 3, value % 256, value % 7, 4)
    elif kind == 1:
        msg = mav.global_position_int_encode(value, value, -value, 40000, 30000, 0, 0, 0, value % 36000)
    elif kind == 2:
        msg = mav.tunnel_encode(0, 0, 32768 + value % 100, value % 129, [value % 256] * 128)
    else:
        msg = mav.statustext_encode(6, b"PreArm: %d" % value)
    mav.send(msg)
    return out.frames[0]


def _receiver(signed: bool) -> mavlink2.MAVLink:
    mav = mavlink2.MAVLink(_Frames(), srcSystem=255, srcComponent=190)
    mav.robust_parsing = True
    if signed:
        setup_signing(mav, KEY, accept_unsigned=(mavlink2.MAVLINK_MSG_ID_HEARTBEAT,))
    return mav


def _seen(msgs: list) -> list:
    out = []
    for m in msgs:
        if m.get_type() == "BAD_DATA":
            out.append(("BAD_DATA", bytes(m.data), m.reason))
        else:
            out.append((m.get_type(), m.get_srcSystem(), m.get_seq(), bytes(m.get_msgbuf()), str(m)))
    return out


def _counts(mav: mavlink2.MAVLink) -> tuple:
    s = mav.signing
    return (
        mav.total_bytes_received,
        mav.total_packets_received,
        mav.total_receive_errors,
        mav.buf_len(),
        s.goodsig_count,
        s.badsig_count,
        s.unsigned_count,
        s.reject_count,
    )


_datagram = st.builds(
    lambda kind, value, key: _frame(kind, value, key),
    st.integers(0, 3),
    st.integers(0, 10**6),
    st.sampled_from([None, KEY, OTHER_KEY]),
)


@st.composite
def _damaged(draw) -> bytes:
    data = bytearray(draw(_datagram))
    how = draw(st.sampled_from(["none", "flip", "truncate", "extend", "length", "flags", "two", "noise"]))
    if how == "flip":
        i = draw(st.integers(0, len(data) - 1))
        data[i] ^= 1 << draw(st.integers(0, 7))
    elif how == "truncate":
        data = data[: draw(st.integers(0, len(data) - 1))]
    elif how == "extend":
        data += draw(st.binary(min_size=1, max_size=20))
    elif how == "length":
        data[1] = draw(st.integers(0, 255))
    elif how == "flags":
        data[2] = draw(st.integers(0, 255))
    elif how == "two":
        data += draw(_datagram)
    elif how == "noise":
        data = bytearray(draw(st.binary(max_size=300)))
    return bytes(data)


@settings(max_examples=400, deadline=None)
@given(datagrams=st.lists(_damaged(), min_size=1, max_size=6), signed=st.booleans())
def test_the_fast_path_parses_every_datagram_as_parse_buffer_does(datagrams, signed):
    fast, reference = _receiver(signed), _receiver(signed)
    for data in datagrams:
        got, expected = parse_bytes(fast, data, True), parse_stream(reference, data, True)
        assert _seen(got) == _seen(expected)
        assert _counts(fast) == _counts(reference)


def test_a_whole_frame_takes_the_fast_path_and_a_stream_does_not():
    data = _frame(1, 1234, None)
    mav = _receiver(False)
    calls = []
    mav.parse_buffer = lambda b: calls.append(b) or []
    (msg,) = parse_bytes(mav, data, True)
    assert msg.get_type() == "GLOBAL_POSITION_INT" and msg.lat == 1234 and calls == []
    parse_bytes(mav, data, False)  # a byte stream (TCP, serial) may split frames: always the state machine
    assert calls == [data]
