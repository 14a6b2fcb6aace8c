"""Default values of the geo package, kept free of heavy imports so that the CLI loads fast."""

from swarmctl.limits import MAX_CELL_M, MAX_GRID_SIDE  # noqa: F401 - shared with the world (WorldConfig)

DEFAULT_CELL = 10.0  # metres
DEFAULT_ALTITUDE = 40.0  # metres relative to home (the paper's hover altitude)
DEFAULT_MARGIN = 0.0  # metres
DEFAULT_MAX_CELLS = 250_000
MAX_GRID_CELLS = 4_000_000  # the most cells a grid may have (`plan --max-cells` and grid files)
MIN_CELL_M = 0.01  # a cell's side in metres, `plan --cell` and grid files
MIN_ALTITUDE_M = 0.01  # a grid's planning altitude in metres, `plan --altitude` and grid files
MAX_ALTITUDE_M = 10_000.0
CIRCLE_SEGMENTS = 32  # per quarter circle when a circle (a no-fly circle) becomes a polygon
GRID_MAX_BYTES = 64 * 2**20  # a grid file (the mask compresses to a few bytes per hundred cells)
METRES_PER_LEVEL = 4.0  # the paper: 10 stories ~ 40 m
UNKNOWN_RULES = ("block", "ignore")  # buildings without a height; the first is the default
