"""The Q-network, checkpoints, exploration, and small seconds-long training runs."""

import csv
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmctl.errors import InputError
from swarmctl.learn.ddql import TrainConfig, train
from swarmctl.learn.evaluate import evaluate
from swarmctl.policy.base import softmax_sample
from swarmctl.policy.checkpoint import load_checkpoint, save_checkpoint
from swarmctl.policy.ddql import make_ddql_policy
from swarmctl.policy.qnet import QNetwork, make_network, parameter_count
from swarmctl.policy.registry import make_policy
from swarmctl.world import SearchEnv, WorldConfig
from swarmctl.world.beliefs import PAPER_VARIANT, SCALES_VARIANT

TINY_WORLD = WorldConfig(map_size=6, uavs=1, targets=1, window=8)


def test_network_layers_and_parameter_count_match_the_paper():
    net = QNetwork(20)
    x = torch.zeros(2, 3, 20, 20)
    shapes = []
    for layer in net.features:
        x = layer(x)
        if isinstance(layer, torch.nn.Conv2d):
            shapes.append(tuple(x.shape[1:]))
    assert shapes == [(20, 20, 20), (20, 17, 17), (20, 7, 7)]
    assert x.shape == (2, 980)
    assert [m.out_features for m in net.head if isinstance(m, torch.nn.Linear)] == [64, 5]
    assert parameter_count(net) == 76_509  # ~76.5 k, as the paper's operation counts give


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 10_000))
def test_softmax_with_tiny_tau_is_greedy(seed):
    rng = np.random.default_rng(seed)
    q = np.stack([rng.permutation(5) for _ in range(50)]) + rng.normal(size=(50, 5)) * 0.1  # gaps > 0.6
    assert (softmax_sample(q, 1e-3, rng.random(50)) == q.argmax(1)).all()


def test_softmax_sample_follows_the_distribution():
    rng = np.random.default_rng(0)
    q = np.tile([0.0, np.log(3.0), 0.0, 0.0, 0.0], (40_000, 1))
    counts = np.bincount(softmax_sample(q, 1.0, rng.random(40_000)), minlength=5) / 40_000
    assert counts == pytest.approx([1 / 7, 3 / 7, 1 / 7, 1 / 7, 1 / 7], abs=0.01)


def test_checkpoint_round_trip_and_validation(tmp_path):
    net = QNetwork(8)
    path = tmp_path / "m.pt"
    save_checkpoint(path, net, TINY_WORLD.as_dict(), {"episodes": 1}, {"seed": 3})
    loaded, info = load_checkpoint(path, window=8)
    for a, b in zip(net.parameters(), loaded.parameters()):
        assert torch.equal(a, b)
    assert info["metadata"]["seed"] == 3 and info["world"]["map_size"] == 6
    with pytest.raises(InputError, match="trained for 8 x 8"):
        load_checkpoint(path, window=20)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint at all")
    with pytest.raises(InputError, match="not a swarmctl checkpoint"):
        load_checkpoint(junk)
    other = tmp_path / "other.pt"
    torch.save({"format": "swarmctl-ddql", "version": 1, "architecture": "resnet", "window": 8}, other)
    with pytest.raises(InputError, match="architecture"):
        load_checkpoint(other)
    plain = tmp_path / "plain.pt"
    torch.save(net.state_dict(), plain)
    with pytest.raises(InputError, match="format marker"):
        load_checkpoint(plain)
    with pytest.raises(InputError, match="no such checkpoint"):
        load_checkpoint(tmp_path / "missing.pt")


def test_a_model_observes_with_its_own_window_and_variant_whatever_the_worlds(tmp_path):
    """`ddql:PATH` alone flies a model as it was trained: in a world of another window and variant (as
    beside a policy that takes those) it moves as in a world of its own."""
    world = WorldConfig(map_size=14, uavs=3, targets=3, window=11, variant=SCALES_VARIANT)
    torch.manual_seed(0)
    path = tmp_path / "scales.pt"
    save_checkpoint(path, make_network(SCALES_VARIANT, 11), world.as_dict(), {"episodes": 1}, {"seed": 0})
    played = []
    for window, variant in ((11, SCALES_VARIANT), (8, PAPER_VARIANT)):
        env = SearchEnv(replace(world, window=window, variant=variant), batch=3, observations=False)
        env.reset(seed=4)
        policy = make_policy(f"ddql:{path}")
        policy.reset(env.beliefs(), 4)
        moves = []
        for _ in range(6):
            moves.append(policy.act(env.beliefs()))
            env.step(moves[-1])
        played.append(np.stack(moves))
    assert np.array_equal(played[0], played[1])


def test_a_checkpoint_carries_its_weights_hash_and_damaged_or_non_finite_weights_are_refused(tmp_path):
    from swarmctl.policy.checkpoint import weights_sha256

    net = QNetwork(8)
    path = tmp_path / "m.pt"
    digest = save_checkpoint(path, net, TINY_WORLD.as_dict(), {}, {})
    _, info = load_checkpoint(path)
    assert info["version"] == 2 and info["weights_sha256"] == digest == weights_sha256(net.state_dict())
    payload = torch.load(path, weights_only=True)
    payload["state_dict"]["head.2.bias"][0] += 1.0  # one weight changed, the hash left as it was
    torch.save(payload, tmp_path / "altered.pt")
    with pytest.raises(InputError, match="do not match their sha256"):
        load_checkpoint(tmp_path / "altered.pt")
    payload["state_dict"]["head.2.bias"][0] = float("nan")
    payload["weights_sha256"] = weights_sha256(payload["state_dict"])
    torch.save(payload, tmp_path / "nan.pt")
    with pytest.raises(InputError, match="NaN or infinite"):
        load_checkpoint(tmp_path / "nan.pt")
    raw = bytearray(path.read_bytes())  # bytes flipped in the middle of the file
    raw[len(raw) // 2 : len(raw) // 2 + 64] = bytes(b ^ 0xFF for b in raw[len(raw) // 2 : len(raw) // 2 + 64])
    (tmp_path / "flipped.pt").write_bytes(bytes(raw))
    with pytest.raises(InputError):
        load_checkpoint(tmp_path / "flipped.pt")


def test_the_shipped_models_carry_no_paths_of_the_machine_that_trained_them():
    import json

    for path in sorted(Path("models").glob("*.pt")):
        _, info = load_checkpoint(path)
        text = json.dumps(info, default=str)
        assert "/tmp" not in text and "/work" not in text and "/home" not in text and "runs/" not in text, path
        assert info["version"] == 2


@pytest.mark.parametrize(
    "spec, needle",
    [
        ("ddql", "give the checkpoint"),
        ("ddql:x.pt:tau=0", "tau"),
        ("ddql:x.pt:tau=abc", "tau"),
        ("ddql-greedy:nope.pt", "no such"),
    ],
)
def test_bad_policy_specs(spec, needle):
    with pytest.raises(InputError, match=needle):
        make_ddql_policy(spec)


def tiny_config(episodes):
    return TrainConfig(
        episodes=episodes,
        parallel_envs=8,
        prefill_episodes=20,
        batch_size=64,
        lr=1e-3,
        target_update_every=100,
        eval_every=episodes,
        eval_episodes=100,
        threads=1,
    )


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    out = tmp_path_factory.mktemp("train") / "tiny.pt"
    meta = train(TINY_WORLD, tiny_config(96), seed=0, out=out, progress=False)
    return out, meta


def test_training_loss_falls(tiny_model):
    out, _ = tiny_model
    rows = list(csv.DictReader(open(out.with_suffix(".csv"))))
    losses = [float(r["loss"]) for r in rows]
    assert np.mean(losses[-3:]) < 0.5 * np.mean(losses[:2])


def test_tiny_policy_beats_random_on_a_6x6_map(tiny_model):
    out, meta = tiny_model
    results = evaluate(TINY_WORLD, ["random", f"ddql:{out}"], 300, seed=0, steps=40, progress=False)
    rand, learned = results
    assert learned["success_rate"] > rand["success_rate"] + 0.15
    assert learned["mean_steps"] < rand["mean_steps"]
    assert meta["final_eval"]["success_rate"] > 0
    _, info = load_checkpoint(out)
    for key in ("scenario", "episodes", "seed", "git_commit", "wall_time_s", "evals"):
        assert key in info["metadata"]


def test_training_is_reproducible_and_transfer_starts_from_init(tmp_path):
    a, b = tmp_path / "a.pt", tmp_path / "b.pt"
    train(TINY_WORLD, tiny_config(16), seed=5, out=a, progress=False)
    train(TINY_WORLD, tiny_config(16), seed=5, out=b, progress=False)
    na, _ = load_checkpoint(a)
    nb, _ = load_checkpoint(b)
    assert all(torch.equal(x, y) for x, y in zip(na.parameters(), nb.parameters()))
    c = tmp_path / "c.pt"
    meta = train(TINY_WORLD, tiny_config(8), seed=6, out=c, init=a, progress=False)
    _, info_a = load_checkpoint(a)
    # the init model is named by file name and weights hash, never by a path of this machine
    assert meta["init"] == {"file": "a.pt", "weights_sha256": info_a["weights_sha256"]}
    assert meta["init_metadata"]["seed"] == 5 and str(tmp_path) not in repr(load_checkpoint(c)[1])


def test_ddql_options_parse_in_any_order(tiny_model):
    out, _ = tiny_model
    paper = make_ddql_policy(f"ddql:{out}:taken=keep:tau=0.2:mask=no:hover=no")
    assert (paper.path, paper.tau, paper.remove_taken, paper.hover, paper.mask) == (str(out), 0.2, False, "no", False)
    ours = make_ddql_policy(f"ddql-greedy:{out}")
    assert (ours.path, ours.tau, ours.remove_taken, ours.hover, ours.mask) == (str(out), None, True, "first", True)


def test_the_best_held_out_checkpoint_is_kept_beside_the_last(tmp_path):
    from dataclasses import replace

    from swarmctl.learn.ddql import best_path

    out = tmp_path / "m.pt"
    meta = train(TINY_WORLD, replace(tiny_config(96), eval_every=32), seed=1, out=out, progress=False)
    evals = meta["evals"]
    assert len(evals) == 3
    _, best = load_checkpoint(best_path(out))
    kept = best["metadata"]["evals"][-1]
    assert kept["success_rate"] == max(e["success_rate"] for e in evals)
    assert kept in evals


def test_snapshots_keep_the_checkpoint_as_it_stood_at_each_count(tmp_path):
    from dataclasses import replace

    from swarmctl.learn.ddql import snapshot_path

    out = tmp_path / "m.pt"
    cfg = replace(tiny_config(96), eval_every=1000, snapshots=(32, 64))
    train(TINY_WORLD, cfg, seed=1, out=out, progress=False)
    first, info32 = load_checkpoint(snapshot_path(out, 32))
    second, info64 = load_checkpoint(snapshot_path(out, 64))
    last, info = load_checkpoint(out)
    assert (info32["metadata"]["episodes"], info64["metadata"]["episodes"], info["metadata"]["episodes"]) == (
        32,
        64,
        96,
    )
    weights = [next(m.parameters()).detach().clone() for m in (first, second, last)]
    assert not torch.equal(weights[0], weights[1]) and not torch.equal(weights[1], weights[2])
    assert not snapshot_path(out, 96).exists()


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from(["softmax", "egreedy"]), st.floats(0.01, 1.0))
def test_exploration_under_the_rules_never_picks_a_refused_move(seed, exploration, value):
    from swarmctl.learn.ddql import explore

    rng = np.random.default_rng(seed)
    q = rng.normal(size=(64, 5)).astype(np.float32)
    allowed = rng.random((64, 5)) < 0.4
    allowed[~allowed.any(1), 0] = True
    cfg = TrainConfig(exploration=exploration)
    actions = explore(q, cfg, value, rng, allowed)
    assert allowed[np.arange(64), actions].all()


def test_training_under_the_rules_hovers_and_never_leaves_the_map(monkeypatch, tmp_path):
    """With --rules, every exploratory action passes the rule mask: vehicles on a free target stay, and
    no move leaves the map."""
    from dataclasses import replace

    import swarmctl.learn.ddql as ddql
    from swarmctl.world.moves import MOVES, STAY

    calls = []
    real_mask, real_explore = ddql.rule_mask, ddql.explore

    def mask_spy(env):
        mask = real_mask(env)
        calls.append(
            {
                "hover": env.beliefs().hovering_self.ravel().copy(),
                "pos": env.pos.reshape(-1, 2).copy(),
                "size": (env.width, env.height),
            }
        )
        return mask

    def explore_spy(q, cfg, value, rng, allowed=None):
        actions = real_explore(q, cfg, value, rng, allowed)
        if calls and "actions" not in calls[-1]:
            calls[-1]["actions"] = actions
        return actions

    monkeypatch.setattr(ddql, "rule_mask", mask_spy)
    monkeypatch.setattr(ddql, "explore", explore_spy)
    cfg = replace(tiny_config(16), rules=True, prefill_episodes=0, eval_every=1000)
    ddql.train(TINY_WORLD, cfg, seed=3, out=tmp_path / "r.pt", progress=False)
    steps = [c for c in calls if "actions" in c]
    assert len(steps) >= 16 * 50 // 8  # every joint step of training went through the rules
    hovered = 0
    for c in steps:
        dest = c["pos"] + MOVES[c["actions"]]
        w, h = c["size"]
        assert ((dest >= 0) & (dest < [w, h])).all()
        assert (c["actions"][c["hover"]] == STAY).all()
        hovered += c["hover"].sum()
    assert hovered > 0  # the tiny map's vehicles do reach targets


def test_snapshots_between_rounds_are_refused():
    from dataclasses import replace

    with pytest.raises(ValueError, match="multiple of"):
        train(TINY_WORLD, replace(tiny_config(96), snapshots=(30,)), seed=1, out=Path("/nonexistent/m.pt"))


def _closer_to_the_unexplored(explored: np.ndarray, blocked: np.ndarray, cell, move: int) -> bool:
    """The move brings `cell` one step nearer (BFS) to the nearest cell not yet explored."""
    from swarmctl.world.moves import MOVES
    from swarmctl.world.paths import grid_distances

    dist = grid_distances(~blocked[None], ~explored[None])[0]
    nx, ny = np.asarray(cell) + MOVES[move]
    return dist[nx, ny] == dist[tuple(cell)] - 1


def test_with_straggler_frontier_the_last_vehicle_searching_heads_for_the_unexplored(tiny_model):
    from tests.helpers import make_env

    out, _ = tiny_model
    # vehicles 0 and 1 hover on their targets; vehicle 2 searches alone for the third, far east
    scenario = dict(targets=[[1, 1], [3, 1], [11, 11]], starts=[[1, 1], [3, 1], [0, 6]], window=8)
    env = make_env(12, **scenario)
    policy = make_ddql_policy(f"ddql:{out}:straggler=frontier")
    policy.reset(env.beliefs(), 0)
    for _ in range(6):
        assert env.beliefs().last_searching()[0].tolist() == [False, False, True]
        moves = policy.act(env.beliefs())
        assert moves[0, :2].tolist() == [0, 0]  # the hover
        assert _closer_to_the_unexplored(env.explored[0, 2], env.beliefs().blocked[0, 2], env.pos[0, 2], moves[0, 2])
        env.step(moves)
    # while two vehicles still search, every move is the network's, draw for draw
    one_hovers = dict(scenario, starts=[[1, 1], [5, 1], [0, 6]])
    plain, ours = (make_ddql_policy(f"ddql:{out}{opt}") for opt in ("", ":straggler=frontier"))
    a, b = make_env(12, **one_hovers), make_env(12, **one_hovers)
    plain.reset(a.beliefs(), 3)
    ours.reset(b.beliefs(), 3)
    for _ in range(5):
        assert not a.beliefs().last_searching().any()
        ma, mb = plain.act(a.beliefs()), ours.act(b.beliefs())
        assert (ma == mb).all()
        a.step(ma), b.step(mb)


def test_in_the_field_the_last_agent_searching_takes_the_frontier_move(tiny_model):
    from swarmctl.knowledge.model import Knowledge, Position
    from swarmctl.mission.decide import FieldPolicy

    out, _ = tiny_model
    kn = Knowledge(12, 12, vehicle_id=2)
    kn.set_position(3, (0, 6))
    kn.sense_truth(np.zeros((12, 12)), np.zeros((12, 12), dtype=bool))
    kn.merge_position(0, Position(3, (1, 1), on_target=True))
    kn.merge_position(1, Position(3, (3, 1), on_target=True))
    policy = FieldPolicy(f"ddql:{out}:straggler=frontier", seed=0)
    assert policy.window == 8  # the observation settings come from the checkpoint
    for _ in range(10):
        choice = policy.choose([kn], step=3)[0]
        assert choice.by == "frontier" and choice.q is not None
        assert _closer_to_the_unexplored(kn.explored, kn.obstacle, (0, 6), choice.move)
    kn.merge_position(1, Position(4, (4, 1)))  # vehicle 1 left its target: two search now
    assert policy.choose([kn])[0].by is None


def test_the_field_observes_with_the_settings_the_model_was_trained_with(tmp_path):
    """A model trained with fov 2, rho 0.3 and 8 x 8 windows is flown with exactly those: the field's
    sensing radius, window and value channel come from its checkpoint, not from constants."""
    from dataclasses import replace

    from swarmctl.knowledge.model import Knowledge
    from swarmctl.mission.decide import FieldPolicy

    world = replace(TINY_WORLD, fov=2.0, rho=0.3)
    out = tmp_path / "fov2.pt"
    train(world, tiny_config(8), seed=1, out=out, progress=False)
    policy = FieldPolicy(f"ddql:{out}", seed=0)
    assert (policy.fov, policy.window, policy.settings.rho) == (2.0, 8, 0.3)
    kn = Knowledge(6, 6, vehicle_id=0)
    kn.set_position(0, (2, 2))
    obstacle = np.zeros((6, 6), dtype=bool)
    obstacle[3, 2] = True
    sensed = kn.sense_truth(np.zeros((6, 6)), obstacle, fov=policy.fov)
    assert sensed == 13  # the disc of radius 2: 13 cells
    d = policy.policy.decide(kn.beliefs(settings=policy.settings))
    assert d.obs.shape == (1, 1, 3, 8, 8)
    assert d.obs[0, 0, 2, 3, 2] == pytest.approx(-0.3)  # the model's rho, not the paper's 0.2
    assert FieldPolicy("frontier").fov == 3.0  # planners keep the paper's
