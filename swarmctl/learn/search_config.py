"""The search recipe's settings (`SearchConfig`) and its curricula (`SEARCH_CURRICULA`), kept apart from
swarmctl.learn.search_recipe so that `swarmctl train-search` reads them without loading torch.

A field the command sets carries its option's help text, bounds and choices in its metadata;
swarmctl.cli_options.options_from makes the option from it, so each default is written here only.

A curriculum is a list of stages, each a few worlds (map, vehicles, targets, obstacles, step limit);
the next stage opens when the student's held-out success on the current one reaches
`advance_share` of the coordinated teacher's on the same episodes (swarmctl.learn.search_recipe).
The Chicago Loop is the unseen city the models are judged on: no stage, world or map file may be it
(`refuse_held_out`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from swarmctl.bounds import MAX_THREADS, SEED_MAX
from swarmctl.errors import InputError
from swarmctl.learn.train_config import MAX_EPISODES

HELD_OUT = "chicago"  # no training, selection or curriculum input may name it
MARGIN_FORMS = ("sum", "max")
TEACHER_TIES = ("one", "all")  # a label: the teacher's tie-broken move, or every move as good as it


def refuse_held_out(text: str, what: str) -> None:
    """InputError when `text` (a name or a path) names the held-out city."""
    if HELD_OUT in str(text).lower():
        raise InputError(
            f"{what} {text!r} names the Chicago Loop, the held-out city the models are judged on: it never "
            "goes into training, selection or a curriculum"
        )


@dataclass(frozen=True)
class StageWorld:
    """One world of a stage: the distribution its training, validation and test episodes come from."""

    name: str
    map_size: int
    uavs: int
    targets: int
    scenario: str = "cluster"
    clusters: int = 1
    obstacles: float = 0.0  # eta of the paper's rectangles
    city: float = 0.0  # > 0: each episode on a crop of the city footprints with about this share blocked
    steps: int = 40  # step limit of its episodes (in training a truncation, never a terminal)

    def __post_init__(self) -> None:
        refuse_held_out(self.name, "a curriculum world")


@dataclass(frozen=True)
class SearchStage:
    name: str
    worlds: tuple[StageWorld, ...]

    def __post_init__(self) -> None:
        refuse_held_out(self.name, "a curriculum stage")
        if not self.worlds:
            raise ValueError(f"stage {self.name!r} has no world")


SEARCH_CURRICULA: dict[str, tuple[SearchStage, ...]] = {
    # the step limits are the paper's test limits (40 on 20 x 20, 100 on big maps) or, where it has
    # none, about twice the coordinated teacher's mean duration (32 x 32: 31 steps; the city: 88)
    "search": (
        SearchStage(
            "20x20 open",
            (
                StageWorld("20x20 cluster U2 K4", 20, 2, 4),
                StageWorld("20x20 cluster U3 K4", 20, 3, 4),
                StageWorld("20x20 sparse U3 K4", 20, 3, 4, scenario="sparse"),
            ),
        ),
        SearchStage("20x20 obstacles", (StageWorld("20x20 cluster U3 K4 eta 0.1", 20, 3, 4, obstacles=0.1),)),
        SearchStage("32x32", (StageWorld("32x32 cluster/2 U4 K8", 32, 4, 8, clusters=2, steps=60),)),
        SearchStage(
            "50x50 U10",
            (StageWorld("50x50 cluster/4 U10 K16 eta 0.1", 50, 10, 16, clusters=4, obstacles=0.1, steps=100),),
        ),
        SearchStage(
            "Helsinki 50x50",
            (StageWorld("Helsinki 50x50 cluster/2 U6 K8", 50, 6, 8, clusters=2, city=0.12, steps=150),),
        ),
    ),
    # seconds of training, for the tests
    "tiny": (
        SearchStage("10x10 open", (StageWorld("10x10 cluster U2 K2", 10, 2, 2, steps=20),)),
        SearchStage("10x10 obstacles", (StageWorld("10x10 cluster U2 K2 eta 0.1", 10, 2, 2, obstacles=0.1, steps=20),)),
    ),
}


@dataclass
class SearchConfig:
    # --- the run ---
    seed: int = field(  # network initialisation, training episodes, replay sampling, exploration draws
        default=0, metadata=dict(lo=0, hi=SEED_MAX, help="Seed: same seed, same machine, same model.")
    )
    episodes: int = field(  # student episodes over the whole curriculum (the teacher's demonstrations not counted)
        default=20_000, metadata=dict(lo=1, hi=MAX_EPISODES, help="Student training episodes, all stages.")
    )
    parallel_envs: int = field(  # episodes stepped together; P x U samples per joint step
        default=16, metadata=dict(option="--parallel", lo=1, hi=4096, help="Episodes stepped together.")
    )
    threads: int = field(default=2, metadata=dict(lo=1, hi=MAX_THREADS, help="Torch CPU threads."))
    # --- the curriculum ---
    curriculum: str = field(
        default="search",
        metadata=dict(choices=tuple(SEARCH_CURRICULA), help="Stages of worlds (swarmctl.learn.search_config)."),
    )
    stages: int = field(  # train on the first N stages only; 0: all of them
        default=0, metadata=dict(lo=0, hi=100, help="Train on the curriculum's first N stages only (0: all).")
    )
    advance_share: float = field(  # the next stage opens at this share of the teacher's validation success
        default=0.8,
        metadata=dict(
            lo=0,
            hi=1,
            help="Open the next stage when the student's validation success reaches this share of the "
            "coordinated teacher's on the same episodes.",
        ),
    )
    current_share: float = field(  # of each batch's demonstration and agent parts, once earlier stages exist
        default=0.5,
        metadata=dict(
            lo=0, hi=1, help="Share of a batch from the current stage; the rest split evenly over earlier stages."
        ),
    )
    city_footprints: str = ""  # building footprints of the city crops; "": Helsinki (learn.city_maps)
    # --- the team reward (shared by every vehicle of an episode) ---
    reward_target: float = field(  # per target the swarm sees for the first time
        default=1.0, metadata=dict(lo=0, hi=100, help="Team reward per target the swarm finds.")
    )
    reward_cell: float = field(  # per free cell the swarm sees for the first time (union over vehicles)
        default=0.01, metadata=dict(lo=0, hi=10, help="Team reward per free cell the swarm newly explores.")
    )
    step_cost: float = field(default=0.05, metadata=dict(lo=0, hi=10, help="Team cost per joint step."))
    success_bonus: float = field(  # on the step that succeeds; success is terminal
        default=10.0, metadata=dict(lo=0, hi=1000, help="Team reward on success (terminal).")
    )
    collision_penalty: float = field(  # per vehicle in a collision
        default=1.0, metadata=dict(lo=0, hi=100, help="Team cost per vehicle in a collision.")
    )
    # --- deep Q-learning from demonstrations (Hester et al., AAAI 2018) ---
    gamma: float = field(default=0.99, metadata=dict(lo=0, hi=1, below=True, help="Discount."))
    n_step: int = field(default=10, metadata=dict(lo=1, hi=1000, help="n of the n-step TD return."))
    nstep_weight: float = field(default=1.0, metadata=dict(lo=0, hi=100, help="Weight of the n-step TD loss."))
    margin: float = field(  # l(a_E, a) for a != a_E in the large-margin loss
        default=0.8, metadata=dict(lo=0, hi=100, help="Margin of the supervised loss on demonstrations.")
    )
    margin_form: str = field(  # learn.search_recipe.margin_loss: "max" is DQfD's, "sum" learns here (its why)
        default="sum",
        metadata=dict(
            choices=MARGIN_FORMS,
            help="The large-margin loss over the other moves: sum of each one's hinge, or DQfD's max.",
        ),
    )
    margin_weight: float = field(default=1.0, metadata=dict(lo=0, hi=100, help="Weight of the supervised loss."))
    teacher_ties: str = field(  # the teacher breaks ties at random: 15-20 % of its labels on 20 x 20 and 50 x 50
        #                         have another move as good, which "one" marks as worse by the margin
        default="one",
        metadata=dict(
            choices=TEACHER_TIES,
            help="What a demonstration labels: the teacher's move (one) or every move as good as it (all); "
            "the margin loss then asks only that the labelled moves lead the others.",
        ),
    )
    l2: float = field(  # Adam's weight decay: the gradient of (l2 / 2) |theta|^2
        default=1e-5, metadata=dict(lo=0, hi=1, help="L2 regularisation.")
    )
    lr: float = field(  # 2.5e-4 imitated the teacher's moves at a third the speed of 1e-3 (35 % against 56 %
        #                     after 800 updates of the supervised loss alone)
        default=1e-3,
        metadata=dict(lo=0, hi=1, above=True, help="Adam learning rate."),
    )
    batch_size: int = field(default=128, metadata=dict(lo=1, hi=65536))
    updates_per_step: float = field(  # gradient steps per joint step of the P parallel episodes
        default=1.0, metadata=dict(lo=0, hi=64, help="Gradient steps per joint step of the parallel episodes.")
    )
    target_update_every: int = field(  # gradient steps between copies of the online network
        default=1000, metadata=dict(option="--target-every", lo=1, hi=10**9, help="Steps between target copies.")
    )
    huber_delta: float = 1.0  # of the TD losses (smooth L1)
    max_grad_norm: float = 10.0
    pretrain_updates: int = field(  # DQfD's pre-training phase: updates on demonstrations only, before acting
        default=2000, metadata=dict(lo=0, hi=10**9, help="Updates on demonstrations only before the student acts.")
    )
    # --- replay: a store per stage for the student, a store per stage for demonstrations ---
    replay_capacity: int = field(  # student samples kept per stage (oldest evicted)
        default=100_000, metadata=dict(option="--replay", lo=1, hi=10**9, help="Student samples kept per stage.")
    )
    demo_episodes: int = field(  # teacher episodes per world, recorded when its stage opens; never evicted
        default=200, metadata=dict(lo=1, hi=1_000_000, help="Teacher demonstration episodes per world.")
    )
    dagger_capacity: int = field(  # teacher-labelled student samples kept per stage (oldest evicted)
        default=50_000, metadata=dict(lo=0, hi=10**9, help="DAgger-labelled samples kept per stage.")
    )
    dagger_every: int = field(  # every N-th student round is labelled by the teacher (0: never)
        default=2, metadata=dict(lo=0, hi=10**6, help="Label every N-th student round with the teacher (0: never).")
    )
    demo_share_start: float = field(  # of each batch from the demonstration stores, annealed linearly ...
        default=0.5,
        metadata=dict(
            option="--demo-share",
            pair="demo_share_end",
            metavar="START END",
            lo=0,
            hi=1,
            help="Share of each batch from the demonstrations, annealed linearly over the run.",
        ),
    )
    demo_share_end: float = 0.1  # ... to this by the end
    # --- exploration: epsilon-greedy among the allowed moves, annealed linearly ... ---
    epsilon_start: float = field(
        default=0.3,
        metadata=dict(
            option="--epsilon",
            pair="epsilon_end",
            metavar="START END",
            lo=0,
            hi=1,
            help="Epsilon-greedy exploration, annealed linearly over the run.",
        ),
    )
    epsilon_end: float = 0.02  # ... to this by the end
    # --- evaluation (swarmctl.learn.evaluate, as `swarmctl eval` runs it) ---
    eval_every: int = field(default=500, metadata=dict(lo=1, hi=MAX_EPISODES, help="Episodes between evaluations."))
    val_episodes: int = field(  # per world; selection and stage opening read them
        default=200, metadata=dict(lo=1, hi=1_000_000, help="Validation episodes per world.")
    )
    val_seed: int = field(default=7919, metadata=dict(lo=0, hi=SEED_MAX, help="Validation episodes' seed."))
    test_episodes: int = field(  # per world, on the test seed, of the selected checkpoint at the end; 0: none
        default=200, metadata=dict(lo=0, hi=1_000_000, help="Test episodes per world at the end (0: none).")
    )
    test_seed: int = field(default=104729, metadata=dict(lo=0, hi=SEED_MAX, help="Test episodes' seed."))
    keep_resume: bool = field(  # at every evaluation, save what --resume needs (the stores: NAME.replay.pt)
        default=True,
        metadata=dict(
            option="--keep-resume/--no-keep-resume",
            help="At every evaluation save what --resume needs (the stores beside --out as NAME.replay.pt).",
        ),
    )

    def __post_init__(self) -> None:
        if self.curriculum not in SEARCH_CURRICULA:
            raise InputError(f"curriculum {self.curriculum!r} is unknown: use one of {', '.join(SEARCH_CURRICULA)}")
        if self.stages > len(SEARCH_CURRICULA[self.curriculum]):
            raise InputError(
                f"--stages {self.stages}: the {self.curriculum} curriculum has "
                f"{len(SEARCH_CURRICULA[self.curriculum])} stages"
            )
        if self.val_seed == self.test_seed:
            raise InputError(f"--val-seed and --test-seed are both {self.val_seed}: selection and report need two")
        if self.city_footprints:
            refuse_held_out(str(Path(self.city_footprints).resolve()), "--city-footprints")

    def curriculum_stages(self) -> tuple[SearchStage, ...]:
        """The stages trained on (the first `stages` of the curriculum, or all)."""
        stages = SEARCH_CURRICULA[self.curriculum]
        return stages[: self.stages] if self.stages else stages

    def epsilon(self, progress: float) -> float:
        """Exploration at training progress in [0, 1]."""
        return self.epsilon_start + (self.epsilon_end - self.epsilon_start) * progress

    def demo_share(self, progress: float) -> float:
        """Share of a batch from the demonstrations at training progress in [0, 1]."""
        return self.demo_share_start + (self.demo_share_end - self.demo_share_start) * progress
