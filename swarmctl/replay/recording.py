"""A recording read back: one model of a mission for every replay output.

`load(path)` takes a recording folder (written by `fly`, `agent` or `demo`) or a bare .tlog (written by
anyone) and returns a `Replay`: the grid, the vehicles (tracks, cells, states, battery, modes, link,
hover points), the frames the slider and the animation step through, each vehicle's knowledge per
frame, the targets found, the truth when the simulator left one, and everything that was skipped.

Frames: a recording with step lines has one frame per decision step (frame s = after round s, frame 0
= the search start); a bare .tlog, or a recording without step lines, has frames evenly spaced in time
(at most MAX_TIME_FRAMES). A vehicle's cell at frame s of a recording is its step record's cell moved
by the guarded move (the step line records where each vehicle was when the round decided).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from swarmctl.bounds import INPUT_MAX_BYTES, load_json, require_memory
from swarmctl.errors import InputError
from swarmctl.geo.buildings import load_buildings
from swarmctl.geo.grid import GeoGrid
from swarmctl.replay import knowledge as kmod
from swarmctl.replay.fit import grid_around, grid_from_cells
from swarmctl.replay.lines import MAX_VEHICLES, Lines, read_lines
from swarmctl.replay.telemetry import GEOD, VehicleTelemetry, path_m, read_telemetry
from swarmctl.replay.tlog import Damage, TlogIndex, index_tlog
from swarmctl.replay.truth import TRUTH_FILE, Truth, load_truth
from swarmctl.world.moves import MOVE_NAMES, MOVES

Progress = Callable[[int], object]  # a progress bar's update

MAX_TIME_FRAMES = 400
FRAME_BYTES = 64  # per vehicle and frame: cell (16), lat and lon (16), state, and the page's copies
HOVER_STILL_M, HOVER_MIN_S = 2.0, 10.0  # a foreign log's hover point: airborne, within 2 m for 10 s
COLOURS = (
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#17becf",
    "#bcbd22",
    "#7f7f7f",
)


@dataclass
class Vehicle:
    """One vehicle over the replay."""

    name: str
    index: int  # mission order (knowledge sender id)
    sysid: int | None
    colour: str
    cells: np.ndarray  # (F, 2) int64 cell per frame, -1 where not known
    states: list[str]  # (F,) state per frame ("" where not known)
    lat: np.ndarray  # (F,) position per frame (degrees; NaN where not known)
    lon: np.ndarray
    track_t: np.ndarray  # the flown track: times (s since 1970), positions
    track_lat: np.ndarray
    track_lon: np.ndarray
    track_alt: np.ndarray  # metres above home (NaN when the track comes from cells)
    track_source: str  # "telemetry" or "steps"
    telemetry: VehicleTelemetry | None = None
    hover: list[tuple[float, float, float]] = field(default_factory=list)  # (time, lat, lon)
    link_events: list[tuple[float, str]] = field(default_factory=list)  # recorded link changes
    summary: dict | None = None  # this vehicle's entry of summary.json

    @property
    def distance_m(self) -> float:
        """Horizontal distance flown: from telemetry when there is some, else between step cells."""
        if self.telemetry is not None and self.telemetry.lat.size >= 2:
            return self.telemetry.distance_m()
        ok = np.isfinite(self.track_lat)
        return path_m(self.track_lat[ok], self.track_lon[ok])

    def link(self, end: float) -> list[tuple[float, str]]:
        """(time, "ok" | "lost") changes: recorded link events when there are some, else heartbeats."""
        if self.link_events:
            return [(t, "ok" if c in ("seen", "back") else "lost") for t, c in self.link_events]
        return self.telemetry.link(end) if self.telemetry is not None else []


@dataclass
class Target:
    cell: tuple[int, int]
    frame: int
    vehicle: str
    lat: float
    lon: float


@dataclass
class Replay:
    """Everything the outputs draw (see the module docstring)."""

    source: Path
    kind: str  # "recording" or "tlog"
    name: str
    grid: GeoGrid
    grid_note: str
    vehicles: list[Vehicle]
    all_vehicles: list[str]
    frame_time: np.ndarray  # (F,) seconds since 1970
    frame_step: np.ndarray | None  # (F,) decision step of each frame; None for time frames
    knowledge: kmod.KnowledgeTimeline | None = None
    targets: list[Target] = field(default_factory=list)
    truth: Truth | None = None
    policy: str | None = None
    outcome: str | None = None
    summary: dict | None = None
    buildings: list[Any] = field(default_factory=list)  # shapely polygons, lon/lat
    damage: dict[str, list[Damage]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    events: Lines | None = None  # kept for checks that re-read the decisions
    tlog: TlogIndex | None = None

    @property
    def frames(self) -> int:
        return int(self.frame_time.size)

    def frame_label(self, f: int) -> str:
        """ "step 12" or "t = 34 s" for frame f."""
        if self.frame_step is not None:
            return f"step {int(self.frame_step[f])}"
        return f"t = {self.frame_time[f] - self.frame_time[0]:.0f} s"

    def frame_of_step(self, step: int) -> int:
        """The frame of a decision step (time frames: the frame of that many seconds)."""
        if self.frame_step is not None:
            return int(np.clip(np.searchsorted(self.frame_step, step), 0, self.frames - 1))
        return int(np.clip(np.searchsorted(self.frame_time - self.frame_time[0], step), 0, self.frames - 1))

    def cells_explored(self) -> np.ndarray | None:
        """(F,) cells known by the vehicles together at each frame."""
        return None if self.knowledge is None else self.knowledge.counts(self.frames)

    def targets_found(self) -> np.ndarray:
        """(F,) targets reported by each frame."""
        hist = np.bincount([min(t.frame, self.frames - 1) for t in self.targets], minlength=self.frames)
        return np.cumsum(hist)[: self.frames]


# --- loading ------------------------------------------------------------------------------------------
def load(
    path: str | Path,
    vehicles: list[str] | None = None,
    grid_file: str | Path | None = None,
    buildings: str | Path | None = None,
    progress: Progress | None = None,
) -> Replay:
    """Read a recording folder or a bare .tlog (InputError, one line, when it cannot be replayed)."""
    path = Path(path)
    if path.is_dir():
        return _Loader(path, progress).recording(vehicles, grid_file, buildings)
    if not path.exists():
        raise InputError(f"{path}: not found; give a recording folder (fly, agent, demo) or a .tlog file")
    return _Loader(path.parent, progress).bare_tlog(path, vehicles, grid_file, buildings)


class _Loader:
    def __init__(self, folder: Path, progress: Progress | None):
        self.folder, self.progress = folder, progress
        self.damage: dict[str, list[Damage]] = {}
        self.notes: list[str] = []
        self._tunnel: dict[int, kmod.TunnelKnowledge | None] = {}

    def tunnel(self, tlog: TlogIndex | None, frame_time: np.ndarray) -> kmod.TunnelKnowledge | None:
        """The knowledge in the log's TUNNEL frames (read once)."""
        if tlog is None:
            return None
        if id(tlog) not in self._tunnel:
            self._tunnel[id(tlog)] = kmod.from_tunnel(tlog, frame_time)
        return self._tunnel[id(tlog)]

    # --- the two kinds of input -----------------------------------------------------------------------
    def recording(self, only: list[str] | None, grid_file: str | Path | None, buildings: str | Path | None) -> Replay:
        folder = self.folder
        events_path, tlog_path = folder / "events.jsonl", folder / "mission.tlog"
        if not events_path.is_file() and not tlog_path.is_file():
            raise InputError(
                f"{folder}: not a recording (no events.jsonl, no mission.tlog); give the folder `swarmctl fly` or "
                "`swarmctl demo` wrote, or a .tlog file"
            )
        lines = self._lines(events_path) if events_path.is_file() else None
        if lines is not None and not lines.events and not (tlog_path.is_file() and tlog_path.stat().st_size):
            raise InputError(f"{events_path}: no readable event in it and no mission.tlog beside it; nothing to replay")
        tlog = self._tlog(tlog_path) if tlog_path.is_file() and tlog_path.stat().st_size else None
        telemetry = self._telemetry(tlog) if tlog is not None else {}
        mission = lines.of("mission")[0] if lines is not None and lines.of("mission") else None
        names = list(dict.fromkeys(mission["vehicles"])) if mission else []
        sysids = self._sysids(lines)
        known = set(names)
        extra = [n for n in sysids if n not in known]
        if len(names) + len(extra) > MAX_VEHICLES:
            self.notes.append(
                f"{events_path.name}: {len(names) + len(extra):,} vehicles named, over the {MAX_VEHICLES} a mission "
                f"may have: replayed the first {MAX_VEHICLES} (mission order)"
            )
            extra = extra[: max(0, MAX_VEHICLES - len(names))]
        names += extra
        if not names:
            return self.bare_tlog(tlog_path, only, grid_file, buildings, tlog=tlog, telemetry=telemetry)
        steps = _step_lines(lines)
        frame_step: np.ndarray | None
        if steps:
            assert lines is not None  # the steps are its lines
            require_memory(
                (max(steps) + 1) * len(names) * FRAME_BYTES,
                f"{events_path}: {max(steps) + 1:,} frames of {len(names)} vehicles",
                "replay fewer vehicles with --vehicle",
            )
            frame_step = np.arange(0, max(steps) + 1)
            frame_time = _step_times(steps, lines, frame_step)
        else:
            frame_time, frame_step = _time_frames(telemetry, lines)
            self.notes.append("no step lines: frames are evenly spaced in time")
        grid, note = self._recording_grid(grid_file, mission, telemetry, tlog, frame_time)
        selected = _select(names, only, {n: sysids.get(n) for n in names})
        vehicles = [
            self._vehicle(n, names.index(n), sysids.get(n), k, grid, frame_time, frame_step, steps, lines, telemetry)
            for k, n in enumerate(selected)
        ]
        summary = _read_json(folder / "summary.json", self)
        if summary is not None:
            entries = summary.get("vehicles", [])
            if not isinstance(entries, list) or not all(isinstance(s, dict) for s in entries):
                self.notes.append("summary.json: vehicles is not a list of objects; replayed without its figures")
                entries = []
            for v in vehicles:
                v.summary = next((s for s in entries if s.get("name") == v.name), None)
        name = str(mission["name"]) if mission else folder.name
        replay = Replay(folder, "recording", name, grid, note, vehicles, names, frame_time, frame_step)
        replay.policy = str(mission["policy"]) if mission else None
        ends = lines.of("end") if lines is not None else []
        outcome = (summary or {}).get("outcome")
        replay.outcome = ends[-1]["outcome"] if ends else (outcome if isinstance(outcome, str) else None)
        replay.summary, replay.events = summary, lines
        return self._finish(replay, tlog, buildings)

    def bare_tlog(
        self,
        path: Path,
        only: list[str] | None,
        grid_file: str | Path | None,
        buildings: str | Path | None,
        tlog: TlogIndex | None = None,
        telemetry: dict | None = None,
    ) -> Replay:
        tlog = tlog if tlog is not None else self._tlog(path)
        telemetry = telemetry if telemetry is not None else self._telemetry(tlog)
        if not telemetry:
            raise InputError(
                f"{path}: no vehicle in it (no autopilot HEARTBEAT among {len(tlog)} MAVLink messages); "
                "nothing to replay"
            )
        frame_time, frame_step = _time_frames(telemetry, None)
        if grid_file is None and (path.parent / "grid.npz").is_file():
            grid_file = path.parent / "grid.npz"
        grid, note = self._grid(grid_file, telemetry, tlog, frame_time)
        names = [f"sysid{s}" for s in sorted(telemetry)]
        sysids = {f"sysid{s}": s for s in sorted(telemetry)}
        selected = _select(names, only, sysids)
        vehicles = [
            self._vehicle(n, names.index(n), sysids[n], k, grid, frame_time, None, {}, None, telemetry)
            for k, n in enumerate(selected)
        ]
        replay = Replay(path, "tlog", path.stem, grid, note, vehicles, names, frame_time, frame_step)
        return self._finish(replay, tlog, buildings)

    def _finish(self, replay: Replay, tlog: TlogIndex | None, buildings: str | Path | None) -> Replay:
        """Knowledge, targets, truth, buildings and what was skipped, for either kind of input."""
        replay.tlog = tlog
        self._knowledge(replay, tlog)
        self._targets(replay, replay.events)
        if replay.kind == "recording":
            self._truth(replay)
        self._buildings(replay, buildings)
        replay.damage, replay.notes = self.damage, self.notes
        return replay

    # --- pieces ---------------------------------------------------------------------------------------
    def _lines(self, path: Path) -> Lines:
        lines = read_lines(path)
        if lines.damage:
            self.damage[path.name] = lines.damage
        if lines.unknown:
            kinds = ", ".join(f"{k} ({n})" for k, n in sorted(lines.unknown.items()))
            self.notes.append(f"{path.name}: skipped lines of kinds the schema does not name: {kinds}")
        return lines

    def _tlog(self, path: Path) -> TlogIndex:
        tlog = index_tlog(path, progress=self.progress)
        if tlog.damage:
            self.damage[path.name] = tlog.damage
        return tlog

    def _telemetry(self, tlog: TlogIndex) -> dict[int, VehicleTelemetry]:
        telemetry = read_telemetry(tlog)
        bad = {s: v.bad_positions for s, v in sorted(telemetry.items()) if v.bad_positions}
        if bad:
            each = ", ".join(f"system {s}: {n}" for s, n in bad.items())
            self.notes.append(
                f"{tlog.path.name}: skipped {sum(bad.values())} positions outside -90..90 latitude, -180..180 "
                f"longitude ({each})"
            )
        return telemetry

    def _recording_grid(
        self, grid_file: str | Path | None, mission: dict | None, telemetry: dict, tlog, frame_time: np.ndarray
    ):
        """The recording's own grid.npz; --grid only for a recording without one, and then it must be the
        size the mission line flew."""
        own = self.folder / "grid.npz"
        if grid_file is None:
            return self._grid(own, telemetry, tlog, frame_time)
        given = Path(grid_file)
        if own.is_file():
            if given.is_file() and _same_file(given, own):
                return self._grid(own, telemetry, tlog, frame_time)
            raise InputError(
                f"--grid {grid_file}: the recording has its own grid ({own}); --grid is for a .tlog or a recording "
                "without grid.npz: leave --grid out"
            )
        grid, note = self._grid(given, telemetry, tlog, frame_time)
        flown = mission.get("grid") if mission else None
        if flown is not None and list(flown) != [grid.width, grid.height]:
            raise InputError(
                f"--grid {grid_file}: a {grid.width} x {grid.height} grid, not the recording's: its mission flew "
                f"{flown[0]} x {flown[1]} cells; give the grid.npz the mission flew (or leave --grid out)"
            )
        return grid, note

    @staticmethod
    def _sysids(lines: Lines | None) -> dict[str, int]:
        out: dict[str, int] = {}
        for e in lines.events if lines is not None else []:
            if e["event"] == "state" and e["vehicle"] not in out:
                out[e["vehicle"]] = int(e["sysid"])
            elif e["event"] == "step":
                for r in e["vehicles"] + e["others"]:
                    out.setdefault(r["vehicle"], int(r["sysid"]))
        return out

    def _grid(self, grid_file: str | Path | None, telemetry: dict, tlog: TlogIndex | None, frame_time: np.ndarray):
        if grid_file is not None and Path(grid_file).is_file():
            return GeoGrid.load(grid_file), f"grid {Path(grid_file).name}"
        if grid_file is not None and Path(grid_file).name != "grid.npz":
            raise InputError(f"--grid {grid_file}: file not found; give a grid.npz written by `swarmctl plan`")
        tunnel = self.tunnel(tlog, frame_time)
        if tunnel is not None and tunnel.positions:
            fitted = _fit_from_tunnel(tunnel, telemetry)
            if fitted is not None:
                grid, rms = fitted
                grid.blocked = tunnel.obstacle.copy()
                return grid, (
                    f"grid {grid.width} x {grid.height} fitted to the knowledge messages' cells "
                    f"({grid.cell:.1f} m cells, {grid.rotation:.1f} deg, {rms:.1f} m RMS)"
                )
        fixes = [(v.lat, v.lon) for v in telemetry.values() if v.lat.size]
        if not fixes:
            bad = sum(v.bad_positions for v in telemetry.values())
            why = f" ({bad} positions out of range skipped)" if bad else ""
            where = tlog.path if tlog is not None else self.folder
            raise InputError(
                f"{where}: no grid.npz and no position in the log to fit a grid around{why}; give --grid FILE"
            )
        grid = grid_around(np.concatenate([f[0] for f in fixes]), np.concatenate([f[1] for f in fixes]))
        return grid, f"grid {grid.width} x {grid.height} of {grid.cell:g} m cells fitted around the tracks"

    def _vehicle(
        self,
        name: str,
        index: int,
        sysid: int | None,
        k: int,
        grid: GeoGrid,
        frame_time: np.ndarray,
        frame_step: np.ndarray | None,
        steps: dict[int, dict],
        lines: Lines | None,
        telemetry: dict[int, VehicleTelemetry],
    ) -> Vehicle:
        frames = frame_time.size
        tel = telemetry.get(sysid) if sysid is not None else None
        if tel is not None and not tel.pos_t.size and not tel.heartbeats.size:
            tel = None
        if frame_step is not None and lines is not None:
            cells, states = _cells_from_steps(name, frames, steps, lines)
        else:
            cells, states = np.full((frames, 2), -1, dtype=np.int64), [""] * frames
            if tel is not None:
                lat, lon, _alt = tel.position_at(frame_time)
                ok = np.isfinite(lat)
                if ok.any():
                    x, y = grid.latlon_to_cells(lat[ok], lon[ok])
                    inside = grid.in_grid(x, y)
                    cells[np.flatnonzero(ok)[inside]] = np.stack([x[inside], y[inside]], axis=1)
                    if not inside.any():
                        self.notes.append(
                            f"{name}: none of its positions lies in the grid (a log of another place?); leave "
                            "--grid out to grid round the tracks"
                        )
                states = _modes_at(tel, frame_time)
        known = cells[:, 0] >= 0
        clat, clon = np.full(frames, np.nan), np.full(frames, np.nan)
        if known.any():
            clat[known], clon[known] = grid.cells_to_latlon(cells[known, 0], cells[known, 1])
        if tel is not None and tel.pos_t.size:
            plat, plon, _ = tel.position_at(frame_time)
            lat, lon = np.where(np.isfinite(plat), plat, clat), np.where(np.isfinite(plon), plon, clon)
            track = (tel.pos_t, tel.lat, tel.lon, tel.alt, "telemetry")
        else:
            lat, lon = clat, clon
            track = (frame_time[known], clat[known], clon[known], np.full(int(known.sum()), np.nan), "steps")
        v = Vehicle(
            name,
            index,
            sysid,
            COLOURS[k % len(COLOURS)],
            cells,
            states,
            lat,
            lon,
            *track,
            telemetry=tel,
        )
        if lines is not None:
            v.hover = [
                (e["t"], *grid.cell_to_latlon(*e["cell"]))
                for e in lines.of("state")
                if e["vehicle"] == name and e["state"] == "hover" and e["cell"] is not None
            ]
            v.link_events = [(e["t"], e["change"]) for e in lines.of("link") if e["sysid"] == sysid]
        elif tel is not None:
            v.hover = _still_points(tel)
        return v

    def _knowledge(self, replay: Replay, tlog: TlogIndex | None) -> None:
        g, vs = replay.grid, replay.vehicles
        first = kmod.empty_first(len(vs), g.width, g.height)
        sources = []
        snap_path = replay.source / "knowledge.jsonl" if replay.kind == "recording" else None
        snap_targets: dict = {}
        if snap_path is not None and snap_path.is_file():
            lines = self._lines(snap_path)
            names = [v.name for v in vs]
            frame_of = {int(s): i for i, s in enumerate(replay.frame_step)} if replay.frame_step is not None else {}
            snap, snap_targets, problems = kmod.from_snapshots(
                lines.of("knowledge"), names, g.width, g.height, frame_of
            )
            if problems:
                self.notes.append(f"{snap_path.name}: skipped {len(problems)} snapshots ({problems[0]}, ...)")
            if (snap < kmod.NEVER).any():
                first, sources = snap, ["snapshots"]
        tunnel = self.tunnel(tlog, replay.frame_time)
        phi = obstacle = None
        if tunnel is not None and (tunnel.width, tunnel.height) == (g.width, g.height):
            by_sysid = {v.sysid: k for k, v in enumerate(vs)}
            for sender, rows in tunnel.first.items():
                k = by_sysid.get(tunnel.senders.get(sender))
                if k is None and replay.kind == "recording":
                    k = next((j for j, v in enumerate(vs) if v.index == sender), None)
                if k is None:
                    continue
                if sources == ["snapshots"]:  # before the first round: only the frames' own messages tell
                    np.minimum(first[k], np.where(rows == 0, 0, kmod.NEVER).astype(np.int32), out=first[k])
                else:
                    np.minimum(first[k], rows, out=first[k])
            if tunnel.first and "snapshots" not in sources:
                sources = ["tunnel"]
            phi, obstacle = tunnel.phi, tunnel.obstacle
            if not replay.targets:
                snap_targets = snap_targets or {
                    c: (f, vs[by_sysid[tunnel.senders[s]]].name)
                    for c, (f, s) in tunnel.targets.items()
                    if tunnel.senders.get(s) in by_sysid
                }
        elif tunnel is not None:
            self.notes.append(
                f"knowledge messages are for a {tunnel.width} x {tunnel.height} grid, not the "
                f"{g.width} x {g.height} grid: no knowledge panels from them"
            )
        if not sources:
            return
        timeline = kmod.KnowledgeTimeline(first, " and ".join(sources), phi=phi, obstacle=obstacle)
        timeline.targets = snap_targets
        replay.knowledge = timeline

    def _targets(self, replay: Replay, lines: Lines | None) -> None:
        g = replay.grid
        found: dict[tuple[int, int], Target] = {}
        for e in lines.of("targets") if lines is not None else []:
            for c in e["cells"]:
                cell = (int(c[0]), int(c[1]))
                if cell not in found and g.in_grid(*cell):
                    found[cell] = Target(
                        cell, replay.frame_of_step(int(e["step"])), e["vehicle"], *g.cell_to_latlon(*cell)
                    )
        if not found and replay.knowledge is not None:
            for cell, (frame, name) in replay.knowledge.targets.items():
                found[cell] = Target(cell, frame, name, *g.cell_to_latlon(*cell))
        replay.targets = sorted(found.values(), key=lambda t: (t.frame, t.cell))

    def _truth(self, replay: Replay) -> None:
        path = replay.source / TRUTH_FILE
        if path.is_file():
            replay.truth = load_truth(path, replay.grid.width, replay.grid.height)

    def _buildings(self, replay: Replay, path: str | Path | None) -> None:
        g = replay.grid
        candidates = [Path(path)] if path is not None else []
        if path is None and g.buildings_name:
            candidates = [self.folder / g.buildings_name]
        for p in candidates:
            if not p.is_file():
                if path is not None:
                    raise InputError(f"--buildings {p}: file not found; give a GeoJSON of building footprints")
                continue
            lat, lon = g.corner_latlon()
            box = shapely.box(lon.min(), lat.min(), lon.max(), lat.max())
            replay.buildings = [b.geometry for b in load_buildings(p).buildings if b.geometry.intersects(box)]


# --- helpers ------------------------------------------------------------------------------------------
def _select(names: list[str], only: list[str] | None, sysids: dict[str, int | None]) -> list[str]:
    if not only:
        return list(names)
    out = []
    for want in only:
        hit = want if want in names else next((n for n in names if str(sysids.get(n)) == want), None)
        if hit is None:
            raise InputError(f"--vehicle {want!r} is not in the recording; use one of {', '.join(names)}")
        if hit not in out:
            out.append(hit)
    return out


def _same_file(a: Path, b: Path) -> bool:
    """Whether two paths are one file, or two files with the same bytes."""
    try:
        if a.samefile(b):
            return True
        return a.stat().st_size == b.stat().st_size and a.read_bytes() == b.read_bytes()
    except OSError:
        return False


def _read_json(path: Path, loader: _Loader) -> dict | None:
    if not path.is_file():
        return None
    try:
        body = load_json(path, "summary", INPUT_MAX_BYTES)
    except InputError as exc:
        loader.notes.append(f"{path.name}: not readable ({str(exc).removeprefix(f'{path}: ')}); replayed without it")
        return None
    if not isinstance(body, dict):
        loader.notes.append(f"{path.name}: not a JSON object; replayed without it")
        return None
    return body


def _step_lines(lines: Lines | None) -> dict[int, dict]:
    out: dict[int, dict] = {}
    for e in lines.of("step") if lines is not None else []:
        out.setdefault(int(e["step"]), e)
    return out


def _step_times(steps: dict[int, dict], lines: Lines, frame_step: np.ndarray) -> np.ndarray:
    known = np.array(sorted(steps), dtype=float)
    times = np.array([steps[int(s)]["t"] for s in known], dtype=float)
    search = [e["t"] for e in lines.of("state") if e["state"] == "search" and e["t"] <= times[0]]
    start = max(search) if search else times[0] - 1.0
    known, times = np.concatenate([[0.0], known]), np.concatenate([[min(start, times[0])], times])
    return np.interp(frame_step.astype(float), known, times)


def _time_frames(telemetry: dict[int, VehicleTelemetry], lines: Lines | None) -> tuple[np.ndarray, None]:
    stamps = [v.pos_t for v in telemetry.values() if v.pos_t.size] or [v.heartbeats for v in telemetry.values()]
    stamps = [s for s in stamps if s.size]
    if lines is not None and lines.events:
        stamps.append(np.array([e["t"] for e in lines.events]))
    if not stamps:
        raise InputError("the recording holds no timed data (no step lines, no telemetry); nothing to replay")
    t0, t1 = min(float(s.min()) for s in stamps), max(float(s.max()) for s in stamps)
    dt = max(1.0, (t1 - t0) / (MAX_TIME_FRAMES - 1))
    dt = next(d for d in (1, 2, 5, 10, 20, 30, 60, 120, 300, 600, math.inf) if d >= dt)
    if math.isinf(dt):
        dt = (t1 - t0) / (MAX_TIME_FRAMES - 1)
    return t0 + np.arange(int(math.floor((t1 - t0) / dt)) + 1) * dt, None


def _cells_from_steps(name: str, frames: int, steps: dict[int, dict], lines: Lines) -> tuple[np.ndarray, list[str]]:
    cells = np.full((frames, 2), -1, dtype=np.int64)
    states = [""] * frames
    start = next(
        (
            e["cell"]
            for e in reversed(lines.of("state"))
            if e["vehicle"] == name and e["state"] == "search" and e["cell"]
        ),
        None,
    )
    first = steps.get(1)
    rec = next((r for r in first["vehicles"] if r["vehicle"] == name), None) if first else None
    if rec is not None:
        start = rec["cell"]
    if start is not None:
        cells[0], states[0] = start, "search"
    for f in range(1, frames):
        e = steps.get(f)
        if e is None:  # a step line was lost: the vehicle stays where it was
            cells[f], states[f] = cells[f - 1], states[f - 1]
            continue
        r = next((r for r in e["vehicles"] if r["vehicle"] == name), None)
        if r is not None:
            dx, dy = MOVES[MOVE_NAMES.index(r["guarded"])]
            cells[f], states[f] = (r["cell"][0] + int(dx), r["cell"][1] + int(dy)), "search"
            continue
        o = next((o for o in e["others"] if o["vehicle"] == name), None)
        if o is not None:
            cells[f] = o["cell"] if o["cell"] is not None else (-1, -1)
            states[f] = o["state"]
    return cells, states


def _modes_at(tel: VehicleTelemetry, times: np.ndarray) -> list[str]:
    if not tel.modes:
        return [""] * times.size
    t = np.array([m[0] for m in tel.modes])
    i = np.searchsorted(t, times, side="right") - 1
    return [tel.modes[j][1] if j >= 0 else "" for j in i]


def _still_points(tel: VehicleTelemetry) -> list[tuple[float, float, float]]:
    """(time, lat, lon) where an airborne vehicle stayed within HOVER_STILL_M for HOVER_MIN_S or more."""
    out = []
    t, lat, lon, alt = tel.pos_t, tel.lat, tel.lon, tel.alt
    i, n = 0, t.size
    while i < n:
        if alt[i] <= 1.0:
            i += 1
            continue
        d = GEOD.inv(np.full(n - i, lon[i]), np.full(n - i, lat[i]), lon[i:], lat[i:])[2]
        away = np.flatnonzero((d > HOVER_STILL_M) | (alt[i:] <= 1.0))
        j = i + (int(away[0]) if away.size else n - i)
        if t[j - 1] - t[i] >= HOVER_MIN_S:
            out.append((float(t[i]), float(np.mean(lat[i:j])), float(np.mean(lon[i:j]))))
        i = max(j, i + 1)
    return out


def _fit_from_tunnel(tunnel: kmod.TunnelKnowledge, telemetry: dict[int, VehicleTelemetry]):
    rows = [(t, s, x, y) for t, s, x, y in tunnel.positions if s in telemetry and telemetry[s].pos_t.size]
    if len(rows) < 3:
        return None
    a = np.array(rows, dtype=float)
    lat = np.empty(len(a))
    lon = np.empty(len(a))
    for s in np.unique(a[:, 1]).astype(int):
        m = a[:, 1] == s
        lat[m], lon[m], _ = telemetry[s].position_at(a[m, 0])
    ok = np.isfinite(lat)
    if ok.sum() < 3 or len({(x, y) for x, y in a[ok][:, 2:4]}) < 2:
        return None
    return grid_from_cells(lat[ok], lon[ok], a[ok, 2], a[ok, 3], tunnel.width, tunnel.height)
