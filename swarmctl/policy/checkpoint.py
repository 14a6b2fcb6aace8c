"""Checkpoints: the network's weights with their config and metadata, validated on load.

A checkpoint is a torch file holding only plain data (loaded with `weights_only=True`), format v2:

    {"format": "swarmctl-ddql", "version": 2, "architecture": ..., "variant": observation variant,
     "window": F, "n_actions": 5, "state_dict": ..., "weights_sha256": ..., "world": WorldConfig fields
     (the observation settings the field flies it with come from here), "train": TrainConfig fields,
     "metadata": {...}, "resume": None or the trainer's state to continue a run}

`weights_sha256` is sha256 over the state dict's tensors in key order (for each: the key, dtype and
shape as text, then the raw little-endian bytes); it is checked on load, so a flipped byte is caught,
and it names an init model in another checkpoint's metadata (never a path of the machine that
trained it). Version 1 files (no hash, no variant) still load as the paper's variant.
"""

from __future__ import annotations

import hashlib
import pickle
import warnings
import zipfile
from dataclasses import fields
from pathlib import Path
from typing import Any

import torch

from swarmctl.bounds import CHECKPOINT_MAX_BYTES, size_text
from swarmctl.errors import InputError, ScenarioError
from swarmctl.policy.qnet import NETWORKS, QNet
from swarmctl.world.beliefs import PAPER_VARIANT
from swarmctl.world.config import WorldConfig

FORMAT = "swarmctl-ddql"
VERSION = 2
VARIANTS = tuple(cls.variant for cls in NETWORKS.values())


def weights_sha256(state_dict: dict[str, torch.Tensor]) -> str:
    """The hash that names a network's weights (see the module docstring)."""
    h = hashlib.sha256()
    for key in state_dict:
        t = state_dict[key].detach().cpu().contiguous()
        h.update(f"{key}|{t.dtype}|{tuple(t.shape)}|".encode())
        h.update(t.numpy().astype(t.numpy().dtype.newbyteorder("<"), copy=False).tobytes())
    return h.hexdigest()


def save_checkpoint(
    path: str | Path,
    net: QNet,
    world: dict[str, Any],
    train: dict[str, Any],
    metadata: dict[str, Any],
    resume: dict[str, Any] | None = None,
) -> str:
    """Write the network and everything needed to reproduce and judge it; returns its weights hash."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu() for k, v in net.state_dict().items()}
    digest = weights_sha256(state)
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "architecture": net.architecture,
        "variant": net.variant,
        "window": net.window,
        "n_actions": 5,
        "state_dict": state,
        "weights_sha256": digest,
        "world": world,
        "train": train,
        "metadata": metadata,
        "resume": resume,
    }
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)
    return digest


def model_reference(path: str | Path, info: dict[str, Any]) -> dict[str, str]:
    """How another checkpoint names this one (e.g. as its init model): file name and weights hash."""
    return {"file": Path(path).name, "weights_sha256": info["weights_sha256"]}


def load_checkpoint(path: str | Path, window: int | None = None) -> tuple[QNet, dict[str, Any]]:
    """Load and validate a checkpoint; returns (network in eval mode, payload without weights).

    Raises InputError naming the file when it is missing, over CHECKPOINT_MAX_BYTES, not a checkpoint,
    from another architecture, variant or version, damaged (weights not matching their hash, NaN or
    infinite weights, a stored world config WorldConfig refuses), or made for another observation size
    than `window`.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such checkpoint file; train one with `swarmctl train ... --out {path}`")
    if path.stat().st_size > CHECKPOINT_MAX_BYTES:
        raise InputError(
            f"{path}: {size_text(path.stat().st_size)}, over the {size_text(CHECKPOINT_MAX_BYTES)} a checkpoint "
            "may have; give a .pt file written by `swarmctl train`"
        )
    try:
        with warnings.catch_warnings():  # torch's warnings about a foreign pickle: the error below says it
            warnings.simplefilter("ignore")
            payload = torch.load(path, map_location="cpu", weights_only=True)
    except (
        pickle.UnpicklingError,
        zipfile.BadZipFile,
        RuntimeError,
        EOFError,
        ValueError,
        OSError,
        KeyError,
        TypeError,
        AttributeError,
    ):
        raise InputError(
            f"{path}: not a swarmctl checkpoint (cannot be read as a torch file); "
            "give a .pt file written by `swarmctl train`"
        ) from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise InputError(f"{path}: not a swarmctl checkpoint (no '{FORMAT}' format marker)")
    version = payload.get("version")
    if version not in (1, VERSION):
        raise InputError(f"{path}: checkpoint version {version!r} is not supported (expected 1 or {VERSION})")
    architecture = payload.get("architecture")
    network = NETWORKS.get(architecture) if isinstance(architecture, str) else None
    if network is None:
        raise InputError(
            f"{path}: architecture {payload.get('architecture')!r} is not one of {', '.join(NETWORKS)}; "
            "retrain with this version of swarmctl"
        )
    payload.setdefault("variant", PAPER_VARIANT)
    if payload["variant"] != network.variant:
        raise InputError(
            f"{path}: observation variant {payload['variant']!r} does not go with the {network.architecture} "
            f"network (it takes {network.variant!r}); the file was altered or mislabelled"
        )
    f = payload.get("window")
    if not isinstance(f, int) or isinstance(f, bool) or not 8 <= f <= 256:
        raise InputError(f"{path}: window {f!r} is not an observation size this network takes (8..256)")
    if window is not None and f != window:
        raise InputError(
            f"{path}: the model was trained for {f} x {f} observations, not {window} x {window}; "
            f"use --window {f} or a model trained for {window}"
        )
    if not isinstance(payload.get("world"), dict):
        raise InputError(f"{path}: the checkpoint has no world config; retrain with this version of swarmctl")
    state = payload.get("state_dict")
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError(f"{path}: the checkpoint holds no weights")
    digest = weights_sha256(state)
    if version >= 2 and payload.get("weights_sha256") != digest:
        raise InputError(
            f"{path}: the weights do not match their sha256 (the file is damaged or was altered); use an intact copy"
        )
    payload["weights_sha256"] = digest
    for key, t in state.items():
        if t.is_floating_point() and not bool(torch.isfinite(t).all()):
            raise InputError(f"{path}: weight {key} holds NaN or infinite values; this model cannot fly")
    try:
        net = network(window=f)
        misfit = _misfit(net.state_dict(), state)
        if misfit is not None:
            raise InputError(
                f"{path}: weights do not fit the {network.architecture} network ({misfit}); give a checkpoint "
                "of that network, written by `swarmctl train`"
            )
        net.load_state_dict(state)
    except (KeyError, RuntimeError, TypeError, ValueError) as exc:
        raise InputError(
            f"{path}: weights do not fit the {network.architecture} network ({str(exc).splitlines()[0]})"
        ) from None
    net.eval()
    info = {k: v for k, v in payload.items() if k != "state_dict"}
    _check_world(info["world"], f, path)
    return net, info


def _check_world(world: dict[str, Any], window: int, path: Path) -> None:
    """The stored world config, as WorldConfig validates one (finite numbers, ranges), with the network's window."""
    known = {f.name: str(f.type) for f in fields(WorldConfig)}  # names: the module's annotations are strings
    for key, value in world.items():
        kind = known.get(key)
        if kind is None:
            continue  # a field of a newer or older swarmctl, never read
        kinds: dict[str, type | tuple[type, ...]] = {"int": int, "float": (int, float), "str": str, "bool": bool}
        types = kinds.get(kind, object)
        if not isinstance(value, types) or (kind != "bool" and isinstance(value, bool)):
            raise InputError(f"{path}: world.{key} = {value!r} is not a {kind}; use an intact checkpoint")
    try:
        WorldConfig(**{k: v for k, v in world.items() if k in known})
    except ScenarioError as exc:
        raise InputError(f"{path}: the stored world config is not valid ({exc}); use an intact checkpoint") from None
    if world.get("window", window) != window:
        raise InputError(
            f"{path}: world.window = {world.get('window')!r} differs from the network's {window}; "
            "use an intact checkpoint"
        )


def _misfit(expected: dict[str, torch.Tensor], given: dict[str, torch.Tensor]) -> str | None:
    """The first difference between a network's state dict and a checkpoint's: a missing or unexpected
    key, or a shape, named (None when they fit)."""
    missing = [k for k in expected if k not in given]
    if missing:
        return f"no {missing[0]} in the file" + (f", and {len(missing) - 1} more missing" if len(missing) > 1 else "")
    extra = [k for k in given if k not in expected]
    if extra:
        return f"{extra[0]} is not a weight of it" + (f", and {len(extra) - 1} more" if len(extra) > 1 else "")
    for key, t in expected.items():
        if tuple(given[key].shape) != tuple(t.shape):
            return f"{key} is {list(given[key].shape)} in the file, {list(t.shape)} in the network"
    return None
