"""Training maps cut from a real city: building footprints rasterised at 10 m cells, cropped, turned.

The big-map curriculum (swarmctl.learn.curriculum) trains on obstacles that look like a city's, not
only on the paper's rectangles. The footprints (OpenStreetMap; missions/data/
helsinki_centre_osm_buildings.geojson by default) are rasterised once, at several rotations, into the
tallest building per cell; a map is a random crop of one raster, flipped or turned by quarter turns,
whose cells block from the height threshold that blocks the fraction closest to a chosen one (5-20 % in
the curriculum): at the flight altitude of 40 m almost no building of the centre blocks, and
the threshold stands for flying lower or for no-fly rules. Buildings with no height in the data get
one drawn from the heights that are known (seeded per building, so every run rasterises the same).
The Chicago Loop is held out: it is the unseen city the model is judged on.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import shapely
from shapely import affinity

from swarmctl.geo.buildings import load_buildings
from swarmctl.geo.projection import LocalProjection

ROOT = Path(__file__).resolve().parent.parent.parent
DEFAULT_CITY = ROOT / "missions" / "data" / "helsinki_centre_osm_buildings.geojson"
ROTATIONS = (0.0, 22.5, 45.0, 67.5)  # degrees; quarter turns and flips come on top when cropping


def height_rasters(path: Path = DEFAULT_CITY, cell: float = 10.0, rotations=ROTATIONS) -> list[np.ndarray]:
    """The tallest building per cell (metres, 0 where none), one (W, H) raster per rotation."""
    bset = load_buildings(path)
    known = np.array([b.height for b in bset.buildings if b.height is not None], dtype=float)
    rng = np.random.default_rng(0xC17)
    heights = np.array(
        [b.height if b.height is not None else float(rng.choice(known)) for b in bset.buildings], dtype=float
    )
    lonlat = shapely.GeometryCollection([b.geometry for b in bset.buildings])
    proj = LocalProjection.centred_on(lonlat.bounds)
    feet = np.array([proj.geometry_to_metres(b.geometry) for b in bset.buildings])
    rasters = []
    for angle in rotations:
        turned = np.array([affinity.rotate(f, angle, origin=(0.0, 0.0)) for f in feet])
        x0, y0, x1, y1 = shapely.GeometryCollection(list(turned)).bounds
        w, h = int(np.ceil((x1 - x0) / cell)), int(np.ceil((y1 - y0) / cell))
        cx, cy = np.meshgrid(np.arange(w), np.arange(h), indexing="ij")
        boxes = shapely.box(
            x0 + cx.ravel() * cell, y0 + cy.ravel() * cell, x0 + (cx.ravel() + 1) * cell, y0 + (cy.ravel() + 1) * cell
        )
        cells, which = shapely.STRtree(turned).query(boxes, predicate="intersects")
        overlap = shapely.area(shapely.intersection(boxes[cells], turned[which])) > 1e-6 * cell * cell
        raster = np.zeros(w * h)
        np.maximum.at(raster, cells[overlap], heights[which[overlap]])
        rasters.append(raster.reshape(w, h))
    return rasters


class CityMaps:
    """Random blocked-cell maps from a city's height rasters."""

    def __init__(self, rasters: list[np.ndarray]):
        self.rasters = rasters

    @classmethod
    def load(cls, path: Path = DEFAULT_CITY, cell: float = 10.0) -> CityMaps:
        return cls(height_rasters(path, cell))

    def sample(self, rng: np.random.Generator, width: int, height: int, fraction: float) -> np.ndarray:
        """A (width, height) bool map: a random crop, turned and flipped, blocking its tallest cells until
        about `fraction` of them are blocked. The crop is taken where buildings are (the raster's bounding
        box is mostly empty at its corners)."""
        raster = self.rasters[int(rng.integers(len(self.rasters)))]
        turns = int(rng.integers(4))
        raster = np.rot90(raster, turns)
        if rng.random() < 0.5:
            raster = raster[::-1]
        w, h = raster.shape
        if width > w or height > h:  # a map bigger than the city: the city in the middle, open around it
            padded = np.zeros((max(w, width), max(h, height)))
            ox, oy = (padded.shape[0] - w) // 2, (padded.shape[1] - h) // 2
            padded[ox : ox + w, oy : oy + h] = raster
            raster, (w, h) = padded, padded.shape
        best, best_cover = None, -1.0
        for _ in range(8):  # prefer crops with buildings in them
            x, y = int(rng.integers(w - width + 1)), int(rng.integers(h - height + 1))
            crop = raster[x : x + width, y : y + height]
            cover = float((crop > 0).mean())
            if cover > best_cover:
                best, best_cover = crop, cover
                if cover >= 2 * fraction:
                    break
        assert best is not None  # the first crop's cover beats -1
        crop = best
        built = crop[crop > 0]
        if built.size == 0:
            return np.zeros((width, height), dtype=bool)
        levels = np.unique(built)  # heights come in steps (levels x 4 m): block from the closest level
        shares = (crop[None] >= levels[:, None, None]).mean(axis=(1, 2))
        return crop >= levels[int(np.argmin(np.abs(shares - fraction)))]
