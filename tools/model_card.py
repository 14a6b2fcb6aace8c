"""Write a model card (Markdown) from a checkpoint and the `swarmctl eval --json` of it.

swarmctl eval ... --policy ddql:models/cluster-2uav.pt --policy la:4 ... --json models/cluster-2uav.eval.json
python tools/model_card.py models/cluster-2uav.pt models/cluster-2uav.eval.json --command "swarmctl train ..."
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

from swarmctl.policy.checkpoint import load_checkpoint


def _init_text(init) -> str:
    """How the card names the model a run started from: its file name and weights hash."""
    if not init:
        return ""
    digest = init.get("weights_sha256")
    return f", initialised from {init['file']}" + (f" (weights sha256 {digest[:16]}...)" if digest else "")


def _trained_on(world: dict, train: dict) -> str:
    """The sentence naming what the model was trained on."""
    if train.get("curriculum"):
        return f"on the **{train['curriculum']}** curriculum of worlds (`--curriculum {train['curriculum']}`)."
    return (
        f"on the **{world['scenario']}** scenario: {world['map_size']} x {world['map_size']} map, "
        f"{world['uavs']} UAVs, "
        f"{world['targets']} targets, obstacles eta = {world['obstacles']}, window F = {world['window']}"
        + (
            ", trained on observations with taken targets removed (`--remove-taken`)."
            if world.get("remove_taken")
            else "."
        )
    )


def _evals_table(evals: list[dict]) -> list[str]:
    """The held-out evaluations during training: one column per curriculum world where it has them."""
    worlds = list(evals[0].get("worlds", {})) if evals else []
    head = ["episodes", "success", "mean steps", *worlds]
    rows = [
        [str(e["episodes"]), f"{e['success_rate']:.3f}", f"{e['mean_steps']:.2f}"]
        + [f"{e['worlds'][w]['success_rate']:.2f}" for w in worlds]
        for e in evals
    ]
    return [f"| {' | '.join(head)} |", "|" + " --- |" * len(head), *[f"| {' | '.join(r)} |" for r in rows]]


def _eval_section(command: str, results: list[dict]) -> list[str]:
    """One evaluation: its command, its setting and the table of its policies."""
    first, sc = results[0], results[0]["scenario"]
    lines = [
        "",
        f"    {command}",
        "",
        f"{first['episodes']} test episodes (seed {first['seed']}, never used in training), "
        f"{sc['steps']}-step limit, all policies on the same episodes:",
        "",
        "| policy | success | mean steps | x oracle | collisions / episode |",
        "| --- | --- | --- | --- | --- |",
    ]
    for r in results:
        lines.append(
            f"| {r['policy']} | {r['success_rate']:.3f} | {r['mean_steps']:.2f} | "
            f"{r['duration_ratio_to_oracle']:.2f} | {r['collisions_per_episode']:.3f} |"
        )
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("eval_json", type=Path, nargs="+", help="one `swarmctl eval --json` per setting")
    ap.add_argument("--command", required=True, help="the training command line, as run")
    ap.add_argument(
        "--eval-command", required=True, action="append", help="the evaluation command line, as run (one per JSON)"
    )
    ap.add_argument("--notes", default="", help="extra paragraphs (Markdown)")
    args = ap.parse_args()
    if len(args.eval_command) != len(args.eval_json):
        ap.error("give one --eval-command per eval JSON")
    net, info = load_checkpoint(args.checkpoint)
    meta, train, world = info["metadata"], info["train"], info["world"]
    params = sum(p.numel() for p in net.parameters())
    lines = [
        f"# {args.checkpoint.name}",
        "",
        f"The shared Q-network ({params:,} parameters, architecture `{info['architecture']}`, observation "
        f"variant `{world.get('variant', 'paper')}`) trained with DDQL " + _trained_on(world, train),
        "",
        "## Training",
        "",
        f"    {args.command}",
        "",
        f"- episodes: {meta['episodes']} of {meta.get('episodes_planned', meta['episodes'])} planned; "
        f"{meta['samples']:,} samples (vehicle transitions), {meta['joint_steps']:,} joint steps of the "
        f"parallel episodes, {meta['updates']:,} gradient steps",
        f"- wall time: {meta['wall_time_s'] / 60:.1f} min on a 2-core x86_64 CPU (Python {platform.python_version()}, "
        f"torch {meta['torch']}, device {meta['device']}), {meta['samples_per_s']:.0f} samples/s, "
        "sharing the machine with other work",
        f"- seed {meta['seed']}, git commit {meta['git_commit']}" + _init_text(meta.get("init")),
        f"- weights sha256 {info['weights_sha256']}",
        "- hyperparameters: " + ", ".join(f"{k} = {v}" for k, v in train.items() if k != "extra"),
        "",
        f"Held-out evaluations during training ({train['eval_episodes']} episodes"
        + ("" if train.get("curriculum") else f" of at most {train.get('eval_steps', 40)} steps")
        + f", seed {train['eval_seed']}, "
        + ("under the hover and mask rules (`--rules`)" if train.get("rules") else "the network alone")
        + f" with softmax tau {train['eval_tau']}):",
        "",
        *_evals_table(meta["evals"]),
        "",
        "## Evaluation",
    ]
    for command, path in zip(args.eval_command, args.eval_json):
        lines += _eval_section(command, json.loads(path.read_text())["results"])
    if args.notes:
        lines += ["", args.notes]
    out = args.checkpoint.with_suffix(".md")
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
