"""The defer hover rule over a lossy channel (swarmctl.policy.hover): a teammate not heard from in the
last OUT_OF_TOUCH_STEPS steps is not counted among the vehicles the known targets must cover."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarmctl.knowledge.model import Knowledge, Position, beliefs_from_knowledge
from swarmctl.policy.coordinated import CoordinatedPolicy
from swarmctl.policy.hover import OUT_OF_TOUCH_STEPS, park_allowed
from swarmctl.policy.registry import make_policy
from swarmctl.world.moves import STAY
from tests.helpers import make_env

DEFERRING = ["coordinated", "frontier:hover=defer", "la:4:hover=defer", "lawnmower:hover=defer"]
# vehicle 0 starts on a target, the only one the swarm knows of; three vehicles need three
ONE_OF_THREE = dict(size=30, targets=[[5, 5], [15, 15], [20, 5]], starts=[[5, 5], [25, 25], [25, 15]])


@given(st.integers(0, 20), st.integers(1, 20), st.none() | st.integers(1, 20), st.integers(0, 19))
def test_the_rule_counts_only_the_vehicles_in_touch(known, vehicles, hold, out_of_touch):
    out_of_touch = min(out_of_touch, vehicles - 1)
    wanted = vehicles if hold is None else min(hold, vehicles)
    assert bool(park_allowed(known, vehicles, hold)) == (known >= wanted)  # everyone heard: the rule as it was
    allowed = bool(park_allowed(known, vehicles, hold, out_of_touch))
    assert allowed == (known >= max(1, min(wanted, vehicles - out_of_touch)))
    if bool(park_allowed(known, vehicles, hold)):
        assert allowed  # losing touch never forbids a park
    assert not park_allowed(0, vehicles, hold, out_of_touch)  # no known target: nothing to park on


def _after_stays(env, steps: int):
    for _ in range(steps):
        env.step(np.full((1, env.uavs), STAY))
    return env.beliefs()


def _heard(beliefs, teammates_at: int):
    """`beliefs` whose decider 0 last heard its teammates at step `teammates_at`."""
    out = copy.copy(beliefs)
    out.heard = beliefs.heard.copy()
    out.heard[0, 0, 1:] = teammates_at
    return out


@pytest.mark.parametrize("spec", DEFERRING)
def test_a_vehicle_that_has_lost_touch_parks_where_one_in_touch_searches_on(spec):
    env = make_env(**ONE_OF_THREE)
    beliefs = _after_stays(env, OUT_OF_TOUCH_STEPS + 1)
    step = beliefs.step
    assert beliefs.hovering_self[0, 0] and beliefs.targets[0, 0].sum() == 1
    assert (beliefs.heard == step).all()  # ideal sharing: everyone heard every step
    moves = {}
    for teammates_at in (step, step - OUT_OF_TOUCH_STEPS, step - OUT_OF_TOUCH_STEPS - 1):
        policy = make_policy(spec)
        b = _heard(beliefs, teammates_at)
        policy.reset(b, 0)
        moves[teammates_at] = int(policy.act(b)[0, 0])
    assert moves[step] != STAY and moves[step - OUT_OF_TOUCH_STEPS] != STAY  # in touch: search on
    assert moves[step - OUT_OF_TOUCH_STEPS - 1] == STAY  # nobody heard lately: park, as `first` does


def test_a_teammate_never_heard_from_counts_as_heard_when_the_swarm_set_out():
    """With no channel at all nobody hears a teammate: they count until OUT_OF_TOUCH_STEPS steps have passed,
    then defer parks as first does."""
    env = make_env(**ONE_OF_THREE, channel="none")
    for steps, parks in ((OUT_OF_TOUCH_STEPS, False), (1, True)):
        beliefs = _after_stays(env, steps)
        assert (beliefs.heard[0, 0, 1:] == -1).all()
        assert (beliefs.out_of_touch(OUT_OF_TOUCH_STEPS) == (2 if parks else 0)).all()
        for rule in ("defer", "first"):
            policy = CoordinatedPolicy(hover=rule)
            policy.reset(beliefs, 0)
            assert (policy.act(beliefs)[0, 0] == STAY) == (parks or rule == "first")


def test_the_controller_counts_what_its_beliefs_count():
    """Knowledge.out_of_touch (the controller's hover rule) and Beliefs.out_of_touch (the policies') agree:
    unknown teammates, reports stamped later than the step, and the vehicles the controller hears on
    their own links (`in_touch`) included."""
    rng = np.random.default_rng(3)
    for _ in range(100):
        n, step = int(rng.integers(1, 6)), int(rng.integers(0, 30))
        k = Knowledge(10, 10, vehicle_id=int(rng.integers(n)))
        k.set_position(step, (1, 1))
        for v in range(n):
            if v != k.vehicle_id and rng.random() < 0.7:
                k.merge_position(v, Position(int(rng.integers(0, step + 3)), (2, v), False))
        in_touch = {int(v) for v in rng.choice(n, size=int(rng.integers(0, n + 1)), replace=False)}
        beliefs = beliefs_from_knowledge([k], n, step=step, in_touch=in_touch)
        assert all(beliefs.heard[0, 0, v] == step for v in in_touch)
        for steps in (0, 3, OUT_OF_TOUCH_STEPS):
            assert k.out_of_touch(step, n, steps, in_touch) == int(beliefs.out_of_touch(steps)[0, 0])
