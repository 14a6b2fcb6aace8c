"""Every experiment tool's fast mode: it runs, writes its JSON, PNG and table, a rerun runs nothing,
and its numbers hang together (CDFs monotone and ending at the success rate, the oracle a lower
bound, failures counted from the per-episode records)."""

import json

import numpy as np
import pytest

from swarmctl.policy.qnet import forward_flops, scales_forward_flops
from tools import experiments
from tools.exp import EXPERIMENTS, tasks
from tools.exp.common import PLANNERS, SEARCH_LABEL

pytestmark = pytest.mark.slow  # about 80 s for the seven fast modes


@pytest.mark.parametrize("name", list(EXPERIMENTS))
def test_the_full_presets_plan_valid_runs(name):
    module = EXPERIMENTS[name]
    runs = module.runs(experiments.parameters(module, False, []), 0)
    keys = [r.key for r in runs]
    assert len(set(keys)) == len(keys)
    assert all(n in keys for r in runs for n in r.needs)


@pytest.fixture(scope="module", params=list(EXPERIMENTS))
def fast(request, tmp_path_factory):
    """(name, output folder, NAME.json) of one experiment's fast mode."""
    name = request.param
    out = tmp_path_factory.mktemp(name)
    record = experiments.main([name, "--fast", "--out", str(out), "--seed", "3"])[name]
    return name, out, record


def eval_results(record: dict) -> list[list[dict]]:
    return [r["results"] for r in record["runs"].values() if "results" in r]


def test_fast_mode_writes_json_png_and_table(fast):
    name, out, record = fast
    assert record["preset"] == "fast" and record["seed"] == 3
    assert record["runs_done"] == record["runs_total"] == len(list((out / "runs").glob("*.json")))
    assert (out / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert record["summary"]["ours"].startswith("FAST MODE, NOT A RESULT")
    assert "|" in (out / f"{name}.md").read_text()
    assert json.loads((out / f"{name}.json").read_text()) == record


def test_a_rerun_runs_nothing(fast, monkeypatch):
    name, out, record = fast

    def refuse(*args):
        raise AssertionError("a done run was run again")

    monkeypatch.setattr(tasks, "TASKS", {k: refuse for k in tasks.TASKS})
    again = experiments.main([name, "--fast", "--out", str(out), "--seed", "3"])[name]
    assert again["runs"] == record["runs"]


def test_every_table_has_the_planners_and_the_oracle_bound(fast):
    for results in eval_results(fast[2]):
        names = [r["policy"] for r in results]
        assert set(PLANNERS) | {"oracle"} <= set(names)
        assert (SEARCH_LABEL in names) == (fast[0] != "mavlink")  # search.pt beside every paper experiment
        oracle = results[names.index("oracle")]
        for r in results:
            assert 0.0 <= r["success_rate"] <= 1.0
            assert r["mean_steps"] >= oracle["mean_steps"] - 1e-9  # the oracle is a lower bound
            assert len(r["per_episode"]) == r["episodes"]


def test_cdfs_are_monotone_and_end_at_the_success_rate(fast):
    for results in eval_results(fast[2]):
        for r in results:
            cdf = np.array(r["steps_cdf"])
            assert (np.diff(cdf) >= 0).all() and cdf[-1] == pytest.approx(r["success_rate"])


def test_the_figures_data_match_the_runs(fast):
    name, out, record = fast
    s, p = record["summary"], record["params"]
    if name == "transfer":
        assert {(q["src"], q["uavs"]) for q in s["panels"]} == {("cluster", u) for u in p["uavs"]} | {
            ("sparse", u) for u in p["uavs"]
        }
        key = f"train-cluster-to-sparse-u{p['uavs'][0]}"
        assert all((out / "runs" / f"{key}.ep{n}.pt").exists() for n in p["n_t"])
    elif name == "obstacles":
        assert [len(q["softmax"]) for q in s["panels"]] == [len(p["train_uavs"])] * len(p["test_uavs"])
    elif name == "bigmaps":
        assert len(s["table"]) == len(p["maps"]) * len(p["clusters"]) * len(p["etas"]) * (len(p["etas"]) + 7)
    elif name == "chicago":
        (results,) = eval_results(record)
        for row in s["table"]:
            r = next(x for x in results if x["policy"] == row["policy"])
            assert row["failures"] == round((1 - r["success_rate"]) * r["episodes"])
        for label, counts in s["failures"].items():
            assert sum(counts.values()) == next(t["failures"] for t in s["table"] if t["policy"] == label)
    elif name == "cost":
        assert all(r["flops_per_decision"] in (None, forward_flops(20), scales_forward_flops()) for r in s["table"])
        assert SEARCH_LABEL in {r["policy"] for r in s["table"]}
        assert all(r["ms_per_vehicle_batch1"] > 0 for r in s["table"])
        assert [t["stages"] for t in s["training"]] == [2, 3, 6, 1] and all(t["wall_min"] > 0 for t in s["training"])
    elif name == "mavlink":
        flown = [r for r in record["runs"].values() if "knowledge_delivered" in r]
        assert flown and all(r["knowledge_delivered"] > 0 for r in flown)  # the agents shared on the bus
        for row in s["table"]:
            for side in ("simulator", "mavlink") if "mavlink_steps" in row else ("simulator",):
                assert row[f"{side}_steps"] <= p["steps"]
                if not row[f"{side}_success"]:
                    assert row[f"{side}_steps"] == p["steps"]
