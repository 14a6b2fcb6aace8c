"""Fuzz the knowledge decoder: 100,000 random and mutated payloads, then mutated MAVLink frames.
Nothing may raise; every payload is either rejected (counted) or a valid message for the grid."""

import numpy as np

from swarmctl.knowledge.codec import PAYLOAD_TYPE_BLOCK, BitmapChunk, KnowledgeCodec, chunk_mask
from swarmctl.knowledge.model import Delta, Detection, Knowledge

N_PAYLOADS = 100_000
W, H = 50, 50


def _seed_payloads(codec: KnowledgeCodec, rng: np.random.Generator) -> list[tuple[int, bytes]]:
    """Valid payloads of every kind to mutate."""
    k = Knowledge(W, H, vehicle_id=3)
    k.set_position(9, (20, 30), True)
    flat = rng.choice(W * H, 400, replace=False)
    k.sense(np.stack([flat // H, flat % H], 1), rng.random(400), rng.random(400) < 0.2)
    out = codec.encode(k.take_delta())
    out += codec.encode(Delta(3, 9, (1, 2), False, [(0, 0)], [255], [True]))
    for chunk in codec.digest(3, 9, (20, 30), True, k.explored):
        out += codec.encode(chunk)
    for chunk in codec.digest(3, 9, None, False, k.explored, target=1):
        out += codec.encode(chunk)
    sparse = np.zeros((W, H), bool)
    sparse.flat[rng.choice(W * H, 30, replace=False)] = True
    for target in (None, 2):  # digests and requests in the cell-list form
        for chunk in codec.digest(3, 9, (20, 30), False, sparse, target=target):
            out += codec.encode(chunk)
    out += codec.encode(Detection(3, 9, (20, 30), True, [(4, 5), (49, 49)]))
    return out


def _check_valid(msg, merged: Knowledge) -> None:
    if isinstance(msg, (Delta, Detection)):
        merged.merge(msg)  # raises on a cell outside the grid
    else:
        assert isinstance(msg, BitmapChunk)
        chunk_mask(msg, W, H)
    if msg.cell is not None:
        assert 0 <= msg.cell[0] < W and 0 <= msg.cell[1] < H


def test_decoder_survives_100000_random_and_mutated_payloads():
    rng = np.random.default_rng(2024)
    codec = KnowledgeCodec(77, W, H)
    seeds = _seed_payloads(codec, rng)
    types = np.array([*PAYLOAD_TYPE_BLOCK[:4], 0, 200, 32768, 32804, 65535])

    # all random draws at once, then one tight loop
    kind = rng.integers(0, 4, N_PAYLOADS)  # 0 random bytes, 1 byte flips, 2 cut / extended, 3 header fields
    noise = rng.integers(0, 256, (N_PAYLOADS, 136), dtype=np.uint8)
    lengths = rng.integers(0, 137, N_PAYLOADS)
    which = rng.integers(0, len(seeds), N_PAYLOADS)
    flip_pos = rng.integers(0, 128, (N_PAYLOADS, 3))
    flip_count = rng.integers(1, 4, N_PAYLOADS)
    random_type = types[rng.integers(0, len(types), N_PAYLOADS)]
    header_pos = rng.integers(0, 18, N_PAYLOADS)

    merged = Knowledge(W, H)
    accepted = 0
    for i in range(N_PAYLOADS):
        k = kind[i]
        if k == 0:
            pt, payload = int(random_type[i]), noise[i, : lengths[i]].tobytes()
        else:
            pt, good = seeds[which[i]]
            b = bytearray(good)
            if k == 1:
                for j in range(flip_count[i]):
                    b[flip_pos[i, j] % len(b)] = noise[i, j]
            elif k == 2:
                b = b[: lengths[i]] if lengths[i] < len(b) else b + noise[i, : lengths[i] - len(b)].tobytes()
            else:
                b[header_pos[i] % len(b)] = noise[i, 0]
            payload = bytes(b)
        before = sum(codec.rejected.values())
        msg = codec.decode(pt, payload)
        if msg is None:
            assert sum(codec.rejected.values()) == before + 1
        else:
            accepted += 1
            _check_valid(msg, merged)
    assert sum(codec.rejected.values()) + accepted == N_PAYLOADS
    assert sum(codec.accepted.values()) == accepted
    # the mutations reach past the header checks: both outcomes happen, for several reasons
    assert accepted > 5_000 and len(codec.rejected) >= 8, (accepted, codec.rejected)


def test_mutated_mavlink_frames_never_raise():
    rng = np.random.default_rng(7)
    codec = KnowledgeCodec(77, W, H)
    frames = [codec.frame(pt, p) for pt, p in _seed_payloads(codec, rng)]
    merged = Knowledge(W, H)
    for i in range(5_000):
        b = bytearray(frames[i % len(frames)])
        for _ in range(int(rng.integers(0, 4))):
            b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
        if rng.random() < 0.3:
            b = b[: int(rng.integers(0, len(b) + 1))]
        if rng.random() < 0.2:
            b += rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8).tobytes()
        for msg in codec.parse_datagram(bytes(b)):
            _check_valid(msg, merged)
    assert codec.rejected["mavlink"] > 1_000
