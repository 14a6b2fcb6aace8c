"""truth.json: what the simulator hid, written beside a demo recording for the replay's true-map panel.

The controller never reads it (it learns about targets only from detector reports). Real missions have
no truth file, and their replays no true-map panel. Format (JSON object):

    format   "swarmctl-truth"          version  1
    seed     the demo's --seed          grid     [W, H] cells
    targets  [[x, y], ...] hidden target cells
    latlon   [[lat, lon], ...] their centres (degrees), in the order of targets
    starts   [[x, y], ...] launch cells, in vehicle order

The true value map is `swarmctl.world.scenario.value_map(targets, W, H)` and the obstacles are the
grid's blocked cells, exactly as the simulated detectors report them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from swarmctl.bounds import INPUT_MAX_BYTES, load_json
from swarmctl.errors import InputError

TRUTH_FILE = "truth.json"
TRUTH_FORMAT = "swarmctl-truth"
TRUTH_VERSION = 1


@dataclass
class Truth:
    """The hidden scenario of a simulated mission."""

    seed: int
    width: int
    height: int
    targets: np.ndarray  # (K, 2) cells
    starts: np.ndarray  # (U, 2) cells

    def value_map(self) -> np.ndarray:
        """phi of every cell, (W, H) float32, as the simulated detectors report it."""
        from swarmctl.world.scenario import value_map

        if not len(self.targets):
            return np.zeros((self.width, self.height), dtype=np.float32)
        return value_map(self.targets, self.width, self.height)


def write_truth(folder: str | Path, swarm: Any, seed: int) -> Path:
    """Write truth.json for a SimSwarm's hidden targets (and launch cells) into the recording folder."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    grid, targets = swarm.grid, np.asarray(swarm.targets, dtype=np.int64).reshape(-1, 2)
    body = {
        "format": TRUTH_FORMAT,
        "version": TRUTH_VERSION,
        "seed": int(seed),
        "grid": [grid.width, grid.height],
        "targets": targets.tolist(),
        "latlon": [[round(v, 7) for v in grid.cell_to_latlon(int(x), int(y))] for x, y in targets],
        "starts": [[int(x), int(y)] for x, y in swarm.starts],
    }
    path = folder / TRUTH_FILE
    path.write_text(json.dumps(body, indent=1) + "\n", encoding="utf-8")
    return path


def load_truth(path: str | Path, width: int, height: int) -> Truth:
    """Read truth.json for a width x height grid; InputError naming the file and field when it is bad."""
    path = Path(path)
    fix = "delete it to replay without the true map"
    body = load_json(path, "truth", INPUT_MAX_BYTES, fix)
    if not isinstance(body, dict) or body.get("format") != TRUTH_FORMAT or body.get("version") != TRUTH_VERSION:
        raise InputError(f"{path}: not a {TRUTH_FORMAT} version {TRUTH_VERSION} file; {fix}")
    if body.get("grid") != [width, height]:
        raise InputError(f"{path}: grid {body.get('grid')!r} is not the recording's [{width}, {height}]; {fix}")
    out = {}
    for key in ("targets", "starts"):
        try:
            cells = np.asarray(body.get(key, []), dtype=np.int64).reshape(-1, 2)
        except (TypeError, ValueError):
            raise InputError(f"{path}: {key} is not a list of [x, y] cells; {fix}") from None
        if len(cells) and ((cells < 0).any() or (cells[:, 0] >= width).any() or (cells[:, 1] >= height).any()):
            raise InputError(f"{path}: {key} has cells outside the {width} x {height} grid; {fix}")
        out[key] = cells
    seed = body.get("seed")
    if not isinstance(seed, int) or isinstance(seed, bool):
        raise InputError(f"{path}: seed {seed!r} is not an integer; {fix}")
    return Truth(seed, width, height, out["targets"], out["starts"])
