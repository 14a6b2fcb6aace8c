"""Real areas to cell grids and back.

- `areas`: search areas from GeoJSON, KML and QGroundControl .plan files; `load`: `load_area`, any of them.
- `buildings`: footprints, heights and the rule that makes a building an obstacle.
- `projection`: the local transverse Mercator frame an area is gridded in.
- `grid`: `GeoGrid` (cell <-> lat/lon, the grid file) and `make_grid`.
- `plan_io`, `export`, `preview`: .plan in/out, grid.geojson, preview.png.
- `cli`: the `swarmctl plan` command.

The package root imports nothing heavy, so `swarmctl` starts fast; import the modules you use.
"""
