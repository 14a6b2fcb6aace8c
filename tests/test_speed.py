"""The fast paths give the reference's answers: the torch forward in chunks, the forward's choice, the
Python-int draws, eval's batch size, the thread setting, the replay memory on a torch device. (The
forward backends against eager torch: tests/test_fast_paths.py.)"""

import json

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.cli import main
from swarmctl.errors import InputError
from swarmctl.learn.replay import ReplayMemory
from swarmctl.policy import draws
from swarmctl.policy.forward import TorchForward, make_forward, onednn_available, onnx_available
from swarmctl.policy.qnet import QNetwork, forward_flops
from swarmctl.policy.threads import ENV_VAR, set_inference_threads, threads_from_env
from swarmctl.world.moves import MOVES, cell_table, move_table


def test_the_torch_forward_in_chunks_is_the_network_in_one_call():
    net = QNetwork(12)
    obs = np.random.default_rng(0).random((150, 3, 12, 12), dtype=np.float32)
    with torch.inference_mode():
        whole = net(torch.from_numpy(obs)).numpy()
    assert np.abs(TorchForward(net, chunk=64)(obs) - whole).max() < 1e-6


def test_forward_choice_and_its_errors(monkeypatch):
    net = QNetwork(20)
    assert make_forward(net, "torch").name == "torch"
    small = "onnx" if onnx_available() else "torch"
    assert make_forward(net, "auto").name == (f"{small}+onednn" if onednn_available() else small)
    with pytest.raises(InputError, match="choose one of"):
        make_forward(net, "tensorrt")
    monkeypatch.setattr("swarmctl.policy.forward.onnx_available", lambda: False)
    monkeypatch.setattr("swarmctl.policy.forward.onednn_available", lambda: False)
    assert make_forward(net, "auto").name == "torch"
    for backend in ("onnx", "onnx+onednn"):
        with pytest.raises(InputError, match=r"swarmctl\[onnx\]"):
            make_forward(net, backend)
    with pytest.raises(InputError, match="oneDNN"):
        make_forward(net, "onednn")


def test_the_network_is_the_papers_4_88_mflop():
    assert forward_flops(20) == 4_884_480


@settings(max_examples=300, deadline=None)
@given(
    seed=st.integers(-(2**62), 2**62),
    episodes=st.lists(st.integers(-(2**40), 2**62), min_size=1, max_size=3),
    step=st.integers(0, 2**40),
    vehicles=st.integers(1, 4),
    stream=st.integers(0, 9),
    shape=st.lists(st.integers(1, 3), max_size=2),
)
def test_the_python_int_draws_are_the_numpy_draws_bit_for_bit(seed, episodes, step, vehicles, stream, shape):
    ep = np.array(episodes)
    ids = np.broadcast_to(np.arange(vehicles), (len(ep), vehicles))
    small = draws._uniform_small(seed, ep.reshape(-1, 1), step, ids, stream, tuple(shape))
    key = draws._key(seed, ep.reshape(-1, 1), step, ids, stream)
    with np.errstate(over="ignore"):
        index = np.arange(int(np.prod(shape)), dtype=np.uint64) * draws._GOLDEN
        bits = draws._mix(key[..., None] + index)
    reference = ((bits >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53))).reshape(*key.shape, *shape)
    assert small.shape == reference.shape and np.array_equal(small, reference)
    if not shape:  # one draw per decider, as a batch-1 decision asks for it
        each = draws._one_each_small(seed, ep, step, ids, stream)
        assert each.shape == reference.shape and np.array_equal(each, reference)


def test_the_move_table_is_the_moves_with_off_map_as_minus_one():
    table, cells = move_table(4, 3), cell_table(4, 3)
    for flat in range(12):
        x, y = cells[flat]
        for a, (dx, dy) in enumerate(MOVES):
            inside = 0 <= x + dx < 4 and 0 <= y + dy < 3
            assert table[flat, a] == ((x + dx) * 3 + y + dy if inside else -1)


def test_eval_results_do_not_depend_on_the_batch(tmp_path):
    results = {}
    for batch in (7, 250):
        out = tmp_path / f"b{batch}.json"
        args = ["eval", "--episodes", "20", "--seed", "4", "--batch", str(batch), "--no-progress", "--json", str(out)]
        for policy in ("random", "la:2", "frontier", "lawnmower", "ddql:models/cluster-2uav.pt"):
            args += ["--policy", policy]
        assert main(args) == 0
        results[batch] = json.loads(out.read_text())["results"]
    for small, large in zip(results[7], results[250]):
        assert small.pop("decision_ms_per_vehicle") > 0 and large.pop("decision_ms_per_vehicle") > 0
        assert small == large


def test_threads_default_to_one_and_the_variable_is_checked(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert threads_from_env() == 1
    monkeypatch.setenv(ENV_VAR, "2")
    assert threads_from_env() == 2
    before = torch.get_num_threads()
    try:
        assert set_inference_threads() == 2 and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv(ENV_VAR, bad)
        with pytest.raises(InputError, match=ENV_VAR):
            threads_from_env()


def test_the_replay_memory_lives_and_samples_on_its_device():
    memory = ReplayMemory(10, (3, 4, 4), seed=1, device=torch.device("cpu"))
    obs = np.arange(12 * 48, dtype=np.float32).reshape(12, 3, 4, 4) % 7
    memory.add(obs[:8], np.arange(8), np.arange(8, dtype=np.float32), obs[:8] + 1)
    memory.add(torch.from_numpy(obs[8:]), np.arange(8, 12), np.arange(8, 12, dtype=np.float32), obs[8:] + 1)
    assert memory.size == 10 and memory.cursor == 2  # the oldest two were overwritten
    o, a, r, o2 = memory.sample(32, torch.channels_last)
    assert o.device.type == "cpu" and o.dtype == torch.float32 and o.is_contiguous(memory_format=torch.channels_last)
    assert set(a.tolist()) <= set(range(2, 12)) and torch.equal(r, a.float())
    assert torch.equal(o2, o + 1) and torch.equal(o, torch.from_numpy(obs)[a])
    same = [ReplayMemory(10, (3, 4, 4), seed=3) for _ in range(2)]
    for m in same:
        m.add(obs[:10], np.arange(10), np.zeros(10, dtype=np.float32), obs[:10])
    assert torch.equal(same[0].sample(32)[1], same[1].sample(32)[1])  # same seed, same minibatches
