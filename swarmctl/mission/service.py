"""Running a mission from the command line: the plan described, signals, the live view, the picture."""

from __future__ import annotations

import asyncio
import logging
import math
import signal
import sys
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from swarmctl.errors import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, printable
from swarmctl.mission import finish, sharing
from swarmctl.mission.agent import State
from swarmctl.mission.controller import Controller
from swarmctl.mission.crew import Crew
from swarmctl.mission.plan import MissionPlan
from swarmctl.mission.recorder import Recorder, reserve_for
from swarmctl.mission.state import MissionState

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.geo.grid import GeoGrid
    from swarmctl.mission.web import LiveSite
    from swarmctl.mission.web_page import WebSetup

log = logging.getLogger(__name__)

# "complete": the search ended as its mission file says it should (its finish line, swarmctl.mission.finish)
OUTCOME_EXIT = {
    "complete": EXIT_OK,
    "partial": EXIT_FAILED,
    "time limit": EXIT_FAILED,
    "failed": EXIT_FAILED,
    "interrupted": EXIT_INTERRUPTED,
}
EXIT_RECORDING_LOST = EXIT_BAD_INPUT  # 2: part of the recording could not be written, whatever the outcome


def describe(plan: MissionPlan) -> list[str]:
    """The plan in a few lines, for the pilot to confirm before anything flies."""
    g, spec = plan.grid, plan.spec
    m = spec.mission
    above = (
        f" (above the {g.altitude:g} m the grid was planned for: it blocks every building of {g.altitude:g} m "
        "or more, though the vehicles clear the lower of them)"
        if plan.altitude > g.altitude
        else ""
    )
    lines = [
        f"mission {m.name!r} (id {m.id}), policy {plan.policy.spec}",
        f"grid {g.width} x {g.height} cells of {g.cell:g} m, {int(g.blocked.sum())} blocked"
        + (f", from {m.grid}" if m.grid else ""),
        f"altitude {m.altitude:g} m above home{above}",
        f"end action {m.end_action}, time limit {spec.timing.time_limit:g} s",
        finish.describe(spec),
        search_text(plan),
        f"sensor footprint {m.footprint_m:g} m round each cell reached ({plan.fov:g} cells)",
        "fence: the area's boundary, uploaded to every vehicle before take-off"
        if m.fence
        else "fence: none (the vehicles' own fence settings apply)",
        *sharing.describe(plan),
    ]
    for i, v in enumerate(spec.vehicles):
        if plan.only is not None and i not in plan.only:
            continue
        autopilot = v.autopilot or "autopilot as its heartbeat says"
        detector = sharing.detector_text(plan.detectors.get(i))
        lines.append(f"  vehicle {v.name}: sysid {v.sysid}, {autopilot}, {v.connection}, {detector}")
    return lines


def search_text(plan: MissionPlan) -> str:
    """How the search is scored and whether the policy weighs cells by the prior, in a line."""
    m = plan.spec.mission
    source = f"the prior {m.prior.name}" if m.prior is not None else "a uniform prior"
    how = (
        "the policy weighs each cell by the probability left on it"
        if plan.policy.uses_prior
        else "ddql policies ignore the prior (their network was trained on the unexplored map)"
    )
    return f"search probability: POS against {source}, detector pod {plan.spec.sensing.pod:g}; {how}"


class LiveView:
    """A table per vehicle (state, cell, battery, link, targets, and in preflight what the vehicle says;
    an ALARM when it is off course, swarmctl.mission.watch) redrawn each step on a terminal, and a
    progress line; `live=False` keeps only the progress lines and a line per preflight note and alarm,
    `quiet=True` prints nothing."""

    def __init__(self, stream: TextIO | None = None, live: bool = True, quiet: bool = False, every: float = 2.0):
        stream = stream if stream is not None else sys.stderr  # looked up now: sys.stderr may be replaced
        self.stream, self.quiet, self.every = stream, quiet, every
        self.live = live and not quiet and stream.isatty()
        self._lines = 0
        self._last = 0.0
        self._notes: dict[str, str | None] = {}  # vehicle -> the preflight note last printed
        self._alarms: dict[str, str | None] = {}  # vehicle -> the alarm last printed
        self.standing: Callable[[], str] | None = None  # how the search stands (FinishLine.standing)

    def __call__(self, state: MissionState, crew: Crew) -> None:
        agents = crew.agents
        if self.quiet:
            return
        now = time.monotonic()
        found = len(set().union(*(a.knowledge.targets for a in agents))) if agents else 0
        if state.ended is not None:  # as the search ended (as the summary says), not as the end actions go
            hovering = len(state.on_targets)
        else:
            hovering = sum(a.state is State.HOVER for a in agents)
        elapsed = state.search_seconds()
        progress = f"step {state.step}  targets found {found}  hovering {hovering}/{len(agents)}  {elapsed:.1f} s" + (
            f"  -> {state.outcome}" if state.outcome else "  PAUSED (live page)" if state.held else ""
        )
        standing = self.standing() if self.standing is not None and state.search_started else None
        if not self.live:
            for a in agents:
                if a.status is not None and self._notes.get(a.name) != a.status:
                    self._notes[a.name] = a.status
                    print(f"{a.name}: {a.status}", file=self.stream, flush=True)
                if self._alarms.get(a.name) != a.alarm:
                    self._alarms[a.name] = a.alarm
                    if a.alarm is not None:
                        print(f"{a.name}: ALARM {a.alarm}", file=self.stream, flush=True)
            if state.search_started and now - self._last >= self.every or state.outcome:
                self._last = now
                print(progress + (f"  {standing}" if standing else ""), file=self.stream, flush=True)
            return
        rows = [f"{'vehicle':<10} {'state':<12} {'cell':<9} {'battery':>7} {'link':<5} {'targets':>7}"]
        for a in agents:
            cell = "-" if a.cell is None else f"{a.cell[0]},{a.cell[1]}"
            battery = a.battery()
            says = f"  {a.status[:60]}" if a.state == State.PREFLIGHT and a.status else ""
            says += f"  ALARM {a.alarm}" if a.alarm else ""
            rows.append(
                f"{a.name:<10} {a.state:<12} {cell:<9} {('-' if battery is None else f'{battery} %'):>7} "
                f"{a.link_text():<5} {a.targets_known:>7}{says}"
            )
        rows.append(progress)
        if standing:
            rows.append(standing)
        out = (f"\x1b[{self._lines}F\x1b[J" if self._lines else "") + "\n".join(rows) + "\n"
        self.stream.write(out)
        self.stream.flush()
        self._lines = len(rows)


SUMMARY_EVERY_S = 2.0  # the running summary.json is rewritten this often, and after every state change
SUMMARY_POLL_S = 0.25  # how soon after a state change


async def keep_summary(controller: Controller, rec: Recorder, extra_summary: Any = None) -> None:
    """Keep summary.json up to date while the mission runs (`"running": true`), so that `watch cat
    summary.json` follows it and a crash leaves the latest state: rewritten every SUMMARY_EVERY_S and
    within SUMMARY_POLL_S of every event that changes it (Recorder.changes). Runs until cancelled."""
    loop = asyncio.get_running_loop()
    changes, written = -1, -math.inf
    while True:
        if rec.changes != changes or loop.time() - written >= SUMMARY_EVERY_S:
            changes, written = rec.changes, loop.time()
            try:
                summary = controller.summary(extra_summary(controller) if extra_summary else None)
                rec.write_summary(summary, running=True)
            except Exception as exc:  # the flight goes on without it; the final summary is written at the end
                log.warning("the running summary.json cannot be written (%s); it is written at the end", exc)
                return
        await asyncio.sleep(SUMMARY_POLL_S)


def live_site(controller: Controller, setup: WebSetup) -> LiveSite:
    """The live page of the controller's mission (swarmctl.mission.web), given the parts it shows."""
    from swarmctl.mission.web import LiveSite

    plan = controller.plan
    spec = plan.spec
    g = controller.grid
    subtitle = (
        f"{len(spec.vehicles) if plan.only is None else len(plan.only)} vehicles, "
        f"{g.width} x {g.height} cells of {g.cell:g} m, "
        f"policy {plan.policy.spec}, end action {spec.mission.end_action}"
    )
    return LiveSite(
        setup,
        controller.state,
        controller.crew,
        controller.finish,
        g,
        controller.rec,
        name=spec.mission.name,
        subtitle=subtitle,
        finish_text=finish.describe(spec),
        time_limit=spec.timing.time_limit,
    )


def run_controller(
    plan: MissionPlan,
    folder: Path,
    view: LiveView | None,
    extra_summary: Any = None,
    extra_files: dict[str, Any] | None = None,
    web: WebSetup | None = None,
    on_web: Callable[[str], None] | None = None,
) -> tuple[int, dict]:
    """Fly the plan with SIGINT/SIGTERM wired to a clean stop; write the recording (summary.json kept up
    to date while it flies; `extra_files`: name -> a function of the folder writing that file after the
    summary, as the picture); exit status: the outcome's, or EXIT_RECORDING_LOST when part of the
    recording could not be written (the summary's `recording_lost` says what). `web`: serve the live
    page there while the mission flies (its address, token included, printed on stderr, or given to
    `on_web` when there is one)."""
    rec = Recorder(folder, reserve=reserve_for(len(plan.spec.vehicles)))  # no room for the end: refused here
    try:
        rec.copy_inputs(plan.mission_file, plan.spec.mission.grid, plan.grid)
    except BaseException:
        rec.close()
        raise
    controller = Controller(plan, rec, view=view)
    if view is not None:
        view.standing = controller.finish.standing

    async def main() -> str:
        loop = asyncio.get_running_loop()
        installed = []
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                loop.add_signal_handler(sig, controller.stop)
                installed.append(sig)
            except (NotImplementedError, RuntimeError, ValueError):  # not the main thread, or Windows
                pass
        site = None
        if web is not None:
            site = live_site(controller, web)
            url = await site.start()  # a port that cannot be served: refused before anything flies
            if on_web is not None:
                on_web(url)
            else:  # the token is printed here only: never logged, never recorded
                print(f"live page: {url}", file=sys.stderr, flush=True)
        summaries = asyncio.ensure_future(keep_summary(controller, rec, extra_summary))
        try:
            return await controller.run()
        finally:
            summaries.cancel()
            await asyncio.gather(summaries, return_exceptions=True)
            if site is not None:  # while Ctrl-C still means stop, not an interrupt of the closing
                await close_site(site)
            for sig in installed:
                loop.remove_signal_handler(sig)

    try:
        try:
            outcome = asyncio.run(main())
        except Exception as exc:
            if controller.state.fault is None:
                raise  # not from the flight (its end actions were not the question)
            # a bug or a reply nothing foresaw stopped the mission, after every vehicle's end action:
            # one line on the terminal (service.fault_line), the traceback in the recording
            outcome = "failed"
            text = "".join(traceback.format_exception(exc))
            rec.write_extra("fault.txt", lambda: (folder / "fault.txt").write_text(text, encoding="utf-8"))
        summary = controller.summary(extra_summary(controller) if extra_summary else None)
        rec.write_summary(summary, running=False)
        rec.write_extra("targets.geojson", lambda: write_targets_geojson(folder / "targets.geojson", summary))
        rec.write_extra("targets.kml", lambda: write_targets_kml(folder / "targets.kml", summary))
        for name, make in (extra_files or {}).items():
            rec.write_extra(name, lambda make=make: make(folder))
    finally:
        rec.close()
    summary["recording_lost"] = dict(rec.lost)  # and what was lost after the summary was written
    if rec.lost:
        return EXIT_RECORDING_LOST, summary
    return OUTCOME_EXIT.get(outcome, EXIT_FAILED), summary


async def close_site(site: LiveSite) -> None:
    """The mission is over: the page says so for a moment, then its server stops (whatever fails in it)."""
    from swarmctl.mission.web import LINGER_S

    site.closed = True
    try:
        await asyncio.sleep(LINGER_S)
        await site.close()
    except Exception as exc:  # the mission's result stands
        log.warning("the live page's server did not close cleanly: %s: %s", type(exc).__name__, exc)


def fault_line(summary: dict, folder: Path) -> str | None:
    """The one line a mission stopped by an unexpected error ends with (None: it was not)."""
    fault = summary.get("fault")
    if not fault:
        return None
    return (
        f"the mission stopped on an unexpected error in {fault['where']} ({fault['error']}); every vehicle in "
        f"the air was given its end action; the traceback is in {folder / 'fault.txt'}"
    )


def _found_by(t: dict) -> dict:
    """A target's find, where the summary has it: the vehicle that found it and the seconds from the
    search's start (swarmctl.mission.finish)."""
    out = {}
    if t.get("vehicle") is not None:
        out["vehicle"] = t["vehicle"]
    if t.get("time_s") is not None:
        out["found_s"] = t["time_s"]
    return out


def write_targets_geojson(path: Path, summary: dict) -> Path:
    """The targets found as GeoJSON points (lon, lat), with their cell, the step of the first report and,
    where known, the vehicle that found it and when (`found_s`: seconds from the search's start)."""
    import json

    features = [
        {
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": [round(t["lon"], 7), round(t["lat"], 7)]},
            "properties": {
                "cell_x": t["cell"][0],
                "cell_y": t["cell"][1],
                "first_step": t["step"],
                "mission": summary["mission"],
                **_found_by(t),
            },
        }
        for t in summary["targets_found"]
    ]
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}, indent=1) + "\n")
    return path


def write_targets_kml(path: Path, summary: dict) -> Path:
    """The targets found as KML placemarks (Google Earth, QGroundControl, ATAK read them)."""
    import xml.etree.ElementTree as ET

    ns = "http://www.opengis.net/kml/2.2"
    kml = ET.Element("kml", xmlns=ns)
    doc = ET.SubElement(kml, "Document")
    ET.SubElement(doc, "name").text = printable(f"{summary['mission']}: targets found")  # a replayed name too
    for t in summary["targets_found"]:
        mark = ET.SubElement(doc, "Placemark")
        x, y = t["cell"]
        ET.SubElement(mark, "name").text = f"target {x},{y}"
        found = _found_by(t)
        by = f" by {printable(found['vehicle'])}" if "vehicle" in found else ""
        when = f", {found['found_s']:g} s into the search" if "found_s" in found else ""
        ET.SubElement(mark, "description").text = f"cell ({x}, {y}), first reported at step {t['step']}{by}{when}"
        point = ET.SubElement(mark, "Point")
        ET.SubElement(point, "coordinates").text = f"{t['lon']:.7f},{t['lat']:.7f},0"
    ET.ElementTree(kml).write(path, encoding="utf-8", xml_declaration=True)
    return path


def draw_mission(folder: Path, grid: GeoGrid, hidden: np.ndarray | None = None, out: Path | None = None) -> Path:
    """mission.png: the grid, blocked cells, each vehicle's path, the targets found (and hidden)."""
    import json

    from swarmctl.figures import pyplot

    plt = pyplot()
    events = []
    for line in (folder / "events.jsonl").read_text(errors="replace").splitlines():
        try:
            events.append(json.loads(line))
        except ValueError:  # a line cut short (the replay lists it as damage): not drawn
            continue
    paths: dict[str, list] = {}
    for e in events:
        if e["event"] == "state" and e.get("cell") is not None:
            paths.setdefault(e["vehicle"], []).append(e["cell"])
        if e["event"] == "step":
            for v in e["vehicles"] + e.get("others", []):
                if v.get("cell") is not None:
                    paths.setdefault(v["vehicle"], []).append(v["cell"])
    summary = json.loads((folder / "summary.json").read_text())
    for v in summary["vehicles"]:
        if v.get("cell") is not None:
            paths.setdefault(v["name"], []).append(v["cell"])
    fig, ax = plt.subplots(figsize=(7, 7))
    ax.imshow(
        grid.blocked.T,
        origin="lower",
        cmap="Greys",
        vmin=0,
        vmax=1.6,
        extent=(-0.5, grid.width - 0.5, -0.5, grid.height - 0.5),
    )
    for name, cells in sorted(paths.items()):
        xy = np.array(cells, dtype=float)
        (line,) = ax.plot(xy[:, 0], xy[:, 1], "-", lw=1.5, alpha=0.85, label=name)
        ax.plot(xy[0, 0], xy[0, 1], "o", color=line.get_color(), ms=6)
        ax.plot(xy[-1, 0], xy[-1, 1], "s", color=line.get_color(), ms=8, mfc="none", mew=2)
    if hidden is not None and len(hidden):
        ax.plot(hidden[:, 0], hidden[:, 1], "x", color="tab:red", ms=9, mew=2, label="hidden target")
    found = np.array([t["cell"] for t in summary["targets_found"]], dtype=float).reshape(-1, 2)
    if len(found):
        ax.plot(found[:, 0], found[:, 1], "*", color="gold", mec="black", ms=16, label="target found")
    ax.set_xlim(-0.5, grid.width - 0.5)
    ax.set_ylim(-0.5, grid.height - 0.5)
    ax.set_xlabel(f"x (cells of {grid.cell:g} m, east)")
    ax.set_ylabel("y (cells, north)")
    ax.set_title(
        f"{summary['mission']}: {summary['outcome']}, {len(found)} targets found, "
        f"{summary['steps']} steps, {summary['search_time_s']:.0f} s"
    )
    ax.legend(loc="upper right", fontsize=8, framealpha=0.85)
    fig.tight_layout()
    path = out or folder / "mission.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
