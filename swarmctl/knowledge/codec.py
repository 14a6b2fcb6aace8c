"""The swarm's knowledge on the wire: standard MAVLink 2 TUNNEL messages (id 385, 128-byte payload).

No custom dialect: every message is a TUNNEL with target_system 0 (broadcast), so stock autopilots,
radios and routers forward it. The message kind is TUNNEL.payload_type, one value per kind from the
private block 32800..32815 (>= 32768, the range MAVLink leaves for private use):

    32800  DELTA       cells newly explored (quantised phi, obstacle bit) + the sender's position
    32801  DIGEST      the sender's explored-cell bitmap, one chunk per message
    32802  REQUEST     "send me these cells": a bitmap chunk addressed to one vehicle
    32803  DETECTION   target cells found by the sender

Every payload starts with the same 17-byte header (little endian):

    0  u8   format version (FORMAT_VERSION = 1)
    1  u16  mission id (two swarms on one channel never mix knowledge)
    3  u8   sender vehicle id
    4  u32  step
    8  u8   grid width W     9  u8  grid height H   (must match the receiver's grid)
    10 u16  sequence number (per sender, all kinds, wraps)
    12 u8   chunk index      13 u8  chunk count     (index < count)
    14 u8   sender x         15 u8  sender y        (255, 255: position unknown)
    16 u8   flags: bit 0 on target, bit 1 repair (answer to a request or a push), bit 2 cell list
            (DIGEST / REQUEST only: the chunk is sent as a list, below); other bits 0

Bodies (byte offsets from 17; TUNNEL.payload_length = header + body exactly; bytes after it are 0):

    DELTA      u8 n (<= 36), then n x { u16 cell = x * H + y, bit 15 = obstacle ; u8 phi * 255 }
    DIGEST     bitmap of cells [i * 880, (i + 1) * 880) of the flat index x * H + y, bit k of the
               chunk in byte k // 8 at bit k % 8 (LSB first); padding bits 0; count = ceil(W H / 880)
    REQUEST    u8 target vehicle id, then a bitmap chunk laid out like DIGEST's
    (cell list) DIGEST and REQUEST chunks with few cells set are sent instead as u8 n, then n x u16
               offsets within the chunk, strictly increasing (the encoder picks the shorter form)
    DETECTION  u8 n (1..55), then n x { u8 x ; u8 y }

Limits: W, H <= 255 and W * H <= 32768 (15-bit cell index): 181 x 181, 128 x 255, ... 50 x 50 needs
3 digest chunks. Steps up to 2^32 - 1, vehicle ids 0..255, mission ids 0..65535. Delta chunks
stand alone (each is a complete delta); a delta of more than 255 chunks is numbered in groups of 255.

Decoding never raises on bad bytes: a payload that is truncated, oversized, of a foreign
payload_type, another version, another mission, another grid, with cells outside the grid, bad
chunk numbers, a body length that does not match its count, non-zero padding or reserved flag bits
is rejected, counted in `rejected` (a Counter by reason) and logged once per reason.
"""

from __future__ import annotations

import hashlib
import logging
import struct
import zlib
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.knowledge.model import Delta, Detection, Report
from swarmctl.signing import setup_signing

log = logging.getLogger("swarmctl.knowledge")

PAYLOAD_TYPE_BLOCK = range(32800, 32816)  # reserved for swarmctl; 32804..32815 unused
PT_DELTA, PT_DIGEST, PT_REQUEST, PT_DETECTION = 32800, 32801, 32802, 32803
KIND_NAMES = {PT_DELTA: "delta", PT_DIGEST: "digest", PT_REQUEST: "request", PT_DETECTION: "detection"}
FORMAT_VERSION = 1
PAYLOAD_SIZE = 128
HEADER = struct.Struct("<BHBIBBHBBBBB")
HEADER_SIZE = HEADER.size  # 17
NO_CELL = 255
FLAG_ON_TARGET, FLAG_REPAIR, FLAG_CELL_LIST = 0x01, 0x02, 0x04
MAX_DELTA_CELLS = (PAYLOAD_SIZE - HEADER_SIZE - 1) // 3  # 36
MAX_DETECTIONS = (PAYLOAD_SIZE - HEADER_SIZE - 1) // 2  # 55
BITMAP_BYTES = PAYLOAD_SIZE - HEADER_SIZE - 1  # 110 (REQUEST needs one byte for its target)
CELLS_PER_CHUNK = BITMAP_BYTES * 8  # 880
MAX_SIDE = 255
MAX_CELLS = 1 << 15
MAX_VEHICLE_ID = 255
MAX_CHUNKS = 255  # u8 chunk count
COMPONENT_ID = mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER  # 191
_CELL_DTYPE = np.dtype([("cell", "<u2"), ("phi", "u1")])
SIGNATURE_REFUSED = "Invalid signature"  # pymavlink's reason for a frame unsigned or wrongly signed


def mission_id_from_name(name: str) -> int:
    """A 16-bit mission id from a mission name (CRC-32 folded), for swarms that share a channel."""
    crc = zlib.crc32(name.encode("utf-8"))
    return (crc ^ (crc >> 16)) & 0xFFFF


def digest_chunk_count(width: int, height: int) -> int:
    return -(-width * height // CELLS_PER_CHUNK)


@dataclass(eq=False)
class BitmapChunk(Report):
    """One chunk of an explored-cell bitmap: a DIGEST (target None) or a REQUEST (target set).

    bits[k] is cell index * CELLS_PER_CHUNK + k (flat index x * H + y)."""

    index: int = 0
    count: int = 1
    bits: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    target: int | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        self.bits = np.asarray(self.bits, dtype=bool).reshape(-1)

    def __eq__(self, other: object) -> bool:
        return (
            self._same_report(other)
            and (self.index, self.count, self.target) == (other.index, other.count, other.target)
            and np.array_equal(self.bits, other.bits)
        )


Message = Delta | BitmapChunk | Detection


def bitmap_chunks(mask: np.ndarray) -> list[np.ndarray]:
    """The flat (x * H + y) bitmap of a (W, H) mask cut into CELLS_PER_CHUNK pieces."""
    flat = np.asarray(mask, dtype=bool).reshape(-1)
    return [flat[i : i + CELLS_PER_CHUNK] for i in range(0, flat.size, CELLS_PER_CHUNK)]


def chunk_mask(chunk: BitmapChunk, width: int, height: int) -> np.ndarray:
    """A (W, H) mask holding only the chunk's bits."""
    flat = np.zeros(width * height, dtype=bool)
    start = chunk.index * CELLS_PER_CHUNK
    flat[start : start + chunk.bits.size] = chunk.bits
    return flat.reshape(width, height)


class KnowledgeCodec:
    """Encode and decode the four knowledge payloads for one mission and grid.

    Payload level: `encode(message) -> [(payload_type, payload bytes)]`, `decode(payload_type, payload)`.
    Wire level (real MAVLink 2 TUNNEL frames, parsed by pymavlink and built as its pack builds them:
    `pack_tunnel`): `frame(...)`, `parse_datagram(bytes)`. Rejections are counted in `self.rejected`,
    accepted messages in `self.accepted` (by kind), other MAVLink traffic in `self.ignored`."""

    def __init__(
        self,
        mission_id: int,
        width: int,
        height: int,
        system_id: int = 1,
        component_id: int = COMPONENT_ID,
        signing_key: bytes | None = None,
    ):
        if not 0 <= mission_id <= 0xFFFF:
            raise ValueError(f"mission id {mission_id} must fit in 16 bits (0..65535)")
        if not (1 <= width <= MAX_SIDE and 1 <= height <= MAX_SIDE and width * height <= MAX_CELLS):
            raise ValueError(
                f"grid {width} x {height} is too large for the knowledge codec: "
                f"sides <= {MAX_SIDE} and at most {MAX_CELLS} cells"
            )
        self.mission_id, self.width, self.height = int(mission_id), int(width), int(height)
        self.chunks = digest_chunk_count(self.width, self.height)
        self.max_delta_chunks = min(MAX_CHUNKS, -(-self.width * self.height // MAX_DELTA_CELLS))
        self.rejected: Counter[str] = Counter()
        self.accepted: Counter[str] = Counter()
        self.ignored: Counter[str] = Counter()
        self._seq = 0
        self._tx = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._rx = mavlink2.MAVLink(None)
        self._rx.robust_parsing = True
        self.signed = signing_key is not None
        if signing_key is not None:  # frames signed; only frames signed with the key are read
            setup_signing(self._tx, signing_key)
            setup_signing(self._rx, signing_key)
        self.last_repair = False  # the repair flag of the last accepted payload

    # ----- encoding ---------------------------------------------------------------------------------
    def _header(
        self,
        sender: int,
        step: int,
        chunk: int,
        chunks: int,
        cell: tuple[int, int] | None,
        on_target: bool,
        repair: bool,
        cell_list: bool = False,
    ) -> bytes:
        if not 0 <= sender <= MAX_VEHICLE_ID:
            raise ValueError(f"vehicle id {sender} must be 0..{MAX_VEHICLE_ID}")
        if not 0 <= step <= 0xFFFFFFFF:
            raise ValueError(f"step {step} does not fit in 32 bits")
        x, y = (NO_CELL, NO_CELL) if cell is None else cell
        if cell is not None and not (0 <= x < self.width and 0 <= y < self.height):
            raise ValueError(f"position {cell} is outside the {self.width} x {self.height} grid")
        flags = (
            (FLAG_ON_TARGET if on_target else 0) | (FLAG_REPAIR if repair else 0) | (FLAG_CELL_LIST if cell_list else 0)
        )
        seq, self._seq = self._seq, (self._seq + 1) & 0xFFFF
        return HEADER.pack(
            FORMAT_VERSION, self.mission_id, sender, step, self.width, self.height, seq, chunk, chunks, x, y, flags
        )

    def encode(self, message: Message, repair: bool = False) -> list[tuple[int, bytes]]:
        """Payloads (payload_type, bytes <= 128) for one message; deltas and detections are chunked."""
        return [(ptype, payload) for ptype, payload, _part in self.encode_parts(message, repair)]

    def encode_parts(self, message: Message, repair: bool = False) -> list[tuple[int, bytes, Message]]:
        """(payload_type, payload, the message the payload decodes to) for one message: `encode` with,
        for each payload, what `decode` gives back (the delta's or detection's chunk, the bitmap chunk
        itself), so an in-process receiver need not decode what it was handed."""
        if isinstance(message, Delta):
            return self._encode_delta(message, repair)
        if isinstance(message, Detection):
            return self._encode_detection(message)
        if isinstance(message, BitmapChunk):
            return [(*self._encode_bitmap(message), message)]
        raise TypeError(f"cannot encode a {type(message).__name__}")

    def _encode_delta(self, delta: Delta, repair: bool) -> list[tuple[int, bytes, Message]]:
        repair = repair or delta.repair
        cells = delta.cells
        if cells.size and (
            (cells < 0).any() or (cells[:, 0] >= self.width).any() or (cells[:, 1] >= self.height).any()
        ):
            raise ValueError(f"delta cells outside the {self.width} x {self.height} grid")
        index = cells[:, 0] * self.height + cells[:, 1]
        if len(set(index.tolist())) != len(cells):
            raise ValueError("a delta lists each cell once")
        body = np.empty(len(cells), dtype=_CELL_DTYPE)
        body["cell"] = index | (delta.obstacle.astype(np.int64) << 15)
        body["phi"] = delta.phi
        raw = body.tobytes()
        parts = delta.split(MAX_DELTA_CELLS)
        if repair and not delta.repair:  # what decoding gives back: the repair flag set
            parts = [Delta(p.sender, p.step, p.cell, p.on_target, p.cells, p.phi, p.obstacle, True) for p in parts]
        out: list[tuple[int, bytes, Message]] = []
        for i, part in enumerate(parts):
            # chunks stand alone; past 255 of them the numbering starts a new group of up to 255
            group = i // MAX_CHUNKS * MAX_CHUNKS
            count = min(MAX_CHUNKS, len(parts) - group)
            head = self._header(delta.sender, delta.step, i - group, count, delta.cell, delta.on_target, repair)
            start = i * MAX_DELTA_CELLS * _CELL_DTYPE.itemsize
            chunk = raw[start : start + len(part) * _CELL_DTYPE.itemsize]
            out.append((PT_DELTA, head + bytes([len(part)]) + chunk, part))
        return out

    def _encode_detection(self, det: Detection) -> list[tuple[int, bytes, Message]]:
        t = det.targets
        if not len(t):
            raise ValueError("a detection needs at least one target cell")
        if (t < 0).any() or (t[:, 0] >= self.width).any() or (t[:, 1] >= self.height).any():
            raise ValueError(f"detection cells outside the {self.width} x {self.height} grid")
        pieces = [t[i : i + MAX_DETECTIONS] for i in range(0, len(t), MAX_DETECTIONS)]
        return [
            (
                PT_DETECTION,
                self._header(det.sender, det.step, i, len(pieces), det.cell, det.on_target, False)
                + bytes([len(p)])
                + p.astype(np.uint8).tobytes(),
                det if len(pieces) == 1 else Detection(det.sender, det.step, det.cell, det.on_target, p),
            )
            for i, p in enumerate(pieces)
        ]

    def _encode_bitmap(self, chunk: BitmapChunk) -> tuple[int, bytes]:
        expected = min(CELLS_PER_CHUNK, self.width * self.height - chunk.index * CELLS_PER_CHUNK)
        if chunk.count != self.chunks or not 0 <= chunk.index < chunk.count or chunk.bits.size != expected:
            raise ValueError(
                f"bitmap chunk {chunk.index}/{chunk.count} of {chunk.bits.size} bits does not fit "
                f"a {self.width} x {self.height} grid ({self.chunks} chunks)"
            )
        bits = np.packbits(chunk.bits, bitorder="little").tobytes()
        offsets = np.flatnonzero(chunk.bits)
        cell_list = 1 + 2 * offsets.size < len(bits)
        if cell_list:
            bits = bytes([offsets.size]) + offsets.astype("<u2").tobytes()
        head = self._header(
            chunk.sender, chunk.step, chunk.index, chunk.count, chunk.cell, chunk.on_target, False, cell_list
        )
        if chunk.target is None:
            return PT_DIGEST, head + bits
        return PT_REQUEST, head + bytes([chunk.target]) + bits

    def digest(
        self,
        sender: int,
        step: int,
        cell: tuple[int, int] | None,
        on_target: bool,
        explored: np.ndarray,
        target: int | None = None,
        only_nonempty: bool = False,
    ) -> list[BitmapChunk]:
        """The chunks of an explored-cell bitmap: a digest, or a request to `target`."""
        return [
            BitmapChunk(sender, step, cell, on_target, i, self.chunks, bits, target)
            for i, bits in enumerate(bitmap_chunks(explored))
            if not only_nonempty or bits.any()
        ]

    # ----- decoding ---------------------------------------------------------------------------------
    def _reject(self, reason: str, detail: str = "") -> None:
        if reason not in self.rejected:
            log.warning(
                "knowledge: rejected a TUNNEL payload (%s)%s; further ones are only counted",
                reason,
                f": {detail}" if detail else "",
            )
        self.rejected[reason] += 1

    def decode(
        self, payload_type: int, payload: bytes | bytearray | list[int], payload_length: int | None = None
    ) -> Message | None:
        """One TUNNEL payload to a message, or None (counted in `rejected`). Never raises on bad bytes.

        `payload_length` is TUNNEL.payload_length; None means len(payload)."""
        try:
            data = bytes(payload)
        except (TypeError, ValueError):
            self._reject("payload")
            return None
        if payload_type not in KIND_NAMES:
            self._reject("payload_type", str(payload_type))
            return None
        n = len(data) if payload_length is None else int(payload_length)
        if len(data) > PAYLOAD_SIZE or n > PAYLOAD_SIZE:
            self._reject("oversized", f"{max(n, len(data))} bytes")
            return None
        if n > len(data) or n < HEADER_SIZE:
            self._reject("truncated", f"{n} bytes")
            return None
        if any(data[n:]):
            self._reject("oversized", "non-zero bytes after payload_length")
            return None
        version, mission, sender, step, w, h, _seq, chunk, chunks, x, y, flags = HEADER.unpack_from(data)
        if version != FORMAT_VERSION:
            self._reject("version", str(version))
            return None
        if mission != self.mission_id:
            self._reject("mission", str(mission))
            return None
        if (w, h) != (self.width, self.height):
            self._reject("grid", f"{w} x {h}")
            return None
        if flags & ~(FLAG_ON_TARGET | FLAG_REPAIR | FLAG_CELL_LIST) or (
            flags & FLAG_CELL_LIST and payload_type not in (PT_DIGEST, PT_REQUEST)
        ):
            self._reject("flags", hex(flags))
            return None
        if (x, y) == (NO_CELL, NO_CELL):
            cell = None
        elif x < w and y < h:
            cell = (x, y)
        else:
            self._reject("cell", f"position ({x}, {y})")
            return None
        if chunks == 0 or chunk >= chunks:
            self._reject("chunks", f"{chunk}/{chunks}")
            return None
        on_target = bool(flags & FLAG_ON_TARGET)
        body = data[HEADER_SIZE:n]
        msg: Message | None
        if payload_type == PT_DELTA:
            msg = self._decode_delta(body, sender, step, cell, on_target, chunks, bool(flags & FLAG_REPAIR))
        elif payload_type == PT_DETECTION:
            msg = self._decode_detection(body, sender, step, cell, on_target)
        else:
            msg = self._decode_bitmap(
                payload_type, body, sender, step, cell, on_target, chunk, chunks, bool(flags & FLAG_CELL_LIST)
            )
        if msg is not None:
            self.accepted[KIND_NAMES[payload_type]] += 1
            self.last_repair = bool(flags & FLAG_REPAIR)
        return msg

    def _decode_delta(
        self,
        body: bytes,
        sender: int,
        step: int,
        cell: tuple[int, int] | None,
        on_target: bool,
        chunks: int,
        repair: bool,
    ) -> Delta | None:
        if chunks > self.max_delta_chunks:
            self._reject("chunks", f"{chunks} delta chunks for {self.width * self.height} cells")
            return None
        if not body or len(body) != 1 + 3 * body[0] or body[0] > MAX_DELTA_CELLS:
            self._reject("length", "delta body does not match its cell count")
            return None
        rec = np.frombuffer(body, dtype=_CELL_DTYPE, offset=1)
        idx = rec["cell"] & 0x7FFF
        if idx.size and int(idx.max()) >= self.width * self.height:
            self._reject("cell", "delta cell outside the grid")
            return None
        cells = np.empty((len(idx), 2), dtype=np.int64)
        np.divmod(idx, self.height, out=(cells[:, 0], cells[:, 1]))
        return Delta(sender, step, cell, on_target, cells, rec["phi"].copy(), rec["cell"] >= 0x8000, repair)

    def _decode_detection(
        self, body: bytes, sender: int, step: int, cell: tuple[int, int] | None, on_target: bool
    ) -> Detection | None:
        if not body or body[0] == 0 or body[0] > MAX_DETECTIONS or len(body) != 1 + 2 * body[0]:
            self._reject("length", "detection body does not match its count")
            return None
        t = np.frombuffer(body, dtype=np.uint8, offset=1).reshape(-1, 2).astype(np.int64)
        if (t[:, 0] >= self.width).any() or (t[:, 1] >= self.height).any():
            self._reject("cell", "detection outside the grid")
            return None
        return Detection(sender, step, cell, on_target, t)

    def _decode_bitmap(
        self,
        ptype: int,
        body: bytes,
        sender: int,
        step: int,
        cell: tuple[int, int] | None,
        on_target: bool,
        chunk: int,
        chunks: int,
        cell_list: bool,
    ) -> BitmapChunk | None:
        if chunks != self.chunks:
            self._reject("chunks", f"{chunks} bitmap chunks, the grid needs {self.chunks}")
            return None
        target = None
        if ptype == PT_REQUEST:
            if not body:
                self._reject("length", "request without a target")
                return None
            target, body = body[0], body[1:]
        nbits = min(CELLS_PER_CHUNK, self.width * self.height - chunk * CELLS_PER_CHUNK)
        if cell_list:
            if not body or len(body) != 1 + 2 * body[0]:
                self._reject("length", "cell list does not match its count")
                return None
            offsets = np.frombuffer(body, dtype="<u2", offset=1)
            if offsets.size and (int(offsets[-1]) >= nbits or (np.diff(offsets.astype(np.int64)) <= 0).any()):
                self._reject("cell", "cell list not increasing or outside the chunk")
                return None
            bits = np.zeros(nbits, dtype=bool)
            bits[offsets] = True
            return BitmapChunk(sender, step, cell, on_target, chunk, chunks, bits, target)
        if len(body) != -(-nbits // 8):
            self._reject("length", f"bitmap chunk of {len(body)} bytes, expected {-(-nbits // 8)}")
            return None
        bits = np.unpackbits(np.frombuffer(body, dtype=np.uint8), bitorder="little").astype(bool)
        if bits[nbits:].any():
            self._reject("padding", "bits beyond the grid are set")
            return None
        return BitmapChunk(sender, step, cell, on_target, chunk, chunks, bits[:nbits], target)

    # ----- MAVLink 2 frames -------------------------------------------------------------------------
    def frame(self, payload_type: int, payload: bytes) -> bytes:
        """A MAVLink 2 TUNNEL frame (broadcast: target_system 0, target_component 0): the bytes
        pymavlink's pack writes (pack_tunnel), with this codec's sequence numbers and signing."""
        buf = pack_tunnel(self._tx, payload_type, payload)
        self._tx.seq = (self._tx.seq + 1) % 256
        return buf

    def statustext(self, severity: int, text: str) -> bytes:
        """A MAVLink 2 STATUSTEXT frame (at most 50 ASCII characters: longer text is cut) from this
        codec's system and component ids, in its sequence and signed as its TUNNELs are (the mission's
        reports to a ground station: swarmctl.mission.finish)."""
        data = text.encode("ascii", "replace")[:50]
        buf: bytes = self._tx.statustext_encode(severity, data).pack(self._tx)
        self._tx.seq = (self._tx.seq + 1) % 256
        return buf

    def frames(self, message: Message, repair: bool = False) -> list[bytes]:
        return [self.frame(pt, p) for pt, p in self.encode(message, repair)]

    def parse_datagram(self, data: bytes) -> list[Message]:
        """Every knowledge message in one UDP datagram; anything else is counted, never raised."""
        return [message for message, _sysid, _size in self.parse_frames(data)]

    def parse_frames(self, data: bytes) -> list[tuple[Message, int, int]]:
        """(message, the frame's system id, the frame's size in bytes) for every knowledge message in one
        UDP datagram (`parse_datagram` without the frames' details). With a signing key only frames
        signed with it are read (the others are rejected as `signature`)."""
        out: list[tuple[Message, int, int]] = []
        try:
            msgs = self._rx.parse_buffer(bytes(data)) or []
        except Exception as exc:  # pymavlink can raise on malformed input even when robust
            msgs = []
            self._reject("mavlink", str(exc))
        if self._rx.buf_len():
            self._reject("mavlink", "frame cut short at the end of a datagram")
            self._rx.buf, self._rx.buf_index = bytearray(), 0
            self._rx.expected_length = mavlink2.HEADER_LEN_V1 + 2
        for m in msgs:
            if isinstance(m, mavlink2.MAVLink_bad_data):
                reason = str(getattr(m, "reason", "bad data"))
                self._reject("signature" if reason == SIGNATURE_REFUSED else "mavlink", reason)
                continue
            if isinstance(m, mavlink2.MAVLink_unknown):
                self.ignored["unknown"] += 1  # one key for every unknown id: the counter stays small
                continue
            if m.get_type() != "TUNNEL":
                self.ignored[m.get_type()] += 1  # the dialect's message names: a bounded set
                continue
            if m.payload_type not in PAYLOAD_TYPE_BLOCK:
                self.ignored["TUNNEL other payload_type"] += 1
                continue
            decoded = self.decode(m.payload_type, bytes(m.payload), m.payload_length)
            if decoded is not None:
                out.append((decoded, m.get_srcSystem(), len(m.get_msgbuf())))
        return out


_TUNNEL_FIELDS = struct.Struct("<HBBB")  # payload_type, target_system, target_component, payload_length
_V2_HEADER = struct.Struct("<BBBBBBBHB")
_SIGNATURE_HEAD = struct.Struct("<BQ")
_TUNNEL_ID = mavlink2.MAVLINK_MSG_ID_TUNNEL
_TUNNEL_CRC_EXTRA = bytes([mavlink2.MAVLink_tunnel_message.crc_extra])


def pack_tunnel(mav: mavlink2.MAVLink, payload_type: int, payload: bytes, target_system: int = 0) -> bytes:
    """The MAVLink 2 frame of TUNNEL(target_system, 0, payload_type, len(payload), payload padded to
    128 bytes) exactly as `MAVLink_tunnel_message(...).pack(mav)` builds it (trailing zeros of the
    message stripped, CRC with the message's crc_extra, signed when `mav` signs: its link id and
    timestamp, which it advances), without pymavlink's per-field Python. Does not advance `mav.seq`
    (pack does not either)."""
    n = len(payload)
    if n > PAYLOAD_SIZE:
        raise ValueError(f"a TUNNEL payload holds at most {PAYLOAD_SIZE} bytes, not {n}")
    body = (_TUNNEL_FIELDS.pack(payload_type, target_system, 0, n) + bytes(payload)).rstrip(b"\0") or b"\0"
    signing = mav.signing
    signed = bool(signing.sign_outgoing)
    head = _V2_HEADER.pack(
        253,
        len(body),
        mavlink2.MAVLINK_IFLAG_SIGNED if signed else 0,
        0,
        mav.seq,
        mav.srcSystem,
        mav.srcComponent,
        _TUNNEL_ID & 0xFFFF,
        _TUNNEL_ID >> 16,
    )
    crc = mavlink2.x25crc(head[1:] + body + _TUNNEL_CRC_EXTRA).crc
    buf = head + body + struct.pack("<H", crc)
    if signed:
        buf += _SIGNATURE_HEAD.pack(signing.link_id, signing.timestamp)[:7]
        buf += hashlib.sha256(signing.secret_key + buf).digest()[:6]
        signing.timestamp += 1
    return buf


def frame_sender_cell(frame_payload: bytes) -> tuple[int, int, tuple[int, int] | None] | None:
    """(mission id, sender, cell) read from a knowledge payload's header without full validation
    (used by the radio to learn positions); None when the payload is too short or another version."""
    if len(frame_payload) < HEADER_SIZE or frame_payload[0] != FORMAT_VERSION:
        return None
    _v, mission, sender, _step, _w, _h, _s, _c, _n, x, y, _f = HEADER.unpack_from(frame_payload)
    return mission, sender, None if (x, y) == (NO_CELL, NO_CELL) else (x, y)
