"""`swarmctl eval`: compare policies on the same episodes."""

from __future__ import annotations

import json
from pathlib import Path

import click

from swarmctl.cli_options import require, world_config, world_options
from swarmctl.learn.evaluate import evaluate
from swarmctl.policy.registry import POLICY_HELP


def format_table(results: list[dict]) -> str:
    """The eval results as an aligned text table."""
    head = ("policy", "success", "mean steps", "x oracle", "collisions/ep", "ms/decision")
    rows = []
    for r in results:
        ms = r["decision_ms_per_vehicle"]
        ratio = r["duration_ratio_to_oracle"]
        rows.append((r["policy"], f"{r['success_rate']:.3f}", f"{r['mean_steps']:.2f}",
                     f"{ratio:.2f}" if ratio is not None else "-", f"{r['collisions_per_episode']:.3f}",
                     f"{ms:.3f}" if ms is not None else "-"))
    widths = [max(len(str(x)) for x in col) for col in zip(head, *rows)]
    line = lambda cells: "  ".join(str(c).rjust(w) if i else str(c).ljust(w) for i, (c, w) in enumerate(zip(cells, widths)))
    return "\n".join([line(head), line(["-" * w for w in widths]), *map(line, rows)])


@click.command("eval")
@world_options
@click.option("--steps", type=int, default=40, show_default=True, help="Step limit N of a test episode.")
@click.option("--episodes", type=int, default=500, show_default=True, help="Test episodes E.")
@click.option("--seed", type=int, default=0, show_default=True, help="Episode seed: same seed, same episodes.")
@click.option("--policy", "policies", multiple=True, required=True, metavar="POLICY",
              help=f"Repeatable; all run on the same episodes. One of: {POLICY_HELP}.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, path_type=Path),
              help='Write {"results": [...]} with success_rate, mean_steps, steps_cdf, ...')
@click.option("--progress/--no-progress", default=True, help="Show a progress bar on a terminal.")
def eval_command(steps, episodes, seed, policies, json_path, progress, **kwargs):
    """Evaluate policies: success rate, mean episode duration, duration CDF, against the oracle bound."""
    cfg = world_config(kwargs)
    require(steps >= 1, f"--steps {steps} must be >= 1")
    require(episodes >= 1, f"--episodes {episodes} must be >= 1")
    results = evaluate(cfg, list(policies), episodes, seed, steps, progress=progress)
    click.echo(f"{cfg.scenario}, M={cfg.map_size}, U={cfg.uavs}, K={cfg.targets}, eta={cfg.obstacles}, "
               f"N={steps}, {episodes} episodes, seed {seed}, channel {cfg.channel}")
    click.echo(format_table(results))
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps({"results": results}, indent=1))
        click.echo(f"wrote {json_path}")
