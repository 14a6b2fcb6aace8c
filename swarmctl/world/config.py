"""World parameters: the paper's defaults, every open choice a documented field.

A field the commands set (`swarmctl eval`, `train`) carries its option's help text, bounds and choices
in its metadata; swarmctl.cli_options.options_from makes the option from it, so each default is
written here only.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Literal, get_args

from swarmctl.errors import ScenarioError
from swarmctl.limits import MAX_CELL_M, MAX_GRID_SIDE
from swarmctl.world.beliefs import PAPER_VARIANT, VARIANT_CHANNELS

SCENARIOS = ("sparse", "cluster", "prior")  # prior: the K targets drawn from the episode's prior (world.prior)
CHANNELS = ("ideal", "none", "model", "fixed")
Finish = Literal["held", "found", "covered"]  # when an episode succeeds (mission files' finish)
FINISHES: tuple[str, ...] = get_args(Finish)
WORLD_FINISHES: tuple[str, ...] = (*FINISHES, "pos")  # WorldConfig.finish: the simulator's also pos
MAX_WINDOW = 256  # the Q-network takes windows of 8..256
MAX_UAVS = 1000
MAX_FOV = 100.0  # cells
MAX_OBSTACLES = 0.4  # the largest obstacle coverage fraction eta
MAX_EXPLORE_REWARD = 10.0


@dataclass(frozen=True)
class WorldConfig:
    """Everything that defines an episode distribution and the world's rules.

    Defaults are the paper's (M = 20, U = 2, K = 4, F = 20, zeta = 3, theta = 1, psi = 0.8).
    """

    scenario: str = field(
        default="cluster",
        metadata=dict(
            choices=SCENARIOS,
            help="Target placement rule: the paper's sparse or cluster, or prior (the targets drawn from the "
            "prior, eval's --prior, uniform without one; no spacing rule).",
        ),
    )
    map_size: int = field(  # M: the grid is M x M
        default=20, metadata=dict(option="--map", lo=1, hi=MAX_GRID_SIDE, help="Map side M.", unit="cells")
    )
    targets: int = field(default=4, metadata=dict(lo=1, help="Targets K."))  # K
    clusters: int = field(  # C: cluster scenario only; > 1 is the multi-cluster extension
        default=1, metadata=dict(lo=1, help="Clusters of targets (cluster scenario; > 1 is multi-cluster).")
    )
    uavs: int = field(  # U
        default=2, metadata=dict(option=("--uavs", "--vehicles"), lo=1, hi=MAX_UAVS, help="Vehicles U.")
    )
    obstacles: float = field(  # eta: fraction of cells covered by rectangular obstacles
        default=0.0,
        metadata=dict(lo=0, hi=MAX_OBSTACLES, help=f"Obstacle coverage fraction eta (0 .. {MAX_OBSTACLES:g})."),
    )
    obstacle_min: int = 1  # h_min: smallest rectangle side (OPEN in the paper)
    obstacle_max: int = 4  # h_max: largest rectangle side (OPEN in the paper)
    d_sparse: float = 8.0  # sparse targets are more than this far apart
    sigma2: float = 1.0  # value-map spread
    phi_cutoff: float = 0.01  # phi below this reads 0
    fov: float = field(  # zeta: sensing disc radius in cells
        default=3.0, metadata=dict(lo=0, hi=MAX_FOV, help="Sensing radius zeta.", unit="cells")
    )
    window: int = field(  # F: observation window side
        default=20, metadata=dict(lo=1, hi=MAX_WINDOW, help="Observation window F.")
    )
    rho: float = 0.2  # obstacle weight in the value channel
    theta: float = 1.0  # invalid-move penalty
    psi: float = 0.8  # collision penalty
    channel: str = field(
        default="ideal",
        metadata=dict(
            choices=CHANNELS,
            help="Knowledge sharing: ideal, none, model (distance-based loss) or fixed (--loss).",
        ),
    )
    loss: float = field(  # packet-loss probability for channel "fixed"
        default=0.0, metadata=dict(lo=0, hi=1, help="Packet-loss probability for --channel fixed.")
    )
    cell_size: float = field(  # metres per cell, for the channel model
        default=10.0, metadata=dict(lo=0, hi=MAX_CELL_M, above=True, help="Metres per cell (channel model).")
    )
    guard: bool = field(  # refuse moves into a cell another vehicle holds or enters (controller's guard)
        default=False,
        metadata=dict(
            option="--guard/--no-guard",
            help="Refuse moves into cells other vehicles hold or enter (the controller's guard).",
        ),
    )
    remove_taken: bool = field(  # observations: targets others sit on leave the value channel (world.taken)
        default=False,
        metadata=dict(
            option="--remove-taken/--keep-taken",
            help="Observations: remove the targets other vehicles sit on from the value channel, "
            "as LA(n) does (--keep-taken is the paper's observation).",
        ),
    )
    variant: str = field(  # observation variant: the paper's window, or "global-local-v1" (+ the whole map)
        default=PAPER_VARIANT,
        metadata=dict(
            choices=tuple(sorted(VARIANT_CHANNELS)),
            help="Observation and network: the paper's window, or global-local-v1 (the window + the whole map pooled).",
        ),
    )
    explore_reward: float = field(  # reward per sensing disc of cells a vehicle newly explores (0: the paper's)
        default=0.0,
        metadata=dict(
            lo=0.0,
            hi=MAX_EXPLORE_REWARD,
            help="Reward per sensing disc of cells a vehicle newly explores (0: the paper's reward).",
        ),
    )
    # success (SearchEnv.step; the reward never reads it): "held" the paper's, every vehicle on a target and no
    # two on one cell; "found" every target in some vehicle's sensing disc so far; "covered" every free cell
    # 4-connected to a start sensed. found and covered need no target per vehicle (K < U is allowed)
    finish: str = field(
        default="held",
        metadata=dict(
            choices=WORLD_FINISHES,
            help="When an episode succeeds: held (the paper's: every vehicle on a target of its own), found "
            "(every target detected), covered (every free cell reachable from the starts sensed) or pos (the "
            "probability of success against the episode's prior reaches --pos-goal). found, covered and pos "
            "accept fewer targets than vehicles; the oracle bound is for held only.",
        ),
    )
    # the detector: a target in a passing vehicle's sensing disc is detected with this probability (world.prior)
    pod: float = field(
        default=1.0,
        metadata=dict(
            lo=0.0,
            hi=1.0,
            above=True,
            help="Probability of detection per pass: a target inside the sensing disc of a vehicle that has just "
            "reached its cell is detected with this probability (1: always, the paper's).",
        ),
    )
    pos_goal: float = field(  # finish pos; every finish reports the step the team's POS reaches it
        default=0.9,
        metadata=dict(
            lo=0.0,
            hi=1.0,
            above=True,
            help="The probability of success (POS, against the episode's prior; uniform without one) that "
            "--finish pos ends at; every finish line reports the step it is reached.",
        ),
    )

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
        if not 0.0 <= self.explore_reward <= MAX_EXPLORE_REWARD:
            raise ScenarioError(f"explore reward {self.explore_reward} must be a number in [0, {MAX_EXPLORE_REWARD:g}]")
        if self.finish not in WORLD_FINISHES:
            raise ScenarioError(f"--finish {self.finish!r} is unknown: use one of {', '.join(WORLD_FINISHES)}")
        if not 0.0 < self.pod <= 1.0:
            raise ScenarioError(f"--pod {self.pod}: the probability of detection must be in (0, 1]")
        if not 0.0 < self.pos_goal <= 1.0:
            raise ScenarioError(f"--pos-goal {self.pos_goal}: the probability of success to reach must be in (0, 1]")
        if self.scenario not in SCENARIOS:
            raise ScenarioError(f"--scenario {self.scenario!r} is unknown: use one of {', '.join(SCENARIOS)}")
        if not 1 <= m <= MAX_GRID_SIDE:
            raise ScenarioError(f"--map {m}: the map side M must be 1..{MAX_GRID_SIDE}")
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
        if not 0.0 <= self.obstacles <= MAX_OBSTACLES:
            raise ScenarioError(f"--obstacles {self.obstacles} cannot be placed: eta must be in [0, {MAX_OBSTACLES:g}]")
        if not 1 <= self.obstacle_min <= self.obstacle_max:
            raise ScenarioError("obstacle sides need 1 <= obstacle_min <= obstacle_max")
        if self.channel not in CHANNELS:
            raise ScenarioError(f"--channel {self.channel!r} is unknown: use one of {', '.join(CHANNELS)}")
        if not 0.0 <= self.loss <= 1.0:
            raise ScenarioError(f"packet loss {self.loss} must be a probability in [0, 1]")
        if not 0 < self.cell_size <= MAX_CELL_M:
            raise ScenarioError(f"--cell-size {self.cell_size}: must be > 0 and at most {MAX_CELL_M:g} metres")
        if not self.sigma2 > 0:
            raise ScenarioError(f"sigma2 = {self.sigma2}: the value-map spread must be > 0")
        if self.targets < self.uavs and self.finish == "held":
            raise ScenarioError(
                f"--targets {self.targets} < --uavs {self.uavs}: success (--finish held) needs a distinct target "
                "for every vehicle; evaluate with --finish found|covered for fewer targets than vehicles"
            )
        cells = m * m
        # Targets need room for their spacing rule: at most one per 2x2 block in the cluster rule (the prior
        # scenario has none: one target per cell).
        max_targets = cells if self.scenario == "prior" else math.ceil(m / 2) ** 2
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

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)
