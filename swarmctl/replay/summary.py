"""The replay's text summary: the outcome line `fly` prints, the vehicle table of its live view (state,
cell, battery, link, targets) at the end of the replay, the targets found, how the search's probability
of success (POS) rose when the recording has it, and what was skipped."""

from __future__ import annotations

import numpy as np

from swarmctl.replay.recording import Replay


def _last_state(replay: Replay, k: int) -> str:
    v = replay.vehicles[k]
    if replay.events is not None:
        states = [e["state"] for e in replay.events.of("state") if e["vehicle"] == v.name]
        if states:
            return states[-1]
    return next((s for s in reversed(v.states) if s), "-")


def pos_series(replay: Replay) -> tuple[np.ndarray, np.ndarray] | None:
    """(steps, POS) of the recording's step lines that carry a `pos` (None: a recording from before POS)."""
    if replay.events is None:
        return None
    rows = [(e["step"], e["pos"]) for e in replay.events.of("step") if isinstance(e.get("pos"), (int, float))]
    if not rows:
        return None
    steps, pos = zip(*rows)
    return np.asarray(steps, dtype=np.int64), np.asarray(pos, dtype=np.float64)


def pos_lines(replay: Replay) -> list[str]:
    """The POS the search reached, its goal, and how it rose (a line; none for recordings without it)."""
    series = pos_series(replay)
    if series is None:
        return []
    steps, pos = series
    summary = replay.summary or {}
    goal = summary.get("pos_goal")
    prior = next(iter(replay.events.of("prior")), None) if replay.events is not None else None
    against = f" against {prior['source']}, pod {prior['pod']:g}" if prior is not None else ""
    marks = [f"{q:.0%} at step {int(steps[np.argmax(pos >= q)])}" for q in (0.25, 0.5, 0.75, 0.9) if pos[-1] >= q]
    line = f"POS {pos[-1]:.4f} at step {int(steps[-1])}{against}"
    if isinstance(goal, (int, float)):
        line += f" (goal {goal:g}: {'met' if pos[-1] >= goal else 'not met'})"
    return [line + (f"; reached {', '.join(marks)}" if marks else "")]


def outcome_line(replay: Replay) -> str:
    """ "complete: 3 targets found, 389 steps in 61.5 s" (what is known of it, for a bare log)."""
    found = len(replay.targets)
    span = float(replay.frame_time[-1] - replay.frame_time[0])
    what = f"{found} target{'s' if found != 1 else ''} found"
    if replay.frame_step is not None:
        what += f", {int(replay.frame_step[-1])} steps in {span:.1f} s"
    else:
        what += f", {span:.1f} s of telemetry"
    return f"{replay.outcome or replay.kind}: {what}"


def summary_lines(replay: Replay) -> list[str]:
    """Every line of the summary."""
    g = replay.grid
    lines = [
        f"{replay.name} ({replay.kind} {replay.source}): {outcome_line(replay)}",
        f"grid {g.width} x {g.height} cells of {g.cell:g} m, {int(g.blocked.sum())} blocked ({replay.grid_note})",
    ]
    if replay.policy:
        lines.append(f"policy {replay.policy}")
    k = replay.knowledge
    lines.append(
        f"knowledge from {k.source}: {int(k.counts(replay.frames)[-1])} cells explored together"
        if k is not None
        else "knowledge: none in this recording (no snapshots, no swarmctl TUNNEL messages)"
    )
    if len(replay.vehicles) < len(replay.all_vehicles):
        lines.append(f"vehicles shown: {', '.join(v.name for v in replay.vehicles)} of {len(replay.all_vehicles)}")
    lines.append(
        f"{'vehicle':<10} {'state':<12} {'cell':<9} {'battery':>7} {'link':<5} {'targets':>7} {'distance':>10}"
    )
    end = float(replay.frame_time[-1])
    for i, v in enumerate(replay.vehicles):
        cell = v.cells[-1]
        where = f"{cell[0]},{cell[1]}" if cell[0] >= 0 else "-"
        battery = f"{int(v.telemetry.battery[-1])} %" if v.telemetry is not None and v.telemetry.battery.size else "-"
        link = v.link(end)
        found = sum(t.vehicle == v.name for t in replay.targets)
        lines.append(
            f"{v.name:<10} {_last_state(replay, i):<12} {where:<9} {battery:>7} {(link[-1][1] if link else '-'):<5} "
            f"{found:>7} {v.distance_m:>8.0f} m"
        )
    for t in replay.targets:
        lines.append(
            f"target {t.cell[0]},{t.cell[1]} ({t.lat:.6f}, {t.lon:.6f}) first reported by {t.vehicle} at "
            f"{replay.frame_label(t.frame)}"
        )
    if replay.truth is not None:
        hidden = {tuple(int(c) for c in x) for x in np.asarray(replay.truth.targets)}
        missed = sorted(hidden - {t.cell for t in replay.targets})
        lines.append(
            f"truth: {len(hidden)} hidden targets, {len(hidden) - len(missed)} found"
            + (f"; not found: {', '.join(f'{x},{y}' for x, y in missed)}" if missed else "")
        )
    lines += pos_lines(replay)
    lines += damage_lines(replay)
    lines += [f"note: {n}" for n in replay.notes]
    return lines


def damage_lines(replay: Replay) -> list[str]:
    """One line per damaged file: how much was skipped, and where."""
    out = []
    for name, damage in replay.damage.items():
        total = sum(d.length for d in damage)
        where = "; ".join(str(d) for d in damage[:5]) + ("; ..." if len(damage) > 5 else "")
        out.append(
            f"skipped in {name}: {len(damage)} stretch{'es' if len(damage) != 1 else ''}, {total} bytes: {where}"
        )
    return out
