"""Tracks for GIS tools: tracks.geojson (QGIS, geojson.io) and tracks.kml (Google Earth).

One LineString per vehicle (lon, lat, metres above home; at most MAX_POINTS points, evenly thinned),
with its timestamps: GeoJSON keeps them per point in the feature's `coordTimes` property (ISO 8601
UTC, the convention of Mapbox's togeojson) and `start` / `end`; KML gives each LineString a TimeSpan
and adds a gx:Track per vehicle (a time-stamped point per position) for Google Earth's time slider.
The targets found are points, written by the mission's own writers (targets.geojson, targets.kml,
swarmctl.mission.service) and copied into the track files.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from swarmctl.errors import printable
from swarmctl.mission.service import write_targets_geojson, write_targets_kml
from swarmctl.replay.recording import Replay, Vehicle

MAX_POINTS = 2000
KML = "http://www.opengis.net/kml/2.2"
GX = "http://www.google.com/kml/ext/2.2"


def _iso(t: float) -> str:
    return datetime.fromtimestamp(float(t), tz=UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")[:-4] + "Z"


def _points(v: Vehicle) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    ok = np.isfinite(v.track_lat) & np.isfinite(v.track_lon)
    t, lat, lon, alt = v.track_t[ok], v.track_lat[ok], v.track_lon[ok], v.track_alt[ok]
    if t.size > MAX_POINTS:
        keep = np.unique(np.append(np.linspace(0, t.size - 1, MAX_POINTS).astype(np.int64), t.size - 1))
        t, lat, lon, alt = t[keep], lat[keep], lon[keep], alt[keep]
    return t, lat, lon, np.nan_to_num(alt, nan=0.0)


def targets_summary(replay: Replay) -> dict:
    """The targets found in the shape the mission's target writers take (with the vehicle that found
    each and, from the recording's `find` events, when: seconds from the search's start)."""
    step = replay.frame_step
    finds = {tuple(e["cell"]): e for e in replay.events.of("find")} if replay.events is not None else {}
    return {
        "mission": replay.name,
        "targets_found": [
            {
                "cell": list(t.cell),
                "lat": t.lat,
                "lon": t.lon,
                "step": int(step[t.frame]) if step is not None else t.frame,
                "vehicle": t.vehicle,
                "time_s": finds.get(tuple(t.cell), {}).get("time_s"),
            }
            for t in replay.targets
        ],
    }


def write_tracks(replay: Replay, out: Path) -> list[Path]:
    """targets.geojson, targets.kml, tracks.geojson and tracks.kml in `out`."""
    summary = targets_summary(replay)
    targets_geojson = write_targets_geojson(out / "targets.geojson", summary)
    targets_kml = write_targets_kml(out / "targets.kml", summary)
    features = []
    for v in replay.vehicles:
        t, lat, lon, alt = _points(v)
        if t.size < 2:
            continue
        features.append(
            {
                "type": "Feature",
                "geometry": {
                    "type": "LineString",
                    "coordinates": [[round(a, 7), round(b, 7), round(c, 2)] for a, b, c in zip(lon, lat, alt)],
                },
                "properties": {
                    "vehicle": v.name,
                    "sysid": v.sysid,
                    "colour": v.colour,
                    "source": v.track_source,
                    "start": _iso(t[0]),
                    "end": _iso(t[-1]),
                    "coordTimes": [_iso(s) for s in t],
                    "distance_m": round(v.distance_m, 1),
                },
            }
        )
    features += json.loads(targets_geojson.read_text())["features"]
    geojson = out / "tracks.geojson"
    geojson.write_text(json.dumps({"type": "FeatureCollection", "features": features}) + "\n", encoding="utf-8")
    return [targets_geojson, targets_kml, geojson, _write_kml(replay, out / "tracks.kml", targets_kml)]


def _kml_colour(hex_rgb: str) -> str:
    r, g, b = hex_rgb[1:3], hex_rgb[3:5], hex_rgb[5:7]
    return f"ff{b}{g}{r}"


def _write_kml(replay: Replay, path: Path, targets_kml: Path) -> Path:
    ET.register_namespace("", KML)
    ET.register_namespace("gx", GX)
    k = f"{{{KML}}}"
    kml = ET.Element(f"{k}kml")
    doc = ET.SubElement(kml, f"{k}Document")
    ET.SubElement(doc, f"{k}name").text = printable(f"{replay.name}: tracks")  # XML holds no control characters
    for v in replay.vehicles:
        style = ET.SubElement(doc, f"{k}Style", id=f"track-{v.index}")
        line = ET.SubElement(style, f"{k}LineStyle")
        ET.SubElement(line, f"{k}color").text = _kml_colour(v.colour)
        ET.SubElement(line, f"{k}width").text = "2"
    for v in replay.vehicles:
        t, lat, lon, alt = _points(v)
        if t.size < 2:
            continue
        coords = " ".join(f"{a:.7f},{b:.7f},{c:.2f}" for a, b, c in zip(lon, lat, alt))
        mark = ET.SubElement(doc, f"{k}Placemark")
        ET.SubElement(mark, f"{k}name").text = printable(v.name)
        ET.SubElement(mark, f"{k}styleUrl").text = f"#track-{v.index}"
        span = ET.SubElement(mark, f"{k}TimeSpan")
        ET.SubElement(span, f"{k}begin").text = _iso(t[0])
        ET.SubElement(span, f"{k}end").text = _iso(t[-1])
        ls = ET.SubElement(mark, f"{k}LineString")
        ET.SubElement(ls, f"{k}altitudeMode").text = "relativeToGround"
        ET.SubElement(ls, f"{k}coordinates").text = coords
        timed = ET.SubElement(doc, f"{k}Placemark")
        ET.SubElement(timed, f"{k}name").text = printable(f"{v.name} (timed)")
        ET.SubElement(timed, f"{k}styleUrl").text = f"#track-{v.index}"
        track = ET.SubElement(timed, f"{{{GX}}}Track")
        ET.SubElement(track, f"{k}altitudeMode").text = "relativeToGround"
        for s in t:
            ET.SubElement(track, f"{k}when").text = _iso(s)
        for a, b, c in zip(lon, lat, alt):
            ET.SubElement(track, f"{{{GX}}}coord").text = f"{a:.7f} {b:.7f} {c:.2f}"
    for mark in ET.parse(targets_kml).getroot().iter(f"{k}Placemark"):
        doc.append(mark)
    ET.ElementTree(kml).write(path, encoding="utf-8", xml_declaration=True)
    return path
