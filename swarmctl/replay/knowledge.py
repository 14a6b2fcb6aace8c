"""Each vehicle's knowledge over a replay: from the recorder's snapshots, or rebuilt from TUNNEL frames.

Knowledge only grows (explored cells and known targets are never forgotten), so it is kept as, per
vehicle and cell, the first frame at which the vehicle knew the cell (`NEVER` if it never did):
knowledge at frame f is `first <= f`.

Sources:
- knowledge.jsonl snapshots (swarmctl.mission.recorder.Recorder.knowledge): exact, one per vehicle
  and step when its knowledge changed;
- the swarmctl TUNNEL payloads in mission.tlog (swarmctl.knowledge.codec, types 32800-32803): what
  each vehicle sent by each frame, i.e. the cells of its DELTAs (the cells it explored itself, and
  its detector's reports) and of its DIGESTs (every cell it knew, received ones too), and the targets
  of its DETECTIONs. A frame appears once when sent and again for each agent that received it; the
  copies are byte-identical and counted once.
The value phi and the obstacle flag of each cell are the same for every vehicle (fixed truth); they
come from the DELTAs when the log has them.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.knowledge.codec import (
    HEADER,
    HEADER_SIZE,
    PAYLOAD_TYPE_BLOCK,
    BitmapChunk,
    KnowledgeCodec,
    chunk_mask,
)
from swarmctl.knowledge.model import Delta, Detection
from swarmctl.mission.inputs import InputsError, inflate
from swarmctl.replay.tlog import TlogIndex

NEVER = np.iinfo(np.int32).max


@dataclass
class KnowledgeTimeline:
    """first[v, x, y]: the first frame vehicle v knew cell (x, y); targets: cell -> (first frame, vehicle name)."""

    first: np.ndarray  # (V, W, H) int32
    source: str  # "snapshots", "tunnel" or "snapshots and tunnel"
    targets: dict[tuple[int, int], tuple[int, str]] = field(default_factory=dict)
    phi: np.ndarray | None = None  # (W, H) float32 phi of the cells reported, NaN where never reported
    obstacle: np.ndarray | None = None  # (W, H) bool obstacle flags reported

    def explored(self, frame: int, vehicles: list[int] | None = None) -> np.ndarray:
        """(W, H) bool: cells known at `frame` by any of the vehicles (all when None)."""
        rows = self.first if vehicles is None else self.first[vehicles]
        return np.asarray((rows <= frame).any(axis=0)) if len(rows) else np.zeros(self.first.shape[1:], dtype=bool)

    def counts(self, frames: int, vehicles: list[int] | None = None) -> np.ndarray:
        """(frames,) int: cells known by the vehicles together at each frame."""
        rows = self.first if vehicles is None else self.first[vehicles]
        if not len(rows):
            return np.zeros(frames, dtype=np.int64)
        union = rows.min(axis=0).ravel()
        hist = np.bincount(np.clip(union[union < NEVER], 0, frames - 1), minlength=frames)
        return np.cumsum(hist)[:frames]


def empty_first(vehicles: int, width: int, height: int) -> np.ndarray:
    return np.full((vehicles, width, height), NEVER, dtype=np.int32)


def from_snapshots(
    lines: list[dict], names: list[str], width: int, height: int, frame_of_step: dict[int, int]
) -> tuple[np.ndarray, dict, list[str]]:
    """(first, targets, problems) from knowledge.jsonl lines; a snapshot that does not decode to a
    W x H mask with its stated cell count (or would decompress to more) is skipped and named in problems."""
    first = empty_first(len(names), width, height)
    targets: dict[tuple[int, int], tuple[int, str]] = {}
    problems: list[str] = []
    index = {n: i for i, n in enumerate(names)}
    cells = width * height
    mask_bytes = (cells + 7) // 8  # numpy.packbits of the W x H mask
    for e in lines:
        v = index.get(e["vehicle"])
        if v is None:
            continue
        frame = frame_of_step.get(int(e["step"]))
        if frame is None:
            continue
        try:  # never more than the mask's bytes decompressed: a zlib bomb is refused, not inflated
            bits = np.unpackbits(np.frombuffer(inflate(e["explored"], mask_bytes, "explored"), np.uint8))
        except InputsError as exc:
            problems.append(f"step {e['step']} {e['vehicle']}: {exc}")
            continue
        if bits.size < cells or bits[cells:].any() or int(bits[:cells].sum()) != e["cells"]:
            problems.append(
                f"step {e['step']} {e['vehicle']}: explored is not a {width} x {height} mask of {e['cells']} cells"
            )
            continue
        mask = bits[:cells].reshape(width, height).astype(bool)
        np.minimum(first[v], np.where(mask, frame, NEVER).astype(np.int32), out=first[v])
        for x, y in e["targets"]:
            if x < width and y < height:
                old = targets.get((x, y))
                if old is None or frame < old[0]:
                    targets[(x, y)] = (frame, names[v])
    return first, targets, problems


@dataclass
class TunnelKnowledge:
    """What the TUNNEL frames of a log say: per sender, first frames; targets; phi; the header's grid."""

    mission_id: int
    width: int
    height: int
    senders: dict[int, int]  # knowledge sender id (vehicle index) -> MAVLink system id that sent it
    first: dict[int, np.ndarray]  # sender -> (W, H) int32 first frame
    targets: dict[tuple[int, int], tuple[int, int]]  # cell -> (first frame, sender)
    phi: np.ndarray
    obstacle: np.ndarray
    positions: list[tuple[float, int, int, int]]  # (time, sysid, x, y): where senders said they were
    rejected: Counter


def from_tunnel(index: TlogIndex, frame_times: np.ndarray | None) -> TunnelKnowledge | None:
    """Rebuild knowledge from the swarmctl TUNNEL frames of a log (None when it has none). A frame's
    time maps to the first replay frame at or after it (`frame_times`); without frame times the
    header's step is the frame."""
    pick = index.select([mavlink2.MAVLINK_MSG_ID_TUNNEL])
    if not pick.size:
        return None
    seen: set[bytes] = set()
    unique = []
    for i in pick:
        raw = index.frame(int(i))
        if raw not in seen:
            seen.add(raw)
            unique.append(int(i))
    msgs = [(t, m) for t, m in index.decode(unique) if m.payload_type in PAYLOAD_TYPE_BLOCK]
    if not msgs:
        return None
    grids: Counter[tuple[int, int, int]] = Counter()
    for _t, m in msgs:
        if m.payload_length >= HEADER_SIZE:
            head = HEADER.unpack_from(bytes(m.payload))
            grids[(head[1], head[4], head[5])] += 1
    if not grids:
        return None
    (mission, w, h), _ = grids.most_common(1)[0]
    codec = KnowledgeCodec(mission, w, h)
    out = TunnelKnowledge(
        mission, w, h, {}, {}, {}, np.full((w, h), np.nan, np.float32), np.zeros((w, h), bool), [], codec.rejected
    )
    sysids: dict[int, Counter] = {}
    for t, m in msgs:
        msg = codec.decode(m.payload_type, bytes(m.payload), m.payload_length)
        if msg is None:
            continue
        sysids.setdefault(msg.sender, Counter())[m.get_srcSystem()] += 1
        if frame_times is None:
            frame = int(msg.step)
        else:
            frame = min(int(np.searchsorted(frame_times, t, side="left")), len(frame_times) - 1)
        first = out.first.get(msg.sender)
        if first is None:
            first = out.first[msg.sender] = np.full((w, h), NEVER, dtype=np.int32)
        if msg.cell is not None:
            out.positions.append((t, m.get_srcSystem(), msg.cell[0], msg.cell[1]))
        if isinstance(msg, Delta) and len(msg):
            x, y = msg.cells[:, 0], msg.cells[:, 1]
            np.minimum.at(first, (x, y), frame)
            phi = msg.phi.astype(np.float32) / 255.0
            known = np.nan_to_num(out.phi[x, y], nan=-1.0)
            out.phi[x, y] = np.maximum(known, phi)
            out.obstacle[x, y] |= msg.obstacle
        elif isinstance(msg, BitmapChunk) and msg.target is None:
            mask = chunk_mask(msg, w, h)
            first[mask] = np.minimum(first[mask], frame)
        elif isinstance(msg, Detection):
            for x, y in msg.targets:
                old = out.targets.get((int(x), int(y)))
                if old is None or frame < old[0]:
                    out.targets[(int(x), int(y))] = (frame, msg.sender)
    out.senders = {s: c.most_common(1)[0][0] for s, c in sysids.items()}
    return out
