"""Bad input at every boundary of every command, as an attacker and a tired user would type it.

Each case runs `swarmctl.cli.main` in-process (a few through the real CLI in a subprocess) and must end
with exit status 2, exactly one line on stderr that names the option, file or field, no traceback, and
within CASE_LIMIT_S seconds (a case still running then fails as a hang).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
import traceback
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from swarmctl.cli import main
from swarmctl.policy.checkpoint import save_checkpoint, weights_sha256
from swarmctl.policy.qnet import QNetwork
from swarmctl.world.config import WorldConfig
from tests.mission_support import small_grid

ROOT = Path(__file__).resolve().parent.parent
CASE_LIMIT_S = 25.0
SITL_LOG = ROOT / "tests/data/logs/arducopter_sitl_guided_takeoff_120s.tlog"
RECORDING = ROOT / "tests/data/logs/sitl3-mission"

# --- the files the cases read ------------------------------------------------------------------------

LON, LAT = -87.632, 41.876  # the Chicago Loop
SQUARE = [[LON, LAT], [LON + 0.002, LAT], [LON + 0.002, LAT + 0.002], [LON, LAT + 0.002], [LON, LAT]]


def polygon(ring: list) -> dict:
    return {"type": "Polygon", "coordinates": [ring]}


def buildings(*heights: dict) -> dict:
    inner = [[LON + 0.0005, LAT + 0.0005], [LON + 0.001, LAT + 0.0005], [LON + 0.001, LAT + 0.001]]
    features = [{"type": "Feature", "properties": props, "geometry": polygon([*inner, inner[0]])} for props in heights]
    return {"type": "FeatureCollection", "features": features}


def plan_file(version: object = 1, fence_version: object = 2, ring: list | None = None) -> dict:
    latlon = [[lat, lon] for lon, lat in (ring or SQUARE)[:-1]]
    return {
        "fileType": "Plan",
        "version": version,
        "geoFence": {"version": fence_version, "polygons": [{"inclusion": True, "polygon": latlon, "version": 1}]},
    }


def kml(coordinates: str) -> str:
    return (
        '<kml xmlns="http://www.opengis.net/kml/2.2"><Placemark><Polygon><outerBoundaryIs><LinearRing>'
        f"<coordinates>{coordinates}</coordinates></LinearRing></outerBoundaryIs></Polygon></Placemark></kml>"
    )


def grid_npz(path: Path, meta: dict | None = None, blocked: np.ndarray | None = None) -> None:
    grid = small_grid()
    body = {**grid.meta(), **(meta or {})}
    mask = grid.blocked if blocked is None else blocked
    with path.open("wb") as fh:
        np.savez_compressed(fh, blocked=mask, meta=np.array(json.dumps(body)))


def grid_declaring(path: Path, shape: tuple[int, int]) -> None:
    """A grid file whose mask header claims `shape` (and holds a few bytes): a decompression bomb's header."""
    header = {"descr": "|b1", "fortran_order": False, "shape": shape}
    npy = bytearray(b"\x93NUMPY\x01\x00")
    text = repr(header).encode() + b" "
    text += b" " * (-(len(npy) + 2 + len(text) + 1) % 64) + b"\n"
    npy += len(text).to_bytes(2, "little") + text + b"\x00" * 16
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("blocked.npy", bytes(npy))
        with zf.open("meta.npy", "w") as fh:
            np.lib.format.write_array(fh, np.array(json.dumps(small_grid().meta())))


def checkpoint(path: Path, *, weights=None, world: dict | None = None, **payload) -> None:
    net = QNetwork(20)
    if weights is not None:
        with torch.no_grad():
            next(net.parameters()).fill_(weights)
    save_checkpoint(path, net, {**WorldConfig().as_dict(), **(world or {})}, {}, {})
    if payload:
        body = torch.load(path, weights_only=True)
        body.update(payload)
        torch.save(body, path)


def mission(folder: Path, tables: str = "", grid: str = '"grid.npz"', **keys: str) -> Path:
    """mission.toml in its own folder: the small test grid, one vehicle, `keys` in [mission] (TOML text)."""
    folder.mkdir(parents=True, exist_ok=True)
    grid_npz(folder / "grid.npz")
    fields = {"name": '"bad"', "grid": grid, "policy": '"frontier"', **keys}
    body = "[mission]\n" + "".join(f"{k} = {v}\n" for k, v in fields.items()) + tables
    body += '[[vehicles]]\nname = "a"\nconnection = "udpin:127.0.0.1:14551"\nsysid = 1\n'
    (folder / "mission.toml").write_text(body)
    return folder / "mission.toml"


def sparse(path: Path, size: int) -> None:
    """A file of `size` bytes that takes no disk space (for the size limits)."""
    with path.open("wb") as fh:
        fh.truncate(size)


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("bad-inputs")
    f: dict[str, Path] = {}

    def text(name: str, body: str | bytes) -> None:
        f[name] = d / name
        (f[name].write_bytes if isinstance(body, bytes) else f[name].write_text)(body)

    def js(name: str, body: object) -> None:
        text(name, json.dumps(body))

    js("area.geojson", polygon(SQUARE))
    js("swapped.geojson", polygon([[lat, lon] for lon, lat in SQUARE]))
    js("over90.geojson", polygon([[-35.36, 149.16], [-35.36, 149.17], [-35.35, 149.17], [-35.36, 149.16]]))
    js("polar.geojson", polygon([[100, 88], [120, 88], [120, 89], [100, 88]]))
    js("pole.geojson", polygon([[0, 80], [90, 80], [180, 80], [-90, 80], [0, 80]]))
    js("antimeridian.geojson", polygon([[179.9, 10], [-179.9, 10], [-179.9, 10.1], [179.9, 10.1], [179.9, 10]]))
    split = [
        [[[179.9, 10], [180, 10], [180, 10.1], [179.9, 10]]],
        [[[-180, 10], [-179.9, 10], [-179.9, 10.1], [-180, 10]]],
    ]
    js("split.geojson", {"type": "MultiPolygon", "coordinates": split})
    text("nan.geojson", '{"type": "Polygon", "coordinates": [[[NaN, 41.8], [-87.6, 41.8], [-87.6, 41.9]]]}')
    js("textcoords.geojson", polygon([["a", "b"], ["c", "d"], ["e", "f"]]))
    js("list.geojson", [1, 2, 3])
    js("crs.geojson", {"type": "FeatureCollection", "crs": {"properties": {"name": "EPSG:3435"}}, "features": []})
    js("points.geojson", {"type": "Point", "coordinates": [LON, LAT]})
    text("deep.geojson", '{"type": "Polygon", "coordinates": ' + "[" * 100_000 + "]" * 100_000 + "}")
    text("deepgc.geojson", '{"type": "GeometryCollection", "geometries": [' * 80 + "]}" * 80)
    text("empty.geojson", "")
    text("binary.geojson", bytes(range(256)) * 64)
    text("broken.geojson", '{"type": "FeatureCollection", "features": [')
    text("area.shp", "not an area")
    f["huge.geojson"] = d / "huge.geojson"
    sparse(f["huge.geojson"], 65 * 2**20)
    (d / "folder.geojson").mkdir()
    f["folder.geojson"] = d / "folder.geojson"
    text("broken.kml", "<kml><Document><Placemark>")
    text("nan.kml", kml("nan,41.8 -87.6,41.8 -87.6,41.9"))
    text("swapped.kml", kml(" ".join(f"{lat},{lon}" for lon, lat in SQUARE)))
    text("badcoords.kml", kml("x;y z;w"))
    f["huge.kml"] = d / "huge.kml"
    sparse(f["huge.kml"], 65 * 2**20)
    js("v99.plan", plan_file(version=99))
    js("vtext.plan", plan_file(version="1"))
    js("fence99.plan", plan_file(fence_version=99))
    js("mission.plan", {"fileType": "Mission", "version": 1})
    js("swapped.plan", {**plan_file(), "geoFence": {"polygons": [{"inclusion": True, "polygon": SQUARE[:-1]}]}})
    text(
        "nanradius.plan",
        '{"fileType": "Plan", "version": 1, "geoFence": {"circles": [{"circle": {"center": [41.8, -87.6], '
        '"radius": NaN}, "inclusion": false}], "polygons": []}}',
    )
    text("deep.plan", '{"fileType": "Plan", "version": 1, "geoFence": ' + "[" * 5000 + "]" * 5000 + "}")
    js("furlongs.geojson", buildings({"height": "12 furlongs"}))
    js("tall.geojson", buildings({"height": "tall"}))
    js("toohigh.geojson", buildings({"height": 1e9}))
    text("nanheight.geojson", json.dumps(buildings({"height": 12345.678})).replace("12345.678", "NaN"))
    js("manylevels.geojson", buildings({"building:levels": "many"}))
    js("inches.geojson", buildings({"height": "3 m 6 in"}))
    f["hugebuildings.geojson"] = d / "hugebuildings.geojson"
    sparse(f["hugebuildings.geojson"], 513 * 2**20)
    # grids
    grid_npz(d / "grid.npz")
    f["grid.npz"] = d / "grid.npz"
    for name, meta in {
        "nanorigin.npz": {"origin": [float("nan"), 0.0]},
        "infcell.npz": {"cell_size_m": float("inf")},
        "zerocell.npz": {"cell_size_m": 0.0},
        "bigorigin.npz": {"origin": [1e12, 0.0]},
        "v2.npz": {"version": 2},
        "noproj.npz": {"proj": "+proj=nonsense"},
        "format.npz": {"format": "something-else"},
        "width.npz": {"width": 11},
    }.items():
        grid_npz(d / name, meta)
        f[name] = d / name
    grid_npz(d / "intmask.npz", blocked=np.zeros((10, 10), dtype=np.int8))
    f["intmask.npz"] = d / "intmask.npz"
    grid_declaring(d / "bomb.npz", (100_000, 100_000))
    f["bomb.npz"] = d / "bomb.npz"
    text("text.npz", "not a grid")
    f["hugegrid.npz"] = d / "hugegrid.npz"
    sparse(f["hugegrid.npz"], 65 * 2**20)
    # checkpoints
    for name, kw in {
        "good.pt": {},
        "nanweights.pt": {"weights": float("nan")},
        "infweights.pt": {"weights": float("inf")},
        "nanfov.pt": {"world": {"fov": float("nan")}},
        "hugemap.pt": {"world": {"map_size": 10**9}},
        "textfov.pt": {"world": {"fov": "3"}},
        "window.pt": {"world": {"window": 16}},
        "v99.pt": {"version": 99},
        "arch.pt": {"architecture": "resnet"},
        "variant.pt": {"variant": "v-unknown"},
    }.items():
        checkpoint(d / name, **kw)
        f[name] = d / name
    data = bytearray(f["good.pt"].read_bytes())
    middle = len(data) // 2
    data[middle : middle + 64] = bytes(b ^ 0xFF for b in data[middle : middle + 64])
    text("flipped.pt", bytes(data))
    f["statedict.pt"] = d / "statedict.pt"
    torch.save(QNetwork(20).state_dict(), f["statedict.pt"])
    f["pickle.pt"] = d / "pickle.pt"
    torch.save({"format": "swarmctl-ddql", "evil": Path("/")}, f["pickle.pt"])  # a class: not plain data
    text("empty.pt", b"")
    text("text.pt", "not a checkpoint")
    f["huge.pt"] = d / "huge.pt"
    sparse(f["huge.pt"], 257 * 2**20)
    # missions
    m = d / "missions"
    for name, keys, tables in [
        ("alt-nan", {"altitude": "nan"}, ""),
        ("alt-inf", {"altitude": "inf"}, ""),
        ("alt-5000", {"altitude": "5000.0"}, ""),
        ("alt-text", {"altitude": '"40"'}, ""),
        ("alt-bool", {"altitude": "true"}, ""),
        ("timeout-nan", {}, "[timing]\nstep_timeout = nan\n"),
        ("limit-neg", {}, "[timing]\ntime_limit = -5.0\n"),
        ("unknown-key", {"colour": '"red"'}, ""),
        ("oracle", {"policy": '"oracle"'}, ""),
        ("nomodel", {"policy": '"ddql:nowhere.pt"'}, ""),
        ("nogrid", {}, ""),
        ("badgrid", {}, ""),
        ("biggrid", {}, ""),
        ("key-short", {"signing_key": '"short.key"'}, ""),
        ("key-huge", {"signing_key": '"huge.key"'}, ""),
        ("batt", {}, "[battery]\ntakeoff_min = 10\nreturn_below = 50\n"),
    ]:
        path = mission(m / name, tables, **keys)
        f[f"mission-{name}"] = path
    (m / "nogrid" / "grid.npz").unlink()
    (m / "badgrid" / "grid.npz").write_text("not a grid")
    small_grid(200, 200).save(m / "biggrid" / "grid.npz")
    (m / "key-short" / "short.key").write_bytes(b"0123")
    sparse(m / "key-huge" / "huge.key", 10 * 2**20)
    f["mission"] = mission(m / "good")
    f["mission-one-cell"] = mission(m / "one-cell")
    small_grid(1, 1).save(m / "one-cell" / "grid.npz")  # room for a vehicle, none for its target
    text("broken.toml", "[mission\nname = ")
    text("binary.toml", bytes(range(256)))
    f["hugemission.toml"] = d / "hugemission.toml"
    sparse(f["hugemission.toml"], 2 * 2**20)
    # keys, folders, recordings
    text("short.key", b"0123456789")
    f["hugekey"] = d / "hugekey"
    sparse(f["hugekey"], 10 * 2**20)
    text("afile", "a file where a folder should be")
    f["under-file"] = d / "afile" / "out"
    f["out"] = d / "out"
    f["folder"] = d
    text("empty.tlog", b"")
    text("foreign.tlog", b"this is not a telemetry log\n" * 100)
    (d / "emptyrec").mkdir()
    f["emptyrec"] = d / "emptyrec"
    f["sitl"] = SITL_LOG
    f["recording"] = RECORDING
    for name, key, shape in (("wideshape.pt", "head.2.weight", (7, 64)), ("extraweight.pt", "evil", (1,))):
        f[name] = d / name
        checkpoint(f[name])
        body = torch.load(f[name], weights_only=True)
        body["state_dict"][key] = torch.zeros(shape)
        body["weights_sha256"] = weights_sha256(body["state_dict"])
        torch.save(body, f[name])
    (d / "earlier-run").mkdir()  # a recording folder an output must not overwrite
    text("earlier-run/events.jsonl", '{"t": 1.0, "event": "mission"}\n')
    f["earlier-run"] = d / "earlier-run"
    f["fifo"] = d / "fifo"
    os.mkfifo(f["fifo"])
    f["long"] = d / ("a" * 5000)  # longer than any file name may be
    return f


# --- the cases: (argv with {file} names, what the one line must name) ---------------------------------

EVAL = ["eval", "--policy", "random", "--episodes", "2", "--no-progress"]
TRAIN = ["train", "--out", "{out}/m.pt", "--episodes", "1", "--prefill", "0", "--no-progress"]
PLAN = ["plan", "{area.geojson}", "--out", "{out}/plan"]
DEMO = ["demo", "--mission", "{mission}", "--out", "{out}/demo", "--quiet", "--time-limit", "5"]
MOCK = ["mock-vehicle", "--duration", "0.1"]
REPLAY = ["replay", "{sitl}", "--out", "{out}/replay", "--quiet"]

CASES: list[tuple[str, list[str], str]] = [
    # eval: the world's numbers
    ("eval-map-0", [*EVAL, "--map", "0"], "--map"),
    ("eval-map-neg", [*EVAL, "--map", "-5"], "--map"),
    ("eval-map-huge", [*EVAL, "--map", "100000"], "--map"),
    ("eval-map-text", [*EVAL, "--map", "big"], "--map"),
    ("eval-map-float", [*EVAL, "--map", "20.5"], "--map"),
    ("eval-uavs-0", [*EVAL, "--uavs", "0"], "--uavs"),
    ("eval-uavs-huge", [*EVAL, "--uavs", "5000"], "--uavs"),
    ("eval-uavs-text", [*EVAL, "--uavs", "many"], "--uavs"),
    ("eval-uavs-over-cells", [*EVAL, "--map", "3", "--uavs", "10", "--targets", "4"], "--uavs"),
    ("eval-targets-0", [*EVAL, "--targets", "0"], "--targets"),
    ("eval-targets-too-many", [*EVAL, "--targets", "200"], "--targets"),
    ("eval-targets-below-uavs", [*EVAL, "--targets", "1"], "--targets"),
    ("eval-clusters-0", [*EVAL, "--clusters", "0"], "--clusters"),
    ("eval-clusters-over-targets", [*EVAL, "--clusters", "9"], "--clusters"),
    ("eval-obstacles-nan", [*EVAL, "--obstacles", "nan"], "--obstacles"),
    ("eval-obstacles-inf", [*EVAL, "--obstacles", "inf"], "--obstacles"),
    ("eval-obstacles-neg", [*EVAL, "--obstacles", "-0.1"], "--obstacles"),
    ("eval-obstacles-high", [*EVAL, "--obstacles", "0.95"], "--obstacles"),
    ("eval-loss-nan", [*EVAL, "--channel", "fixed", "--loss", "nan"], "--loss"),
    ("eval-loss-over-1", [*EVAL, "--channel", "fixed", "--loss", "1.5"], "--loss"),
    ("eval-loss-minus-inf", [*EVAL, "--loss", "-inf"], "--loss"),
    ("eval-loss-without-fixed", [*EVAL, "--loss", "0.5"], "only --channel fixed reads it"),
    ("eval-clusters-sparse", [*EVAL, "--scenario", "sparse", "--clusters", "3"], "only --scenario cluster"),
    ("eval-cell-nan", [*EVAL, "--channel", "model", "--cell-size", "nan"], "--cell-size"),
    ("eval-cell-inf", [*EVAL, "--channel", "model", "--cell-size", "inf"], "--cell-size"),
    ("eval-cell-0", [*EVAL, "--cell-size", "0"], "--cell-size"),
    ("eval-cell-neg", [*EVAL, "--cell-size", "-10"], "--cell-size"),
    ("eval-cell-huge", [*EVAL, "--cell-size", "1e9"], "--cell-size"),
    ("eval-fov-nan", [*EVAL, "--fov", "nan"], "--fov"),
    ("eval-fov-inf", [*EVAL, "--fov", "inf"], "--fov"),
    ("eval-fov-neg", [*EVAL, "--fov", "-1"], "--fov"),
    ("eval-fov-huge", [*EVAL, "--fov", "1000"], "--fov"),
    ("eval-window-0", [*EVAL, "--window", "0"], "--window"),
    ("eval-window-huge", [*EVAL, "--window", "100000"], "--window"),
    ("eval-scenario", [*EVAL, "--scenario", "everywhere"], "--scenario"),
    ("eval-channel", [*EVAL, "--channel", "telepathy"], "--channel"),
    ("eval-steps-0", [*EVAL, "--steps", "0"], "--steps"),
    ("eval-steps-huge", [*EVAL, "--steps", "1000000000"], "--steps"),
    ("eval-steps-exp", [*EVAL, "--steps", "1e3"], "--steps"),
    ("eval-episodes-0", [*EVAL, "--episodes", "0"], "--episodes"),
    ("eval-episodes-huge", [*EVAL, "--episodes", "1000000000000"], "--episodes"),
    ("eval-seed-neg", [*EVAL, "--seed", "-1"], "--seed"),
    ("eval-seed-huge", [*EVAL, "--seed", str(2**64)], "--seed"),
    ("eval-seed-nan", [*EVAL, "--seed", "nan"], "--seed"),
    # eval: memory before any array exists
    ("eval-memory-map", [*EVAL, "--map", "4000"], "limit"),
    ("eval-memory-vehicles", [*EVAL, "--map", "300", "--uavs", "50", "--targets", "50", "--episodes", "500"], "limit"),
    ("eval-memory-fov", [*EVAL, "--map", "1000", "--fov", "100"], "limit"),
    # eval: policies
    ("policy-missing", ["eval", "--episodes", "2"], "--policy"),
    ("policy-unknown", ["eval", "--policy", "nonsense"], "--policy"),
    ("policy-la-text", ["eval", "--policy", "la:x"], "la:4"),
    ("policy-la-deep", ["eval", "--policy", "la:99"], "la:4"),
    ("policy-ddql-bare", ["eval", "--policy", "ddql:"], "ddql:"),
    ("policy-ddql-missing", ["eval", "--policy", "ddql:/nonexistent/model.pt"], "model.pt"),
    ("policy-tau-nan", ["eval", "--policy", "ddql:{good.pt}:tau=nan"], "tau"),
    ("policy-tau-inf", ["eval", "--policy", "ddql:{good.pt}:tau=inf"], "tau"),
    ("policy-tau-zero", ["eval", "--policy", "ddql:{good.pt}:tau=0"], "tau"),
    ("policy-tau-neg", ["eval", "--policy", "ddql:{good.pt}:tau=-1"], "tau"),
    ("policy-hover", ["eval", "--policy", "ddql:{good.pt}:hover=maybe"], "hover"),
    ("policy-straggler", ["eval", "--policy", "ddql:{good.pt}:straggler=who"], "straggler"),
    # eval: checkpoints
    ("ckpt-nan-weights", ["eval", "--policy", "ddql:{nanweights.pt}"], "NaN"),
    ("ckpt-inf-weights", ["eval", "--policy", "ddql:{infweights.pt}"], "infinite"),
    ("ckpt-flipped", ["eval", "--policy", "ddql:{flipped.pt}"], "flipped.pt"),
    ("ckpt-state-dict", ["eval", "--policy", "ddql:{statedict.pt}"], "statedict.pt"),
    ("ckpt-pickle", ["eval", "--policy", "ddql:{pickle.pt}"], "pickle.pt"),
    ("ckpt-empty", ["eval", "--policy", "ddql:{empty.pt}"], "empty.pt"),
    ("ckpt-text", ["eval", "--policy", "ddql:{text.pt}"], "text.pt"),
    ("ckpt-huge", ["eval", "--policy", "ddql:{huge.pt}"], "huge.pt"),
    ("ckpt-version", ["eval", "--policy", "ddql:{v99.pt}"], "version 99"),
    ("ckpt-architecture", ["eval", "--policy", "ddql:{arch.pt}"], "architecture"),
    ("ckpt-variant", ["eval", "--policy", "ddql:{variant.pt}"], "variant"),
    ("ckpt-world-nan", ["eval", "--policy", "ddql:{nanfov.pt}"], "nanfov.pt"),
    ("ckpt-world-huge", ["eval", "--policy", "ddql:{hugemap.pt}"], "hugemap.pt"),
    ("ckpt-world-text", ["eval", "--policy", "ddql:{textfov.pt}"], "world.fov"),
    ("ckpt-world-window", ["eval", "--policy", "ddql:{window.pt}"], "world.window"),
    ("ckpt-folder", ["eval", "--policy", "ddql:{folder}"], "checkpoint"),
    ("ckpt-shape", ["eval", "--policy", "ddql:{wideshape.pt}"], "head.2.weight is [7, 64] in the file, [5, 64]"),
    ("ckpt-extra-weight", ["eval", "--policy", "ddql:{extraweight.pt}"], "evil is not a weight of it"),
    # eval: files
    ("eval-json-under-file", [*EVAL, "--json", "{under-file}/r.json"], "--json"),
    ("eval-json-folder", [*EVAL, "--json", "{folder}"], "--json"),
    ("eval-grid-missing", [*EVAL, "--grid", "{out}/nowhere.npz"], "nowhere.npz"),
    ("eval-grid-text", [*EVAL, "--grid", "{text.npz}"], "text.npz"),
    ("eval-grid-nan-origin", [*EVAL, "--grid", "{nanorigin.npz}"], "nanorigin.npz"),
    ("eval-grid-inf-cell", [*EVAL, "--grid", "{infcell.npz}"], "infcell.npz"),
    ("eval-grid-zero-cell", [*EVAL, "--grid", "{zerocell.npz}"], "cell_size_m"),
    ("eval-grid-far-origin", [*EVAL, "--grid", "{bigorigin.npz}"], "origin"),
    ("eval-grid-version", [*EVAL, "--grid", "{v2.npz}"], "version 2"),
    ("eval-grid-projection", [*EVAL, "--grid", "{noproj.npz}"], "projection"),
    ("eval-grid-format", [*EVAL, "--grid", "{format.npz}"], "format"),
    ("eval-grid-width", [*EVAL, "--grid", "{width.npz}"], "width.npz"),
    ("eval-grid-int-mask", [*EVAL, "--grid", "{intmask.npz}"], "bool"),
    ("eval-grid-bomb", [*EVAL, "--grid", "{bomb.npz}"], "100000 x 100000"),
    ("eval-grid-huge", [*EVAL, "--grid", "{hugegrid.npz}"], "hugegrid.npz"),
    ("eval-unknown-option", [*EVAL, "--speed", "3"], "--speed"),
    ("eval-option-no-value", [*EVAL, "--uavs"], "--uavs"),
    # train
    ("train-out-under-file", ["train", "--out", "{under-file}/m.pt", "--episodes", "1"], "--out"),
    ("train-out-folder", ["train", "--out", "{folder}", "--episodes", "1"], "--out"),
    ("train-out-missing", ["train", "--episodes", "1"], "--out"),
    ("train-updates-inf", [*TRAIN, "--updates-per-step", "inf"], "--updates-per-step"),
    ("train-updates-nan", [*TRAIN, "--updates-per-step", "nan"], "--updates-per-step"),
    ("train-updates-0", [*TRAIN, "--updates-per-step", "0"], "--updates-per-step"),
    ("train-updates-huge", [*TRAIN, "--updates-per-step", "1000"], "--updates-per-step"),
    ("train-lr-nan", [*TRAIN, "--lr", "nan"], "--lr"),
    ("train-lr-0", [*TRAIN, "--lr", "0"], "--lr"),
    ("train-lr-inf", [*TRAIN, "--lr", "inf"], "--lr"),
    ("train-temperature-nan", [*TRAIN, "--temperature", "nan", "0.1"], "--temperature"),
    ("train-temperature-0", [*TRAIN, "--temperature", "1", "0"], "--temperature"),
    ("train-temperature-inf", [*TRAIN, "--temperature", "inf", "0.1"], "--temperature"),
    ("train-epsilon-2", [*TRAIN, "--epsilon", "2", "0"], "--epsilon"),
    ("train-epsilon-nan", [*TRAIN, "--epsilon", "nan", "0"], "--epsilon"),
    ("train-parallel-0", [*TRAIN, "--parallel", "0"], "--parallel"),
    ("train-batch-0", [*TRAIN, "--batch-size", "0"], "--batch-size"),
    ("train-replay-small", [*TRAIN, "--replay", "10"], "--replay"),
    ("train-replay-memory", [*TRAIN, "--replay", "10000000000"], "--replay"),
    ("train-prefill-neg", [*TRAIN, "--prefill", "-1"], "--prefill"),
    ("train-threads-0", [*TRAIN, "--threads", "0"], "--threads"),
    ("train-target-every-0", [*TRAIN, "--target-every", "0"], "--target-every"),
    ("train-eval-every-0", [*TRAIN, "--eval-every", "0"], "--eval-every"),
    ("train-eval-episodes-0", [*TRAIN, "--eval-episodes", "0"], "--eval-episodes"),
    ("train-eval-steps-0", [*TRAIN, "--eval-steps", "0"], "--eval-steps"),
    ("train-window-small", [*TRAIN, "--window", "4"], "--window"),
    ("train-episodes-0", ["train", "--out", "{out}/m.pt", "--episodes", "0"], "--episodes"),
    ("train-exploration", [*TRAIN, "--exploration", "curiosity"], "--exploration"),
    ("train-memory-world", [*TRAIN, "--map", "2000", "--parallel", "64"], "limit"),
    ("train-init-missing", [*TRAIN, "--init", "{out}/none.pt"], "--init"),
    ("train-init-text", [*TRAIN, "--init", "{text.pt}"], "text.pt"),
    ("train-init-nan", [*TRAIN, "--init", "{nanweights.pt}"], "NaN"),
    ("train-init-window", [*TRAIN, "--window", "16", "--init", "{good.pt}"], "--window"),
    # bench
    ("bench-seconds-nan", ["bench", "--seconds", "nan"], "--seconds"),
    ("bench-seconds-inf", ["bench", "--seconds", "inf"], "--seconds"),
    ("bench-seconds-0", ["bench", "--seconds", "0"], "--seconds"),
    ("bench-seconds-neg", ["bench", "--seconds", "-1"], "--seconds"),
    ("bench-seconds-huge", ["bench", "--seconds", "1e9"], "--seconds"),
    ("bench-json-under-file", ["bench", "--seconds", "0.01", "--json", "{under-file}/b.json"], "--json"),
    ("bench-json-folder", ["bench", "--seconds", "0.01", "--json", "{folder}"], "--json"),
    # plan: area files
    ("plan-area-missing", ["plan", "{out}/nowhere.geojson", "--out", "{out}/p"], "nowhere.geojson"),
    ("plan-area-folder", ["plan", "{folder.geojson}", "--out", "{out}/p"], "folder.geojson"),
    ("plan-area-empty", ["plan", "{empty.geojson}", "--out", "{out}/p"], "empty.geojson"),
    ("plan-area-binary", ["plan", "{binary.geojson}", "--out", "{out}/p"], "UTF-8"),
    ("plan-area-broken", ["plan", "{broken.geojson}", "--out", "{out}/p"], "not valid JSON"),
    ("plan-area-deep", ["plan", "{deep.geojson}", "--out", "{out}/p"], "nested"),
    ("plan-area-deep-collections", ["plan", "{deepgc.geojson}", "--out", "{out}/p"], "nested"),
    ("plan-area-huge", ["plan", "{huge.geojson}", "--out", "{out}/p"], "huge.geojson"),
    ("plan-area-swapped", ["plan", "{swapped.geojson}", "--out", "{out}/p"], "[lon, lat]"),
    ("plan-area-over-90", ["plan", "{over90.geojson}", "--out", "{out}/p"], "swap"),
    ("plan-area-polar", ["plan", "{polar.geojson}", "--out", "{out}/p"], "pole"),
    ("plan-area-pole", ["plan", "{pole.geojson}", "--out", "{out}/p"], "North Pole"),
    ("plan-area-antimeridian", ["plan", "{antimeridian.geojson}", "--out", "{out}/p"], "antimeridian"),
    ("plan-area-split-antimeridian", ["plan", "{split.geojson}", "--out", "{out}/p"], "antimeridian"),
    ("plan-area-nan", ["plan", "{nan.geojson}", "--out", "{out}/p"], "NaN"),
    ("plan-area-text-coords", ["plan", "{textcoords.geojson}", "--out", "{out}/p"], "numbers"),
    ("plan-area-list", ["plan", "{list.geojson}", "--out", "{out}/p"], "GeoJSON"),
    ("plan-area-crs", ["plan", "{crs.geojson}", "--out", "{out}/p"], "EPSG:3435"),
    ("plan-area-points", ["plan", "{points.geojson}", "--out", "{out}/p"], "no area polygon"),
    ("plan-area-extension", ["plan", "{area.shp}", "--out", "{out}/p"], ".shp"),
    ("plan-kml-broken", ["plan", "{broken.kml}", "--out", "{out}/p"], "KML"),
    ("plan-kml-nan", ["plan", "{nan.kml}", "--out", "{out}/p"], "NaN"),
    ("plan-kml-swapped", ["plan", "{swapped.kml}", "--out", "{out}/p"], "[lon, lat]"),
    ("plan-kml-bad-coordinates", ["plan", "{badcoords.kml}", "--out", "{out}/p"], "coordinates"),
    ("plan-kml-huge", ["plan", "{huge.kml}", "--out", "{out}/p"], "huge.kml"),
    ("plan-qgc-version-99", ["plan", "{v99.plan}", "--out", "{out}/p"], "version 99"),
    ("plan-qgc-version-text", ["plan", "{vtext.plan}", "--out", "{out}/p"], "version '1'"),
    ("plan-qgc-fence-version", ["plan", "{fence99.plan}", "--out", "{out}/p"], "geoFence version 99"),
    ("plan-qgc-file-type", ["plan", "{mission.plan}", "--out", "{out}/p"], "fileType"),
    ("plan-qgc-swapped", ["plan", "{swapped.plan}", "--out", "{out}/p"], "[lat, lon]"),
    ("plan-qgc-nan-radius", ["plan", "{nanradius.plan}", "--out", "{out}/p"], "radius"),
    ("plan-qgc-deep", ["plan", "{deep.plan}", "--out", "{out}/p"], "nested"),
    # plan: buildings
    ("plan-height-unit", [*PLAN, "--buildings", "{furlongs.geojson}"], "12 furlongs"),
    ("plan-height-text", [*PLAN, "--buildings", "{tall.geojson}"], "'tall'"),
    ("plan-height-huge", [*PLAN, "--buildings", "{toohigh.geojson}"], "taller than any building"),
    ("plan-height-nan", [*PLAN, "--buildings", "{nanheight.geojson}"], "finite"),
    ("plan-height-inches", [*PLAN, "--buildings", "{inches.geojson}"], "inches"),
    ("plan-levels-text", [*PLAN, "--buildings", "{manylevels.geojson}"], "'many'"),
    ("plan-buildings-huge", [*PLAN, "--buildings", "{hugebuildings.geojson}"], "hugebuildings.geojson"),
    ("plan-buildings-swapped", [*PLAN, "--buildings", "{swapped.geojson}"], "swap"),
    ("plan-buildings-missing", [*PLAN, "--buildings", "{out}/none.geojson"], "none.geojson"),
    # plan: numbers and the output
    ("plan-cell-nan", [*PLAN, "--cell", "nan"], "--cell"),
    ("plan-cell-inf", [*PLAN, "--cell", "inf"], "--cell"),
    ("plan-cell-0", [*PLAN, "--cell", "0"], "--cell"),
    ("plan-cell-neg", [*PLAN, "--cell", "-5"], "--cell"),
    ("plan-cell-tiny", [*PLAN, "--cell", "0.05"], "--max-cells"),
    ("plan-altitude-nan", [*PLAN, "--altitude", "nan"], "--altitude"),
    ("plan-altitude-0", [*PLAN, "--altitude", "0"], "--altitude"),
    ("plan-altitude-inf", [*PLAN, "--altitude", "inf"], "--altitude"),
    ("plan-margin-nan", [*PLAN, "--margin", "nan"], "--margin"),
    ("plan-margin-neg", [*PLAN, "--margin", "-1"], "--margin"),
    ("plan-margin-over-altitude", [*PLAN, "--margin", "50"], "--margin"),
    ("plan-max-cells-0", [*PLAN, "--max-cells", "0"], "--max-cells"),
    ("plan-max-cells-huge", [*PLAN, "--max-cells", "1000000000"], "--max-cells"),
    ("plan-unknown-rule", [*PLAN, "--unknown-height", "guess"], "--unknown-height"),
    ("plan-out-under-file", ["plan", "{area.geojson}", "--out", "{under-file}"], "--out"),
    ("plan-out-is-file", ["plan", "{area.geojson}", "--out", "{afile}"], "--out"),
    ("plan-out-recording", ["plan", "{area.geojson}", "--out", "{earlier-run}"], "already holds a recording"),
    ("plan-area-long-name", ["plan", "{long}.geojson", "--out", "{out}/plan"], "File name too long"),
    ("demo-out-recording", ["demo", "--mission", "{mission}", "--out", "{earlier-run}"], "already holds a recording"),
    ("train-out-fifo", ["train", "--out", "{fifo}", "--episodes", "1"], "not a regular file"),
    ("train-out-long-name", ["train", "--out", "{long}.pt", "--episodes", "1"], "File name too long"),
    ("eval-json-fifo", [*EVAL, "--json", "{fifo}"], "not a regular file"),
    ("replay-long-name", ["replay", "{long}"], "File name too long"),
    ("replay-out-long-name", [*REPLAY[:2], "--out", "{long}", "--quiet"], "File name too long"),
    # demo
    ("demo-uavs-0", [*DEMO, "--uavs", "0"], "--uavs"),
    ("demo-uavs-51", [*DEMO, "--uavs", "51"], "--uavs"),
    ("demo-seed-neg", [*DEMO, "--seed", "-3"], "--seed"),
    ("demo-speedup-nan", [*DEMO, "--speedup", "nan"], "--speedup"),
    ("demo-speedup-inf", [*DEMO, "--speedup", "inf"], "--speedup"),
    ("demo-speedup-0", [*DEMO, "--speedup", "0"], "--speedup"),
    ("demo-speedup-neg", [*DEMO, "--speedup", "-1"], "--speedup"),
    ("demo-targets-0", [*DEMO, "--targets", "0"], "--targets"),
    ("demo-targets-too-many", [*DEMO, "--targets", "5000"], "--targets"),
    (
        "demo-grid-too-small",
        ["demo", "--mission", "{mission-one-cell}", "--uavs", "1", "--out", "{out}/one-cell"],
        "too few for 1 vehicles and 1 hidden targets",
    ),
    ("demo-time-limit-nan", [*DEMO, "--time-limit", "nan"], "--time-limit"),
    ("demo-time-limit-inf", [*DEMO, "--time-limit", "inf"], "--time-limit"),
    ("demo-time-limit-0", [*DEMO, "--time-limit", "0"], "--time-limit"),
    ("demo-end-action", [*DEMO, "--end-action", "explode"], "--end-action"),
    ("demo-gcs-udpin", [*DEMO, "--gcs", "udpin:0.0.0.0:14550"], "--gcs"),
    ("demo-gcs-garbage", [*DEMO, "--gcs", "qgc please"], "--gcs"),
    ("demo-gcs-port", [*DEMO, "--gcs", "udpout:127.0.0.1:99999"], "--gcs"),
    ("demo-policy-oracle", [*DEMO, "--policy", "oracle"], "oracle"),
    ("demo-policy-la-0", [*DEMO, "--policy", "la:0"], "la:4"),
    ("demo-policy-nan-ckpt", [*DEMO, "--policy", "ddql:{nanweights.pt}"], "NaN"),
    ("demo-mission-missing", ["demo", "--mission", "{out}/none.toml"], "none.toml"),
    ("demo-mission-broken", ["demo", "--mission", "{broken.toml}"], "TOML"),
    ("demo-mission-binary", ["demo", "--mission", "{binary.toml}"], "binary.toml"),
    ("demo-mission-huge", ["demo", "--mission", "{hugemission.toml}"], "too large"),
    ("demo-mission-alt-nan", ["demo", "--mission", "{mission-alt-nan}"], "altitude"),
    ("demo-mission-alt-inf", ["demo", "--mission", "{mission-alt-inf}"], "altitude"),
    ("demo-mission-alt-5000", ["demo", "--mission", "{mission-alt-5000}"], "altitude"),
    ("demo-mission-alt-text", ["demo", "--mission", "{mission-alt-text}"], "altitude"),
    ("demo-mission-alt-bool", ["demo", "--mission", "{mission-alt-bool}"], "altitude"),
    ("demo-mission-timeout-nan", ["demo", "--mission", "{mission-timeout-nan}"], "step_timeout"),
    ("demo-mission-unknown-key", ["demo", "--mission", "{mission-unknown-key}"], "colour"),
    ("demo-mission-no-grid", ["demo", "--mission", "{mission-nogrid}"], "grid"),
    ("demo-mission-bad-grid", ["demo", "--mission", "{mission-badgrid}"], "grid.npz"),
    ("demo-mission-big-grid", ["demo", "--mission", "{mission-biggrid}", "--out", "{out}/big"], "200 x 200"),
    ("demo-out-under-file", ["demo", "--mission", "{mission}", "--out", "{under-file}"], "--out"),
    # fly and agent
    ("fly-missing", ["fly", "{out}/none.toml"], "none.toml"),
    ("fly-folder", ["fly", "{folder}"], "mission file"),
    ("fly-alt-nan", ["fly", "{mission-alt-nan}"], "altitude"),
    ("fly-limit-neg", ["fly", "{mission-limit-neg}"], "time_limit"),
    ("fly-oracle", ["fly", "{mission-oracle}"], "oracle"),
    ("fly-no-model", ["fly", "{mission-nomodel}"], "nowhere.pt"),
    ("fly-key-short", ["fly", "{mission-key-short}"], "signing"),
    ("fly-key-huge", ["fly", "{mission-key-huge}"], "mission.signing_key"),
    ("fly-battery-order", ["fly", "{mission-batt}"], "return_below"),
    ("fly-big-grid", ["fly", "{mission-biggrid}"], "200 x 200"),
    ("fly-seed-neg", ["fly", "{mission}", "--seed", "-1"], "--seed"),
    ("fly-out-under-file", ["fly", "{mission}", "--out", "{under-file}"], "--out"),
    ("agent-no-vehicle", ["agent", "{mission}"], "--vehicle"),
    ("agent-unknown-vehicle", ["agent", "{mission}", "--vehicle", "zeta"], "zeta"),
    ("agent-detector-garbage", ["agent", "{mission}", "--vehicle", "a", "--detector", "camera"], "--detector"),
    ("agent-detector-udpout", ["agent", "{mission}", "--vehicle", "a", "--detector", "udpout:1.2.3.4:5"], "--detector"),
    ("agent-out-under-file", ["agent", "{mission}", "--vehicle", "a", "--out", "{under-file}"], "--out"),
    # mock-vehicle
    ("mock-sysid-0", [*MOCK, "--sysid", "0"], "--sysid"),
    ("mock-sysid-256", [*MOCK, "--sysid", "256"], "--sysid"),
    ("mock-connect-garbage", [*MOCK, "--connect", "somewhere"], "--connect"),
    ("mock-connect-port-0", [*MOCK, "--connect", "udpout:127.0.0.1:0"], "--connect"),
    ("mock-connect-port-text", [*MOCK, "--connect", "tcp:127.0.0.1:http"], "--connect"),
    ("mock-home-nan", [*MOCK, "--home", "nan,149.1,584"], "--home"),
    ("mock-home-91", [*MOCK, "--home", "91,149.1,584"], "--home"),
    ("mock-home-two", [*MOCK, "--home", "1,2"], "--home"),
    ("mock-home-text", [*MOCK, "--home", "a,b,c"], "--home"),
    ("mock-home-alt-inf", [*MOCK, "--home", "-35.3,149.1,inf"], "--home"),
    ("mock-speed-nan", [*MOCK, "--speed", "nan"], "--speed"),
    ("mock-speed-inf", [*MOCK, "--speed", "inf"], "--speed"),
    ("mock-speed-0", [*MOCK, "--speed", "0"], "--speed"),
    ("mock-speedup-nan", [*MOCK, "--speedup", "nan"], "--speedup"),
    ("mock-speedup-neg", [*MOCK, "--speedup", "-2"], "--speedup"),
    ("mock-ready-nan", [*MOCK, "--ready-after", "nan"], "--ready-after"),
    ("mock-ready-neg", [*MOCK, "--ready-after", "-1"], "--ready-after"),
    ("mock-failsafe-inf", [*MOCK, "--gcs-failsafe", "inf"], "--gcs-failsafe"),
    ("mock-duration-nan", ["mock-vehicle", "--duration", "nan"], "--duration"),
    ("mock-duration-inf", ["mock-vehicle", "--duration", "inf"], "--duration"),
    ("mock-duration-neg", ["mock-vehicle", "--duration", "-1"], "--duration"),
    ("mock-autopilot", [*MOCK, "--autopilot", "betaflight"], "--autopilot"),
    ("mock-key-missing", [*MOCK, "--signing-key", "{out}/none.key"], "--signing-key"),
    ("mock-key-short", [*MOCK, "--signing-key", "{short.key}"], "short.key"),
    ("mock-key-huge", [*MOCK, "--signing-key", "{hugekey}"], "--signing-key"),
    ("mock-key-device", [*MOCK, "--signing-key", "/dev/zero"], "/dev/zero"),
    # replay
    ("replay-missing", ["replay", "{out}/none"], "none"),
    ("replay-empty-tlog", ["replay", "{empty.tlog}", "--quiet"], "empty.tlog"),
    ("replay-foreign", ["replay", "{foreign.tlog}", "--quiet"], "foreign.tlog"),
    ("replay-empty-folder", ["replay", "{emptyrec}", "--quiet"], "emptyrec"),
    ("replay-fps-nan", [*REPLAY, "--fps", "nan"], "--fps"),
    ("replay-fps-0", [*REPLAY, "--fps", "0"], "--fps"),
    ("replay-fps-huge", [*REPLAY, "--fps", "1000"], "--fps"),
    ("replay-fps-inf", [*REPLAY, "--fps", "inf"], "--fps"),
    ("replay-steps-text", [*REPLAY, "--steps", "first,last"], "--steps"),
    ("replay-steps-neg", [*REPLAY, "--steps", "-1"], "--steps"),
    ("replay-steps-many", [*REPLAY, "--steps", ",".join(map(str, range(500)))], "--steps"),
    ("replay-steps-beyond", [*REPLAY, "--steps", "100000"], "--steps"),
    ("replay-from-neg", [*REPLAY, "--from-step", "-1"], "--from-step"),
    ("replay-to-beyond", [*REPLAY, "--to-step", "100000"], "--to-step"),
    ("replay-from-after-to", [*REPLAY, "--from-step", "20", "--to-step", "10"], "--from-step"),
    ("replay-basemap", [*REPLAY, "--basemap", "https://tiles.example/tile.png"], "--basemap"),
    ("replay-out-under-file", ["replay", "{sitl}", "--out", "{under-file}", "--quiet"], "--out"),
    ("replay-grid-text", [*REPLAY, "--grid", "{text.npz}"], "text.npz"),
    ("replay-grid-bomb", [*REPLAY, "--grid", "{bomb.npz}"], "bomb.npz"),
    ("replay-vehicle", ["replay", "{recording}", "--out", "{out}/rv", "--quiet", "--vehicle", "zeta"], "zeta"),
    ("replay-buildings", [*REPLAY, "--buildings", "{tall.geojson}"], "tall"),
]

# Through the real CLI, in a subprocess (about ten of them: each costs an interpreter start).
SUBPROCESS = {
    "eval-seed-neg",
    "eval-memory-map",
    "train-updates-inf",
    "bench-seconds-nan",
    "plan-area-swapped",
    "plan-height-unit",
    "demo-speedup-inf",
    "fly-alt-nan",
    "mock-duration-nan",
    "replay-fps-nan",
    "ckpt-nan-weights",
}


def _argv(template: list[str], files: dict[str, Path]) -> list[str]:
    out = []
    for arg in template:
        arg = re.sub(r"\{([\w.-]+)\}", lambda m: str(files[m.group(1)]), arg)
        out.append(arg)
    return out


def _in_process(argv: list[str]) -> tuple[int | None, str | None, float]:
    """main(argv) in a thread that must finish within CASE_LIMIT_S: (exit status, traceback, seconds)."""
    result: dict = {}

    def run() -> None:
        try:
            result["code"] = main(argv)
        except BaseException:  # a traceback the CLI let through: the test reports it
            result["error"] = traceback.format_exc()

    started = time.monotonic()
    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(CASE_LIMIT_S)
    took = time.monotonic() - started
    assert not worker.is_alive(), f"still running after {CASE_LIMIT_S:g} s: a hang"
    return result.get("code"), result.get("error"), took


def _subprocess(argv: list[str]) -> tuple[int, str, str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [sys.executable, "-m", "swarmctl.cli", *argv],
        capture_output=True,
        text=True,
        timeout=CASE_LIMIT_S,
        cwd=ROOT,
        env=env,
        stdin=subprocess.DEVNULL,
    )
    return proc.returncode, proc.stdout, proc.stderr


def test_the_table_is_large_and_covers_every_command():
    names = [c[0] for c in CASES]
    assert len(names) == len(set(names)) and len(names) >= 150
    commands = {c[1][0] for c in CASES}
    assert commands == {"eval", "train", "bench", "plan", "demo", "fly", "agent", "mock-vehicle", "replay"}
    assert SUBPROCESS <= set(names) and 8 <= len(SUBPROCESS) <= 12


@pytest.mark.parametrize("name, template, needle", CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_one_line_naming_the_field_and_exit_2(name, template, needle, files, capsys):
    argv = _argv(template, files)
    if name in SUBPROCESS:
        code, out, err = _subprocess(argv)
        error = "Traceback" if "Traceback" in err + out else None
    else:
        capsys.readouterr()
        code, error, took = _in_process(argv)
        out, err = capsys.readouterr()
        assert took < CASE_LIMIT_S
    assert error is None, error
    assert "Traceback" not in err + out
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, err
    assert len(lines) == 1, err
    assert lines[0].startswith("swarmctl: error: ") and needle in lines[0], lines[0]


@given(st.text())
def test_printable_text_is_printable_and_printable_text_is_kept(text):
    from swarmctl.errors import printable

    shown = printable(text)
    assert shown.isprintable()
    assert (shown == text) == text.isprintable()


def test_an_error_naming_a_file_prints_its_escapes_as_text(tmp_path, capsys):
    bad = tmp_path / "area\x1b[2J\x1b]0;owned\x07.geojson"  # a name that would clear the terminal
    bad.write_text("{not json")
    assert main(["plan", str(bad), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "\x1b" not in err and "area\\x1b[2J\\x1b]0;owned\\x07.geojson" in err, err
