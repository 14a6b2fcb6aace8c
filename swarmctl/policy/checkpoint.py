"""Checkpoints: the network's weights with their config and metadata, validated on load.

A checkpoint is a torch file holding only plain data (loaded with `weights_only=True`):
{"format": "swarmctl-ddql", "version": 1, "architecture": ..., "window": F, "n_actions": 5,
 "state_dict": ..., "world": WorldConfig fields, "train": TrainConfig fields, "metadata": {...}}.
"""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path

import torch

from swarmctl.errors import InputError
from swarmctl.policy.qnet import ARCHITECTURE, QNetwork

FORMAT = "swarmctl-ddql"
VERSION = 1


def save_checkpoint(path: str | Path, net: QNetwork, world: dict, train: dict, metadata: dict) -> None:
    """Write the network and everything needed to reproduce and judge it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "architecture": ARCHITECTURE,
        "window": net.window,
        "n_actions": 5,
        "state_dict": {k: v.detach().cpu() for k, v in net.state_dict().items()},
        "world": world,
        "train": train,
        "metadata": metadata,
    }
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)


def load_checkpoint(path: str | Path, window: int | None = None) -> tuple[QNetwork, dict]:
    """Load and validate a checkpoint; returns (network in eval mode, payload without weights).

    Raises InputError naming the file when it is missing, not a checkpoint, from another
    architecture or version, or made for another observation size than `window`.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such checkpoint file; train one with `swarmctl train ... --out {path}`")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, zipfile.BadZipFile, RuntimeError, EOFError, ValueError, OSError) as exc:
        raise InputError(
            f"{path}: not a swarmctl checkpoint (cannot be read as a torch file: {type(exc).__name__})"
        ) from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise InputError(f"{path}: not a swarmctl checkpoint (no '{FORMAT}' format marker)")
    if payload.get("version") != VERSION:
        raise InputError(f"{path}: checkpoint version {payload.get('version')} is not supported (expected {VERSION})")
    if payload.get("architecture") != ARCHITECTURE:
        raise InputError(
            f"{path}: architecture {payload.get('architecture')!r} is not {ARCHITECTURE!r}; "
            "retrain with this version of swarmctl"
        )
    f = payload.get("window")
    if window is not None and f != window:
        raise InputError(
            f"{path}: the model was trained for {f} x {f} observations, not {window} x {window}; "
            f"use --window {f} or a model trained for {window}"
        )
    try:
        net = QNetwork(window=int(f))
        net.load_state_dict(payload["state_dict"])
    except (KeyError, RuntimeError, TypeError, ValueError) as exc:
        raise InputError(
            f"{path}: weights do not fit the {ARCHITECTURE} network ({str(exc).splitlines()[0]})"
        ) from None
    net.eval()
    info = {k: v for k, v in payload.items() if k != "state_dict"}
    return net, info
