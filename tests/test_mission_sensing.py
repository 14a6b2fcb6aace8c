"""Sensing from where the vehicle is, and knowledge without a hub: mock vehicles with no detector
search (coverage), the agents share in the process, each agent's TUNNEL goes out once on its own
vehicle's link; the sensed disc is the model's fov; a report is used only where the vehicle was."""

from __future__ import annotations

import json
from collections import Counter
from types import SimpleNamespace

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.knowledge.model import disc_cells
from swarmctl.mission.recorder import Recorder
from swarmctl.mission.sensing import sense
from swarmctl.sim.detector import SimDetector
from swarmctl.sim.swarm import SimSwarm
from tests.mission_support import fly, our_threads, small_grid


class LinkCounter(Recorder):
    """A recorder that also counts, per vehicle link, the TUNNEL frames the controller writes on it."""

    def __init__(self, folder):
        super().__init__(folder)
        self.written: dict[str, Counter] = {}

    def tap_link(self, link) -> None:
        super().tap_link(link)
        inner, parser = link.mav.file, mavlink2.MAVLink(None)
        counts = self.written.setdefault(str(link.endpoint), Counter())

        class _Count:
            def write(self, data: bytes) -> None:
                for m in parser.parse_buffer(bytes(data)) or []:
                    if m.get_type() == "TUNNEL":
                        counts[(m.get_srcSystem(), m.get_srcComponent())] += 1
                inner.write(data)

        link.mav.file = _Count()


def knowledge_lines(folder) -> list[dict]:
    path = folder / "knowledge.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.is_file() else []


def tunnels_in_tlog(path) -> Counter:
    log = mavutil.mavlink_connection(str(path))
    counts: Counter = Counter()
    while (m := log.recv_match(type="TUNNEL")) is not None:
        counts[(m.get_srcSystem(), m.get_srcComponent())] += 1
    return counts


@pytest.mark.slow
def test_without_detectors_the_swarm_searches_and_shares_with_no_knowledge_section(tmp_path, monkeypatch):
    """The issue's flight (frontier, no detector, no [knowledge] section), on mock ArduCopters."""
    import tests.mission_support as support

    grid = small_grid(16, 16)
    monkeypatch.setattr(support, "Recorder", LinkCounter)
    with SimSwarm(grid, uavs=3, seed=11, speedup=30.0, carry_detectors=False) as swarm:
        plan = swarm.plan("frontier", end_action="land", time_limit=12.0)
        assert plan.spec.knowledge.channel is None and plan.detectors == {} and not plan.onboard
        assert swarm.radio is None  # no hub: nothing is started for the knowledge
        controller, outcome = fly(plan, tmp_path)
        links = {str(s.connection): s.sysid for s in swarm.specs}
    assert outcome == "time limit"  # a coverage search finds nothing and ends at its time limit
    agents = controller.agents
    assert all(a.end_state == "landed" for a in agents) and not any(a.knowledge.targets for a in agents)
    # every vehicle searched: distinct cells each, none shared between vehicles at a step
    steps = [e for e in map(json.loads, (tmp_path / "events.jsonl").read_text().splitlines()) if e["event"] == "step"]
    for a in agents:
        cells = {tuple(v["cell"]) for e in steps for v in e["vehicles"] if v["vehicle"] == a.name}
        assert len(a.visited) >= 5 and len(cells) >= 4, (a.name, sorted(a.visited))
    for e in steps:
        held = [tuple(v["cell"]) for v in e["vehicles"]]
        assert len(held) == len(set(held))
    # explored cells grow, and each agent knows what the others explored (it never flew there)
    for a in agents:
        counts = [e["cells"] for e in knowledge_lines(tmp_path) if e["vehicle"] == a.name]
        assert counts == sorted(counts) and counts[-1] > counts[0]
        own = np.zeros_like(a.knowledge.explored)
        for cell in a.visited:
            c = disc_cells(cell, grid.width, grid.height, plan.fov)
            own[c[:, 0], c[:, 1]] = True
        assert (a.knowledge.explored & ~own).any()  # cells only the others explored
        assert set(a.knowledge.positions) == {0, 1, 2}
        assert a.exchange.stats["received_packets"] > 0 and a.exchange.codec.rejected.total() == 0
        # obstacles sensed are the grid's blocked cells, and only where explored
        assert np.array_equal(a.knowledge.obstacle, a.knowledge.explored & grid.blocked)
    # each agent's TUNNEL frames went out once, on its own vehicle's link only, and the tlog holds them once
    rec = controller.rec
    for endpoint, counts in rec.written.items():
        sysid = links[endpoint]
        mine = next(a for a in agents if a.spec.sysid == sysid)
        assert dict(counts) == {(sysid, 191): mine.exchange.stats["sent_packets"]}
        assert mine.exchange.stats["link_packets"] == mine.exchange.stats["sent_packets"] > 0
    assert tunnels_in_tlog(tmp_path / "mission.tlog") == Counter(
        {(a.spec.sysid, 191): a.exchange.stats["sent_packets"] for a in agents}
    )
    assert controller.bus.counters()["lost"] == 0 and controller.bus.delivered > 0
    assert not our_threads()


@pytest.mark.slow
def test_a_model_trained_with_fov_2_senses_a_disc_of_radius_2_in_the_field(tmp_path):
    import torch

    from swarmctl.policy.checkpoint import save_checkpoint
    from swarmctl.policy.qnet import QNetwork

    torch.manual_seed(0)
    model = tmp_path / "fov2.pt"
    save_checkpoint(model, QNetwork(window=20), {"window": 20, "fov": 2.0}, {}, {"note": "untrained, for tests"})
    grid = small_grid(12, 12)
    with SimSwarm(grid, uavs=1, seed=3, speedup=30.0, carry_detectors=False) as swarm:
        plan = swarm.plan(f"ddql:{model}:tau=1.0", end_action="land", time_limit=4.0)
        assert plan.fov == 2.0 and plan.spec.mission.footprint_m == 20.0
        controller, _ = fly(plan, tmp_path / "rec")
    (a,) = controller.agents
    assert a.visited
    expected = np.zeros_like(a.knowledge.explored)
    for cell in a.visited:
        c = disc_cells(cell, grid.width, grid.height, 2.0)
        expected[c[:, 0], c[:, 1]] = True
    assert np.array_equal(a.knowledge.explored, expected)  # radius 2 (13 cells a disc), not the planners' 3
    first = knowledge_lines(tmp_path / "rec")[0]
    assert first["cells"] <= 13


@pytest.mark.slow
def test_a_swarm_with_nothing_hidden_searches_until_its_time_limit(tmp_path):
    """Zero targets: the simulated detectors report empty footprints (they crashed in value_map)."""
    grid = small_grid()
    with SimSwarm(grid, uavs=2, seed=5, speedup=30.0, targets=np.zeros((0, 2), dtype=np.int64)) as swarm:
        plan = swarm.plan("frontier", end_action="land", time_limit=5.0)
        assert set(plan.detectors.values()) == {"mavlink"}
        controller, outcome = fly(plan, tmp_path)
        sent = [d.sent_reports for d in swarm.detectors]
    assert outcome == "time limit" and all(n > 0 for n in sent)
    for a in controller.agents:
        assert a.feed.reports > 0 and not a.knowledge.targets and a.knowledge.explored.sum() >= 29


def test_the_simulated_detector_reports_an_empty_view_with_zero_targets():
    d = SimDetector(small_grid(), np.zeros((0, 2), dtype=np.int64), 0, 7, 40.0)
    cells, phi, obstacle, targets = d.observe((3, 3))
    assert len(cells) == 29 and not phi.any() and targets.shape == (0, 2)
    assert len(d.payloads((3, 3))) == 1  # a DELTA, no DETECTION


def test_reports_count_only_within_the_footprints_of_cells_the_vehicle_reached():
    grid = small_grid(20, 20)
    report = SimpleNamespace(
        cell=(5, 5),
        cells=np.array([[5, 5], [6, 5], [9, 5], [5, 8]]),  # (9, 5) is 4 cells away: outside a radius of 3
        phi=np.array([1.0, 0.6, 0.9, 0.2], dtype=np.float32),
        obstacle=np.array([False, False, False, False]),
        targets=np.array([[5, 5], [9, 5]]),
    )
    elsewhere = SimpleNamespace(**{**vars(report), "cell": (15, 15)})  # a cell it never reached
    s = sense(grid, 3.0, (5, 5), [report, elsewhere], visited={(5, 5)})
    assert {tuple(t) for t in s.targets} == {(5, 5)}
    assert s.dropped == 2 + 6  # one cell and one target outside; the whole report for (15, 15)
    reported = {tuple(c): p for c, p in zip(s.cells[29:], s.phi[29:])}
    assert reported == {(5, 5): 1.0, (6, 5): pytest.approx(0.6), (5, 8): pytest.approx(0.2)}
    disc = s.cells[:29]  # the footprint from the position comes first: phi 0, the grid's obstacles
    assert len(disc) == 29 and not s.phi[:29].any()
    assert np.array_equal(s.obstacle[:29], grid.blocked[disc[:, 0], disc[:, 1]])
    late = sense(grid, 3.0, None, [report], visited={(5, 5)})  # a late report: only its own part
    assert {tuple(t) for t in late.targets} == {(5, 5)} and len(late.cells) == 3
    assert sense(grid, 3.0, None, [], visited=set()).cells.shape == (0, 2)
