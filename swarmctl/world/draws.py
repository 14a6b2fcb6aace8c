"""Random draws keyed by (seed, episode, step, vehicle, stream): batch size never changes a draw.

Every random number of a simulated episode (the policies' tie-breaks and sampling, swarmctl.policy.draws;
the world's message losses, swarmctl.world.channel) is a pure function of a seed, the episode id, the
step, a vehicle's index in the swarm, a stream id naming the purpose, and the element's index: a
counter-based generator (SplitMix64 finalisers over the key, vectorised in numpy). So an episode plays
the same whether it runs alone or in a batch of 500, in chunks or not. 53-bit uniforms in [0, 1).

Streams: the policies' are small (1..6, swarmctl.policy.draws); the world's start at 0x100, so a policy
and the world keyed by the same seed never share a number.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import numpy.typing as npt

# the world's streams (the policies' are 1..6)
LOSSES = 0x100  # one per message: lost or delivered (swarmctl.world.channel)
DETECTIONS = 0x101  # one per (vehicle, target) of a pass: detected or missed (SearchEnv, pod < 1)

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1, _M2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)


def _mix(z: np.ndarray) -> np.ndarray:
    z = z.astype(np.uint64, copy=True)
    z ^= z >> np.uint64(30)
    z *= _M1
    z ^= z >> np.uint64(27)
    z *= _M2
    z ^= z >> np.uint64(31)
    return z


def _key(*parts: npt.ArrayLike) -> np.ndarray:
    """Fold integer arrays (broadcast together) into one 64-bit key per element."""
    with np.errstate(over="ignore"):
        h: np.ndarray = np.asarray(np.uint64(0x5EED))
        for p in parts:
            h = _mix(np.asarray(h, dtype=np.uint64) + _GOLDEN + np.asarray(p).astype(np.int64).astype(np.uint64))
        return h


def _column(a: np.ndarray, shape: tuple[int, ...], size: int) -> list[int]:
    """The values of `a` broadcast to `shape`, flat, as Python ints."""
    if a.size == 1:
        return [int(a.reshape(-1)[0])] * size
    if a.shape == shape:
        return a.ravel().tolist()
    return np.broadcast_to(a, shape).ravel().tolist()


# The same arithmetic on Python ints, for the few draws of a batch-1 decision (a numpy call costs about
# a microsecond whatever its size; tests/test_planners.py checks that both give the same bits).
SMALL = 16  # draws up to which the Python path is used
_MASK = (1 << 64) - 1
_G, _M1_INT, _M2_INT = int(_GOLDEN), int(_M1), int(_M2)


def _mix_int(z: int) -> int:
    z &= _MASK
    z ^= z >> 30
    z = (z * _M1_INT) & _MASK
    z ^= z >> 27
    z = (z * _M2_INT) & _MASK
    return z ^ (z >> 31)


def uniform(
    seed: int, episodes: np.ndarray, step: int, vehicles: np.ndarray, stream: int, shape: tuple[int, ...] = ()
) -> np.ndarray:
    """Uniforms in [0, 1) of shape broadcast(episodes[:, None...], vehicles) + shape.

    episodes: (B,) ids; vehicles: (B, V) indices in the swarm (deciders, or any vehicles)."""
    vehicles = np.asarray(vehicles)
    episodes = np.asarray(episodes, dtype=np.int64).reshape(-1, *([1] * (vehicles.ndim - 1)))
    size = math.prod(shape)
    if episodes.size * vehicles.size * size <= SMALL:
        return _uniform_small(int(seed), episodes, int(step), vehicles, int(stream), shape)
    key = _key(seed, episodes, step, vehicles, stream)  # (B, V)
    with np.errstate(over="ignore"):
        index = np.arange(size, dtype=np.uint64) * _GOLDEN
        bits = _mix(key[..., None] + index)
    out = (bits >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53))
    return out.reshape(*key.shape, *shape)


@lru_cache(maxsize=64)
def _seed_key(seed: int) -> int:
    return _mix_int(0x5EED + _G + (seed & _MASK))


def _uniform_small(
    seed: int, episodes: np.ndarray, step: int, vehicles: np.ndarray, stream: int, shape: tuple[int, ...]
) -> np.ndarray:
    """uniform() for a few draws, on Python ints: the same bits (the key's part up to the step is
    folded once per episode)."""
    kshape = vehicles.shape if episodes.size == 1 else np.broadcast_shapes(episodes.shape, vehicles.shape)
    n, size = math.prod(kshape), math.prod(shape)
    head, at_step, tail = _seed_key(seed), _G + (step & _MASK), _G + (stream & _MASK)
    upto_step: dict[int, int] = {}
    bits: list[int] = []
    for e, v in zip(_column(episodes, kshape, n), _column(vehicles, kshape, n)):
        k = upto_step.get(e)
        if k is None:
            k = upto_step[e] = _mix_int(_mix_int(head + _G + (e & _MASK)) + at_step)
        k = _mix_int(_mix_int(k + _G + (v & _MASK)) + tail)
        bits.extend(_mix_int(k + i * _G) >> 11 for i in range(size))
    return (np.array(bits, dtype=np.float64) * (1.0 / (1 << 53))).reshape(*kshape, *shape)


@lru_cache(maxsize=1024)
def _episode_key(seed: int, episode: int) -> int:
    """The key folded up to the episode (the step comes next)."""
    return _mix_int(_seed_key(seed) + _G + (episode & _MASK))


_UNIT = 1.0 / (1 << 53)


def _one_each_small(seed: int, episodes: np.ndarray, step: int, me: np.ndarray, stream: int) -> np.ndarray:
    """uniform(seed, episodes, step, me, stream) for me (B, U) with a few elements: the same bits (a
    53-bit integer times 2^-53 is exact in a Python float as in numpy)."""
    at_step, tail = _G + (step & _MASK), _G + (stream & _MASK)
    out: list[float] = []
    for e, row in zip(episodes.tolist(), me.tolist()):
        k = _mix_int(_episode_key(seed, e) + at_step)
        out.extend((_mix_int(_mix_int(_mix_int(k + _G + (v & _MASK)) + tail)) >> 11) * _UNIT for v in row)
    return np.array(out, dtype=np.float64).reshape(me.shape)
