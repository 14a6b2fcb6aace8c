"""docs/RESULTS.md's experiment sections: written from the committed results by
`tools/experiments.py --report`, fast-mode records never reported, runs not done named."""

import json
import shutil

from tools.exp import EXPERIMENTS
from tools.exp.report import BEGIN, END, render, update
from tools.exp.runs import ROOT

RESULTS = ROOT / "results/experiments"


def test_results_md_is_what_the_report_writes_from_the_committed_results():
    text = (ROOT / "docs/RESULTS.md").read_text()
    generated = text.split(BEGIN, 1)[1].split(END, 1)[0]
    assert generated.strip() == render(EXPERIMENTS, RESULTS, "../results/experiments").strip()


def test_every_figure_the_report_shows_is_committed():
    body = render(EXPERIMENTS, RESULTS, "../results/experiments")
    shown = [name for name in EXPERIMENTS if f"({'../results/experiments'}/{name}/{name}.png)" in body]
    assert shown and all((RESULTS / name / f"{name}.png").exists() for name in shown)


def test_fast_records_are_never_reported_and_missing_runs_are_named(tmp_path):
    (tmp_path / "chicago").mkdir()
    (tmp_path / "chicago" / "chicago.json").write_text(json.dumps({"preset": "fast"}))
    record = json.loads((RESULTS / "swarm" / "swarm.json").read_text())
    done = sorted(record["runs"])
    record["runs"] = {k: record["runs"][k] for k in done[:-1]}  # one run cut
    record["runs_done"] = len(record["runs"])
    (tmp_path / "swarm").mkdir()
    (tmp_path / "swarm" / "swarm.json").write_text(json.dumps(record))
    body = render(EXPERIMENTS, tmp_path, "figs")
    chicago = body.split("(`chicago`)", 1)[1].split("###", 1)[0]
    assert "Not run here yet" in chicago and "|" not in chicago
    swarm = body.split("(`swarm`)", 1)[1].split("###", 1)[0]
    assert f"Not run yet: {done[-1]}" in swarm and "(figs/swarm/swarm.png)" in swarm


def test_update_rewrites_only_between_the_markers(tmp_path):
    doc = tmp_path / "RESULTS.md"
    doc.write_text("# Before\n")
    first = update(doc, EXPERIMENTS, tmp_path, "figs")
    doc.write_text(first + "\n## After\n")
    (tmp_path / "cost").mkdir()
    shutil.copy(RESULTS / "cost" / "cost.json", tmp_path / "cost" / "cost.json")
    second = update(doc, EXPERIMENTS, tmp_path, "figs")
    assert second.startswith("# Before\n") and second.endswith("\n## After\n")
    assert second.count(BEGIN) == second.count(END) == 1
    assert "(figs/cost/cost.png)" in second and "(figs/cost/cost.png)" not in first
