"""The knowledge codec: decode(encode(x)) == x for every kind, chunking on a 50 x 50 grid, every
rejection reason, and real MAVLink 2 TUNNEL frames."""

import logging
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.knowledge.codec import (
    CELLS_PER_CHUNK,
    HEADER,
    MAX_DELTA_CELLS,
    MAX_DETECTIONS,
    PAYLOAD_TYPE_BLOCK,
    PT_DELTA,
    PT_DETECTION,
    PT_DIGEST,
    PT_REQUEST,
    KnowledgeCodec,
    chunk_mask,
    digest_chunk_count,
    mission_id_from_name,
)
from swarmctl.knowledge.model import Delta, Detection, Knowledge

grids = st.tuples(st.integers(1, 80), st.integers(1, 80))
headers = st.fixed_dictionaries(
    {"sender": st.integers(0, 255), "step": st.integers(0, 2**32 - 1), "on_target": st.booleans()}
)


def _cell(draw, w, h):
    return draw(st.one_of(st.none(), st.tuples(st.integers(0, w - 1), st.integers(0, h - 1))))


def roundtrip(codec, message, repair=False):
    """encode then decode; encode_parts names, beside each payload, exactly what it decodes to (the
    in-process bus merges that without decoding)."""
    seq = codec._seq
    parts = codec.encode_parts(message, repair)
    codec._seq = seq
    payloads = codec.encode(message, repair)
    assert payloads == [(pt, p) for pt, p, _ in parts]
    assert all(len(p) <= 128 and pt in PAYLOAD_TYPE_BLOCK for pt, p in payloads)
    decoded = [codec.decode(pt, p) for pt, p in payloads]
    assert None not in decoded, codec.rejected
    assert decoded == [part for _, _, part in parts]
    return payloads, decoded


def _rng(data):
    return np.random.default_rng(data.draw(st.integers(0, 2**32 - 1), label="numpy seed"))


@settings(max_examples=80)
@given(grids, headers, st.data())
def test_delta_round_trip_with_chunks(grid, head, data):
    w, h = grid
    rng = _rng(data)
    n = data.draw(st.integers(0, min(100, w * h)))
    flat = rng.choice(w * h, size=n, replace=False)
    delta = Delta(
        head["sender"],
        head["step"],
        _cell(data.draw, w, h),
        head["on_target"],
        np.stack([flat // h, flat % h], axis=1),
        rng.integers(0, 256, n).astype(np.uint8),
        rng.random(n) < 0.3,
    )
    codec = KnowledgeCodec(data.draw(st.integers(0, 65535)), w, h)
    payloads, decoded = roundtrip(codec, delta)
    assert len(payloads) == max(1, -(-n // MAX_DELTA_CELLS))
    assert Delta.concat(decoded) == delta
    assert all(d.sender == delta.sender and d.cell == delta.cell for d in decoded)  # every chunk stands alone


@settings(max_examples=80)
@given(grids, headers, st.data())
def test_digest_and_request_round_trip(grid, head, data):
    w, h = grid
    mask = _rng(data).random((w, h)) < data.draw(st.sampled_from([0.0, 0.1, 0.5, 1.0]))
    target = data.draw(st.one_of(st.none(), st.integers(0, 255)))
    codec = KnowledgeCodec(3, w, h)
    chunks = codec.digest(head["sender"], head["step"], _cell(data.draw, w, h), head["on_target"], mask, target)
    assert len(chunks) == digest_chunk_count(w, h)
    rebuilt = np.zeros((w, h), bool)
    for chunk in chunks:
        payloads, decoded = roundtrip(codec, chunk)
        assert len(payloads) == 1 and payloads[0][0] == (PT_DIGEST if target is None else PT_REQUEST)
        assert decoded[0] == chunk
        rebuilt |= chunk_mask(decoded[0], w, h)
    assert np.array_equal(rebuilt, mask)


@settings(max_examples=80)
@given(grids, headers, st.data())
def test_detection_round_trip(grid, head, data):
    w, h = grid
    rng = _rng(data)
    n = data.draw(st.integers(1, 130))
    t = np.stack([rng.integers(0, w, n), rng.integers(0, h, n)], axis=1)
    det = Detection(head["sender"], head["step"], _cell(data.draw, w, h), head["on_target"], t)
    codec = KnowledgeCodec(9, w, h)
    payloads, decoded = roundtrip(codec, det)
    assert len(payloads) == -(-n // MAX_DETECTIONS)
    assert all(p[0] == PT_DETECTION for p in payloads)
    assert np.array_equal(np.concatenate([d.targets for d in decoded]), t)


def test_chunking_a_whole_50_x_50_map():
    k = Knowledge(50, 50, vehicle_id=4)
    k.set_position(12, (49, 0))
    rng = np.random.default_rng(1)
    xs, ys = np.meshgrid(np.arange(50), np.arange(50), indexing="ij")
    k.sense(np.stack([xs.ravel(), ys.ravel()], 1), rng.random(2500), rng.random(2500) < 0.12)
    codec = KnowledgeCodec(1, 50, 50)
    delta = k.take_delta()
    payloads = codec.encode(delta)
    assert len(delta) == 2500 and len(payloads) == 70  # ceil(2500 / 36)
    heads = [HEADER.unpack_from(p) for _, p in payloads]
    assert [h[7] for h in heads] == list(range(70)) and {h[8] for h in heads} == {70}
    assert {len(p) for _, p in payloads[:-1]} == {17 + 1 + 36 * 3} and len(payloads[-1][1]) == 17 + 1 + 16 * 3
    other = Knowledge(50, 50, vehicle_id=0)
    for pt, p in reversed(payloads):  # chunks merge independently, in any order
        other.merge(codec.decode(pt, p))
    assert other.same_map(k) and other.positions == k.positions

    digest = codec.digest(4, 12, (49, 0), False, k.explored)
    assert [c.bits.size for c in digest] == [880, 880, 740] and CELLS_PER_CHUNK == 880
    sizes = [len(codec.encode(c)[0][1]) for c in digest]
    assert sizes == [17 + 110, 17 + 110, 17 + 93]


def test_the_largest_grid_carries_a_whole_map_in_one_delta():
    k = Knowledge(181, 181, vehicle_id=1)
    k.set_position(1, (180, 180))
    xs, ys = np.meshgrid(np.arange(181), np.arange(181), indexing="ij")
    k.sense(np.stack([xs.ravel(), ys.ravel()], 1), np.full(181 * 181, 0.5), np.zeros(181 * 181, bool))
    codec = KnowledgeCodec(1, 181, 181)
    payloads = codec.encode(k.take_delta())
    assert len(payloads) == 911  # ceil(32761 / 36): numbered 255, 255, 255, 146
    assert [HEADER.unpack_from(p)[8] for _, p in payloads[::255]] == [255, 255, 255, 146]
    other = Knowledge(181, 181)
    for pt, p in payloads:
        other.merge(codec.decode(pt, p))
    assert other.same_map(k) and codec.rejected == {}
    assert len(codec.digest(1, 1, None, False, k.explored)) == 38


def test_the_grid_limit_is_stated_and_enforced():
    KnowledgeCodec(0, 181, 181)
    KnowledgeCodec(0, 128, 256 - 1)
    with pytest.raises(ValueError, match="too large"):
        KnowledgeCodec(0, 182, 182)
    with pytest.raises(ValueError, match="too large"):
        KnowledgeCodec(0, 256, 10)
    with pytest.raises(ValueError, match="outside"):
        KnowledgeCodec(0, 5, 5).encode(Delta(0, 0, None, cells=[(5, 0)], phi=[0], obstacle=[False]))
    with pytest.raises(ValueError, match="once"):
        KnowledgeCodec(0, 5, 5).encode(Delta(0, 0, None, cells=[(1, 0), (1, 0)], phi=[0, 0], obstacle=[0, 0]))


def test_mission_ids_from_names_are_16_bit_and_stable():
    assert mission_id_from_name("chicago-loop") == mission_id_from_name("chicago-loop")
    assert mission_id_from_name("chicago-loop") != mission_id_from_name("chicago-loop-2")
    assert 0 <= mission_id_from_name("x" * 100) <= 0xFFFF


# ----- rejections ------------------------------------------------------------------------------------


def _valid(codec):
    return codec.encode(Delta(2, 7, (1, 1), False, [(0, 0), (3, 4)], [10, 20], [False, True]))[0]


def _patch(payload, offset, fmt, value):
    b = bytearray(payload)
    struct.pack_into(fmt, b, offset, value)
    return bytes(b)


def _bad_payloads(codec):
    pt, good = _valid(codec)
    digest_pt, digest = codec.encode(codec.digest(2, 7, (1, 1), False, np.ones((10, 10), bool))[0])[0]
    few = np.zeros((10, 10), bool)
    few[0, 1] = few[2, 3] = few[5, 5] = True  # offsets 1, 23, 55
    list_pt, sparse = codec.encode(codec.digest(2, 7, (1, 1), False, few)[0])[0]
    assert sparse[16] & 0x04 and len(sparse) == 17 + 1 + 2 * 3  # the cell-list form
    return {
        "payload_type": [(40, good), (PT_DELTA + 15, good)],
        "truncated": [(pt, good[:10]), (pt, b"")],
        "oversized": [(pt, good + bytes(200)), (pt, good + bytes(129 - len(good)))],
        "version": [(pt, _patch(good, 0, "<B", 2))],
        "mission": [(pt, _patch(good, 1, "<H", 8))],
        "grid": [(pt, _patch(good, 8, "<B", 11))],
        "chunks": [
            (pt, _patch(good, 12, "<B", 1)),
            (pt, _patch(good, 13, "<B", 0)),
            (pt, _patch(good, 13, "<B", 200)),
            (digest_pt, _patch(digest, 13, "<B", 2)),
        ],
        "cell": [
            (pt, _patch(good, 14, "<B", 10)),
            (pt, _patch(good, 18, "<H", 100)),
            (list_pt, _patch(sparse, 18, "<H", 30)),
            (list_pt, _patch(sparse, 22, "<H", 100)),
        ],
        "flags": [(pt, _patch(good, 16, "<B", 0x80)), (pt, _patch(good, 16, "<B", 0x04))],
        "length": [
            (pt, _patch(good, 17, "<B", 3)),
            (pt, good[:-1]),
            (pt, good + b"\x01"),
            (PT_DETECTION, good),
            (PT_REQUEST, digest[:17]),
            (digest_pt, digest[:-1]),
            (list_pt, sparse[:-2]),
            (list_pt, _patch(sparse, 17, "<B", 4)),
        ],
        "padding": [(digest_pt, digest[:-1] + b"\xff")],
    }


def test_every_kind_of_bad_payload_is_rejected_counted_and_logged_once(caplog):
    codec = KnowledgeCodec(7, 10, 10)
    bad = _bad_payloads(codec)
    with caplog.at_level(logging.WARNING, logger="swarmctl.knowledge"):
        for reason, cases in bad.items():
            for pt, payload in cases:
                assert codec.decode(pt, payload) is None, reason
                assert codec.decode(pt, payload) is None
    assert dict(codec.rejected) == {reason: 2 * len(cases) for reason, cases in bad.items()}
    logged = [r.getMessage() for r in caplog.records]
    assert len(logged) == len(bad)  # once per reason
    assert all(any(f"({reason})" in m for m in logged) for reason in bad)
    assert sum(codec.accepted.values()) == 0


def test_payload_length_field_is_checked_against_the_bytes():
    codec = KnowledgeCodec(7, 10, 10)
    pt, good = _valid(codec)
    padded = good + bytes(128 - len(good))
    assert codec.decode(pt, padded, payload_length=len(good)) is not None
    assert codec.decode(pt, padded, payload_length=len(good) - 1) is None
    assert codec.decode(pt, padded, payload_length=200) is None
    assert codec.rejected == {"oversized": 2}  # a byte after payload_length, a length over 128


# ----- MAVLink 2 frames ------------------------------------------------------------------------------


def test_frames_are_real_mavlink2_tunnel_broadcasts():
    codec = KnowledgeCodec(7, 10, 10, system_id=3)
    delta = Delta(2, 7, (1, 1), True, [(0, 0), (3, 4)], [10, 255], [False, True])
    frame = codec.frames(delta)[0]
    assert frame[0] == 0xFD  # MAVLink 2 start byte
    msg = mavlink2.MAVLink(None).parse_buffer(frame)[0]
    assert msg.get_type() == "TUNNEL" and msg.id == 385
    assert (msg.target_system, msg.target_component, msg.payload_type) == (0, 0, PT_DELTA)
    assert msg.get_srcSystem() == 3 and msg.get_srcComponent() == 191
    assert codec.parse_datagram(frame) == [delta]


def test_corrupted_cut_and_foreign_frames_are_counted_not_raised():
    codec = KnowledgeCodec(7, 10, 10)
    frame = codec.frames(Delta(2, 7, (1, 1), False, [(0, 0)], [10], [False]))[0]
    flipped = bytearray(frame)
    flipped[20] ^= 0x40
    assert codec.parse_datagram(bytes(flipped)) == []
    assert codec.parse_datagram(frame[:-5]) == []
    assert codec.parse_datagram(b"\x00garbage\xfd\x01") == []
    assert codec.rejected["mavlink"] >= 3
    other = mavlink2.MAVLink(None, 1, 1)
    hb = other.heartbeat_encode(2, 3, 0, 0, 0).pack(other)
    foreign = mavlink2.MAVLink_tunnel_message(0, 0, 201, 3, [1, 2, 3] + [0] * 125).pack(other)
    assert codec.parse_datagram(hb + foreign + frame) == [Delta(2, 7, (1, 1), False, [(0, 0)], [10], [False])]
    assert codec.ignored["HEARTBEAT"] == 1 and codec.ignored["TUNNEL other payload_type"] == 1
