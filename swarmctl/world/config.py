"""World parameters: the paper's defaults, every open choice a documented field."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from swarmctl.errors import ScenarioError
from swarmctl.world.beliefs import VARIANT_CHANNELS

SCENARIOS = ("sparse", "cluster")
CHANNELS = ("ideal", "none", "model", "fixed")
FINISHES = ("held", "found", "covered")  # when an episode succeeds (WorldConfig.finish)
MAX_MAP = 4000  # cells per side, as a grid file (swarmctl.geo.defaults.MAX_GRID_SIDE)
MAX_WINDOW = 256  # the Q-network takes windows of 8..256
MAX_UAVS = 1000
MAX_FOV = 100.0  # cells
MAX_CELL_SIZE = 10_000.0  # metres


@dataclass(frozen=True)
class WorldConfig:
    """Everything that defines an episode distribution and the world's rules.

    Defaults are the paper's (M = 20, U = 2, K = 4, F = 20, zeta = 3, theta = 1, psi = 0.8).
    """

    scenario: str = "cluster"  # sparse | cluster
    map_size: int = 20  # M: the grid is M x M
    targets: int = 4  # K
    clusters: int = 1  # C: cluster scenario only; > 1 is the multi-cluster extension
    uavs: int = 2  # U
    obstacles: float = 0.0  # eta: fraction of cells covered by rectangular obstacles
    obstacle_min: int = 1  # h_min: smallest rectangle side (OPEN in the paper)
    obstacle_max: int = 4  # h_max: largest rectangle side (OPEN in the paper)
    d_sparse: float = 8.0  # sparse targets are more than this far apart
    sigma2: float = 1.0  # value-map spread
    phi_cutoff: float = 0.01  # phi below this reads 0
    fov: float = 3.0  # zeta: sensing disc radius in cells
    window: int = 20  # F: observation window side
    rho: float = 0.2  # obstacle weight in the value channel
    theta: float = 1.0  # invalid-move penalty
    psi: float = 0.8  # collision penalty
    channel: str = "ideal"  # ideal | none | model | fixed
    loss: float = 0.0  # packet-loss probability for channel "fixed"
    cell_size: float = 10.0  # metres per cell, for the channel model
    guard: bool = False  # refuse moves into a cell another vehicle holds or enters (controller's guard)
    remove_taken: bool = False  # observations: targets others sit on leave the value channel (world.taken)
    variant: str = "venturini2021"  # observation variant: the paper's window, or "global-local-v1" (+ the whole map)
    explore_reward: float = 0.0  # reward per sensing disc of cells a vehicle newly explores (0: the paper's reward)
    # success (SearchEnv.step; the reward never reads it): "held" the paper's, every vehicle on a target and no
    # two on one cell; "found" every target in some vehicle's sensing disc so far; "covered" every free cell
    # 4-connected to a start sensed. found and covered need no target per vehicle (K < U is allowed)
    finish: str = "held"

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise ScenarioError naming the parameter and its limit for any impossible request."""
        m = self.map_size
        for name, value in asdict(self).items():
            if isinstance(value, float) and not math.isfinite(value):
                raise ScenarioError(f"{name} = {value}: must be a finite number")
        if self.variant not in VARIANT_CHANNELS:
            raise ScenarioError(f"variant {self.variant!r} is unknown: use one of {', '.join(VARIANT_CHANNELS)}")
        if not 0.0 <= self.explore_reward <= 10.0:
            raise ScenarioError(f"explore reward {self.explore_reward} must be a number in [0, 10]")
        if self.finish not in FINISHES:
            raise ScenarioError(f"--finish {self.finish!r} is unknown: use one of {', '.join(FINISHES)}")
        if self.scenario not in SCENARIOS:
            raise ScenarioError(f"--scenario {self.scenario!r} is unknown: use one of {', '.join(SCENARIOS)}")
        if not 1 <= m <= MAX_MAP:
            raise ScenarioError(f"--map {m}: the map side M must be 1..{MAX_MAP}")
        if not 1 <= self.window <= MAX_WINDOW:
            raise ScenarioError(f"--window {self.window}: the observation window F must be 1..{MAX_WINDOW}")
        if not 1 <= self.uavs <= MAX_UAVS:
            raise ScenarioError(f"--uavs {self.uavs}: give 1..{MAX_UAVS} vehicles")
        if self.targets < 1:
            raise ScenarioError(f"--targets {self.targets}: at least 1 target is needed")
        if not 1 <= self.clusters <= self.targets:
            raise ScenarioError(f"--clusters {self.clusters} must be between 1 and --targets ({self.targets})")
        if not 0 <= self.fov <= MAX_FOV:
            raise ScenarioError(f"--fov {self.fov}: the sensing radius must be 0..{MAX_FOV:g} cells")
        if not 0.0 <= self.obstacles <= 0.4:
            raise ScenarioError(f"--obstacles {self.obstacles} cannot be placed: eta must be in [0, 0.4]")
        if not 1 <= self.obstacle_min <= self.obstacle_max:
            raise ScenarioError("obstacle sides need 1 <= obstacle_min <= obstacle_max")
        if self.channel not in CHANNELS:
            raise ScenarioError(f"--channel {self.channel!r} is unknown: use one of {', '.join(CHANNELS)}")
        if not 0.0 <= self.loss <= 1.0:
            raise ScenarioError(f"packet loss {self.loss} must be a probability in [0, 1]")
        if not 0 < self.cell_size <= MAX_CELL_SIZE:
            raise ScenarioError(f"--cell-size {self.cell_size}: must be > 0 and at most {MAX_CELL_SIZE:g} metres")
        if not self.sigma2 > 0:
            raise ScenarioError(f"sigma2 = {self.sigma2}: the value-map spread must be > 0")
        if self.targets < self.uavs and self.finish == "held":
            raise ScenarioError(
                f"--targets {self.targets} < --uavs {self.uavs}: success (--finish held) needs a distinct target "
                "for every vehicle; evaluate with --finish found|covered for fewer targets than vehicles"
            )
        cells = m * m
        # Targets need room for their spacing rule: at most one per 2x2 block in the cluster rule.
        max_targets = math.ceil(m / 2) ** 2
        if self.targets > max_targets:
            raise ScenarioError(
                f"--targets {self.targets} do not fit on a {m} x {m} map with spacing > 1: at most {max_targets}"
            )
        free_after_obstacles = int(cells * (1.0 - self.obstacles)) - self.targets
        if self.uavs > free_after_obstacles:
            raise ScenarioError(
                f"--uavs {self.uavs} is larger than the free cells ({max(free_after_obstacles, 0)}) "
                f"of a {m} x {m} map with {self.targets} targets and eta {self.obstacles}"
            )

    def as_dict(self) -> dict:
        return asdict(self)
