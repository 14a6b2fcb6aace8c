"""`swarmctl bench`: simulator throughput, decision times against the network's FLOP limit (the paper's
network and the search recipe's scales network), the planners' decision times on the Chicago Loop grid
(the coordinated planner against frontier), the coordinated teacher's labelling rate there, and the
throughput of both trainers (`swarmctl train` and `train-search`) against their FLOP ceilings, all
measured in one run on this machine.

Every time is the median of five rounds (each round at least `seconds` / 5), in CPU time of the
measuring thread (`time.thread_time`): what the work costs, not how long it waited for a core, so a
figure measured on a busy machine is the one an idle machine would give, less what the other work
costs through the shared caches. The FLOP rate is that of a 1,024 x 1,024 float32 matmul on the same
threads and clock, measured in the same run (in rounds alternating with the decision it is set
against, and just before and after the training), so the ratios hold for the machine's state while
their figures were measured; the load average before and after is reported beside them. With more than one thread the
other threads' CPU time is not counted: use `--threads 1` (the default) for the ratios.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import click
import numpy as np

from swarmctl.bounds import MAX_THREADS, real, whole, writable_file
from swarmctl.policy.base import Policy
from swarmctl.policy.lookahead import LookAhead
from swarmctl.world.beliefs import SCALES_VARIANT
from swarmctl.world.config import WorldConfig
from swarmctl.world.env import SearchEnv

ROUNDS = 5
PAPER_OPTIONS = ":taken=keep:hover=no:mask=no"  # the paper's DDQL Soft: the network and softmax alone
# the search recipe's observation and network (`train-search --variant scales-v1 --window 11`) in the
# paper's 20 x 20, 2-vehicle world: only the observation differs from the paper network's decision
SCALES_WORLD = WorldConfig(variant=SCALES_VARIANT, window=11)


CLOCK = time.thread_time  # CPU seconds of this thread (module docstring)


def _median_seconds(fn, seconds: float) -> float:
    """Median over ROUNDS rounds of the CPU time of one call of fn (after one warm-up call; the
    clock is read once per group of calls that take about a millisecond, as reading it costs ~2 us)."""
    start = CLOCK()
    fn()
    group = max(1, min(1000, int(1e-3 / max(CLOCK() - start, 1e-9))))
    per_round, times = seconds / ROUNDS, []
    for _ in range(ROUNDS):
        calls, start = 0, CLOCK()
        while True:
            for _ in range(group):
                fn()
            calls += group
            elapsed = CLOCK() - start
            if elapsed >= per_round:
                break
        times.append(elapsed / calls)
    return statistics.median(times)


def matmul_flops_per_s(seconds: float, n: int = 1024) -> float:
    """float32 FLOP/s of an n x n matmul on torch's current threads: the machine's practical peak."""
    import torch

    a, b = torch.rand(n, n), torch.rand(n, n)
    return 2 * n**3 / _median_seconds(lambda: a @ b, seconds)


def env_throughput(cfg: WorldConfig, batch: int, observations: bool, seconds: float) -> float:
    """Vehicle-steps per second of random joint moves, observations included if asked."""
    env = SearchEnv(cfg, batch=batch, stop_at_success=False, observations=observations)
    env.reset(seed=0)
    actions = np.random.default_rng(0).integers(0, 5, size=(64, batch, cfg.uavs))
    i = iter(range(10**12))
    return batch * cfg.uavs / _median_seconds(lambda: env.step(actions[next(i) % 64]), seconds)


def decision_seconds(policy, batch_episodes: int, seconds: float, world: WorldConfig | None = None) -> float:
    """Time of one decision per vehicle: `policy.act` on fresh beliefs (their lazy maps included) of
    a batch of episodes of `world` (default the paper's: U = 2; five steps in); building the Beliefs
    object itself is not timed."""
    env = SearchEnv(world or WorldConfig(), batch=batch_episodes, observations=False)
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.tile([[1, 2]], (batch_episodes, 1)))
    policy.reset(env.beliefs(), 0)
    policy.act(env.beliefs())  # warm-up
    rounds = [act_seconds(policy, env, seconds / ROUNDS) for _ in range(ROUNDS)]
    return statistics.median(rounds) / (batch_episodes * env.uavs)


def act_seconds(policy, env: SearchEnv, seconds: float) -> float:
    """CPU seconds of one `policy.act` on the env's fresh beliefs (not timed: building them), over at
    least `seconds` of calls."""
    spent, calls = 0.0, 0
    while calls == 0 or spent < seconds:
        beliefs = env.beliefs()
        t0 = CLOCK()
        policy.act(beliefs)
        spent += CLOCK() - t0
        calls += 1
    return spent / calls


def decision_and_matmul(
    policy: Policy, seconds: float, others: Sequence[tuple[Policy, WorldConfig]] = ()
) -> tuple[float, ...]:
    """(matmul FLOP/s, decision_seconds at batch 1, and that of each (policy, world) of `others`),
    measured in ROUNDS alternating rounds, each figure the median of its rounds: the machine's speed
    drifts (the matmul rate of a 2-core AMD EPYC moved between 67 and 97 GFLOP/s from one run to the
    next, a minute apart), so the decisions and the limits they are set against come from the same
    stretch of time."""
    rates: list[float] = []
    decisions: list[list[float]] = [[] for _ in range(1 + len(others))]
    timed: list[tuple[Policy, WorldConfig | None]] = [(policy, None), *others]
    for _ in range(ROUNDS):
        rates.append(matmul_flops_per_s(seconds / ROUNDS))
        for (p, world), out in zip(timed, decisions):
            out.append(decision_seconds(p, 1, seconds / ROUNDS, world))
    return (statistics.median(rates), *(statistics.median(d) for d in decisions))


def decision_figures(paper: Policy, scales: Policy, seconds: float) -> dict[str, float]:
    """The paper network's and the scales network's batch-1 decisions (`ddql:` policies with the same
    options), each against its FLOP limit at the matmul rate, and their ratio, in alternating rounds
    (decision_and_matmul). A decision is one episode's 2 vehicles deciding, divided by 2: per vehicle,
    as the limit (one forward of one observation) is."""
    from swarmctl.policy.qnet import forward_flops, scales_forward_flops

    rate, decision, scales_decision = decision_and_matmul(paper, seconds, [(scales, SCALES_WORLD)])
    return {
        "matmul_gflop_per_s": rate / 1e9,
        "qnet_flop_limit_ms_batch1": 1000.0 * forward_flops(WorldConfig().window) / rate,
        "ddql_decision_ms_batch1": 1000.0 * decision,
        "scales_flop_limit_ms_batch1": 1000.0 * scales_forward_flops(SCALES_WORLD.window) / rate,
        "scales_decision_ms_per_vehicle_batch1": 1000.0 * scales_decision,
        "scales_decision_over_flop_limit": scales_decision * rate / scales_forward_flops(SCALES_WORLD.window),
        "scales_over_paper_decision": scales_decision / decision,
    }


CHICAGO_GRID = Path(__file__).resolve().parents[1] / "missions" / "chicago-loop" / "grid.npz"
PLANNER_SWARMS = (3, 12, 50)  # vehicles on the Chicago Loop grid


def planner_blocked() -> np.ndarray:
    """The Chicago Loop grid's blocked cells (50 x 50, 12 % blocked), or, without the repository's
    missions/ (an installed package), a 50 x 50 map of 10 % rectangles like it."""
    if CHICAGO_GRID.exists():
        from swarmctl.geo.grid import GeoGrid

        return GeoGrid.load(CHICAGO_GRID).blocked.copy()
    env = SearchEnv(WorldConfig(map_size=50, obstacles=0.1), batch=1, observations=False)
    env.reset(seed=0)
    return env.obstacles[0].copy()


def planner_world(blocked: np.ndarray, vehicles: int) -> WorldConfig:
    """The planners' world on `blocked`: as many targets as vehicles, sparse, at least 2 cells apart."""
    w, h = blocked.shape
    return WorldConfig(scenario="sparse", map_size=max(w, h), uavs=vehicles, targets=vehicles, d_sparse=2.0)


def planner_decisions(specs: list[str], vehicles: int, seconds: float, blocked: np.ndarray) -> list[float]:
    """Seconds per vehicle of one batch-1 decision of each planner spec, for `vehicles` vehicles a few
    steps into a sparse search on `blocked`, measured in alternating rounds (the ratios between
    them hold for one stretch of the machine's time)."""
    from swarmctl.policy.registry import make_decider

    env = SearchEnv(planner_world(blocked, vehicles), batch=1, observations=False)
    env.reset(seed=0, blocked=blocked)
    walk = make_decider("frontier:hover=no")
    walk.reset(env.beliefs(), 0)
    for _ in range(8):  # some of the map explored, the swarm spread out
        env.step(walk.act(env.beliefs()))
    policies = [make_decider(s) for s in specs]
    for p in policies:
        p.reset(env.beliefs(), 0)
        p.act(env.beliefs())  # warm-up
    times: list[list[float]] = [[] for _ in specs]
    for _ in range(ROUNDS):
        for p, out in zip(policies, times):
            out.append(act_seconds(p, env, seconds / ROUNDS) / vehicles)
    return [statistics.median(t) for t in times]


LABEL_STEPS = 100  # the search curriculum's step limit on 50 x 50 maps: the teacher's horizon


def coordinated_labels_per_s(blocked: np.ndarray, seconds: float, episodes: int = 16, vehicles: int = 3) -> float:
    """Vehicle-steps per second the coordinated planner decides, as the search recipe's teacher labels
    them: `episodes` episodes of `vehicles` vehicles on `blocked` in the batched simulator, every vehicle
    moving as the planner says, the live episodes decided (as `run_policy` does), the next episodes
    started when all are over or after LABEL_STEPS steps. Only the planner's `act` is timed (the
    beliefs' lazy maps included); the median of ROUNDS rounds, the episodes going on from round to round."""
    from swarmctl.policy.coordinated import CoordinatedPolicy

    env = SearchEnv(planner_world(blocked, vehicles), batch=episodes, observations=False)
    teacher = CoordinatedPolicy()
    teacher.horizon = LABEL_STEPS
    started = 0

    def start() -> None:
        nonlocal started
        env.reset(seed=0, episodes=range(started, started + episodes), blocked=blocked)
        started += episodes
        teacher.reset(env.beliefs(), 0)

    def decide() -> tuple[int, float]:
        """One joint step: (vehicle-steps decided, CPU seconds of the decision)."""
        if env.t >= LABEL_STEPS or env.done.all():
            start()
        live = ~env.done
        beliefs = env.beliefs(None if live.all() else live)
        t0 = CLOCK()
        moves = teacher.act(beliefs)
        spent = CLOCK() - t0
        actions = np.zeros((episodes, vehicles), dtype=np.int64)
        actions[live] = moves
        env.step(actions)
        return moves.size, spent

    start()
    decide()  # warm-up
    rates = []
    for _ in range(ROUNDS):
        labels, spent = 0, 0.0
        while labels == 0 or spent < seconds / ROUNDS:
            n, t = decide()
            labels, spent = labels + n, spent + t
        rates.append(labels / spent)
    return statistics.median(rates)


def ddql_policy(tmp: Path, options: str = ""):
    """`ddql:PATH[options]` on an untrained network of the paper's architecture (weights do not
    change the cost)."""
    from swarmctl.policy.checkpoint import save_checkpoint
    from swarmctl.policy.ddql import make_ddql_policy
    from swarmctl.policy.qnet import QNetwork

    world = WorldConfig()
    path = tmp / "untrained.pt"
    if not path.exists():
        save_checkpoint(path, QNetwork(world.window), world.as_dict(), {}, {})
    return make_ddql_policy(f"ddql:{path}{options}")


def scales_policy(tmp: Path, options: str = ""):
    """`ddql:PATH[options]` on an untrained network of the search recipe's scales variant (window 11)."""
    from swarmctl.policy.checkpoint import save_checkpoint
    from swarmctl.policy.ddql import make_ddql_policy
    from swarmctl.policy.qnet import make_network

    path = tmp / "untrained-scales.pt"
    if not path.exists():
        net = make_network(SCALES_WORLD.variant, SCALES_WORLD.window)
        save_checkpoint(path, net, SCALES_WORLD.as_dict(), {}, {})
    return make_ddql_policy(f"ddql:{path}{options}")


def forward_seconds(policy, rows: int, seconds: float) -> float:
    """Time of the policy's forward pass alone for `rows` observations, per observation."""
    obs = np.random.default_rng(0).random((rows, 3, 20, 20), dtype=np.float32)
    return _median_seconds(lambda: policy.forward(obs), seconds) / rows


def training_figures(threads: int, seconds: float) -> dict:
    """Samples per CPU second of the training loop (2 UAVs, 8 parallel episodes, batch 64, one gradient
    step per joint step; per wall second beside it) and the ceiling the FLOPs allow: per sample, one forward to act plus
    (batch / samples per joint step) x (online forward on o and o', target forward on o', and a
    backward counted as two forwards), at the mean of the matmul rates measured just before and just
    after the training (the machine's speed drifts: decision_and_matmul)."""
    from swarmctl.learn.ddql import TrainConfig, train
    from swarmctl.policy.qnet import forward_flops

    world = WorldConfig()
    rounds = max(2, round(seconds / 2))
    cfg = TrainConfig(
        episodes=8 * rounds,
        parallel_envs=8,
        episode_lengths=(50, 50),
        prefill_episodes=8,
        eval_every=10**9,
        eval_episodes=4,
        eval_steps=2,
        threads=threads,
    )
    before = matmul_flops_per_s(seconds / 2)
    with tempfile.TemporaryDirectory() as tmp:
        meta = train(world, cfg, seed=0, out=Path(tmp) / "bench.pt", progress=False)
    flops_per_s = (before + matmul_flops_per_s(seconds / 2)) / 2
    per_step = cfg.parallel_envs * world.uavs
    flops = forward_flops(world.window) * (1 + cfg.updates_per_step * cfg.batch_size / per_step * 5)
    ceiling = flops_per_s / flops
    return {
        "train_matmul_gflop_per_s": flops_per_s / 1e9,
        "train_samples_per_s": meta["train_samples_per_cpu_s"],  # per CPU second, as every figure here
        "train_samples_per_wall_s": meta["train_samples_per_s"],
        "train_flop_ceiling_samples_per_s": ceiling,
        "train_fraction_of_ceiling": meta["train_samples_per_cpu_s"] / ceiling,
        "train_setting": "2 UAVs, 20 x 20, 8 parallel episodes, batch 64, 1 gradient step per joint step",
    }


SEARCH_FORWARDS_PER_ROW = 7  # a DQfD gradient step per batch row: online on o, online and target on o'1 and
#                               o'n (twin_forward runs a scales network's two one after the other), backward 2


def search_training_figures(
    threads: int, seconds: float, parallel_envs: int = 16, curriculum: str = "search"
) -> dict[str, float | str]:
    """Samples per CPU second of the search recipe's training rounds (per wall second beside it) on its
    first stage, as `train-search --variant scales-v1 --window 11` runs them (SearchTrainer, which
    swarmctl.learn.search_recipe.train drives: the same stage opening, pre-training and rounds; no
    evaluation, nothing written), and the ceiling the FLOPs allow. The stage's opening (the teacher's
    demonstrations, one batch per world, and its validation) and two pre-training updates come first,
    untimed: in so short a run they would outweigh the rounds. Then an even number of rounds, the
    student's and DAgger's in turn, about one per second of `seconds` (two at the default; a round of
    16 episodes is about 1.5 CPU seconds). The ceiling counts what the rounds ran, per sample: the
    student's forwards to act (every vehicle of the P episodes, finished ones included) and the
    gradient steps' batch rows x SEARCH_FORWARDS_PER_ROW forwards, at the mean of the matmul rates
    measured just before and just after the rounds (the accounting of training_figures)."""
    from swarmctl.learn.search_config import SearchConfig
    from swarmctl.learn.search_recipe import SearchTrainer
    from swarmctl.policy.qnet import scales_forward_flops

    rounds = 2 * max(1, round(seconds / 2))
    stage = SearchConfig(curriculum=curriculum).curriculum_stages()[0]
    round_slots = parallel_envs * max(w.uavs * (w.steps + 1) for w in stage.worlds)
    cfg = SearchConfig(
        episodes=parallel_envs * rounds,
        parallel_envs=parallel_envs,
        threads=threads,
        curriculum=curriculum,
        stages=1,
        pretrain_updates=2,
        replay_capacity=round_slots * rounds,
        dagger_capacity=round_slots * rounds,
        demo_episodes=parallel_envs,
        eval_every=10**9,
        val_episodes=1,
        test_episodes=0,
        keep_resume=False,
    )
    with tempfile.TemporaryDirectory() as tmp:
        setup_wall = time.perf_counter()
        run = SearchTrainer(SCALES_WORLD, cfg, Path(tmp) / "bench-search.pt")
        run.open_stage(0)
        for _ in range(cfg.pretrain_updates):
            run.learn(demos_only=True)
        setup_wall = time.perf_counter() - setup_wall
        before = matmul_flops_per_s(seconds / 2)
        samples, updates, act_rows = run.state.samples, run.state.updates, 0
        cpu, wall = CLOCK(), time.perf_counter()
        for _ in range(rounds):
            act_rows += run.collect().actions.size
        cpu, wall = CLOCK() - cpu, time.perf_counter() - wall
        samples, updates = run.state.samples - samples, run.state.updates - updates
    flops_per_s = (before + matmul_flops_per_s(seconds / 2)) / 2
    flops = scales_forward_flops(SCALES_WORLD.window) * (act_rows + updates * cfg.batch_size * SEARCH_FORWARDS_PER_ROW)
    ceiling = flops_per_s / (flops / samples)
    return {
        "search_train_matmul_gflop_per_s": flops_per_s / 1e9,
        "search_train_samples_per_s": samples / cpu,  # per CPU second, as every figure here
        "search_train_samples_per_wall_s": samples / wall,
        "search_train_flop_ceiling_samples_per_s": ceiling,
        "search_train_fraction_of_ceiling": samples / cpu / ceiling,
        "search_train_setup_wall_s": setup_wall,
        "search_train_setting": (
            f"train-search, scales-v1 window 11, {curriculum} stage 1 ({stage.name}: "
            f"{', '.join(w.name for w in stage.worlds)}), {parallel_envs} parallel episodes, batch "
            f"{cfg.batch_size}, {cfg.updates_per_step:g} gradient step per joint step; {rounds} rounds timed "
            f"({samples} samples, {updates} gradient steps), after the untimed stage opening (the teacher's "
            f"demonstrations and validation) and {cfg.pretrain_updates} pre-training updates"
        ),
    }


def cpu_id(cpuinfo: str | None = None) -> dict:
    """The processor as Linux's /proc/cpuinfo (or the text `cpuinfo`) names its first CPU: name, family
    and model numbers, and its widest vector instructions (what a virtual machine's bare "AMD EPYC"
    leaves out, and what the figures depend on); what platform knows of it where there is no such file."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            cpuinfo = ""
    fields: dict[str, str] = {}
    for line in cpuinfo.split("\n\n", 1)[0].splitlines():
        key, sep, value = line.partition(":")
        if sep:
            fields.setdefault(key.strip(), value.strip())
    flags = set(fields.get("flags", "").split())
    isa = [
        name
        for name, flag in (
            ("AVX2", "avx2"),
            ("AVX-512", "avx512f"),
            ("AVX-512 BF16", "avx512_bf16"),
            ("AMX", "amx_tile"),
        )
        if flag in flags
    ]
    family, model = fields.get("cpu family", ""), fields.get("model", "")
    return {
        "name": fields.get("model name") or platform.processor() or platform.machine(),
        "family": int(family) if family.isdigit() else None,
        "model": int(model) if model.isdigit() else None,
        "isa": isa,
    }


def cpu_model(cpuinfo: str | None = None) -> str:
    """The processor in one line, e.g. "AMD EPYC (family 25, model 17; AVX2, AVX-512, AVX-512 BF16)"."""
    cpu = cpu_id(cpuinfo)
    parts = []
    if cpu["family"] is not None:
        parts.append(f"family {cpu['family']}" + (f", model {cpu['model']}" if cpu["model"] is not None else ""))
    if cpu["isa"]:
        parts.append(", ".join(cpu["isa"]))
    return cpu["name"] + (f" ({'; '.join(parts)})" if parts else "")


def machine(threads: int) -> dict:
    """What the figures were measured on."""
    import torch

    from swarmctl.policy.forward import onnx_available

    ort = None
    if onnx_available():
        import onnxruntime

        ort = onnxruntime.__version__
    return {
        "cpu_model": cpu_model(),
        "cpu": cpu_id(),
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "torch": str(torch.__version__),
        "onnxruntime": ort,
        "threads": threads,
    }


def run_bench(seconds: float = 2.0, threads: int = 1, train: bool = True) -> dict:
    """All benchmark figures, keys naming their unit (module docstring)."""
    from swarmctl.policy.threads import set_inference_threads

    set_inference_threads(threads)
    load_before = os.getloadavg()
    m20 = WorldConfig()
    m50 = WorldConfig(map_size=50, uavs=10, targets=16, clusters=4, obstacles=0.1)
    out: dict = {"machine": machine(threads)}
    with tempfile.TemporaryDirectory() as tmp:
        ddql = ddql_policy(Path(tmp))
        torch_ddql = ddql_policy(Path(tmp), ":forward=torch")
        out.update(decision_figures(ddql, scales_policy(Path(tmp)), seconds))
        out["ddql_forward"] = ddql.forward.name
        out["ddql_decision_ms_batch1_torch_forward"] = 1000.0 * decision_seconds(torch_ddql, 1, seconds)
        out["ddql_paper_decision_ms_batch1"] = 1000.0 * decision_seconds(
            ddql_policy(Path(tmp), PAPER_OPTIONS), 1, seconds
        )
        out["ddql_decision_ms_per_vehicle_batch256"] = 1000.0 * decision_seconds(ddql, 256, seconds)
        out["qnet_forward_ms_batch1"] = 1000.0 * forward_seconds(ddql, 1, seconds)
        out["qnet_forward_ms_batch1_torch"] = 1000.0 * forward_seconds(torch_ddql, 1, seconds)
        out["qnet_forward_ms_per_row_batch512"] = 1000.0 * forward_seconds(ddql, 512, seconds)
    out["ddql_decision_over_flop_limit"] = out["ddql_decision_ms_batch1"] / out["qnet_flop_limit_ms_batch1"]
    out["la4_decision_ms_batch1"] = 1000.0 * decision_seconds(LookAhead(4), 1, seconds)
    out["la4_over_ddql_decision_time"] = out["la4_decision_ms_batch1"] / out["ddql_decision_ms_batch1"]
    blocked = planner_blocked()
    for vehicles in PLANNER_SWARMS:
        coordinated, frontier = planner_decisions(["coordinated", "frontier"], vehicles, seconds, blocked)
        out[f"coordinated_decision_ms_per_vehicle_chicago_u{vehicles}"] = 1000.0 * coordinated
        out[f"frontier_decision_ms_per_vehicle_chicago_u{vehicles}"] = 1000.0 * frontier
        out[f"coordinated_over_frontier_decision_u{vehicles}"] = coordinated / frontier
    out["coordinated_labels_per_s_chicago"] = coordinated_labels_per_s(blocked, seconds)
    for batch in (1, 256):
        out[f"env_vehicle_steps_per_s_batch{batch}"] = env_throughput(m20, batch, True, seconds)
        out[f"env_vehicle_steps_per_s_batch{batch}_no_obs"] = env_throughput(m20, batch, False, seconds)
    out["env_m50_u10_vehicle_steps_per_s_batch64"] = env_throughput(m50, 64, True, seconds)
    out["env_m50_u10_vehicle_steps_per_s_batch64_no_obs"] = env_throughput(m50, 64, False, seconds)
    env = SearchEnv(m20, batch=256, stop_at_success=False)
    env.reset(seed=0)
    out["observe_ms_per_batch_256x2"] = 1000.0 * _median_seconds(env.observe, seconds)
    if train:
        out.update(training_figures(threads, seconds))
        out.update(search_training_figures(threads, seconds))
    out["machine"]["load_average_before"] = list(load_before)
    out["machine"]["load_average_after"] = list(os.getloadavg())
    return out


def format_figures(results: dict) -> str:
    """The figures as aligned text lines, the machine last."""
    lines = []
    for key, value in results.items():
        if key == "machine":
            continue
        lines.append(f"{key:>48}: {value:,.4f}" if isinstance(value, float) else f"{key:>48}: {value}")
    m = results["machine"]
    lines.append(
        f"{'machine':>48}: {m['cpu_model']}, {m['cpu_count']} cores, {m['threads']} thread(s), Python {m['python']}, "
        f"numpy {m['numpy']}, torch {m['torch']}, onnxruntime {m['onnxruntime']}"
    )
    before, after = m["load_average_before"], m["load_average_after"]
    lines.append(f"{'load average (1, 5, 15 min)':>48}: before {before}, after {after}")
    return "\n".join(lines)


@click.command("bench")
@click.option("--seconds", type=real(0, 600, above=True), default=2.0, show_default=True, help="Time per measurement.")
@click.option(
    "--threads", type=whole(1, MAX_THREADS), default=1, show_default=True, help="Torch and onnxruntime CPU threads."
)
@click.option("--no-train", is_flag=True, help="Leave out both trainers' throughput (about 15 s).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, path_type=Path), help="Write the figures here.")
def bench_command(seconds, threads, no_train, json_path):
    """Measure the simulator (batch 1 and 256), decision times (DDQL and the search recipe's scales network
    against their FLOP limits, LA(4), the planners), the coordinated teacher's labelling rate and both
    trainers' throughput against their FLOP ceilings, in one run."""
    if json_path is not None:
        writable_file(json_path, "--json")
    results = run_bench(seconds, threads, train=not no_train)
    click.echo(format_figures(results))
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps(results, indent=1))
        click.echo(f"wrote {json_path}")
