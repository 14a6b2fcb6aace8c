"""The decision inputs (swarmctl.mission.inputs): what the recorder writes of each round's beliefs reads
back as the very Beliefs the policy was given, and every policy decides on them what it decided live."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.knowledge.model import Knowledge, Position, disc_cells
from swarmctl.mission.decide import FieldPolicy
from swarmctl.mission.events import check_event
from swarmctl.mission.inputs import InputsDecoder, InputsEncoder, InputsError
from swarmctl.world.moves import MOVES

MODEL = Path(__file__).resolve().parent.parent / "models" / "obstacles-3uav.pt"
POLICIES = ["frontier", "la:2", "lawnmower", "random", f"ddql:{MODEL}:straggler=frontier", f"ddql-greedy:{MODEL}"]
FIELDS = ("explored", "phi_hat", "obstacles", "targets", "positions", "hovering", "me", "episodes", "heard")


class _World:
    """n vehicles walking a w x h grid with random truth, sharing some of what they sense."""

    def __init__(self, rng: np.random.Generator, n: int, w: int, h: int):
        self.rng, self.n, self.w, self.h = rng, n, w, h
        self.phi = rng.random((w, h)) * (rng.random((w, h)) < 0.3)
        self.obstacle = rng.random((w, h)) < 0.1
        self.cells = [(int(rng.integers(w)), int(rng.integers(h))) for _ in range(n)]
        self.knowledge = [Knowledge(w, h, vehicle_id=i) for i in range(n)]

    def round(self, step: int) -> None:
        rng = self.rng
        for i, kn in enumerate(self.knowledge):
            dx, dy = MOVES[rng.integers(5)]
            x, y = self.cells[i]
            self.cells[i] = (int(np.clip(x + dx, 0, self.w - 1)), int(np.clip(y + dy, 0, self.h - 1)))
            kn.set_position(step, self.cells[i], bool(rng.random() < 0.2))
            c = disc_cells(self.cells[i], self.w, self.h, float(rng.integers(1, 3)))
            kn.sense(c, self.phi[c[:, 0], c[:, 1]], self.obstacle[c[:, 0], c[:, 1]])
            if rng.random() < 0.3:
                kn.add_targets([self.cells[i]], step)
        for i, kn in enumerate(self.knowledge):
            for j in range(self.n):
                if j != i and rng.random() < 0.5:  # some pairs share, some do not
                    kn.merge(self.knowledge[j])
                    kn.merge_position(j, Position(step, self.cells[j], bool(rng.random() < 0.3)))


def _rounds(seed: int, n: int, w: int, h: int, rounds: int, everyone: bool = False):
    """(step, deciders, Knowledge list) of each round of a random mission (deciders: a random subset, or
    every vehicle)."""
    rng = np.random.default_rng(seed)
    world = _World(rng, n, w, h)
    for step in range(1, rounds + 1):
        world.round(step)
        deciders = sorted(int(i) for i in rng.choice(n, size=int(rng.integers(1, n + 1)), replace=False))
        deciders = list(range(n)) if everyone else deciders
        yield step, deciders, [world.knowledge[i].copy() for i in deciders]


def _same(a, b) -> None:
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and np.array_equal(x, y), name
    assert a.step == b.step and a.settings == b.settings
    assert np.array_equal(a.value_channel(True), b.value_channel(True))


@settings(max_examples=40, deadline=None)
@given(
    st.integers(0, 10_000),
    st.integers(1, 5),
    st.integers(2, 12),
    st.integers(2, 12),
    st.integers(1, 6),
    st.integers(1, 3),
)
def test_inputs_read_back_as_the_beliefs_written(seed, n, w, h, rounds, key_every):
    """Every round, whatever the deciders, the sharing and the key rounds: the same Beliefs, bit for bit,
    and each line is valid under the recorded schema."""
    policy = FieldPolicy("frontier", seed=seed)
    encoder, decoder = InputsEncoder(key_every), InputsDecoder(w, h, n)
    for step, deciders, knowledges in _rounds(seed, n, w, h, rounds):
        beliefs = policy.beliefs(knowledges, step - 1, n)
        line = encoder.line(step, [f"v{i}" for i in deciders], beliefs, [(-1, (0, 0))])
        line = json.loads(json.dumps({"t": 0.0, "event": "inputs", **line}))
        assert check_event(line, strict=True) == "inputs"
        _same(decoder.beliefs(line, deciders, policy.settings), beliefs)


@pytest.mark.parametrize("spec", POLICIES)
@settings(max_examples=15, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 4), st.integers(4, 10), st.integers(2, 5))
def test_each_policy_decides_on_the_read_back_inputs_what_it_decided_live(spec, seed, n, size, rounds):
    """The live policy on the live beliefs, and a second one (as --verify builds it) on the beliefs read
    back from the lines, round after round (lawnmower keeping its lanes in both): the same moves."""
    live, again = FieldPolicy(spec, seed=seed), FieldPolicy(spec, seed=seed)
    encoder, decoder = InputsEncoder(2), InputsDecoder(size, size, n)
    for step, deciders, knowledges in _rounds(seed, n, size, size, rounds):
        beliefs = live.beliefs(knowledges, step - 1, n)
        line = encoder.line(step, [f"v{i}" for i in deciders], beliefs, [])
        moves = [c.move for c in live.decide(beliefs)]
        assert [c.move for c in again.decide(decoder.beliefs(line, deciders, again.settings))] == moves


def test_a_change_whose_base_line_is_missing_is_refused():
    """A delta needs its base: a line skipped (damaged) makes the next delta of its vehicles unreadable,
    and the next whole-map line reads again."""
    policy = FieldPolicy("frontier")
    encoder, decoder = InputsEncoder(3), InputsDecoder(8, 8, 2)
    lines = [
        encoder.line(step, ["a", "b"], policy.beliefs(knowledges, step - 1, 2), [])
        for step, _deciders, knowledges in _rounds(1, 2, 8, 8, 4, everyone=True)
    ]
    assert [line["since"] for line in lines] == [[0, 0], [1, 1], [2, 2], [0, 0]]
    decoder.beliefs(lines[0], [0, 1], policy.settings)
    with pytest.raises(InputsError, match="step 2, whose line was not read"):  # round 2 was skipped
        decoder.beliefs(lines[2], [0, 1], policy.settings)
    decoder.beliefs(lines[3], [0, 1], policy.settings)  # round 4 = 1 + 3: every map whole


def test_a_line_written_before_heard_existed_reads_as_every_position_current():
    """Older recordings have no `heard`: their beliefs read back without it, as their policy had them."""
    policy = FieldPolicy("coordinated")
    encoder, decoder = InputsEncoder(1), InputsDecoder(8, 8, 3)
    for step, deciders, knowledges in _rounds(2, 3, 8, 8, 3):
        line = encoder.line(step, [f"v{i}" for i in deciders], policy.beliefs(knowledges, step - 1, 3), [])
        assert "heard" in line
        del line["heard"]
        assert check_event({"t": 0.0, "event": "inputs", **line}, strict=True) == "inputs"
        beliefs = decoder.beliefs(line, deciders, policy.settings)
        assert beliefs.heard is None and not beliefs.out_of_touch(0).any()
