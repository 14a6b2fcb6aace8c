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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("eval_json", type=Path)
    ap.add_argument("--command", required=True, help="the training command line, as run")
    ap.add_argument("--eval-command", required=True, help="the evaluation command line, as run")
    ap.add_argument("--notes", default="", help="extra paragraphs (Markdown)")
    args = ap.parse_args()
    _, info = load_checkpoint(args.checkpoint)
    meta, train, world = info["metadata"], info["train"], info["world"]
    results = json.loads(args.eval_json.read_text())["results"]
    sc = results[0]["scenario"]
    lines = [
        f"# {args.checkpoint.name}",
        "",
        f"The shared Q-network (76,509 parameters, the paper's 3 conv + 2 linear layers) trained with DDQL on the "
        f"**{world['scenario']}** scenario: {world['map_size']} x {world['map_size']} map, {world['uavs']} UAVs, "
        f"{world['targets']} targets, obstacles eta = {world['obstacles']}, window F = {world['window']}"
        + (
            ", trained on observations with taken targets removed (`--remove-taken`)."
            if world.get("remove_taken")
            else "."
        ),
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
        f"Held-out evaluations during training ({train['eval_episodes']} episodes of at most "
        f"{train.get('eval_steps', 40)} steps, seed {train['eval_seed']}, "
        + ("under the hover and mask rules (`--rules`)" if train.get("rules") else "the network alone")
        + f" with softmax tau {train['eval_tau']}):",
        "",
        "| episodes | success | mean steps |",
        "| --- | --- | --- |",
        *[f"| {e['episodes']} | {e['success_rate']:.3f} | {e['mean_steps']:.2f} |" for e in meta["evals"]],
        "",
        "## Evaluation",
        "",
        f"    {args.eval_command}",
        "",
        f"{results[0]['episodes']} test episodes (seed {results[0]['seed']}, never used in training), "
        f"{sc['steps']}-step limit, all policies on the same episodes:",
        "",
        "| policy | success | mean steps | x oracle | collisions / episode |",
        "| --- | --- | --- | --- | --- |",
    ]
    for r in results:
        ratio = r["duration_ratio_to_oracle"]
        lines.append(
            f"| {r['policy']} | {r['success_rate']:.3f} | {r['mean_steps']:.2f} | "
            f"{ratio:.2f} | {r['collisions_per_episode']:.3f} |"
        )
    if args.notes:
        lines += ["", args.notes]
    out = args.checkpoint.with_suffix(".md")
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
