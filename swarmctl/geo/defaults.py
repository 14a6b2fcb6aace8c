"""Default values of the geo package, kept free of heavy imports so that the CLI loads fast."""

DEFAULT_CELL = 10.0  # metres
DEFAULT_ALTITUDE = 40.0  # metres relative to home (the paper's hover altitude)
DEFAULT_MARGIN = 0.0  # metres
DEFAULT_MAX_CELLS = 250_000
MAX_GRID_CELLS = 4_000_000  # the most cells a grid may have (`plan --max-cells` and grid files)
MAX_GRID_SIDE = 4_000  # cells along either side (swarmctl.world.config.MAX_MAP)
GRID_MAX_BYTES = 64 * 2**20  # a grid file (the mask compresses to a few bytes per hundred cells)
METRES_PER_LEVEL = 4.0  # the paper: 10 stories ~ 40 m
UNKNOWN_RULES = ("block", "ignore")  # buildings without a height; the first is the default
