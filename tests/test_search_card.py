"""tools/search_card.py: the card and learning curve of a `train-search` checkpoint (every stage, its
opening, the teacher's bars, the validation rows, a held-out test with its paired difference), and of a
checkpoint whose metadata lacks keys. The checkpoint is written as the recipe writes one (its metadata,
its Progress record, its CSV's columns), without training."""

from __future__ import annotations

import csv
import json
import math
import shutil
from dataclasses import asdict
from pathlib import Path

import pytest
import torch

from swarmctl.learn.search_config import SEARCH_CURRICULA, SearchConfig
from swarmctl.learn.search_recipe import METRICS, RECIPE, Progress, flight_rules
from swarmctl.policy.checkpoint import save_checkpoint
from swarmctl.policy.qnet import make_network
from swarmctl.world.config import WorldConfig
from tools.planner_table import SETTINGS, slug
from tools.search_card import main, write_card

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
WORLD = WorldConfig(window=8)
CONFIG = SearchConfig(curriculum="tiny", episodes=12, eval_every=4, val_episodes=2)
STAGES = SEARCH_CURRICULA["tiny"]
OPEN, OBSTACLES = (stage.worlds[0].name for stage in STAGES)
TEACHER = {OPEN: 0.95, OBSTACLES: 0.85}
EVALS = [  # the second stage opens at episode 4: 0.8 >= advance_share 0.8 x 0.95
    {
        "episodes": 4,
        "stage": 0,
        "success_rate": 0.8,
        "mean_steps": 12.5,
        "stage_success": 0.8,
        "teacher_stage_success": 0.95,
        "worlds": {OPEN: {"success_rate": 0.8, "mean_steps": 12.5}},
    },
    {
        "episodes": 8,
        "stage": 1,
        "success_rate": 0.7,
        "mean_steps": 14.25,
        "stage_success": 0.5,
        "teacher_stage_success": 0.85,
        "worlds": {
            OPEN: {"success_rate": 0.9, "mean_steps": 11.0},
            OBSTACLES: {"success_rate": 0.5, "mean_steps": 17.5},
        },
    },
]
COUNTS = dict(samples=1234, demo_samples=567, updates=89)


def write_run(path: Path) -> Path:
    """A checkpoint saved at episode 8 of 12 (both stages open) and its CSV, one row beyond it."""
    progress = Progress(episodes_done=8, rounds=2, stage=1, stage_opened=[0, 4], teacher=TEACHER, evals=EVALS, **COUNTS)
    metadata = {
        "recipe": RECIPE,
        "scenario": "search curriculum tiny",
        "stages": [s.name for s in STAGES],
        "stage_reached": 1,
        "episodes": 8,
        "episodes_planned": 12,
        "seed": 0,
        "git_commit": "abc1234",
        "wall_time_s": 7200.0,
        **COUNTS,
        "train_samples_per_s": 321.5,
        "teacher_val_success": TEACHER,
        "evals": EVALS,
        "changes": [{"episode": 4, "option": "demo_share_end", "from": 0.1, "to": 0.5}],
        "final_eval": EVALS[-1],
        "torch": str(torch.__version__),
        "device": "cpu",
    }
    train = {**asdict(CONFIG), "recipe": flight_rules(WORLD)}
    net = make_network(WORLD.variant, WORLD.window)
    save_checkpoint(path, net, WORLD.as_dict(), train, metadata, resume={"progress": asdict(progress)})
    with open(path.with_suffix(".csv"), "w", newline="") as fh:
        out = csv.DictWriter(fh, METRICS)
        out.writeheader()
        for episodes, stage, loss in ((4, 1, 2.5), (8, 1, 1.5), (12, 1, 1.0)):
            out.writerow(dict(episodes=episodes, stage=stage, loss=loss, tdn=loss / 2, margin=0.3, demo_share=0.4))
    return path


@pytest.fixture
def run(tmp_path: Path) -> Path:
    return write_run(tmp_path / "run" / "search.pt")


def outcome_file(path: Path, policy: str, wins: list[bool]) -> None:
    """A result as tools/planner_table.py writes it (run_policy's record) on episodes of seed 5."""
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {
        "policy": policy,
        "seed": 5,
        "episodes": len(wins),
        "success_rate": sum(wins) / len(wins),
        "mean_steps": 20.0,
        "duration_ratio_to_oracle": 1.5,
        "per_episode": [{"episode": i, "steps": 20, "success": w} for i, w in enumerate(wins)],
    }
    path.write_text(json.dumps(record))


def test_the_card_names_every_stage_its_opening_the_teacher_bars_and_the_tests(run: Path, tmp_path: Path):
    results = tmp_path / "planners" / "5"
    policy = "ddql:models/search.pt"
    outcome_file(results / "cluster2" / f"{slug(policy)}.json", policy, [True, True, False, True])
    outcome_file(results / "cluster2" / "coordinated.json", "coordinated", [True, False, False, False])
    outcome_file(results / "sparse2" / "coordinated.json", "coordinated", [True] * 4)
    notes = tmp_path / "notes.md"
    notes.write_text("## Notes\n\nA closing paragraph.\n")

    sessions = "swarmctl train-search --curriculum tiny\nswarmctl train-search --curriculum tiny --resume"
    card, png = write_card(run, sessions, tmp_path / "card.md", results, policy, notes=notes)
    text = card.read_text()

    assert png == tmp_path / "card.png" and png.read_bytes().startswith(PNG_MAGIC)
    assert f"![learning curve]({png.name})" in text and text.endswith("A closing paragraph.\n")
    assert "    swarmctl train-search --curriculum tiny\n    swarmctl train-search --curriculum tiny --resume" in text
    assert "- on --resume from episode 4: demo_share_end 0.1 -> 0.5" in text
    assert "hover = no, mask = yes, taken = keep" in text and f"recipe `{RECIPE}`" in text
    saved = torch.load(run, map_location="cpu", weights_only=True)
    assert f"weights sha256 {saved['weights_sha256']}" in text
    assert "- episodes: 8 of 12 planned (student episodes); stage reached: stage 1 (10x10 obstacles)" in text
    assert "1,234 student samples (vehicle transitions) and 567 demonstration samples" in text
    assert "89 gradient updates" in text and "2.00 h" in text and "321.5 student samples/s" in text
    assert "seed 0, git commit abc1234" in text and "lr = 0.001" in text
    assert f"| 0: {STAGES[0].name} | 0 | {OPEN} | 0.950 | 0.760 |" in text  # the bar: 0.8 x 0.95
    assert f"| 1: {STAGES[1].name} | 4 | {OBSTACLES} | 0.850 | - (the last stage) |" in text
    assert "validation seed 7919, 2 episodes per world" in text
    assert f"| episodes | stage | success | mean steps | {OPEN} | {OBSTACLES} |" in text
    assert "| 4 | 0 | 0.800 | 12.50 | 0.800 |  |" in text and "| 8 | 1 | 0.700 | 14.25 | 0.900 | 0.500 |" in text
    assert "(its row after this checkpoint's episode left out)" in text

    # the held-out test: 0.75 +- sqrt(0.75 x 0.25 / 4); differences 0, 1, 0, 1: +0.5 +- sqrt(1/3) / 2
    assert f"    swarmctl eval {SETTINGS['cluster2']['command']} --episodes 4 --seed 5 --policy {policy}" in text
    assert f"| {policy} | 0.750 +- {math.sqrt(0.75 * 0.25 / 4):.3f} | 20.0 | 1.50 |" in text
    assert "| coordinated (teacher) | 0.250 +- 0.217 | 20.0 | 1.50 |" in text
    assert f"over the 4 episodes both played: +0.500 +- {math.sqrt(1 / 3) / 2:.3f} (paired)" in text
    assert "sparse2 (no ddql_models_search.pt.json)" in text and "chicago (no " in text


def test_a_checkpoint_lacking_metadata_keys_still_renders(run: Path, tmp_path: Path, capsys):
    saved = torch.load(run, map_location="cpu", weights_only=True)
    saved["metadata"] = {"stages": saved["metadata"]["stages"]}
    saved["resume"] = None  # a finished run's checkpoint: no record of the stage openings
    for key in ("val_seed", "advance_share", "recipe"):
        del saved["train"][key]
    old = tmp_path / "old.pt"
    torch.save(saved, old)
    shutil.copyfile(run.with_suffix(".csv"), old.with_suffix(".csv"))

    assert main([str(old), "--command", "swarmctl train-search"]) == 0
    text = old.with_suffix(".md").read_text()
    assert old.with_suffix(".png").read_bytes().startswith(PNG_MAGIC)
    assert "- episodes: unknown of unknown planned" in text and "git commit unknown" in text
    assert "hover = unknown" in text and "advance_share = unknown" in text
    assert f"| 1: {STAGES[1].name} | 4 (from the CSV) |" in text  # its first row at stage 1
    assert "The checkpoint holds no evaluation." in text

    assert main([str(old), "--command", "x", "--out", str(tmp_path / "card.txt")]) == 2
    assert "give a .md path" in capsys.readouterr().err


def test_a_shipped_copy_keeps_the_weights_and_the_counters_and_drops_the_trainer_state(run: Path, tmp_path: Path):
    from tools.ship_model import main as ship_main

    payload = torch.load(run, weights_only=True)
    payload["resume"]["optimizer"] = {"state": {}, "param_groups": []}
    torch.save(payload, run)
    shipped = tmp_path / "models" / "search.pt"
    assert ship_main([str(run), str(shipped), "--change", "6", "demo_share_start", "0.5", "0.7"]) == 0
    copy = torch.load(shipped, weights_only=True)
    assert copy["weights_sha256"] == payload["weights_sha256"] and list(copy["resume"]) == ["progress"]
    assert copy["metadata"]["changes"][-1] == {"episode": 6, "option": "demo_share_start", "from": 0.5, "to": 0.7}
    card, _ = write_card(shipped, "swarmctl train-search", tmp_path / "card.md")
    assert "- on --resume from episode 6: demo_share_start 0.5 -> 0.7" in card.read_text()
    assert ship_main([str(run), str(shipped), "--change", "x", "demo_share_start", "0.5", "0.7"]) == 2
    assert ship_main([str(run), str(shipped), "--change", "6", "lr", "0.5", "0.7"]) == 2
