"""The decision inputs of a recording (inputs.jsonl): each round's beliefs of the deciding vehicles,
written compactly and read back exactly, so that `swarmctl replay --verify` decides again what the
policy decided.

One `inputs` line per decision round (swarmctl.mission.events has its fields). What it holds of each
decider (the searching vehicles of the round, in the order the policy took them) is exactly the
Beliefs the policy was given (swarmctl.world.beliefs): its map, where it believes every vehicle is
and which of them hover on a target; the step and the swarm's size come with the line and the
mission line. The guard's view (the cells of the vehicles that did not search) is in `held`.

The map, one uint16 per cell and decider:

    bits 0-7  phi_hat quantised (0..255, swarmctl.knowledge.model.PHI_LEVELS) where explored, else 0
              (an unexplored cell reads 1 in phi_hat)
    bit 8     explored          bit 9  a known obstacle          bit 10  a known target

is written as a delta: the cells whose value changed since the decider's previous line (that line's
step is `since`; since 0 means from an all-zero map: a decider's first line, and every round
1, 1 + KEY_EVERY, 1 + 2 KEY_EVERY, ..., so a damaged line costs at most KEY_EVERY rounds). A delta is
base64 of zlib of the cells' flat indices x * H + y (ascending; the first one, then each one's
difference to the one before, uint32 little-endian) followed by their new values (uint16
little-endian); deciders with the same delta share one entry of `maps` (with ideal sharing every
decider knows the same map, so a round stores it once). Positions: base64 of zlib of int16
little-endian (A, N, 3), for each of the A deciders and N vehicles the cell x, y where the decider
believes the vehicle is (-1, -1: unknown; its own row is its own cell) and 1 when it believes the
vehicle hovers on a target. Heard (optional; lines written before it decided as if every position
were current): base64 of zlib of int16 little-endian (A, N), how many steps before the policy's step
the decider last heard each vehicle (negative: a report stamped later than that step, as a vehicle's
own position is; -32768: never; clipped to +-32767), which the hover rule reads.
"""

from __future__ import annotations

import base64
import zlib
from typing import Any

import numpy as np

from swarmctl.knowledge.model import PHI_LEVELS, dequantise_phi
from swarmctl.world.beliefs import Beliefs, ObservationSettings

KEY_EVERY = 50  # rounds between the lines that carry every decider's whole map
MAX_AGE, NEVER_HEARD = 32767, -32768  # the ages of news a line records, in steps (int16), and "never"
EXPLORED, OBSTACLE, TARGET = np.uint16(1 << 8), np.uint16(1 << 9), np.uint16(1 << 10)
PHI_BITS = np.uint16(0xFF)


class InputsError(ValueError):
    """An inputs line that cannot be read back (damaged, or its delta's base is missing)."""


def cell_values(beliefs: Beliefs) -> np.ndarray:
    """(U, W, H) uint16: the map of each decider of batch 0, as the module docstring packs it."""
    explored = beliefs.explored[0]
    scaled = beliefs.phi_hat[0] * np.float32(PHI_LEVELS)
    values = np.rint(scaled, out=scaled).astype(np.uint16)
    values *= explored
    # the flag bits 8-10 from the bool maps' bytes (0 or 1), shifted in one uint8 pass
    flags = explored.view(np.uint8) | (beliefs.obstacles[0].view(np.uint8) << 1)
    flags |= beliefs.targets[0].view(np.uint8) << 2
    values |= flags.astype(np.uint16) << 8
    return values


def _b64(data: bytes) -> str:
    return base64.b64encode(zlib.compress(data, 6)).decode("ascii")


def b64_text_bound(limit: int) -> int:
    """The longest base64 text of zlib data that decompresses to at most `limit` bytes (zlib's compressBound)."""
    packed = limit + (limit >> 12) + (limit >> 14) + (limit >> 25) + 13
    return 4 * ((packed + 2) // 3)


def inflate(text: Any, limit: int, what: str) -> bytes:
    """base64 of zlib data decompressed, refused (InputsError) when it would be more than `limit` bytes: at
    most `limit` bytes are ever decompressed, so a decompression bomb costs nothing."""
    if not isinstance(text, str):
        raise InputsError(f"{what} is not a string")
    if len(text) > b64_text_bound(limit):
        raise InputsError(f"{what} is {len(text):,} characters, longer than {limit:,} bytes can compress to")
    try:
        inflater = zlib.decompressobj()
        raw = inflater.decompress(base64.b64decode(text, validate=True), limit + 1)
    except (ValueError, zlib.error) as exc:
        raise InputsError(f"{what} does not decode ({exc})") from None
    if len(raw) > limit or inflater.unconsumed_tail:
        raise InputsError(f"{what} decompresses to more than the {limit:,} bytes it may hold")
    if not inflater.eof or inflater.unused_data:
        raise InputsError(f"{what} does not decode (the zlib data is cut short or followed by other bytes)")
    return raw


def _delta(flat: np.ndarray, values: np.ndarray) -> bytes:
    gaps = np.diff(flat, prepend=0).astype("<u4")
    return gaps.tobytes() + values.astype("<u2").tobytes()


class InputsEncoder:
    """Builds the inputs lines of one mission, round after round (it keeps each decider's last map)."""

    def __init__(self, key_every: int = KEY_EVERY) -> None:
        self.key_every = int(key_every)
        self._last: dict[int, tuple[int, np.ndarray]] = {}  # vehicle index -> (step, map) of its last line

    def line(self, step: int, names: list[str], beliefs: Beliefs, held: list[tuple[int, tuple[int, int]]]) -> dict:
        """The fields of round `step`'s line (all but `t` and `event`): `names` are the deciders of
        `beliefs` (a batch of one), `held` the guard's other vehicles as (mission index or -1, cell)."""
        values = cell_values(beliefs)
        me = [int(v) for v in beliefs.me[0]]
        key = (step - 1) % self.key_every == 0
        zero = np.zeros(values.shape[1:], dtype=np.uint16)
        since, bases = [], []
        for v in me:
            last = None if key else self._last.get(v)
            since.append(0 if last is None else last[0])
            bases.append(zero if last is None else last[1])
        base = np.stack(bases)
        changed = values != base
        # with ideal sharing every decider holds decider 0's map and had its base: one delta for all
        like_first = (values == values[0]).all(axis=(1, 2)) & (base == base[0]).all(axis=(1, 2))
        maps: list[str] = []
        found: dict[bytes, int] = {}
        index: list[int] = []
        for u, v in enumerate(me):
            if u and like_first[u]:
                index.append(index[0])
            else:
                flat = np.flatnonzero(changed[u])
                if not flat.size:
                    index.append(-1)
                else:
                    blob = _delta(flat, values[u].reshape(-1)[flat])
                    if blob not in found:
                        found[blob] = len(maps)
                        maps.append(_b64(blob))
                    index.append(found[blob])
            self._last[v] = (int(step), values[u])
        table = np.concatenate([beliefs.positions[0], beliefs.hovering[0][..., None]], axis=-1)
        line = dict(
            step=int(step),
            vehicles=list(names),
            since=since,
            map=index,
            maps=maps,
            positions=_b64(table.astype("<i2").tobytes()),
            held=[dict(index=int(i), cell=[int(c[0]), int(c[1])]) for i, c in held],
        )
        if beliefs.heard is not None:
            heard = beliefs.heard[0]
            ages = np.where(heard >= 0, np.clip(beliefs.step - heard, -MAX_AGE, MAX_AGE), NEVER_HEARD)
            line["heard"] = _b64(ages.astype("<i2").tobytes())
        return line


class InputsDecoder:
    """Reads the inputs lines of one mission back, in step order, into the deciders' Beliefs."""

    def __init__(self, width: int, height: int, vehicles: int):
        self.width, self.height, self.vehicles = int(width), int(height), int(vehicles)
        self._last: dict[int, tuple[int, np.ndarray]] = {}

    def _map(self, line: dict, u: int, v: int, maps: list[np.ndarray | None]) -> np.ndarray:
        since, k = line["since"][u], line["map"][u]
        if since == 0:
            base = np.zeros((self.width, self.height), dtype=np.uint16)
        else:
            last = self._last.get(v)
            if last is None or last[0] != since:
                raise InputsError(f"its map is a change since step {since}, whose line was not read")
            base = last[1]
        if k == -1:
            return base
        if not 0 <= k < len(maps):
            raise InputsError(f"map index {k} is not one of the line's {len(maps)} maps")
        if maps[k] is None:
            maps[k] = self._delta(line["maps"][k], f"maps[{k}]")
        flat, values = maps[k]
        out = base.copy()
        out.reshape(-1)[flat] = values
        return out

    def _delta(self, text: str, what: str) -> tuple[np.ndarray, np.ndarray]:
        raw = inflate(text, 6 * self.width * self.height, what)  # at most every cell: uint32 index, uint16 value
        if len(raw) % 6:
            raise InputsError(f"{what} holds {len(raw)} bytes, not 6 a cell")
        n = len(raw) // 6
        flat = np.cumsum(np.frombuffer(raw[: 4 * n], dtype="<u4").astype(np.int64))
        values = np.frombuffer(raw[4 * n :], dtype="<u2").astype(np.uint16)
        if n and (flat[-1] >= self.width * self.height or (np.diff(flat) <= 0).any()):
            raise InputsError(f"{what} names cells outside the {self.width} x {self.height} grid")
        return flat, values

    def beliefs(self, line: dict, me: list[int], settings: ObservationSettings) -> Beliefs:
        """The Beliefs the deciders of `line` had (`me`: their mission indices, in the line's order),
        with the step the policy was given (the line's round - 1). Lines must come in step order;
        InputsError when this one cannot be read (the deciders' maps are then left as they were)."""
        a = len(me)
        for name in ("since", "map"):
            if len(line[name]) != a:
                raise InputsError(f"{name} has {len(line[name])} entries for {a} vehicles")
        maps: list[Any] = [None] * len(line["maps"])
        values = np.stack([self._map(line, u, v, maps) for u, v in enumerate(me)])
        raw = inflate(line["positions"], a * self.vehicles * 3 * 2, "positions")
        if len(raw) != a * self.vehicles * 3 * 2:
            raise InputsError(f"positions hold {len(raw)} bytes, not {a} x {self.vehicles} x 3 int16")
        table = np.frombuffer(raw, dtype="<i2").reshape(a, self.vehicles, 3).astype(np.int64)
        step = int(line["step"]) - 1
        heard = None
        if line.get("heard") is not None:
            raw = inflate(line["heard"], a * self.vehicles * 2, "heard")
            if len(raw) != a * self.vehicles * 2:
                raise InputsError(f"heard holds {len(raw)} bytes, not {a} x {self.vehicles} int16")
            ages = np.frombuffer(raw, dtype="<i2").reshape(a, self.vehicles).astype(np.int64)
            heard = np.where(ages != NEVER_HEARD, np.maximum(step - ages, -1), -1)[None]
        for u, v in enumerate(me):
            self._last[v] = (int(line["step"]), values[u])
        explored = (values & EXPLORED) != 0
        phi_hat = np.where(explored, dequantise_phi(values & PHI_BITS), np.float32(1.0)).astype(np.float32)
        try:
            return Beliefs(
                explored[None],
                phi_hat[None],
                ((values & OBSTACLE) != 0)[None],
                ((values & TARGET) != 0)[None],
                table[None, ..., :2],
                (table[None, ..., 2] != 0),
                np.array([me], dtype=np.int64),
                np.zeros(1, dtype=np.int64),
                step,
                settings,
                heard=heard,
            )
        except ValueError as exc:
            raise InputsError(str(exc)) from None
