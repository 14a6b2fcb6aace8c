"""Reading telemetry logs (.tlog) fast, and saying what could not be read.

A .tlog (MAVProxy, QGroundControl, ArduPilot SITL, swarmctl's recorder) is a sequence of records: an
8-byte big-endian timestamp (microseconds since 1970) and one raw MAVLink 1 or 2 frame. `index_tlog`
walks the records once, reading only the headers, and checks each frame's CRC with pymavlink's
x25crc and the dialect's CRC extra, so a frame is taken only when it is whole and its checksum holds.
Bytes that do not form a valid record (garbage, a frame cut short at the end of the file, a bad
checksum) are skipped: the walk looks for the next record that is whole, has a known message id, a
valid CRC and a plausible timestamp (a frame of a message id the dialect does not know is taken when
it is whole and another record follows it), and every skipped stretch is kept as a `Damage` (byte offset,
length, why). Messages are then decoded by pymavlink only for the message ids a caller asks for.

Only a regular file of at most TLOG_MAX_BYTES is read (a device such as /dev/zero, a pipe or a larger
file is refused with one line before a byte is read), and with one read bounded by that size.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from pymavlink.generator.mavcrc import x25crc

from swarmctl.bounds import GIB, read_limited, size_text
from swarmctl.errors import InputError

TLOG_MAX_BYTES = GIB  # 14 times the 74 MB tlog of a 50-vehicle, 200-step mission; as events.jsonl's cap

V1, V2 = 0xFE, 0xFD
STAMP = 8
SIGNATURE = 13
MIN_STAMP_US, MAX_STAMP_US = 10**15, 5 * 10**15  # 2001 .. 2128: anything else is not a tlog timestamp
_CRC_EXTRA = {msgid: cls.crc_extra for msgid, cls in mavlink2.mavlink_map.items()}
_DATAFLASH = b"\xa3\x95"


@dataclass(frozen=True)
class Damage:
    """A stretch of a file that was skipped."""

    offset: int  # byte offset of the first skipped byte
    length: int  # bytes skipped
    reason: str

    def __str__(self) -> str:
        return f"{self.length} bytes at byte {self.offset} ({self.reason})"


@dataclass
class TlogIndex:
    """The records of a .tlog: arrays with one entry per valid frame, in file order."""

    path: Path
    data: bytes
    start: np.ndarray  # byte offset of the frame (after its timestamp)
    length: np.ndarray  # frame length in bytes
    time: np.ndarray  # seconds since 1970 (float64)
    msgid: np.ndarray
    sysid: np.ndarray
    compid: np.ndarray
    damage: list[Damage] = field(default_factory=list)
    unchecked: int = 0  # frames of message ids the dialect does not know (whole, CRC not checkable)

    def __len__(self) -> int:
        return int(self.start.size)

    def frame(self, i: int) -> bytes:
        """The raw bytes of frame i."""
        s = int(self.start[i])
        return self.data[s : s + int(self.length[i])]

    def decode(self, which: np.ndarray | Iterable[int]) -> list[tuple[float, Any]]:
        """(time, pymavlink message) for the frames at the given indices; frames pymavlink refuses are
        left out (their CRC was already checked, so this does not happen with a dialect message)."""
        mav = mavlink2.MAVLink(None)
        out = []
        for i in np.asarray(list(which) if not isinstance(which, np.ndarray) else which, dtype=np.int64):
            try:
                msg = mav.decode(bytearray(self.frame(int(i))))
            except (mavlink2.MAVError, ValueError, TypeError):
                continue
            out.append((float(self.time[i]), msg))
        return out

    def select(self, msgids: Iterable[int]) -> np.ndarray:
        """Indices of the frames with these message ids."""
        return np.flatnonzero(np.isin(self.msgid, np.fromiter(msgids, dtype=np.int64)))


def _frame_size(data: bytes, at: int) -> int | None:
    """Size of the frame starting at `at` from its header, or None if the header is not a frame's."""
    if at + 3 > len(data):
        return None
    magic = data[at]
    if magic == V2:
        if data[at + 2] & ~0x01:  # an incompatibility flag MAVLink 2 does not define: not a frame we can read
            return None
        return 12 + data[at + 1] + (SIGNATURE if data[at + 2] & 0x01 else 0)
    if magic == V1:
        return 8 + data[at + 1]
    return None


def _check(data: bytes, at: int, size: int) -> tuple[int, bool] | None:
    """(message id, crc checked) for a whole frame at `at` whose CRC holds (or whose id is unknown)."""
    if data[at] == V2:
        msgid = data[at + 7] | data[at + 8] << 8 | data[at + 9] << 16
        payload_end = at + 10 + data[at + 1]
    else:
        msgid = data[at + 5]
        payload_end = at + 6 + data[at + 1]
    extra = _CRC_EXTRA.get(msgid)
    if extra is None:
        return msgid, False
    crc = x25crc(data[at + 1 : payload_end])
    crc.accumulate(bytes((extra,)))
    if crc.crc != data[payload_end] | data[payload_end + 1] << 8:
        return None
    return msgid, True


def _stamp(data: bytes, at: int) -> int:
    return int.from_bytes(data[at : at + STAMP], "big")


def _plausible(data: bytes, p: int) -> bool:
    """A record could start at p: a timestamp in range, then a frame header."""
    return p + STAMP + 3 <= len(data) and MIN_STAMP_US <= _stamp(data, p) < MAX_STAMP_US and data[p + STAMP] in (V1, V2)


def _record_at(data: bytes, p: int, strict: bool) -> tuple[int, int, bool] | None:
    """(size, msgid, crc checked) of a valid record at p. A frame whose message id the dialect does not
    know (so its CRC cannot be checked) is taken only in step (not `strict`) and when a record, or the
    end of the file, follows it."""
    if not _plausible(data, p):
        return None
    size = _frame_size(data, p + STAMP)
    if size is None or p + STAMP + size > len(data):
        return None
    checked = _check(data, p + STAMP, size)
    if checked is None:
        return None
    if not checked[1]:
        after = p + STAMP + size
        if strict or (after < len(data) and not _plausible(data, after)):
            return None
    return size, checked[0], checked[1]


def _resync(data: bytes, p: int) -> int:
    """The offset of the next valid record after a bad one at p (len(data) when there is none)."""
    n = len(data)
    q = p + 1
    while q < n - STAMP:
        nxt = [i for i in (data.find(b"\xfd", q + STAMP), data.find(b"\xfe", q + STAMP)) if i >= 0]
        if not nxt:
            return n
        q = min(nxt) - STAMP
        if _record_at(data, q, strict=True) is not None:
            return q
        q += 1
    return n


def _why(data: bytes, p: int, q: int) -> str:
    """What the skipped stretch [p, q) was."""
    if q == len(data):
        size = _frame_size(data, p + STAMP)
        if p + STAMP + 3 > len(data) or (size is not None and p + STAMP + size > len(data)):
            return "a record cut short at the end of the file"
    return "not a valid MAVLink record"


def read_tlog(path: Path) -> bytes:
    """The bytes of a .tlog: a regular file of at most TLOG_MAX_BYTES (InputError, one line, otherwise)."""
    try:
        info = os.stat(path)
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror}); give a .tlog file or a recording folder") from None
    if not stat.S_ISREG(info.st_mode):
        raise InputError(
            f"{path}: not a regular file (a device, a pipe or a socket); give a .tlog file or a recording folder"
        )
    if info.st_size > TLOG_MAX_BYTES:
        raise InputError(
            f"{path}: {size_text(info.st_size)}, over the {size_text(TLOG_MAX_BYTES)} a .tlog may have; "
            "replay a shorter log (split it by time)"
        )
    return read_limited(path, "telemetry log (.tlog)", TLOG_MAX_BYTES)


def index_tlog(path: str | Path, progress: Callable[[int], object] | None = None) -> TlogIndex:
    """Index every valid record of a .tlog; InputError (one line) for an empty file or one that holds no
    MAVLink telemetry at all. `progress(bytes_done)` is called now and then."""
    path = Path(path)
    data = read_tlog(path)
    if not data:
        raise InputError(f"{path}: the file is empty; a telemetry log holds timestamped MAVLink packets")
    n = len(data)
    starts: list[int] = []
    sizes: list[int] = []
    ids: list[int] = []
    damage: list[Damage] = []
    unchecked = 0
    p, strict, last_report = 0, True, 0
    while p < n:
        rec = _record_at(data, p, strict)
        if rec is None:
            q = _resync(data, p)
            damage.append(Damage(p, q - p, _why(data, p, q)))
            p, strict = q, True
            continue
        size, msgid, checked = rec
        starts.append(p + STAMP)
        sizes.append(size)
        ids.append(msgid)
        unchecked += not checked
        p += STAMP + size
        strict = False  # in step again: a frame of an unknown message id is taken when it is whole
        if progress is not None and p - last_report > 1 << 22:
            progress(p - last_report)
            last_report = p
    if progress is not None:
        progress(n - last_report)
    if not starts:
        hint = (
            " (it looks like an ArduPilot dataflash .bin log: replay the telemetry log, .tlog, instead)"
            if data.startswith(_DATAFLASH)
            else ""
        )
        raise InputError(
            f"{path}: no MAVLink telemetry found in {n} bytes{hint}; give a .tlog (MAVProxy, QGroundControl, "
            "swarmctl) or a recording folder"
        )
    start = np.asarray(starts, dtype=np.int64)
    buf = np.frombuffer(data, dtype=np.uint8)
    stamps = np.zeros(start.size, dtype=np.uint64)
    for k in range(STAMP):  # the big-endian timestamps, all at once
        stamps = (stamps << np.uint64(8)) | buf[start - STAMP + k].astype(np.uint64)
    v2 = buf[start] == V2
    return TlogIndex(
        path=path,
        data=data,
        start=start,
        length=np.asarray(sizes, dtype=np.int64),
        time=stamps.astype(np.float64) / 1e6,
        msgid=np.asarray(ids, dtype=np.int64),
        sysid=np.where(v2, buf[start + 5], buf[start + 3]).astype(np.int64),
        compid=np.where(v2, buf[start + 6], buf[start + 4]).astype(np.int64),
        damage=damage,
        unchecked=unchecked,
    )
