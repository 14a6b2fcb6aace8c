"""Fault injection, one part of the controller at a time: an unexpected error (a bug, a reply nothing
foresaw) raised mid-search in the decision round, the policy, the knowledge exchange, the recorder, a
driver or the live table. Every vehicle in the air still gets its end action, the exit status says
the mission failed (the live table's fault only turns the table off), and the recording reads to its
last line and says where it happened."""

from __future__ import annotations

import json

import pytest

from swarmctl.errors import EXIT_FAILED
from swarmctl.mission.events import check_event
from swarmctl.mission.service import LiveView, fault_line, run_controller
from swarmctl.sim.swarm import SimSwarm
from tests.fault_entry import failing, parts
from tests.mission_support import small_grid

PARTS = parts()

FAST = dict(takeoff_at_once=4, end_timeout=20.0)


def lines(folder) -> list[dict]:
    """events.jsonl, every line parsed and checked against the schema (a line cut short fails here)."""
    out = []
    for line in (folder / "events.jsonl").read_text().splitlines():
        event = json.loads(line)
        check_event(event, strict=True)
        out.append(event)
    return out


def fly_with(monkeypatch, tmp_path, target, name, at, view=None):
    monkeypatch.setattr(target, name, failing(getattr(target, name), at))
    with SimSwarm(small_grid(), uavs=2, seed=3, speedup=60.0) as swarm:
        plan = swarm.plan("frontier", end_action="rtl", time_limit=20.0, **FAST)
        code, summary = run_controller(plan, tmp_path, view)
        for mock in swarm.mocks:
            mock.wait_for(lambda m: not m.state().armed, 60)  # home and disarmed: the end action flew
    return code, summary


@pytest.mark.parametrize("part", sorted(PARTS))
def test_a_fault_in_each_part_still_brings_every_vehicle_home(part, monkeypatch, tmp_path):
    target, name, at = PARTS[part]
    code, summary = fly_with(monkeypatch, tmp_path, target, name, at)
    assert code == EXIT_FAILED and summary["outcome"] == "failed"
    fault = summary["fault"]
    assert fault["part"] == "mission" and fault["error"].startswith("Injected: injected on call")
    assert fault["where"].startswith("swarmctl/") and " in " in fault["where"]
    assert [v["end_action"] for v in summary["vehicles"]] == ["rtl", "rtl"]
    assert [v["end_state"] for v in summary["vehicles"]] == ["landed at home"] * 2
    recorded = lines(tmp_path)
    if part != "recorder":  # its step records are what failed; the events around them are there
        assert any(e["event"] == "step" for e in recorded)
    assert [e["error"] for e in recorded if e["event"] == "fault"] == [fault["error"]]
    ended = sorted(e["vehicle"] for e in recorded if e["event"] == "end_action" and e["action"] == "rtl")
    assert ended == sorted(v["name"] for v in summary["vehicles"])
    assert [e["outcome"] for e in recorded if e["event"] == "end"] == ["failed"]
    assert "Injected: injected on call" in (tmp_path / "fault.txt").read_text()
    assert "every vehicle in the air was given its end action" in fault_line(summary, tmp_path)


def test_a_fault_in_the_live_table_turns_it_off_and_the_search_goes_on(monkeypatch, tmp_path):
    code, summary = fly_with(monkeypatch, tmp_path, LiveView, "__call__", 4, view=LiveView(live=False, quiet=False))
    assert summary["fault"] is None  # the mission was not stopped by it
    assert summary["outcome"] in ("complete", "time limit") and summary["steps"] > 3
    assert code == (0 if summary["outcome"] == "complete" else EXIT_FAILED)
    recorded = lines(tmp_path)
    faults = [e for e in recorded if e["event"] == "fault"]
    assert len(faults) == 1 and faults[0]["part"] == "live view"
    assert [v["end_action"] for v in summary["vehicles"]] == ["rtl", "rtl"]


def test_a_fault_in_the_live_pages_server_answers_500_and_the_search_flies_on(monkeypatch, tmp_path):
    import threading
    import urllib.error
    import urllib.request

    from swarmctl.mission.web import LiveSite
    from swarmctl.mission.web_page import WebSetup

    monkeypatch.setattr(LiveSite, "snapshot", failing(LiveSite.snapshot, 1))
    answers: list[int] = []
    askers: list[threading.Thread] = []

    def ask(url: str) -> None:  # on the controller's loop: the requests come from a thread
        def get() -> None:
            for _ in range(3):
                try:
                    urllib.request.urlopen(url.split("#")[0] + "live/state", timeout=10)
                except urllib.error.HTTPError as exc:
                    answers.append(exc.code)

        askers.append(threading.Thread(target=get, daemon=True))
        askers[-1].start()

    with SimSwarm(small_grid(), uavs=2, seed=3, speedup=60.0) as swarm:
        plan = swarm.plan("frontier", end_action="rtl", time_limit=20.0, **FAST)
        setup = WebSetup("127.0.0.1", 0, "a-token-for-this-test-only-0123")
        code, summary = run_controller(plan, tmp_path, None, web=setup, on_web=ask)
        for mock in swarm.mocks:
            mock.wait_for(lambda m: not m.state().armed, 60)
    askers[0].join(10)
    assert answers == [500, 500, 500]
    assert summary["fault"] is None  # the mission was not stopped by it
    assert summary["outcome"] in ("complete", "time limit") and summary["steps"] > 3
    faults = [e for e in lines(tmp_path) if e["event"] == "fault"]
    assert len(faults) == 1 and faults[0]["part"] == "web page" and faults[0]["error"].startswith("Injected")
    assert [v["end_action"] for v in summary["vehicles"]] == ["rtl", "rtl"]
