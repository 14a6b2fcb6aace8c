"""`swarmctl replay --gaps`: the cells still worth searching after a mission, for the next sortie.

What is left of the prior is swarmctl.world.prior's residual, prior * (1 - pod) ** passes. A recording
gives the three from its `prior` line (`pod`, `weights`: W lists of H numbers indexed [x][y], `source`)
and summary.json's `passes` (W lists of H ints, the team's pass counts). Without a `prior` line the
prior is uniform over the free cells with pod 1; without `passes` (a recording from before them, or one
cut off before its summary) a cell the vehicles explored counts one pass and any other none.

A cell is left when its residual is above `gaps_min` times what one free cell held under a uniform
prior before the search (prior.py's `density`); by default, with pod 1 every cell with any residual is
left, and with pod < 1 those above DEFAULT_GAPS_MIN. The cells left are merged into polygons (the
union of their squares, in exact grid units, then to metres and lon/lat through the grid's
projection) and written as gaps.geojson, gaps.kml and gaps.prior.geojson (the `[mission] prior`
format: each polygon's share of the residual, summing to 1).
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely
from scipy import ndimage
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient

from swarmctl.bounds import read_limited
from swarmctl.errors import InputError, printable
from swarmctl.replay.lines import LINES_MAX_BYTES
from swarmctl.replay.recording import Replay
from swarmctl.replay.tracks import KML
from swarmctl.world.prior import check_pod, density, normalise_prior, residual, uniform_prior

DEFAULT_GAPS_MIN = 0.1  # pod < 1: a cell holding under a tenth of a uniform cell's share is not worth a pass
DECIMALS = 9  # lon/lat: 0.1 mm, well under the smallest cell (1 cm)
PRIOR_EVENT = "prior"
NO_PRIOR = "uniform prior, pod 1"


@dataclass
class Gap:
    """One polygon of cells left: lon/lat, its cells, its area and the residual probability inside."""

    polygon: Polygon
    cells: int
    area_m2: float
    probability: float


@dataclass
class Gaps:
    """What is left after a mission, and where its inputs came from."""

    left: np.ndarray  # (W, H) bool the cells still worth searching
    residual: np.ndarray  # (W, H) float64 the probability each cell still holds the person
    pod: float
    prior_source: str  # "uniform prior, pod 1", or the prior line's source
    passes_source: str  # "summary.json" or "the explored cells"
    gaps: list[Gap] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def probability(self) -> float:
        return float(self.residual[self.left].sum())

    def summary_lines(self, cell_m: float) -> list[str]:
        """One line for the replay's summary (and one more for a recording cut off before its summary)."""
        cells = int(self.left.sum())
        area = cells * cell_m * cell_m
        line = (
            f"gaps: {cells} cells, {area:,.0f} m2 ({area / 1e4:.2f} ha) in {len(self.gaps)} "
            f"polygon{'s' if len(self.gaps) != 1 else ''}, probability left {self.probability:.4f} "
            f"({self.prior_source}; passes from {self.passes_source})"
        )
        return [line] + [f"gaps: {n}" for n in self.notes]


def find_gaps(replay: Replay, gaps_min: float | None = None) -> Gaps:
    """The cells left after `replay` and their polygons (module docstring); InputError for a bad `prior`
    line or `passes`."""
    g = replay.grid
    free = ~np.asarray(g.blocked, dtype=bool)
    shape = (g.width, g.height)
    notes: list[str] = []
    event = _prior_event(replay)
    if event is None:
        prior, pod, prior_source = uniform_prior(free), 1.0, NO_PRIOR
    else:
        where, obj = event
        prior, pod = _prior_from_event(where, obj, shape, free)
        prior_source = f"prior {printable(str(obj.get('source', '?')))}, pod {pod:g}"
    passes = _summary_passes(replay, shape)
    if passes is not None:
        passes_source = "summary.json"
    else:
        passes_source = "the explored cells"
        k = replay.knowledge
        explored = k.explored(replay.frames - 1) if k is not None else np.zeros(shape, dtype=bool)
        passes = explored.astype(np.int64)
        if k is None:
            notes.append("no knowledge in this recording: every free cell counted unsearched")
        if replay.kind == "recording" and replay.summary is None:
            notes.append("no summary.json (the recording was cut off before it): passes from the explored cells")
    rest = residual(prior, passes, pod)
    if gaps_min is None and pod == 1.0:
        left = rest > 0
    else:
        threshold = DEFAULT_GAPS_MIN if gaps_min is None else gaps_min
        left = density(prior, passes, pod, free) > threshold
    left &= free
    out = Gaps(left, rest, pod, prior_source, passes_source, notes=notes)
    out.gaps = _polygons(replay, left, rest)
    return out


def _prior_event(replay: Replay) -> tuple[str, dict] | None:
    """The first `prior` line of events.jsonl, read here rather than from the checked lines so that a bad one
    is refused by name instead of skipped as damage: (where, line)."""
    if replay.kind != "recording":
        return None
    path = replay.source / "events.jsonl"
    if not path.is_file():
        return None
    raw = read_limited(path, "recording's JSON-lines file", LINES_MAX_BYTES)
    for number, line in enumerate(raw.split(b"\n"), start=1):
        if b'"prior"' not in line:
            continue
        try:
            obj = json.loads(line)
        except (ValueError, RecursionError):
            continue  # the loader lists it as damage
        if isinstance(obj, dict) and obj.get("event") == PRIOR_EVENT:
            return f"{path} line {number}: the prior event", obj
    return None


def _grid_numbers(value: object, shape: tuple[int, int], kinds: tuple[type, ...]) -> str | None:
    """Why `value` is not W lists of H numbers of `kinds` (None: it is)."""
    w, h = shape
    if not isinstance(value, list) or len(value) != w:
        n = f"{len(value)} lists" if isinstance(value, list) else type(value).__name__
        return f"has {n}, not the grid's {w} (one list of {h} per x)"
    for x, column in enumerate(value):
        if not isinstance(column, list) or len(column) != h:
            n = f"{len(column)} entries" if isinstance(column, list) else f"a {type(column).__name__}"
            return f"[{x}] has {n}, not the grid's {h}"
        if not all(type(v) in kinds for v in column):
            y = next(y for y, v in enumerate(column) if type(v) not in kinds)
            return f"[{x}][{y}] is {json.dumps(column[y])[:40]}, not {'an int' if kinds == (int,) else 'a number'}"
    return None


def _prior_from_event(where: str, obj: dict, shape: tuple[int, int], free: np.ndarray) -> tuple[np.ndarray, float]:
    value = obj.get("pod")
    pod = float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan
    if not (math.isfinite(pod) and 0.0 < pod <= 1.0):
        raise InputError(f"{where}: pod {json.dumps(value)[:40]} is not a probability of detection in (0, 1]")
    why = _grid_numbers(obj.get("weights"), shape, (int, float))
    if why is not None:
        raise InputError(f"{where}: weights {why}; record the prior on the grid the mission flew")
    weights = np.asarray(obj["weights"], dtype=np.float64)
    if not np.isfinite(weights).all():
        x, y = np.argwhere(~np.isfinite(weights))[0]
        raise InputError(f"{where}: weights[{x}][{y}] is {weights[x, y]}; every weight must be a finite number >= 0")
    if (weights < 0).any():
        x, y = np.argwhere(weights < 0)[0]
        raise InputError(f"{where}: weights[{x}][{y}] is {weights[x, y]:g}; every weight must be a number >= 0")
    return normalise_prior(weights, free, name=f"{where}: weights"), check_pod(pod)


def _summary_passes(replay: Replay, shape: tuple[int, int]) -> np.ndarray | None:
    summary = replay.summary
    if summary is None or "passes" not in summary:
        return None
    value = summary["passes"]
    why = _grid_numbers(value, shape, (int,))
    if why is not None:
        raise InputError(f"{replay.source / 'summary.json'}: passes {why}; passes are W lists of H pass counts")
    passes = np.asarray(value, dtype=np.int64)
    if (passes < 0).any():
        x, y = np.argwhere(passes < 0)[0]
        raise InputError(f"{replay.source / 'summary.json'}: passes[{x}][{y}] is {passes[x, y]}; counts are >= 0")
    return passes


def _polygons(replay: Replay, left: np.ndarray, rest: np.ndarray) -> list[Gap]:
    """The cells left merged into lon/lat polygons, most probable first."""
    if not left.any():
        return []
    g = replay.grid
    # each column's runs of cells left as one rectangle: the same union as the squares, far fewer of them
    padded = np.pad(left, ((0, 0), (1, 1))).astype(np.int8)
    edges = np.diff(padded, axis=1)
    xs, y0 = np.nonzero(edges == 1)
    _, y1 = np.nonzero(edges == -1)
    union = shapely.union_all(shapely.box(xs, y0, xs + 1, y1))
    polys = list(shapely.simplify(list(union.geoms) if hasattr(union, "geoms") else [union], 0))  # collinear vertices
    # a 4-connected group of cells is one polygon: found by one of its cells' centres
    labels, count = ndimage.label(left)
    index = np.arange(1, count + 1)
    first = ndimage.minimum_position(np.arange(labels.size).reshape(labels.shape), labels, index)
    centres = shapely.points([(x + 0.5, y + 0.5) for x, y in first])
    which = np.full(count, -1)
    found, tree_index = shapely.STRtree(polys).query(centres, predicate="within")
    which[found] = tree_index
    sizes = ndimage.sum_labels(left, labels, index)
    mass = ndimage.sum_labels(rest, labels, index)
    cells = np.bincount(which, weights=sizes, minlength=len(polys))
    probability = np.bincount(which, weights=mass, minlength=len(polys))

    def to_lonlat(xy: np.ndarray) -> np.ndarray:
        e, n = g.grid_to_metres(xy[:, 0], xy[:, 1])
        lon, lat = g.projection.to_lonlat(e, n)
        return np.round(np.column_stack([lon, lat]), DECIMALS)

    out = [
        Gap(orient(shapely.transform(p, to_lonlat), 1.0), int(c), float(p.area) * g.cell * g.cell, float(m))
        for p, c, m in zip(polys, cells, probability)
    ]
    return sorted(out, key=lambda gap: -gap.probability)


def _rings(p: Polygon) -> list[list[list[float]]]:
    return [[[x, y] for x, y in ring.coords] for ring in (p.exterior, *p.interiors)]


def _collection(features: list[dict]) -> str:
    return json.dumps({"type": "FeatureCollection", "features": features}) + "\n"


def write_gaps(gaps: Gaps, name: str, out: Path) -> list[Path]:
    """gaps.geojson, gaps.kml and gaps.prior.geojson in `out` (empty collections when nothing is left)."""
    total = sum(gap.probability for gap in gaps.gaps)
    features, prior = [], []
    for gap in gaps.gaps:
        geometry = {"type": "Polygon", "coordinates": _rings(gap.polygon)}
        properties = {"probability": gap.probability, "cells": gap.cells, "area_m2": round(gap.area_m2, 2)}
        features.append({"type": "Feature", "geometry": geometry, "properties": properties})
        share = gap.probability / total if total > 0 else 1.0 / len(gaps.gaps)
        prior.append({"type": "Feature", "geometry": geometry, "properties": {"probability": share}})
    paths = [out / "gaps.geojson", out / "gaps.kml", out / "gaps.prior.geojson"]
    paths[0].write_text(_collection(features), encoding="utf-8")
    _write_kml(gaps, name, paths[1])
    paths[2].write_text(_collection(prior), encoding="utf-8")
    return paths


def _write_kml(gaps: Gaps, name: str, path: Path) -> None:
    ET.register_namespace("", KML)
    k = f"{{{KML}}}"
    kml = ET.Element(f"{k}kml")
    doc = ET.SubElement(kml, f"{k}Document")
    ET.SubElement(doc, f"{k}name").text = printable(f"{name}: gaps")  # XML holds no control characters
    style = ET.SubElement(doc, f"{k}Style", id="gap")
    ET.SubElement(ET.SubElement(style, f"{k}LineStyle"), f"{k}color").text = "ff0000ff"
    ET.SubElement(ET.SubElement(style, f"{k}PolyStyle"), f"{k}color").text = "400000ff"
    for i, gap in enumerate(gaps.gaps):
        mark = ET.SubElement(doc, f"{k}Placemark")
        ET.SubElement(mark, f"{k}name").text = f"gap {i + 1}: {gap.probability:.4f}"
        ET.SubElement(mark, f"{k}styleUrl").text = "#gap"
        data = ET.SubElement(mark, f"{k}ExtendedData")
        for key, value in (("probability", repr(gap.probability)), ("cells", str(gap.cells))):
            ET.SubElement(ET.SubElement(data, f"{k}Data", name=key), f"{k}value").text = value
        ET.SubElement(ET.SubElement(data, f"{k}Data", name="area_m2"), f"{k}value").text = f"{gap.area_m2:.2f}"
        poly = ET.SubElement(mark, f"{k}Polygon")
        for j, ring in enumerate(_rings(gap.polygon)):
            boundary = ET.SubElement(poly, f"{k}{'outerBoundaryIs' if j == 0 else 'innerBoundaryIs'}")
            coords = " ".join(f"{x:.{DECIMALS}f},{y:.{DECIMALS}f}" for x, y in ring)
            ET.SubElement(ET.SubElement(boundary, f"{k}LinearRing"), f"{k}coordinates").text = coords
    ET.ElementTree(kml).write(path, encoding="utf-8", xml_declaration=True)
