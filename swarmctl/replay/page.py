"""map.html: the self-contained map page of a replay (open it in any browser, offline).

It shows the area and its no-fly zones, the grid with its blocked cells (and grid lines when zoomed in),
building footprints when the replay has them, each vehicle's track in its own colour, the targets
found, hover points, the simulation's hidden targets (a checkbox, when there is a truth file), and a
time slider with a play button that moves the vehicles and shows the cells the chosen vehicle (or all
together) had explored at that frame. Pan by dragging, zoom with the wheel.

Everything is in the one file: the data as JSON, the code and style inline (page_template). The page
loads nothing from the network unless it is written with a basemap tile URL (`--basemap`, e.g.
https://tile.openstreetmap.org/{z}/{x}/{y}.png): then the browser fetches those tiles.
"""

from __future__ import annotations

import base64
import html
import json
import re
import time
from pathlib import Path

import numpy as np
import shapely

from swarmctl.replay.knowledge import NEVER
from swarmctl.replay.page_template import DRAW_JS, PAGE
from swarmctl.replay.recording import Replay

MAX_TRACK_POINTS = 1000
MAX_KNOWLEDGE_VALUES = 8_000_000  # vehicles x cells; above it the page gets only the union (no per-vehicle choice)


def _rings(wkt: str) -> list[list[list[float]]]:
    if not wkt:
        return []
    geom = shapely.from_wkt(wkt)
    out = []
    for poly in shapely.get_parts(geom):
        if isinstance(poly, shapely.Polygon):
            out.append(np.round(np.asarray(poly.exterior.coords)[:, :2], 7).tolist())
    return out


def _round(a: np.ndarray, digits: int) -> list:
    return [None if not np.isfinite(v) else round(float(v), digits) for v in a]


def orders(replay: Replay) -> list[dict]:
    """The operator's orders from the live page (`operator` lines): the frame of each, and what it was."""
    out = []
    for e in replay.events.of("operator") if replay.events is not None else []:
        what = str(e["action"]) + (f" {e['vehicle']}" if e.get("vehicle") else "")
        out.append({"frame": replay.frame_of_step(int(e["step"])), "text": f"{what} ({e['source']}, step {e['step']})"})
    return out


def page_data(replay: Replay, basemap: str | None = None, attribution: str = "") -> dict:
    """The JSON the page draws (see page_template)."""
    g = replay.grid
    lat, lon = g.corner_latlon()
    corners = [[float(lat[i, j]), float(lon[i, j])] for i, j in ((0, 0), (-1, 0), (-1, -1), (0, -1))]
    t0 = float(replay.frame_time[0])
    vehicles = []
    for v in replay.vehicles:
        ok = np.isfinite(v.track_lat) & np.isfinite(v.track_lon)
        t, la, lo = v.track_t[ok], v.track_lat[ok], v.track_lon[ok]
        if t.size > MAX_TRACK_POINTS:
            keep = np.unique(np.append(np.linspace(0, t.size - 1, MAX_TRACK_POINTS).astype(np.int64), t.size - 1))
            t, la, lo = t[keep], la[keep], lo[keep]
        vehicles.append(
            {
                "name": v.name,
                "colour": v.colour,
                "sysid": v.sysid,
                "lat": _round(v.lat, 7),
                "lon": _round(v.lon, 7),
                "state": v.states,
                "cell": [None if c[0] < 0 else [int(c[0]), int(c[1])] for c in v.cells],
                "track": np.round(np.column_stack([lo, la]), 7).tolist(),
                "trackT": np.round(t - t0, 2).tolist(),
            }
        )
    knowledge = None
    k = replay.knowledge
    if k is not None:
        first = k.first if k.first.size <= MAX_KNOWLEDGE_VALUES else k.first.min(axis=0, keepdims=True)
        words = np.where(first >= NEVER, 0xFFFF, np.minimum(first, 0xFFFE)).astype("<u2")
        knowledge = {"vehicles": int(first.shape[0]), "first": base64.b64encode(words.tobytes()).decode("ascii")}
    index = {v.name: i for i, v in enumerate(replay.vehicles)}
    hover = [
        {"lat": round(la, 7), "lon": round(lo, 7), "vehicle": i, "t": round(t - t0, 2)}
        for i, v in enumerate(replay.vehicles)
        for t, la, lo in v.hover
    ]
    hidden = []
    if replay.truth is not None:
        hidden = [dict(zip(("lat", "lon"), g.cell_to_latlon(int(x), int(y)))) for x, y in replay.truth.targets]
    subtitle = (
        f"{replay.kind} {replay.source.name}: {len(replay.vehicles)} vehicles, {replay.frames} frames; "
        f"{g.width} x {g.height} cells of {g.cell:g} m ({replay.grid_note})"
        + (f"; policy {replay.policy}" if replay.policy else "")
        + (f"; outcome {replay.outcome}" if replay.outcome else "")
        + (f"; knowledge from {k.source}" if k is not None else "; no knowledge in this log")
    )
    return {
        "name": replay.name,
        "subtitle": subtitle,
        "frameTimes": np.round(replay.frame_time - t0, 3).tolist(),
        "frameLabels": [replay.frame_label(f) for f in range(replay.frames)],
        "clock": [time.strftime("%H:%M:%S", time.gmtime(t)) + " UTC" for t in replay.frame_time],
        "grid": {
            "w": g.width,
            "h": g.height,
            "corners": corners,
            "blocked": base64.b64encode(np.packbits(g.blocked.reshape(-1)).tobytes()).decode("ascii"),
        },
        "area": _rings(g.area_wkt),
        "nofly": _rings(g.nofly_wkt),
        "buildings": [r for b in replay.buildings for r in _rings(b.wkt)],
        "vehicles": vehicles,
        "knowledge": knowledge,
        "targets": [
            {"lat": t.lat, "lon": t.lon, "frame": t.frame, "vehicle": index.get(t.vehicle, -1), "cell": list(t.cell)}
            for t in replay.targets
        ],
        "hover": hover,
        "orders": orders(replay),
        "hidden": hidden,
        "basemap": basemap,
        "basemapAttribution": attribution,
    }


def write_page(replay: Replay, path: Path, basemap: str | None = None, attribution: str = "") -> Path:
    """Write the page; `basemap` is a tile URL template with {z}, {x} and {y}, or None (offline)."""
    data = json.dumps(page_data(replay, basemap, attribution), separators=(",", ":"), allow_nan=False)
    # "<" only occurs inside JSON strings, where \u003c means the same: so no recorded text ("</script>",
    # "<!--") can end or change the script element the data sits in.
    data = data.replace("<", "\\u003c")
    fill = {"__TITLE__": html.escape(f"{replay.name}: replay"), "__DATA__": data, "__DRAW__": DRAW_JS}
    # One pass: text put in for one marker is never searched for the others.
    path.write_text(re.sub("__TITLE__|__DATA__|__DRAW__", lambda m: fill[m.group()], PAGE), encoding="utf-8")
    return path
