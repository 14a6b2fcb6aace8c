"""What the experiments share: the comparison policies, run builders, tables and the figure's
claim box."""

from __future__ import annotations

import textwrap

from tools.exp.runs import Run

CLUSTER, SPARSE, OBSTACLES = "models/cluster-2uav.pt", "models/sparse-2uav.pt", "models/obstacles-3uav.pt"
SEARCH = "models/search.pt"  # the search recipe's network (models/search.md), beside the paper's in every run
SEARCH_LABEL = "models/search.pt (search recipe)"
PLANNERS = ["coordinated", "la:4", "lawnmower", "frontier"]  # with the oracle bound, beside every learned policy
RECIPE = dict(  # transfer-learning stages of the tools' training (the shipped models' stage-2 recipe)
    parallel_envs=5,
    updates_per_step=0.5,
    prefill_episodes=100,
    temperature_start=0.3,
    temperature_end=0.05,
    eval_episodes=100,
    threads=1,
)


def eval_run(key: str, world: dict, p: dict, seed: int, learned: dict[str, str], **extra) -> Run:
    """An evaluation run: the `learned` policies ({label: spec with "{input}" names}, inputs named
    in extra["inputs"]), models/search.pt, then the planners and the oracle, on p["test_episodes"]
    episodes of `seed`."""
    inputs = {**extra.pop("inputs", {}), "search": SEARCH}
    learned = {**learned, SEARCH_LABEL: "ddql:{search}"}
    labels = [*learned, *PLANNERS, "oracle"]
    params = dict(
        world=world,
        policies=[*learned.values(), *PLANNERS, "oracle"],
        labels=labels,
        episodes=p["test_episodes"],
        seed=seed,
        steps=extra.pop("steps", p["steps"]),
        **extra,
    )
    return Run(key, "eval", params, inputs)


def train_run(key: str, world: dict, p: dict, seed: int, init: str | None, episodes: int, **train) -> Run:
    """A training run from the checkpoint `init` (a repository path) for `episodes` episodes."""
    cfg = {**RECIPE, **p.get("train", {}), "episodes": episodes, "eval_every": episodes, **train}
    params = dict(world=world, train=cfg, seed=seed, init="{init}" if init else None)
    return Run(key, "train", params, {"init": init} if init else {})


def beside(res: dict[str, dict]) -> str:
    """models/search.pt's and the coordinated planner's success and mean steps, for a claim box."""
    named = (("search.pt", SEARCH_LABEL), ("coordinated", "coordinated"))
    return ", ".join(
        f"{name} {r['success_rate']:.2f} in {r['mean_steps']:.0f}" for name, label in named if (r := res.get(label))
    )


def by_policy(result: dict | None) -> dict[str, dict]:
    """An eval run's results keyed by policy label ({} for a run not done yet)."""
    return {r["policy"]: r for r in (result or {}).get("results", [])}


def rows(results: list[dict], **columns) -> list[dict]:
    """Table rows (policy, success, mean steps, x oracle, collisions) plus constant columns."""
    return [
        {
            **columns,
            "policy": r["policy"],
            "success": r["success_rate"],
            "mean_steps": r["mean_steps"],
            "x_oracle": r["duration_ratio_to_oracle"],
            "collisions": r["collisions_per_episode"],
        }
        for r in results
    ]


def markdown(table: list[dict], columns: list[str] | None = None) -> str:
    """A Markdown table of row dicts (floats to 3 decimals, None as -)."""
    if not table:
        return "(no runs done yet)"
    columns = columns or list(table[0])

    def cell(v):
        if v is None:
            return "-"
        if isinstance(v, float):
            return f"{v:.3f}"
        return str(v)

    lines = ["| " + " | ".join(c.replace("_", " ") for c in columns) + " |", "|" + " --- |" * len(columns)]
    lines += ["| " + " | ".join(cell(r.get(c)) for c in columns) + " |" for r in table]
    return "\n".join(lines)


FAST_TRAIN = dict(  # the fast modes' training: seconds, never a result
    episode_lengths=[10, 10], prefill_episodes=5, eval_episodes=4, eval_steps=5, updates_per_step=0.2
)


def save(fig, path, paper: str, ours: str, bottom: float = 0.12) -> None:
    """Put the claim box under the figure, write it as PNG and close it."""
    import matplotlib.pyplot as plt

    claim_box(fig, paper, ours)
    fig.tight_layout(rect=(0, bottom, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def claim_box(fig, paper: str, ours: str) -> None:
    """The paper's claim beside ours, under the figure."""
    text = (
        "paper: "
        + textwrap.fill(paper, 110, subsequent_indent="  ")
        + "\nours: "
        + textwrap.fill(ours, 110, subsequent_indent="  ")
    )
    fig.text(0.01, 0.01, text, fontsize=7, va="bottom", ha="left", family="monospace")
