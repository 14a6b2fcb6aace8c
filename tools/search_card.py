"""Write a model card (Markdown) and its learning curve (PNG) for a checkpoint of `swarmctl train-search`.

    python tools/search_card.py models/search.pt --command "swarmctl train-search ... --out models/search.pt" \\
        [--results results/planners/61206] [--policy ddql:models/search.pt] [--teacher coordinated] \\
        [--notes notes.md] [--out models/search.md]

The card (default: the checkpoint with suffix .md) and the figure beside it (same stem, .png) state only
what the checkpoint, the run's CSV (NAME.csv beside NAME.pt or NAME.best.pt; --csv names another) and the
result files hold; a key an older checkpoint lacks reads "unknown". With --results, each setting folder of
tools/planner_table.py's results/planners/SEED that holds both the policy's and the teacher's JSON gives a
held-out test table: success with its standard error, mean steps, x oracle, and the difference of the two
successes with its standard error over the episodes both played (episode i depends on (seed, i) only, so the
difference is paired).
"""

from __future__ import annotations

import argparse
import csv
import io
import math
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmctl.bounds import INPUT_MAX_BYTES, load_json, read_limited, writable_file  # noqa: E402
from swarmctl.errors import InputError, printable  # noqa: E402
from swarmctl.figures import pyplot  # noqa: E402
from swarmctl.learn.search_config import SEARCH_CURRICULA  # noqa: E402
from swarmctl.policy.checkpoint import load_checkpoint  # noqa: E402
from swarmctl.policy.qnet import parameter_count  # noqa: E402
from tools.planner_table import SETTINGS, slug  # noqa: E402

UNKNOWN = "unknown"
DPI = 150
MARKERS = "osD^vPX*"  # a world's points stay apart from another's drawn at the same place
LOSS_COLUMNS = (("loss", "total loss"), ("tdn", "n-step TD loss"), ("margin", "margin loss"))

# --- the files' values, read without trusting their shape ------------------------------------------------------------


def as_dict(value: object) -> dict[str, object]:
    return {str(k): v for k, v in value.items()} if isinstance(value, dict) else {}


def as_list(value: object) -> list[object]:
    return list(value) if isinstance(value, list | tuple) else []


def number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return float(value)


def count(value: object) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def shown(value: object) -> str:
    """A value from a file as the card writes it ("unknown" when absent)."""
    if value is None:
        return UNKNOWN
    if value == "":
        return '""'
    return printable(str(value))


def thousands(value: object) -> str:
    n = count(value)
    return UNKNOWN if n is None else f"{n:,}"


def fixed(value: object, digits: int) -> str:
    x = number(value)
    return UNKNOWN if x is None else f"{x:.{digits}f}"


def cell(text: str) -> str:
    """Text for a Markdown table cell (a `|` would end it)."""
    return text.replace("|", "\\|")


def row(cells: Iterable[str]) -> str:
    return "| " + " | ".join(cell(c) for c in cells) + " |"


def table(head: Sequence[str], rows: Iterable[Sequence[str]]) -> list[str]:
    return [row(head), "|" + " --- |" * len(head), *(row(r) for r in rows)]


# --- the run: checkpoint and CSV ----------------------------------------------------------------------------------


@dataclass
class Evaluation:
    episodes: int
    stage: int | None
    success: float | None
    mean_steps: float | None
    worlds: dict[str, float]  # world name -> validation success


@dataclass
class Run:
    path: Path
    parameters: int
    info: dict[str, object]
    meta: dict[str, object]
    train: dict[str, object]
    stages: list[str]
    stage_worlds: list[list[str]]  # per stage, its worlds' names (empty: not known)
    opened: list[int | None]  # per stage, the episode it opened at (None: not reached or not known)
    opened_from_csv: bool
    teacher: dict[str, float]  # world name -> the teacher's validation success
    evals: list[Evaluation]
    csv_path: Path | None
    csv_rows: list[dict[str, float]] = field(default_factory=list)
    csv_dropped: int = 0  # rows after the checkpoint's episode

    @property
    def worlds(self) -> list[str]:
        """Every world named, in curriculum order, then any only the evaluations name."""
        names = [w for ws in self.stage_worlds for w in ws]
        names += [w for w in self.teacher if w not in names]
        for e in self.evals:
            names += [w for w in e.worlds if w not in names]
        return names

    def stage_of(self, world: str) -> int | None:
        return next((s for s, ws in enumerate(self.stage_worlds) if world in ws), None)


def read_evaluations(raw: list[object]) -> list[Evaluation]:
    out = []
    for item in raw:
        e = as_dict(item)
        episodes = count(e.get("episodes"))
        if episodes is None:
            continue
        worlds = {}
        for name, value in as_dict(e.get("worlds")).items():
            success = number(as_dict(value).get("success_rate"))
            if success is not None:
                worlds[name] = success
        out.append(Evaluation(episodes, count(e.get("stage")), number(e.get("success_rate")),
                              number(e.get("mean_steps")), worlds))  # fmt: skip
    return out


def stage_worlds(stages: list[str], train: dict[str, object], evals: list[Evaluation]) -> list[list[str]]:
    """Each stage's worlds: the curriculum's as this swarmctl defines it when its stage names are the
    checkpoint's, else as the evaluations show them (a world first evaluated at stage s is stage s's)."""
    curriculum = SEARCH_CURRICULA.get(str(train.get("curriculum")))
    if curriculum and [s.name for s in curriculum[: len(stages)]] == stages:
        return [[w.name for w in s.worlds] for s in curriculum[: len(stages)]]
    out: list[list[str]] = [[] for _ in stages]
    seen: set[str] = set()
    for e in evals:
        for w in e.worlds:
            if w not in seen:
                seen.add(w)
                if e.stage is not None and 0 <= e.stage < len(out):
                    out[e.stage].append(w)
    return out


def csv_beside(checkpoint: Path) -> Path:
    """The run's CSV: NAME.csv beside NAME.pt, and beside NAME.best.pt too."""
    own = checkpoint.with_suffix(".csv")
    if own.is_file() or not checkpoint.stem.endswith(".best"):
        return own
    return checkpoint.with_name(checkpoint.stem[: -len(".best")] + ".csv")


def read_csv(path: Path) -> list[dict[str, float]]:
    """The CSV's rows as numbers (empty cells left out); a resumed run's rows for episodes it played again
    replace the earlier ones."""
    text = read_limited(path, "training CSV", INPUT_MAX_BYTES, "--csv").decode("utf-8", errors="replace")
    rows: list[dict[str, float]] = []
    for raw in csv.DictReader(io.StringIO(text)):
        values = {}
        for key, value in raw.items():
            try:
                x = float(value) if key is not None and value not in (None, "") else math.nan
            except (TypeError, ValueError):
                continue
            if math.isfinite(x):
                values[str(key)] = x
        if "episodes" not in values:
            continue
        while rows and rows[-1]["episodes"] >= values["episodes"]:
            rows.pop()
        rows.append(values)
    return rows


def stage_openings(progress: dict[str, object], rows: list[dict[str, float]], n: int) -> tuple[list[int | None], bool]:
    """Each stage's opening episode: the run's record when the checkpoint holds it, else the first CSV row
    at that stage (a stage opens at an evaluation, whose row already carries it); (openings, from the CSV)."""
    recorded = [count(x) for x in as_list(progress.get("stage_opened"))]
    if recorded:
        return (recorded + [None] * n)[: max(n, len(recorded))], False
    firsts: dict[int, int] = {}
    for r in rows:
        if "stage" in r:
            firsts.setdefault(int(r["stage"]), int(r["episodes"]))
    return [firsts.get(s) for s in range(n)], bool(firsts)


def load_run(checkpoint: Path, csv_path: Path | None) -> Run:
    net, info = load_checkpoint(checkpoint)
    meta, train = as_dict(info.get("metadata")), as_dict(info.get("train"))
    progress = as_dict(as_dict(info.get("resume")).get("progress"))
    stages = [str(s) for s in as_list(meta.get("stages"))]
    evals = read_evaluations(as_list(meta.get("evals")) or as_list(progress.get("evals")))
    teacher = {}
    for name, value in (as_dict(meta.get("teacher_val_success")) or as_dict(progress.get("teacher"))).items():
        success = number(value)
        if success is not None:
            teacher[name] = success
    given = csv_path is not None
    path = csv_path if csv_path is not None else csv_beside(checkpoint)
    rows: list[dict[str, float]] = []
    if given or path.is_file():
        rows = read_csv(path)
    kept, dropped = rows, 0
    done = count(meta.get("episodes"))
    if done is not None:
        kept = [r for r in rows if r["episodes"] <= done]
        dropped = len(rows) - len(kept)
    opened, from_csv = stage_openings(progress, rows, len(stages))
    return Run(
        path=checkpoint,
        parameters=parameter_count(net),
        info=info,
        meta=meta,
        train=train,
        stages=stages,
        stage_worlds=stage_worlds(stages, train, evals),
        opened=opened,
        opened_from_csv=from_csv,
        teacher=teacher,
        evals=evals,
        csv_path=path if (given or path.is_file()) else None,
        csv_rows=kept,
        csv_dropped=dropped,
    )


# --- the card's sections ------------------------------------------------------------------------------------------


def header(run: Run) -> list[str]:
    info, train, meta = run.info, run.train, run.meta
    world = as_dict(info.get("world"))
    rules = as_dict(train.get("recipe"))
    recipe = shown(rules.get("name") or meta.get("recipe"))
    window = count(info.get("window"))
    curriculum = train.get("curriculum")
    lines = [
        f"# {printable(run.path.name)}",
        "",
        f"The shared Q-network ({run.parameters:,} parameters, architecture `{shown(info.get('architecture'))}`, "
        f"observation variant `{shown(info.get('variant') or world.get('variant'))}`, window "
        + (f"{window} x {window}" if window is not None else UNKNOWN)
        + f") trained by `swarmctl train-search` with the recipe `{recipe}`"
        + (f" on the **{printable(str(curriculum))}** curriculum" if curriculum is not None else "")
        + f" ({len(run.stages) if run.stages else UNKNOWN} stages).",
        "",
        "It flies under the recipe's rules, stored in the checkpoint (`ddql:PATH` with no options takes them): "
        + ", ".join(f"{key} = {shown(rules.get(key))}" for key in ("hover", "mask", "taken"))
        + ".",
    ]
    if run.path.stem.endswith(".best"):
        lines += [
            "",
            "This file is the run's best checkpoint on validation (NAME.best.pt: the latest stage reached, then "
            "the highest validation success), saved at the evaluation of the last row of the validation table.",
        ]
    return lines


def training(run: Run, command: str) -> list[str]:
    meta, train = run.meta, run.train
    hours = number(meta.get("wall_time_s"))
    reached = count(meta.get("stage_reached"))
    reached_text = UNKNOWN
    if reached is not None:
        name = run.stages[reached] if 0 <= reached < len(run.stages) else None
        reached_text = f"stage {reached}" + (f" ({printable(name)})" if name else "")
    hyper = ", ".join(f"{k} = {shown(v)}" for k, v in train.items() if k != "recipe")
    changes = [as_dict(c) for c in as_list(meta.get("changes"))]
    return [
        "## Training",
        "",
        *(f"    {printable(line)}" for line in command.splitlines()),
        "",
        f"- episodes: {thousands(meta.get('episodes'))} of {thousands(meta.get('episodes_planned'))} planned "
        f"(student episodes); stage reached: {reached_text}",
        f"- samples: {thousands(meta.get('samples'))} student samples (vehicle transitions) and "
        f"{thousands(meta.get('demo_samples'))} demonstration samples (the teacher's episodes and its DAgger "
        f"labels); {thousands(meta.get('updates'))} gradient updates",
        "- wall time: "
        + (UNKNOWN if hours is None else f"{hours / 3600:.2f} h")
        + f" (evaluations included); {fixed(meta.get('train_samples_per_s'), 1)} student samples/s over the "
        f"collecting and learning time; torch {shown(meta.get('torch'))}, device {shown(meta.get('device'))}",
        f"- seed {shown(meta.get('seed', train.get('seed')))}, git commit {shown(meta.get('git_commit'))}",
        f"- weights sha256 {shown(run.info.get('weights_sha256'))}",
        "- hyperparameters: " + (hyper or UNKNOWN),
        *(
            f"- on --resume from episode {thousands(c.get('episode'))}: {shown(c.get('option'))} "
            f"{shown(c.get('from'))} -> {shown(c.get('to'))}"
            for c in changes
        ),
    ]


def curriculum(run: Run) -> list[str]:
    share = number(run.train.get("advance_share"))
    lines = [
        "## Curriculum",
        "",
        "A stage opens when the student's validation success on the current stage (the mean over its worlds) "
        f"reaches advance_share = {shown(share)} of the coordinated teacher's on the same episodes "
        f"(validation seed {shown(run.train.get('val_seed'))}, {shown(run.train.get('val_episodes'))} episodes "
        "per world). The teacher's validation success was measured when each stage opened.",
        "",
    ]
    if not run.stages:
        return [*lines, "The checkpoint names no stages (unknown)."]
    reached = count(run.meta.get("stage_reached"))
    rows = []
    for s, name in enumerate(run.stages):
        opened = run.opened[s] if s < len(run.opened) else None
        if opened is not None:
            when = f"{opened:,}" + (" (from the CSV)" if run.opened_from_csv else "")
        else:
            when = "not reached" if reached is not None and s > reached else UNKNOWN
        worlds = run.stage_worlds[s] if s < len(run.stage_worlds) else []
        bars = [run.teacher.get(w) for w in worlds]
        known = [b for b in bars if b is not None]
        if s + 1 == len(run.stages):
            bar = "- (the last stage)"
        elif share is None or not worlds or len(known) < len(worlds):
            bar = UNKNOWN
        else:
            bar = f"{share * sum(known) / len(known):.3f}"
        for i, w in enumerate(worlds or [UNKNOWN]):
            teacher = run.teacher.get(w)
            first = i == 0
            rows.append([
                f"{s}: {printable(name)}" if first else "",
                when if first else "",
                printable(w),
                UNKNOWN if teacher is None else f"{teacher:.3f}",
                bar if first else "",
            ])  # fmt: skip
    head = ["stage", "opened at episode", "world", "teacher's validation success", "bar to open the next stage"]
    return [*lines, *table(head, rows)]


def validation(run: Run) -> list[str]:
    lines = [
        "## Validation during training",
        "",
        f"Each evaluation ran the network under its rules on every opened stage's worlds, "
        f"{shown(run.train.get('val_episodes'))} episodes per world on the validation seed "
        f"{shown(run.train.get('val_seed'))}; stage is the current stage when it ran, success and mean steps are the "
        "means over the opened worlds, and a world's cell is empty before its stage opened.",
        "",
    ]
    if not run.evals:
        return [*lines, "The checkpoint holds no evaluation."]
    worlds = run.worlds
    rows = [
        [
            f"{e.episodes:,}",
            shown(e.stage),
            fixed(e.success, 3),
            fixed(e.mean_steps, 2),
            *(f"{e.worlds[w]:.3f}" if w in e.worlds else "" for w in worlds),
        ]
        for e in run.evals
    ]
    return [*lines, *table(["episodes", "stage", "success", "mean steps", *map(printable, worlds)], rows)]


def figure_text(run: Run, png: Path) -> list[str]:
    if run.csv_path is None:
        below = "no CSV was found beside the checkpoint, so the lower panel is empty"
    else:
        below = (
            f"the lower panel is {printable(run.csv_path.name)}: the losses (each round's mean) and the share of "
            "each batch drawn from the demonstrations"
        )
        if run.csv_dropped:
            rows = "its row" if run.csv_dropped == 1 else f"its {run.csv_dropped} rows"
            below += f" ({rows} after this checkpoint's episode left out)"
    return [
        "## Learning curve",
        "",
        f"![learning curve]({png.name})",
        "",
        "Upper panel: validation success per world (solid), the teacher's validation success on the same "
        f"episodes (dashed, the same colour, from its stage's opening) and the stage openings (dotted); {below}.",
    ]


def figure(run: Run, png: Path) -> None:
    """Validation success per world with the teacher's bars and the stage openings above; the CSV's losses
    and demonstration share below."""
    plt = pyplot()
    from matplotlib.lines import Line2D

    fig, (top, bottom) = plt.subplots(
        2, 1, figsize=(11, 7.5), sharex=True, gridspec_kw=dict(height_ratios=[3, 2], hspace=0.08)
    )
    ends = [e.episodes for e in run.evals] + [int(r["episodes"]) for r in run.csv_rows]
    done = count(run.meta.get("episodes"))
    right = max([*ends, *([done] if done is not None else []), 1])
    colours = plt.get_cmap("tab10" if len(run.worlds) <= 10 else "tab20")
    handles: list[Line2D] = []
    for i, w in enumerate(run.worlds):
        colour = colours(i % colours.N)
        points = [(e.episodes, e.worlds[w]) for e in run.evals if w in e.worlds]
        if points:
            marker, size = MARKERS[i % len(MARKERS)], 3.5 if len(points) > 1 else 7
            (line,) = top.plot(*zip(*points), ls="-", marker=marker, color=colour, lw=1.6, ms=size, label=w)
            handles.append(line)
        bar = run.teacher.get(w)
        if bar is not None:
            stage = run.stage_of(w)
            start = run.opened[stage] if stage is not None and stage < len(run.opened) else None
            start = start if start is not None else (points[0][0] if points else 0)
            top.hlines(bar, start, right, colors=[colour], linestyles="--", lw=1.2)
            if not points:
                handles.append(Line2D([], [], color=colour, ls="--", label=w))
    handles += [
        Line2D([], [], color="0.2", ls="--", lw=1.2, label="teacher (coordinated), validation"),
        Line2D([], [], color="0.45", ls=":", lw=1.2, label="a stage opens"),
    ]
    for s, x in enumerate(run.opened):
        if x is None:
            continue
        name = run.stages[s] if s < len(run.stages) else ""
        for ax in (top, bottom):
            ax.axvline(x, color="0.45", ls=":", lw=1.2)
        top.text(x + right * 0.004, 0.03, f"stage {s}: {name}", rotation=90, va="bottom", ha="left", fontsize=8,
                 color="0.25", bbox=dict(facecolor="white", edgecolor="none", alpha=0.75, pad=1))  # fmt: skip
    top.set_ylim(-0.02, 1.03)
    top.set_xlim(0, right * 1.01)
    top.set_ylabel("validation success")
    top.grid(axis="y", color="0.9")
    if not run.evals:
        top.text(0.5, 0.5, "no evaluation in the checkpoint", transform=top.transAxes, ha="center", color="0.4")
    top.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    top.set_title(
        f"{run.path.name}: validation success per world ({shown(run.train.get('val_episodes'))} episodes each, "
        f"seed {shown(run.train.get('val_seed'))})",
        fontsize=10,
    )
    lower: list[Line2D] = []
    for key, label in LOSS_COLUMNS:
        curve = [(r["episodes"], r[key]) for r in run.csv_rows if key in r]
        if curve:
            lower += bottom.plot(*zip(*curve), lw=1.0, label=label)
    bottom.set_ylabel("loss (mean of a round)")
    bottom.set_xlabel("student training episodes")
    bottom.set_ylim(bottom=0)
    share = [(r["episodes"], r["demo_share"]) for r in run.csv_rows if "demo_share" in r]
    if share:
        twin = bottom.twinx()
        lower += twin.plot(*zip(*share), color="0.35", ls="--", lw=1.2, label="demonstration share of a batch")
        twin.set_ylim(0, 1)
        twin.set_ylabel("demonstration share")
    if lower:
        bottom.legend(handles=lower, loc="upper left", bbox_to_anchor=(1.07, 1.0), fontsize=8, frameon=False)
    else:
        bottom.text(0.5, 0.5, "no training CSV", transform=bottom.transAxes, ha="center", color="0.4")
    fig.savefig(png, dpi=DPI, bbox_inches="tight")
    plt.close(fig)


# --- held-out tests: tools/planner_table.py's results -------------------------------------------------------------


@dataclass
class TestResult:
    policy: str
    episodes: int | None
    seed: int | None
    success: float | None
    mean_steps: float | None
    oracle_ratio: float | None
    outcomes: dict[int, bool]  # episode index -> success
    command: str | None


def read_result(path: Path, policy: str) -> TestResult:
    """One policy's result: run_policy's record as planner_table writes it, or `swarmctl eval --json`'s
    {"results": [...]} with the policy among them."""
    data = as_dict(load_json(path, "evaluation result", fix="write it again with tools/planner_table.py"))
    record = data
    if "results" in data:
        records = [as_dict(r) for r in as_list(data.get("results"))]
        mine = [r for r in records if r.get("policy") == policy] or (records if len(records) == 1 else [])
        if not mine:
            raise InputError(f"{path}: holds no result of {policy}; give --policy as it was evaluated")
        record = mine[0]
    outcomes = {}
    for item in as_list(record.get("per_episode")):
        e = as_dict(item)
        index, ok = count(e.get("episode")), e.get("success")
        if index is not None and isinstance(ok, bool):
            outcomes[index] = ok
    command = record.get("command", data.get("command"))
    return TestResult(
        policy=str(record.get("policy", policy)),
        episodes=count(record.get("episodes")),
        seed=count(record.get("seed")),
        success=number(record.get("success_rate")),
        mean_steps=number(record.get("mean_steps")),
        oracle_ratio=number(record.get("duration_ratio_to_oracle")),
        outcomes=outcomes,
        command=command if isinstance(command, str) else None,
    )


def success_text(r: TestResult) -> str:
    """Success with its binomial standard error, as planner_table gives it."""
    if r.success is None:
        return UNKNOWN
    if r.episodes is None or r.episodes <= 0:
        return f"{r.success:.3f}"
    return f"{r.success:.3f} +- {math.sqrt(r.success * (1 - r.success) / r.episodes):.3f}"


def paired_difference(a: TestResult, b: TestResult) -> tuple[float, float, int] | None:
    """(mean, standard error, n) of a's success minus b's over the episodes both played on the same seed."""
    if a.seed is None or a.seed != b.seed:
        return None
    shared = sorted(set(a.outcomes) & set(b.outcomes))
    if not shared:
        return None
    d = [float(a.outcomes[e]) - float(b.outcomes[e]) for e in shared]
    mean = sum(d) / len(d)
    se = math.sqrt(sum((x - mean) ** 2 for x in d) / (len(d) - 1) / len(d)) if len(d) > 1 else math.nan
    return mean, se, len(d)


def setting_section(
    name: str, policy: TestResult, teacher: TestResult, validation_seed: int | None, test_seed: int | None
) -> list[str]:
    setting = SETTINGS.get(name, {})
    title = printable(str(setting.get("title", name)))
    lines = [f"### {title} ({shown(policy.episodes)} episodes, seed {shown(policy.seed)})", ""]
    if policy.seed is not None and policy.seed in (validation_seed, test_seed):
        which, option = ("validation", "--val-seed") if policy.seed == validation_seed else ("test", "--test-seed")
        lines += [f"The seed is the run's {which} seed (`{option}`).", ""]
    commands = [c for c in dict.fromkeys((policy.command, teacher.command)) if c]
    if not commands and "command" in setting:
        commands = [
            f"swarmctl eval {setting['command']} --episodes {shown(policy.episodes)} --seed {shown(policy.seed)} "
            f"--policy {policy.policy} --policy {teacher.policy}"
        ]
    lines += [*(f"    {printable(c)}" for c in commands), *([""] if commands else [])]
    rows = [
        [
            f"{printable(r.policy)}{' (teacher)' if r is teacher else ''}",
            success_text(r),
            fixed(r.mean_steps, 1),
            "-" if r.oracle_ratio is None else f"{r.oracle_ratio:.2f}",
        ]
        for r in (policy, teacher)
    ]
    lines += table(["policy", "success", "mean steps", "x oracle"], rows)
    diff = paired_difference(policy, teacher)
    if diff is None:
        lines += ["", "Success difference: unknown (the two files share no episodes with outcomes on one seed)."]
    else:
        mean, se, n = diff
        lines += [
            "",
            f"Success difference, {printable(policy.policy)} - {printable(teacher.policy)}, over the {n} episodes "
            f"both played: {mean:+.3f} +- {se:.3f} (paired).",
        ]
    return lines


def tests_section(folder: Path, policy: str, teacher: str, train: dict[str, object]) -> list[str]:
    names = list(SETTINGS) + sorted(d.name for d in folder.iterdir() if d.is_dir() and d.name not in SETTINGS)
    lines = [
        f"## Held-out tests ({printable(str(folder))})",
        "",
        "The episodes of tools/planner_table.py: episode i of a setting comes from (seed, i) alone, so the policy "
        "and the teacher play the same ones and their success difference is paired.",
    ]
    missing = []
    for name in names:
        files = {spec: folder / name / f"{slug(spec)}.json" for spec in (policy, teacher)}
        absent = [p.name for p in files.values() if not p.is_file()]
        if absent:
            missing.append(f"{printable(name)} (no {' and no '.join(map(printable, absent))})")
            continue
        mine, theirs = read_result(files[policy], policy), read_result(files[teacher], teacher)
        lines += ["", *setting_section(name, mine, theirs, count(train.get("val_seed")), count(train.get("test_seed")))]
    if missing:
        lines += ["", "Not run: " + "; ".join(missing) + "."]
    return lines


# --- the command ---------------------------------------------------------------------------------------------------


def write_card(
    checkpoint: Path,
    command: str,
    out: Path | None = None,
    results: Path | None = None,
    policy: str | None = None,
    teacher: str = "coordinated",
    notes: Path | None = None,
    csv_path: Path | None = None,
) -> tuple[Path, Path]:
    """Write the card and its figure; returns their paths."""
    card = out if out is not None else checkpoint.with_suffix(".md")
    if card.suffix != ".md":
        raise InputError(f"--out {card}: the card is Markdown; give a .md path (the figure goes beside it as .png)")
    png = card.with_suffix(".png")
    if results is not None and not results.is_dir():
        raise InputError(
            f"--results {results}: no such folder; give results/planners/SEED as tools/planner_table.py writes it"
        )
    writable_file(card, "--out")
    writable_file(png, "--out")
    note_text = (
        read_limited(notes, "notes file", INPUT_MAX_BYTES, "--notes").decode("utf-8", "replace") if notes else ""
    )
    run = load_run(checkpoint, csv_path)
    lines = [*header(run), "", *training(run, command), "", *curriculum(run), "", *validation(run), ""]
    lines += figure_text(run, png)
    if results is not None:
        lines += ["", *tests_section(results, policy or f"ddql:{checkpoint}", teacher, run.train)]
    if note_text.strip():
        lines += ["", note_text.strip()]
    card.parent.mkdir(parents=True, exist_ok=True)
    figure(run, png)
    card.write_text("\n".join(lines) + "\n")
    return card, png


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path, help="a checkpoint written by swarmctl train-search")
    ap.add_argument(
        "--command", required=True, action="append", help="the training command line, as run (repeat: each session's)"
    )
    ap.add_argument("--results", type=Path, help="results/planners/SEED of tools/planner_table.py: the held-out tests")
    ap.add_argument("--policy", help="the policy's name in --results (default: ddql:CHECKPOINT, as given)")
    ap.add_argument("--teacher", default="coordinated", help="the policy it is compared with in --results")
    ap.add_argument("--notes", type=Path, help="a Markdown file appended to the card")
    ap.add_argument("--csv", type=Path, help="the run's metrics CSV (default: NAME.csv beside the checkpoint)")
    ap.add_argument("--out", type=Path, help="the card (default: the checkpoint with suffix .md); the PNG beside it")
    args = ap.parse_args(argv)
    try:
        card, png = write_card(
            args.checkpoint,
            "\n".join(args.command),
            args.out,
            args.results,
            args.policy,
            args.teacher,
            args.notes,
            args.csv,
        )
    except InputError as exc:
        print(f"search_card: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {card} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
