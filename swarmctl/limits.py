"""Limits shared by layers that must not import each other (the world and the geo package), with no
imports of their own so that anything may read them at no cost."""

MAX_GRID_SIDE = 4_000  # cells along either side, of a grid file and of a simulated map (WorldConfig.map_size)
MAX_CELL_M = 10_000.0  # a cell's side in metres at most, of a grid file and of WorldConfig.cell_size
