"""Fast paths that copy a reference's logic give the reference's answers, over random inputs (hypothesis,
the repeatable profile of tests/conftest.py), one property test per pair:

- SearchEnv.observe (built from the world's arrays) against observe(env.beliefs()): bit for bit;
- the six forward backends of swarmctl.policy.forward against eager torch: within 1e-5 of the call's
  largest |Q| (at least 1); the split ones and `auto` bit for bit the backend each call goes to.

Two more pairs have theirs beside the rest of their tests (not repeated here):
- knowledge.stepping.step_all against KnowledgeExchange.step agent by agent:
  tests/test_knowledge_stepping.py::test_a_batched_round_is_the_per_agent_round;
- KnowledgeStack.merge_batch against Knowledge.merge of each message into each receiver:
  tests/test_knowledge_stack.py::test_a_batch_merge_is_each_message_merged_into_each_receiver.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, reject, settings
from hypothesis import strategies as st

from swarmctl.errors import ScenarioError
from swarmctl.policy.checkpoint import load_checkpoint
from swarmctl.policy.forward import (
    BACKENDS,
    CHUNK,
    SMALL_ROWS,
    SPLIT_ROWS,
    SplitForward,
    TorchForward,
    make_forward,
    onednn_available,
    onnx_available,
)
from swarmctl.policy.qnet import GlobalLocalQNetwork, QNetwork
from swarmctl.world import SearchEnv, WorldConfig
from swarmctl.world.observe import observe

# --- SearchEnv.observe and observe(beliefs) ----------------------------------------------------------------


@settings(max_examples=150)
@given(
    map_size=st.integers(3, 13),
    window=st.sampled_from([1, 3, 4, 8, 13, 20]),
    uavs=st.integers(1, 5),
    targets=st.integers(1, 3),
    batch=st.integers(1, 5),
    obstacles=st.sampled_from([0.0, 0.1, 0.3]),
    fov=st.sampled_from([0.0, 1.0, 2.5]),
    channel=st.sampled_from([("ideal", 0.0), ("none", 0.0), ("fixed", 0.5), ("model", 0.0)]),
    guard=st.booleans(),
    steps=st.integers(0, 8),
    seed=st.integers(0, 2**16),
)
def test_search_env_observe_is_observe_of_its_beliefs(
    map_size, window, uavs, targets, batch, obstacles, fov, channel, guard, steps, seed
):
    """The fast path (SearchEnv.observe without taken-target removal, paper variant) builds the
    observations from the arrays behind the beliefs; it must give observe(beliefs) bit for bit, on both
    of observe's builders (a few deciders: Beliefs.crews; more: the batched one) and every window
    placement (inside the map, clipped at its edges, larger than the map)."""
    cfg = dict(map_size=map_size, window=window, uavs=uavs, targets=targets, obstacles=obstacles, fov=fov)
    cfg |= dict(channel=channel[0], loss=channel[1], guard=guard, finish="found")  # fewer targets allowed
    try:
        env = SearchEnv(WorldConfig(**cfg), batch=batch, stop_at_success=False, observations=False)
        env.reset(seed=seed)
    except ScenarioError:  # no room for the targets and vehicles on this map
        reject()
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        env.step(rng.integers(0, 5, (batch, uavs)))
        fast, reference = env.observe(remove_taken=False), observe(env.beliefs(), False)
        assert fast.dtype == reference.dtype == np.float32
        assert fast.shape == reference.shape == (batch, uavs, 3, window, window)
        assert np.array_equal(fast, reference)
    assert np.array_equal(env.observe(remove_taken=False), observe(env.beliefs(), False))


# --- the forward backends and eager torch ------------------------------------------------------------------

MODEL = Path(__file__).resolve().parent.parent / "models" / "obstacles-3uav.pt"
# (class, window) with weights seeded by the index, or the shipped model (trained: Q-values up to ~400 on
# random inputs, ~12 on the world's observations, where random weights give ~0.1)
NETS = [(QNetwork, 8), (QNetwork, 20), (GlobalLocalQNetwork, 13), MODEL]
# onnxruntime and oneDNN sum in other orders than eager torch: within 1e-5 of the call's largest |Q| (at
# least 1). Measured: 4e-8 for random weights, 4e-4 at |Q| 360 for the shipped model on random inputs
# (4e-6 on the world's observations, where forward.py's docstring says 1e-5)
TOLERANCE = 1e-5


def available(backend: str) -> bool:
    return not ("onnx" in backend and not onnx_available()) and not ("onednn" in backend and not onednn_available())


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """Inference runs on one thread (swarmctl.policy.threads), onnxruntime's too: so here."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@cache
def forwards(which: int) -> tuple[torch.nn.Module, dict[str, object]]:
    """A network (NETS[which]) and every backend that can run here (one ONNX export per network)."""
    if NETS[which] == MODEL:
        net = load_checkpoint(MODEL)[0]
    else:
        cls, window = NETS[which]
        torch.manual_seed(which)
        net = cls(window)
    before = {k: v.clone() for k, v in net.state_dict().items()}
    built = {b: make_forward(net, b, key=f"test-fast-paths-{which}") for b in BACKENDS if available(b)}
    # building them leaves the network alone: same weights, plain (unfused) convolutions
    assert all(torch.equal(before[k], v) for k, v in net.state_dict().items())
    assert all(type(m) is torch.nn.Conv2d for m in net.modules() if isinstance(m, torch.nn.Conv2d))
    return net, built


rows_strategy = st.one_of(
    st.integers(1, SMALL_ROWS + 2),
    st.sampled_from([SPLIT_ROWS, SPLIT_ROWS + 1, SMALL_ROWS, SMALL_ROWS + 1, CHUNK, CHUNK + 1]),
)


@settings(max_examples=20)
@given(
    which=st.integers(0, len(NETS) - 1),
    rows=rows_strategy,
    binary=st.booleans(),
    seed=st.integers(0, 2**16),
)
def test_forward_backends_are_eager_torch(which, rows, binary, seed):
    """Every backend (torch, onnx, onednn, onnx+onednn, torch+onednn, auto) on random observations:
    Q-values (N, 5) float32 within TOLERANCE of eager torch's (the torch backend: bit for bit); the
    same rows again, the same bits; a split backend gives bit for bit its small part's numbers up to
    SPLIT_ROWS rows and its large part's beyond; `auto` is the backend its name says, bit for bit.
    Those needing onnxruntime or oneDNN are left out where they cannot run (tests/test_speed.py checks
    the errors they give)."""
    net, built = forwards(which)
    rng = np.random.default_rng(seed)
    obs = rng.random((rows, net.in_channels, net.window, net.window), dtype=np.float32)
    obs = obs.round() if binary else obs * 2 - 0.5  # 0 / 1 cells, or any values
    reference = TorchForward(net)(obs)
    assert reference.shape == (rows, 5) and reference.dtype == np.float32
    tolerance = TOLERANCE * max(1.0, float(np.abs(reference).max()))
    for name, forward in built.items():
        q = forward(obs)
        assert q.shape == (rows, 5) and q.dtype == np.float32, name
        assert np.abs(q - reference).max() <= tolerance, name
        assert name != "torch" or np.array_equal(q, reference)
        assert np.array_equal(forward(obs.copy()), q), name
        if isinstance(forward, SplitForward):
            part = forward.small if rows <= SPLIT_ROWS else forward.large
            assert np.array_equal(part(obs), q), name
    auto = built["auto"]
    assert auto.name in built and auto.name != "auto"
    assert np.array_equal(auto(obs), built[auto.name](obs))
