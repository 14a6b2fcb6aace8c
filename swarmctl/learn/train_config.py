"""The trainer's hyperparameters (`TrainConfig`), kept apart from swarmctl.learn.ddql so that the
`swarmctl` command reads them without loading torch.

A field `swarmctl train` sets carries its option's help text, bounds and choices in its metadata;
swarmctl.cli_options.options_from makes the option from it, so each default is written here only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from swarmctl.bounds import MAX_THREADS
from swarmctl.learn.curriculum import CURRICULA

EXPLORATIONS = ("softmax", "egreedy")
MAX_STEPS = 100_000  # a test or held-out episode's step limit
MAX_EPISODES = 10_000_000


@dataclass
class TrainConfig:
    episodes: int = field(  # N_e training episodes (the paper's longest run)
        default=3000, metadata=dict(lo=1, hi=MAX_EPISODES, help="Training episodes N_e.")
    )
    parallel_envs: int = field(  # episodes stepped together; P * U samples per joint step
        default=16, metadata=dict(option="--parallel", lo=1, hi=4096, help="Episodes stepped together.")
    )
    episode_lengths: tuple[int, int] = (50, 150)  # alternating training-episode lengths (paper)
    prefill_episodes: int = field(  # random-policy episodes in the replay before training (paper)
        default=1000, metadata=dict(option="--prefill", lo=0, hi=1_000_000, help="Random episodes in the replay first.")
    )
    replay_capacity: int = field(  # samples (vehicle transitions)
        default=100_000, metadata=dict(option="--replay", lo=1, help="Replay capacity.")
    )
    batch_size: int = field(default=64, metadata=dict(lo=1, hi=65536))
    updates_per_step: float = field(  # gradient steps per joint step of the P parallel episodes
        default=1.0,
        metadata=dict(lo=0, hi=64, above=True, help="Gradient steps per joint step of the parallel episodes."),
    )
    lr: float = field(default=5e-4, metadata=dict(lo=0, hi=1, above=True, help="RAdam learning rate."))
    gamma: float = 0.9  # discount (paper)
    target_update_every: int = field(  # n_q, gradient steps between target-network copies
        default=500, metadata=dict(option="--target-every", lo=1, hi=10**9, help="n_q: steps between target copies.")
    )
    double: bool = field(  # double DQN target; False = plain target-network target
        default=True,
        metadata=dict(option="--plain-target", help="Use the plain target-network target, not double DQN."),
    )
    huber: bool = True  # Huber (smooth L1) loss; False = MSE
    max_grad_norm: float = 10.0
    exploration: str = field(default="softmax", metadata=dict(choices=EXPLORATIONS))
    rules: bool = field(  # act under the deployment rules (hover on a free target, no move off the map or into a
        #               known obstacle) while exploring and in the held-out evaluation; False = the paper
        default=False,
        metadata=dict(
            option="--rules/--no-rules",
            help="Explore and evaluate under the deployment rules of ddql:PATH (hover on a free target, no move "
            "off the map or into a known obstacle); --no-rules is the paper.",
        ),
    )
    temperature_start: float = field(  # softmax temperature, annealed linearly ...
        default=1.0,
        metadata=dict(
            option="--temperature",
            pair="temperature_end",
            metavar="START END",
            lo=0,
            hi=1000,
            above=True,
            help="Softmax exploration temperature, annealed linearly over the run.",
        ),
    )
    temperature_end: float = 0.1  # ... to the test-time tau
    epsilon_start: float = field(  # epsilon-greedy, annealed linearly ...
        default=1.0,
        metadata=dict(
            option="--epsilon",
            pair="epsilon_end",
            metavar="START END",
            lo=0,
            hi=1,
            help="Epsilon-greedy exploration, annealed linearly over the run.",
        ),
    )
    epsilon_end: float = 0.0  # ... to 0 by the end (paper)
    eval_every: int = field(  # episodes between held-out evaluations
        default=250, metadata=dict(lo=1, hi=MAX_EPISODES, help="Episodes between evaluations.")
    )
    eval_episodes: int = field(default=200, metadata=dict(lo=1, hi=1_000_000))
    eval_seed: int = 2026  # held-out evaluation episodes (the tables of docs/guide.md use seed 0)
    eval_steps: int = field(
        default=40,
        metadata=dict(
            lo=1,
            hi=MAX_STEPS,
            help="Step limit of the held-out episodes (the paper: 40 on 20 x 20, 100 on big maps).",
        ),
    )
    eval_tau: float = 0.1
    snapshots: tuple[int, ...] = ()  # episode counts at which a copy is kept as NAME.epN.pt (learning curves)
    curriculum: str | None = field(  # train on many worlds (learn.curriculum.CURRICULA), None = the one given
        default=None,
        metadata=dict(
            choices=tuple(sorted(CURRICULA)),
            help="Train on many worlds, small maps to large (swarmctl.learn.curriculum); the world options set "
            "only the observation (window, fov, rho) then.",
        ),
    )
    keep_resume: bool = field(  # at every evaluation, save what --resume needs (the replay too: NAME.replay.pt)
        default=False,
        metadata=dict(
            option="--keep-resume/--no-keep-resume",
            help="At every evaluation save what --resume needs (the replay memory beside --out as "
            "NAME.replay.pt). Default: on with --curriculum or --resume.",
        ),
    )
    threads: int = field(default=2, metadata=dict(lo=1, hi=MAX_THREADS, help="Torch CPU threads."))  # torch CPU threads
    extra: dict = field(default_factory=dict)

    def exploration_value(self, progress: float) -> float:
        """Temperature (softmax) or epsilon (egreedy) at training progress in [0, 1]."""
        if self.exploration == "softmax":
            return self.temperature_start + (self.temperature_end - self.temperature_start) * progress
        return self.epsilon_start + (self.epsilon_end - self.epsilon_start) * progress
