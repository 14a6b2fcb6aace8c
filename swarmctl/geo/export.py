"""`grid.geojson`: every cell as a WGS84 lon/lat polygon with its x, y and blocked flag."""

from __future__ import annotations

import json
from pathlib import Path

from swarmctl.geo.grid import GeoGrid

DECIMALS = 7  # about 1 cm


def grid_geojson_text(grid: GeoGrid) -> str:
    """A FeatureCollection with one Polygon per cell (corners anticlockwise from the south-west one),
    properties {"x", "y", "blocked"}, as compact JSON text.

    Written as text rather than through `json.dumps` of dicts: a 250,000-cell grid takes a second
    instead of ten. Each corner is formatted once and shared by the four cells around it.
    """
    lat, lon = grid.corner_latlon()
    pair = [
        [f"[{lon[i, j]:.{DECIMALS}f},{lat[i, j]:.{DECIMALS}f}]" for j in range(grid.height + 1)]
        for i in range(grid.width + 1)
    ]
    flag = ("false", "true")
    blocked = grid.blocked.tolist()
    parts = []
    for x in range(grid.width):
        left, right, column = pair[x], pair[x + 1], blocked[x]
        for y in range(grid.height):
            parts.append(
                f'{{"type":"Feature","properties":{{"x":{x},"y":{y},"blocked":{flag[column[y]]}}},'
                f'"geometry":{{"type":"Polygon","coordinates":[[{left[y]},{right[y]},{right[y + 1]},'
                f"{left[y + 1]},{left[y]}]]}}}}"
            )
    name = json.dumps(f"{grid.area_name} grid")
    return f'{{"type":"FeatureCollection","name":{name},"features":[\n' + ",\n".join(parts) + "\n]}\n"


def write_grid_geojson(grid: GeoGrid, path: str | Path) -> Path:
    """Write `grid_geojson_text(grid)` to `path`."""
    path = Path(path)
    path.write_text(grid_geojson_text(grid), encoding="utf-8")
    return path
