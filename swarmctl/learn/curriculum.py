"""Training on many worlds: a curriculum of stages from small maps to large ones.

A curriculum is a list of `Stage`s, each until a fraction of the training's episodes; every training
round (the P parallel episodes) draws one world from the stage it falls in: the map's sides, the
number of vehicles and targets, the scenario (sparse, or clusters), the obstacles (none, the paper's
rectangles, or a crop of a real city: swarmctl.learn.city_maps) and the episode length, long enough
to cover the map. A round's draw depends only on (seed, round), so an interrupted run resumes on the
same worlds. The observation settings (window, variant, rho, fov, ...) come from the base WorldConfig
and do not change: one network serves every map.

`CURRICULA["city"]` is the one `models/city.pt` is trained with; `held_out_worlds` are the fixed
worlds the trainer evaluates on (never the Chicago Loop: that is the unseen city of the judgement).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from swarmctl.errors import ScenarioError
from swarmctl.world.config import WorldConfig
from swarmctl.world.scenario import generate_scenario


@dataclass(frozen=True)
class Stage:
    """The worlds of a part of training (ranges are inclusive; probabilities of the obstacle kinds)."""

    until: float  # training progress (0..1] at which the stage ends
    sides: tuple[int, int] = (20, 20)  # map side range (cells)
    aspect: float = 1.0  # the longer side is at most this times the shorter one
    uavs: tuple[int, int] = (2, 3)
    targets_per_uav: tuple[float, float] = (1.0, 2.0)
    clusters: tuple[int, int] = (1, 4)
    sparse: float = 0.4  # probability of the sparse scenario (else clusters)
    rectangles: float = 0.3  # probability of the paper's rectangles (eta in 0.05..0.15)
    city: float = 0.3  # probability of a city crop (5-20 % blocked)
    steps: tuple[int, int] = (50, 300)  # bounds of the episode length (else: enough to cover the map)


@dataclass
class World:
    """One round's world: its config, its fixed map (None: the config's own obstacles) and length."""

    cfg: WorldConfig
    blocked: np.ndarray | None
    steps: int
    name: str = ""


CURRICULA: dict[str, list[Stage]] = {
    "city": [
        Stage(0.15, sides=(20, 24), uavs=(2, 3), rectangles=0.5, city=0.2, steps=(50, 120)),
        Stage(0.40, sides=(20, 40), aspect=1.5, uavs=(2, 6), steps=(50, 200)),
        Stage(0.70, sides=(24, 56), aspect=1.5, uavs=(2, 10), steps=(60, 300)),
        Stage(1.00, sides=(20, 64), aspect=1.5, uavs=(2, 12), steps=(50, 300)),
    ],
    # a few seconds of training, for the tests and the tools' fast modes
    "smoke": [Stage(0.5, sides=(10, 12), uavs=(2, 2), steps=(20, 30)), Stage(1.0, sides=(10, 16), uavs=(2, 3))],
}


def curriculum_side(name: str) -> int:
    """The largest map side a curriculum's worlds have (held-out worlds included)."""
    return max(max(s.sides[1] for s in CURRICULA[name]), 50 if name == "city" else 12)


def cover_steps(width: int, height: int, uavs: int, fov: float) -> int:
    """Joint steps for `uavs` vehicles to sweep a width x height map (a disc of 2 fov + 1 cells wide
    a step each), with half again as many to spare."""
    return int(np.ceil(1.5 * width * height / (uavs * (2 * fov + 1))))


class Curriculum:
    """Draws each round's world from the stages (see the module docstring)."""

    def __init__(self, stages: list[Stage], base: WorldConfig, seed: int, city_maps=None):
        if not stages or stages[-1].until < 1.0:
            raise ValueError("a curriculum's last stage must run until 1.0")
        self.stages, self.base, self.seed = stages, base, int(seed)
        self._city = city_maps

    @property
    def city(self):
        if self._city is None:
            from swarmctl.learn.city_maps import CityMaps

            self._city = CityMaps.load()
        return self._city

    def stage(self, progress: float) -> Stage:
        return next(s for s in self.stages if progress < s.until or s is self.stages[-1])

    def world(self, round_index: int, progress: float, attempt: int = 0) -> World:
        """The world of training round `round_index` (negative: the replay's prefill) at `progress` (0..1);
        `attempt` > 0 draws another one (when the first cannot hold its episodes)."""
        kind, index = (0, int(round_index)) if round_index >= 0 else (1, -int(round_index))
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, index, kind, int(attempt), 0xC0C0]))
        stage = self.stage(progress)
        for _ in range(20):
            try:
                return self._draw(rng, stage)
            except ScenarioError:
                continue  # a draw that cannot hold its targets or vehicles: draw again
        return World(replace(self.base, map_size=20, uavs=2, targets=4, obstacles=0.0), None, 40, "fallback")

    def _draw(self, rng: np.random.Generator, s: Stage) -> World:
        side = int(rng.integers(s.sides[0], s.sides[1] + 1))
        other = int(np.clip(round(side * rng.uniform(1.0 / s.aspect, s.aspect)), s.sides[0], s.sides[1]))
        width, height = (side, other) if rng.random() < 0.5 else (other, side)
        uavs = int(rng.integers(s.uavs[0], s.uavs[1] + 1))
        targets = max(uavs, int(round(uavs * rng.uniform(*s.targets_per_uav))))
        sparse = rng.random() < s.sparse
        clusters = 1 if sparse else int(rng.integers(s.clusters[0], min(s.clusters[1], targets) + 1))
        kind = rng.choice(3, p=_normalised([1.0 - s.rectangles - s.city, s.rectangles, s.city]))
        blocked, eta = None, 0.0
        if kind == 2:
            blocked = self.city.sample(rng, width, height, float(rng.uniform(0.05, 0.20)))
        elif kind == 1 or width != height:  # rectangular maps are fixed maps (the generator draws squares)
            eta = float(rng.uniform(0.05, 0.15)) if kind == 1 else 0.0
            blocked = _rectangles(rng, width, height, eta) if width != height else None
        cfg = replace(
            self.base,
            scenario="sparse" if sparse else "cluster",
            map_size=max(width, height),
            uavs=uavs,
            targets=targets,
            clusters=clusters,
            obstacles=eta if blocked is None else 0.0,
        )
        steps = int(np.clip(cover_steps(width, height, uavs, cfg.fov), *s.steps))
        name = f"{width}x{height} {cfg.scenario}{'' if sparse else f'/{clusters}'} U{uavs} K{targets} " + (
            "city" if kind == 2 else f"eta {eta:.2f}" if kind == 1 else "open"
        )
        if blocked is not None:
            _check_room(blocked, cfg)
        generate_scenario(cfg, self.seed, 0, blocked)  # ScenarioError when its targets and starts do not fit
        return World(cfg, blocked, steps, name)


def held_out_worlds(base: WorldConfig, curriculum: str = "city") -> list[World]:
    """The fixed worlds a curriculum's trainer evaluates on (none is the Chicago Loop)."""
    from swarmctl.learn.city_maps import CityMaps

    if curriculum == "smoke":
        return [World(replace(base, scenario="cluster", map_size=12, uavs=2, targets=3), None, 30, "12x12 U2")]

    crop = CityMaps.load().sample(np.random.default_rng(2026), 50, 50, 0.12)
    return [
        World(
            replace(base, scenario="cluster", map_size=20, uavs=2, targets=4, clusters=1), None, 40, "20x20 cluster U2"
        ),
        World(
            replace(base, scenario="cluster", map_size=20, uavs=3, targets=4, obstacles=0.1),
            None,
            40,
            "20x20 obstacles U3",
        ),
        World(
            replace(base, scenario="cluster", map_size=50, uavs=10, targets=16, clusters=4, obstacles=0.1),
            None,
            100,
            "50x50 U10 K16/4",
        ),
        World(
            replace(base, scenario="sparse", map_size=50, uavs=3, targets=3, clusters=1),
            crop,
            300,
            "city crop 50x50 U3 K3",
        ),
    ]


def _normalised(p: list[float]) -> np.ndarray:
    a = np.clip(np.asarray(p, dtype=float), 0.0, None)
    return a / a.sum()


def _rectangles(rng: np.random.Generator, width: int, height: int, eta: float) -> np.ndarray:
    """Rectangles of sides 1..4 at random until eta of a width x height map is covered (for rectangular
    maps; square ones use the paper's generator through WorldConfig.obstacles)."""
    blocked = np.zeros((width, height), dtype=bool)
    while blocked.mean() < eta:
        w, h = int(rng.integers(1, 5)), int(rng.integers(1, 5))
        x, y = int(rng.integers(0, max(1, width - w + 1))), int(rng.integers(0, max(1, height - h + 1)))
        blocked[x : x + w, y : y + h] = True
    return blocked


def _check_room(blocked: np.ndarray, cfg: WorldConfig) -> None:
    from swarmctl.world.paths import largest_free_region

    room = int(largest_free_region(blocked).sum())
    if room < 4 * (cfg.targets + cfg.uavs):
        raise ScenarioError("the map's free region is too small for the draw")
