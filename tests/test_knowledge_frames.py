"""The knowledge codec's TUNNEL frames are byte for byte what pymavlink packs: header, trailing-zero
truncation, CRC with crc_extra, sequence numbers and MAVLink 2 signatures (link id, timestamps)."""

from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.knowledge.codec import PAYLOAD_SIZE, PAYLOAD_TYPE_BLOCK, KnowledgeCodec, pack_tunnel
from swarmctl.signing import setup_signing

payloads = st.one_of(
    st.binary(min_size=0, max_size=PAYLOAD_SIZE),
    # payloads ending in zeros (the frame drops the message's trailing zeros) and all-zero ones
    st.tuples(st.binary(max_size=40), st.integers(0, 88)).map(lambda t: t[0] + bytes(t[1])),
)
keys = st.one_of(st.none(), st.binary(min_size=32, max_size=32))


def _pymavlink_frame(mav, payload_type, payload, target_system=0):
    padded = list(payload) + [0] * (PAYLOAD_SIZE - len(payload))
    msg = mavlink2.MAVLink_tunnel_message(target_system, 0, payload_type, len(payload), padded)
    return bytes(msg.pack(mav))


def _mav(sysid, compid, seq, key, link_id, timestamp):
    mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.seq = seq
    if key is not None:
        setup_signing(mav, key, link_id=link_id)
        mav.signing.timestamp = timestamp
    return mav


@settings(max_examples=300)
@given(
    st.sampled_from([*PAYLOAD_TYPE_BLOCK, 0, 65535]),
    payloads,
    st.integers(0, 255),
    st.integers(0, 255),
    st.integers(0, 255),
    keys,
    st.integers(0, 255),
    st.integers(0, 2**48 - 10),
    st.integers(0, 255),
)
def test_pack_tunnel_is_pymavlinks_pack(ptype, payload, sysid, compid, seq, key, link_id, timestamp, target):
    ours = _mav(sysid, compid, seq, key, link_id, timestamp)
    theirs = _mav(sysid, compid, seq, key, link_id, timestamp)
    for _ in range(2):  # the signing timestamp advances the same way
        assert pack_tunnel(ours, ptype, payload, target) == _pymavlink_frame(theirs, ptype, payload, target)
    assert ours.signing.timestamp == theirs.signing.timestamp and ours.seq == theirs.seq


@settings(max_examples=50)
@given(st.lists(payloads, min_size=1, max_size=300), keys, st.integers(1, 255))
def test_codec_frames_match_pymavlink_with_sequence_numbers_and_parse_back(bodies, key, sysid):
    """A codec's frames over a long run (its sequence number wraps at 256) are pymavlink's, and
    pymavlink parses them back (signature verified) into the same TUNNEL fields."""
    codec = KnowledgeCodec(7, 50, 50, system_id=sysid, signing_key=key)
    reference = _mav(sysid, codec._tx.srcComponent, 0, key, 0, codec._tx.signing.timestamp)
    rx = mavlink2.MAVLink(None)
    if key is not None:
        setup_signing(rx, key)
    for i, body in enumerate(bodies):
        frame = codec.frame(32800, body)
        assert frame == _pymavlink_frame(reference, 32800, body)
        reference.seq = (reference.seq + 1) % 256
        msg = rx.parse_char(frame)
        assert msg is not None and msg.get_type() == "TUNNEL", i
        fields = (msg.get_seq(), msg.get_srcSystem(), msg.payload_type, msg.payload_length)
        assert fields == (i % 256, sysid, 32800, len(body))
        assert bytes(msg.payload) == body + bytes(PAYLOAD_SIZE - len(body))
