"""The replay's plots, one PNG each: cells explored, targets found and the probability of success (POS,
when the recording has it) over the mission, distance flown
per vehicle, battery, link state and flight modes over time. Plots that need what a log does not have
are left out (cells explored needs knowledge; battery needs battery telemetry), and `write_plots`
returns only the files it wrote."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from swarmctl.bounds import finite
from swarmctl.replay.panels import _plt
from swarmctl.replay.recording import Replay
from swarmctl.replay.summary import pos_series


def _axis(replay: Replay) -> tuple[np.ndarray, str]:
    if replay.frame_step is not None:
        return replay.frame_step, "decision step"
    return replay.frame_time - replay.frame_time[0], "time (s)"


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    _plt().close(fig)
    return path


def write_plots(replay: Replay, out: Path) -> list[Path]:
    """Write every plot the replay has data for into `out`."""
    plt = _plt()
    x, label = _axis(replay)
    t0 = replay.frame_time[0]
    paths: list[Path] = []
    knowledge = replay.knowledge
    if knowledge is not None:
        counts = knowledge.counts(replay.frames)  # replay.cells_explored()
        fig, ax = plt.subplots(figsize=(6.4, 3.6))
        ax.plot(x, counts, color="black", lw=2, label="together")
        if len(replay.vehicles) <= 10:
            for k, v in enumerate(replay.vehicles):
                ax.plot(x, knowledge.counts(replay.frames, [k]), color=v.colour, lw=1, label=v.name)
        ax.axhline(int((~replay.grid.blocked).sum()), color="grey", ls=":", lw=1, label="free cells")
        ax.set(xlabel=label, ylabel="cells explored", title=f"{replay.name}: cells explored ({knowledge.source})")
        ax.legend(fontsize=7)
        paths.append(_save(fig, out / "explored.png"))
    if replay.kind == "recording" or replay.targets:
        fig, ax = plt.subplots(figsize=(6.4, 3.2))
        ax.step(x, replay.targets_found(), where="post", color="tab:red")
        total = len(replay.truth.targets) if replay.truth is not None else None
        if total:
            ax.axhline(total, color="grey", ls=":", lw=1, label="hidden targets")
            ax.legend(fontsize=7)
        ax.set(xlabel=label, ylabel="targets found", title=f"{replay.name}: targets found")
        ax.yaxis.get_major_locator().set_params(integer=True)
        paths.append(_save(fig, out / "targets.png"))
    series = pos_series(replay)
    if series is not None:
        fig, ax = plt.subplots(figsize=(6.4, 3.2))
        ax.plot(series[0], series[1], color="tab:purple", lw=2, label="POS")
        goal = (replay.summary or {}).get("pos_goal")
        if isinstance(goal, (int, float)) and finite(goal, 0.0, 1.0):
            ax.axhline(float(goal), color="grey", ls=":", lw=1, label=f"goal {goal:g}")
        ax.set(xlabel="decision step", ylabel="probability of success", ylim=(0, 1.01), title=f"{replay.name}: POS")
        ax.legend(fontsize=7)
        paths.append(_save(fig, out / "pos.png"))
    names = [v.name for v in replay.vehicles]
    fig, ax = plt.subplots(figsize=(max(4.0, 0.45 * len(names) + 2), 3.4))
    flown = [v.distance_m for v in replay.vehicles]
    pos = np.arange(len(names))
    ax.bar(pos - 0.2, flown, 0.4, color=[v.colour for v in replay.vehicles], label="whole flight (telemetry)")
    # the summary's count: 3-D over the whole flight (distance_3d_m); older recordings: the search, horizontal
    summaries = [v.summary or {} for v in replay.vehicles]
    counted = [s.get("distance_3d_m", s.get("distance_m")) for s in summaries]
    counted = [c if finite(c, 0.0, math.inf) else None for c in counted]  # a damaged summary's text or NaN
    if any(c is not None for c in counted):
        label = "whole flight, 3-D (summary)" if any("distance_3d_m" in s for s in summaries) else "search (summary)"
        ax.bar(pos + 0.2, [c or 0 for c in counted], 0.4, color="lightgrey", edgecolor="black", label=label)
        ax.legend(fontsize=7)
    ax.set_xticks(pos, names, rotation=90 if len(names) > 8 else 0, fontsize=7)
    ax.set(ylabel="distance flown (m)", title=f"{replay.name}: distance flown")
    paths.append(_save(fig, out / "distance.png"))
    with_battery = [v for v in replay.vehicles if v.telemetry is not None and v.telemetry.battery.size]
    if with_battery:
        fig, ax = plt.subplots(figsize=(6.4, 3.4))
        for v in with_battery:
            tel = v.telemetry
            assert tel is not None  # (with_battery)
            ax.plot(tel.battery_t - t0, tel.battery, color=v.colour, lw=1, label=v.name)
        ax.set(xlabel="time (s)", ylabel="battery (%)", ylim=(0, 101), title=f"{replay.name}: battery")
        if len(with_battery) <= 10:
            ax.legend(fontsize=7)
        paths.append(_save(fig, out / "battery.png"))
    end = float(replay.frame_time[-1])
    rows = [(v, v.link(end)) for v in replay.vehicles]
    if any(changes for _v, changes in rows):
        paths.append(
            _save(_bands(replay, [(v.name, changes) for v, changes in rows], "link", t0, end), out / "link.png")
        )
    modes = [(v.name, v.telemetry.modes) for v in replay.vehicles if v.telemetry is not None and v.telemetry.modes]
    if modes:
        paths.append(_save(_bands(replay, modes, "flight mode", t0, end), out / "modes.png"))
    return paths


def _bands(replay: Replay, rows: list[tuple[str, list[tuple[float, str]]]], what: str, t0: float, end: float):
    """One horizontal band per vehicle, coloured by the value in force (link state, flight mode)."""
    plt = _plt()
    values = sorted({v for _n, changes in rows for _t, v in changes})
    fixed = {"ok": "tab:green", "lost": "tab:red"}
    palette = plt.get_cmap("tab20")
    colour = {v: fixed.get(v, palette(i % 20)) for i, v in enumerate(values)}
    fig, ax = plt.subplots(figsize=(7.0, max(2.2, 0.32 * len(rows) + 1.4)))
    for k, (_name, changes) in enumerate(rows):
        for i, (t, v) in enumerate(changes):
            stop = changes[i + 1][0] if i + 1 < len(changes) else max(end, t)
            ax.barh(k, stop - t, left=t - t0, height=0.7, color=colour[v], edgecolor="none")
    ax.set_yticks(range(len(rows)), [n for n, _c in rows], fontsize=7)
    ax.set(xlabel="time (s)", title=f"{replay.name}: {what} over time")
    handles = [plt.Rectangle((0, 0), 1, 1, color=colour[v]) for v in values]
    ax.legend(handles, values, fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax.invert_yaxis()
    return fig
