"""A search's prior on its grid: where the missing person is likely to be, read from a file.

`[mission] prior = "FILE"` names one of:

- a GeoJSON FeatureCollection of Polygon / MultiPolygon features (WGS84 lon/lat), either each with a
  `probability` property (the chance the person is inside it; they sum to at most 1, and the free cells
  area in no polygon shares what is left evenly) or all with a `weight` property (relative likelihood per unit
  area; cells in no polygon get none). A feature's share goes to the free cells it overlaps in proportion
  to the overlap (shapely, in the grid's cells); a polygon that reaches past the grid gives its whole
  share to the part on it, one wholly outside is refused;
- an `.npz` with an array `prior` of the grid's shape (W, H), indexed [x, y] like every grid array
  (`swarmctl eval --prior` reads the same file);
- a GeoTIFF, only with the rasterio package installed.

Blocked cells get 0 and the result sums to 1 over the free cells (swarmctl.world.prior.normalise_prior).
Every bad input is an InputError naming the file, the feature and the fix.
"""

from __future__ import annotations

import importlib.util
import io
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import shapely
from shapely.geometry import box

from swarmctl.bounds import INPUT_MAX_BYTES, read_limited
from swarmctl.errors import InputError, ScenarioError
from swarmctl.geo.readers import GEOMETRY_ERRORS, geojson_polygons, json_number, read_json, show_json
from swarmctl.world.prior import normalise_prior

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.geo.grid import GeoGrid

PRIOR_NPZ_MAX_BYTES = 256 * 2**20  # a float64 array of the largest grid (4 M cells) is 32 MiB
MAX_WEIGHT = 1e12  # relative weights beyond this are not likelihoods but typing slips
OVERLAP_EPS = 1e-9  # cell areas: less overlap than this is a touch, not a share
PROBABILITY_SLACK = 1e-9  # probabilities summing to 1 + this are 1, as written with rounding
NPZ_FIX = "save it with numpy.savez(FILE, prior=ARRAY), ARRAY of the grid's shape (W, H) indexed [x, y]"


def load_prior(path: Path, grid: GeoGrid) -> np.ndarray:
    """(W, H) float64 the prior `path` gives on `grid`: 0 on blocked cells, summing to 1 (module docstring)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npz":
        weights = _npz_weights(path, grid)
    elif suffix in (".tif", ".tiff"):
        weights = _geotiff_weights(path)
    else:
        weights = _geojson_weights(path, grid)
    try:
        return normalise_prior(weights, ~np.asarray(grid.blocked, dtype=bool), name=str(path))
    except ScenarioError as exc:
        raise InputError(f"{exc}; fix the prior so that some free cell of the grid is likely") from None


def _npz_weights(path: Path, grid: GeoGrid) -> np.ndarray:
    data = read_limited(path, "prior file", PRIOR_NPZ_MAX_BYTES)
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            if "prior" not in npz.files:
                names = ", ".join(npz.files) or "none"
                raise InputError(f"{path}: no array named `prior` (it has: {names}); {NPZ_FIX}")
            arr = np.asarray(npz["prior"])
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise InputError(f"{path}: not a numpy .npz file ({type(exc).__name__}); {NPZ_FIX}") from None
    shape = (grid.width, grid.height)
    if arr.shape != shape:
        raise InputError(f"{path}: `prior` has the shape {arr.shape}, not the grid's {shape}; {NPZ_FIX}")
    if arr.dtype.kind not in "fiub":
        raise InputError(f"{path}: `prior` holds {arr.dtype}, not numbers; {NPZ_FIX}")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise InputError(f"{path}: `prior` has NaN or infinite values; give every cell a finite weight >= 0")
    if (arr < 0).any():
        raise InputError(f"{path}: `prior` has negative values (min {arr.min():g}); give every cell a weight >= 0")
    return arr


def _geotiff_weights(path: Path) -> np.ndarray:
    if importlib.util.find_spec("rasterio") is None:  # optional: not a dependency
        raise InputError(
            f"{path}: a GeoTIFF prior needs the rasterio package, which is not installed; install it, or give the "
            f"prior as an .npz ({NPZ_FIX}) or as GeoJSON polygons with a `probability` each"
        )
    raise InputError(
        f"{path}: GeoTIFF priors are not read yet; give the prior as an .npz ({NPZ_FIX}) or as GeoJSON polygons"
    )


def _geojson_weights(path: Path, grid: GeoGrid) -> np.ndarray:
    obj = read_json(path, "GeoJSON", INPUT_MAX_BYTES)
    fix = "give a FeatureCollection of Polygon features, each with a `probability` (or all with a `weight`)"
    if not isinstance(obj, dict) or obj.get("type") != "FeatureCollection" or not isinstance(obj.get("features"), list):
        raise InputError(f"{path}: not a GeoJSON FeatureCollection; {fix}")
    features = obj["features"]
    if not features:
        raise InputError(f"{path}: the FeatureCollection has no features; {fix}")
    parts: dict[int, list] = {}
    for poly, _props, _label, index in geojson_polygons(obj, path):
        parts.setdefault(index, []).append(poly)
    kind = _value_kind(path, features)
    values = []
    for i, feature in enumerate(features):
        if i not in parts:
            raise InputError(f"{path}: feature {i} has no Polygon or MultiPolygon geometry; {fix}")
        props = feature.get("properties") if isinstance(feature.get("properties"), dict) else {}
        field = f"features[{i}].properties.{kind}"
        v = json_number(props.get(kind), path, f"feature {i}: {field}", f"give a number >= 0 ({kind})")
        if v < 0 or (kind == "probability" and v > 1) or v > MAX_WEIGHT:
            rule = "between 0 and 1" if kind == "probability" else f"between 0 and {MAX_WEIGHT:g}"
            raise InputError(f"{path}: feature {i}: {field} is {show_json(v)}; give a {kind} {rule}")
        values.append(v)
    if kind == "probability" and sum(values) > 1.0 + PROBABILITY_SLACK:
        raise InputError(
            f"{path}: the features' probabilities sum to {sum(values):.6g}, over 1; scale them so that they sum to "
            "at most 1 (what is left goes to the cells in no polygon)"
        )
    free = ~np.asarray(grid.blocked, dtype=bool)
    overlaps = _overlaps(path, grid, parts, len(features))  # (features, W, H) cell areas covered
    if kind == "weight":
        return np.tensordot(np.asarray(values), overlaps, axes=1)
    weights = np.zeros(free.shape, dtype=np.float64)
    for i, (p, overlap) in enumerate(zip(values, overlaps)):
        share = overlap * free
        total = share.sum()
        if total <= OVERLAP_EPS:
            raise InputError(f"{path}: feature {i} covers only blocked cells of the grid; move it onto free cells")
        weights += p * share / total
    # what is left goes to the free cells' area in no polygon, evenly (a cell half covered gets half a share)
    rest = np.where(free, 1.0 - np.clip(overlaps.sum(axis=0), 0.0, 1.0), 0.0)
    left = max(0.0, 1.0 - sum(values))
    if rest.sum() > OVERLAP_EPS and left > 0:
        weights += left * rest / rest.sum()
    return weights


def _value_kind(path: Path, features: list) -> str:
    """The property every feature has: `probability` or `weight`; else an InputError."""
    has = {
        kind: [isinstance(f.get("properties"), dict) and kind in f["properties"] for f in features]
        for kind in ("probability", "weight")
    }
    for kind in ("probability", "weight"):
        if all(has[kind]):
            return kind
    if any(has["probability"]) and any(has["weight"]):
        why = "mixes `probability` and `weight` features"
    else:
        common = "probability" if any(has["probability"]) else "weight"
        why = f"feature {has[common].index(False)} has neither a `probability` nor a `weight` property"
    raise InputError(
        f"{path}: {why}; give every feature a `probability` (the chance the person is inside it) or every "
        "feature a `weight` (relative likelihood per unit area)"
    )


def _overlaps(path: Path, grid: GeoGrid, parts: dict[int, list], count: int) -> np.ndarray:
    """(count, W, H) the area (in cells) of each cell each feature covers."""
    w, h = grid.width, grid.height
    out = np.zeros((count, w, h), dtype=np.float64)
    cx, cy = np.meshgrid(np.arange(w), np.arange(h), indexing="ij")
    boxes = shapely.box(cx.ravel(), cy.ravel(), cx.ravel() + 1, cy.ravel() + 1)
    tree = shapely.STRtree(boxes)
    extent = box(0, 0, w, h)
    for i, polys in sorted(parts.items()):
        try:
            shape = grid.geometry_to_grid(grid.projection.geometry_to_metres(shapely.union_all(polys)))
            if shape.intersection(extent).area <= OVERLAP_EPS:
                raise InputError(
                    f"{path}: feature {i} lies outside the grid ({w} x {h} cells); fix its coordinates or drop it"
                )
            cells = tree.query(shape, predicate="intersects")
            areas = shapely.area(shapely.intersection(boxes[cells], shape))
        except GEOMETRY_ERRORS as exc:
            raise InputError(f"{path}: feature {i}: unusable polygon ({exc}); fix the file") from None
        out[i].ravel()[cells] = areas
    return out
