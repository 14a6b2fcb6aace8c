"""`swarmctl demo`, `swarmctl fly` and `swarmctl agent`: the controller on the command line.

Exit status: 0 mission complete (its finish line met: by default every live vehicle hovered on a
distinct target; `[mission] finish`, swarmctl.mission.finish), 1 it ran but did not complete (time
limit, vehicles failed, the search ended short of its finish line), 2 bad input, or part of the
recording could not be written (a full disk: whatever the outcome, every vehicle given its end action;
docs/recording.md), 130 interrupted (after the end actions, with the recording closed).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

import swarmctl
from swarmctl.bounds import SEED, new_recording_folder, real, whole
from swarmctl.cli_options import options_from
from swarmctl.errors import EXIT_FAILED, InputError
from swarmctl.mission.spec import DEMO_SETTINGS, END_ACTIONS, ON_FIND, MissionSpec, MissionTable, TimingTable
from swarmctl.mission.web_page import WEB_FIELDS, WEB_OVERRIDES, WebOptions, WebSetup, probe, web_setup
from swarmctl.world.config import CHANNELS

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.mission.decide import FieldPolicy

ROOT = Path(swarmctl.__file__).resolve().parent.parent
DEMO_GRID = Path("missions/chicago-loop/grid.npz")
# The demo flies the policy measured best on its map (the Chicago Loop grid, 3 vehicles, 3 targets):
# the coordinated planner (docs/RESULTS.md). The networks, trained on 20 x 20 maps, find every target
# far less often there; `--policy ddql:models/obstacles-3uav.pt:straggler=frontier` flies the best of them.
DEMO_POLICY = "coordinated"
DEMO_FIGURES = dict(rate="1.00", networks="0.10-0.85")  # tools/planner_table.py, docs/RESULTS.md
DEMO_WHY = (
    "flying the coordinated planner, the best measured policy on this grid: it finds all 3 targets in "
    "{rate} of held-out searches within 300 steps, against {networks} for the shipped networks (docs/RESULTS.md)"
)


def _find(relative: Path) -> Path | None:
    for base in (Path.cwd(), ROOT):
        if (base / relative).is_file():
            return base / relative
    return None


def default_policy(seed: int = 0) -> tuple[FieldPolicy, str]:
    """The demo's FieldPolicy (the coordinated planner) and why it flies that one."""
    from swarmctl.mission.decide import FieldPolicy

    return FieldPolicy(DEMO_POLICY, seed=seed), DEMO_WHY.format(**DEMO_FIGURES)


def _out_folder(out: Path | None, name: str) -> Path:
    """The recording folder (--out, or runs/NAME-TIME), checked to be writable and to hold no recording
    before anything flies."""
    folder = out if out is not None else Path("runs") / f"{name}-{time.strftime('%Y%m%d-%H%M%S')}"
    return new_recording_folder(folder, "--out")


def _finish(code: int, folder: Path, summary: dict, quiet: bool) -> None:
    from swarmctl.mission.service import fault_line

    fault = fault_line(summary, folder)
    if fault is not None:  # shown even when quiet: it is an error
        click.echo(f"swarmctl: error: {fault}", err=True)
    if not quiet:
        found = len(summary["targets_found"])
        lost = summary.get("recording_lost") or {}
        cut = f" (incomplete: {', '.join(lost)} not written to the end)" if lost else ""
        click.echo(
            f"{summary['outcome']}: {found} target{'s' if found != 1 else ''} found, "
            f"{summary['steps']} steps in {summary['search_time_s']:.1f} s; recording in {folder}{cut}"
        )
    if code:
        raise click.exceptions.Exit(code)


def view_options(func):
    """The live table's options, and the live page's (swarmctl.mission.web_page.WebOptions)."""
    func = options_from(WebOptions, WEB_FIELDS, WEB_OVERRIDES)(func)
    func = click.option("--no-live", is_flag=True, help="No live table; progress lines only (for logs).")(func)
    return click.option("--quiet", "-q", is_flag=True, help="Print nothing while flying.")(func)


def web_from(web: str | None, web_token_file: str | None) -> WebSetup | None:
    """The live page's address and token from --web and --web-token-file (None: no page)."""
    setup = web_setup(WebOptions(web=web, web_token_file=web_token_file))
    if setup is not None:
        probe(setup)
    return setup


@click.command("demo")
@click.option("--uavs", "--vehicles", "uavs", type=whole(1, 50), default=3, show_default=True, help="Mock vehicles.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Where the targets hide, and the policy's draws.")
@click.option(
    "--out", type=click.Path(path_type=Path), default=None, help="Recording folder (default runs/demo-YYYYmmdd-HHMMSS)."
)
@click.option(
    "--policy",
    default=None,
    help="coordinated, ddql:PATH[:options], ddql-greedy:PATH, la:N, frontier, lawnmower or random, each "
    "with :hover=defer|first|no (default defer). Default: coordinated (the best measured on the demo's "
    "grid; the line it prints says why).",
)
@click.option(
    "--mission",
    "mission_file",
    type=click.Path(path_type=Path),
    default=None,
    help="Your own mission file: its grid and settings (the demo's faster timing over them, these "
    "options over both), mock vehicles instead of its [[vehicles]].",
)
@click.option(
    "--speedup",
    type=real(0, 100, above=True),
    default=10.0,
    show_default=True,
    help="Mock physics runs this many times faster than the wall clock. The controller's own time per "
    "round is multiplied too, in mock time: higher values cost the mock batteries more per step.",
)
@click.option("--targets", type=whole(1), default=None, help="Hidden targets (default: one per vehicle).")
@click.option("--end-action", type=click.Choice(END_ACTIONS), default="rtl", show_default=True)
@click.option(
    "--time-limit",
    type=real(*TimingTable.bounds("time_limit")),
    default=DEMO_SETTINGS["time_limit"],
    show_default=True,
    help="Search time limit, seconds.",
)
@click.option(
    "--gcs",
    default=None,
    metavar="udpout:HOST:PORT",
    help="Forward the mock vehicles' MAVLink to a ground station (QGroundControl: udpout:127.0.0.1:14550). "
    "Default: the mission file's gcs, else none.",
)
@click.option(
    "--fence",
    is_flag=True,
    help="Upload the area's boundary to every mock vehicle as its geofence before take-off "
    "(also on when the --mission file says fence = true).",
)
@click.option(
    "--channel",
    type=click.Choice(CHANNELS),
    default="ideal",
    show_default=True,
    help="Knowledge between the vehicles' agents (shared in this process): ideal, none, model (the "
    "simulator's distance-based loss at the grid's cell size) or fixed (--loss).",
)
@click.option(
    "--loss", type=real(0.0, 1.0), default=0.0, show_default=True, help="Packet-loss probability for --channel fixed."
)
@click.option(
    "--no-detectors",
    is_flag=True,
    help="Mock vehicles without detectors: a coverage search (cells explored from the vehicles' positions, "
    "nothing found).",
)
@click.option(
    "--finish",
    default=None,
    metavar="LINE",
    help="When the search is complete: held (N targets hovered on), found (N targets found; N unknown: the "
    "area covered), covered (every reachable cell explored) or 'pos >= X' (the probability of success "
    "against the prior reaches X). Default: the --mission file's, else held.",
)
@click.option(
    "--expected-targets",
    type=whole(*MissionTable.bounds("expected_targets")),
    default=None,
    help="N, the targets the finish line counts. Default: the --mission file's, else held: one a vehicle; "
    "found: unknown.",
)
@click.option(
    "--on-find",
    type=click.Choice(ON_FIND),
    default=None,
    help="At a target found: hold (hover on it) or mark (report it and search on; needs --finish found or "
    "covered). Default: the --mission file's, else hold.",
)
@click.option(
    "--pod",
    type=real(0.0, 1.0, above=True),
    default=None,
    help="The mock detectors' probability of detection: each target in the footprint is reported in a pass "
    "with this probability (seeded by --seed); the mission's [sensing] pod. Default: the --mission file's, else 1.",
)
@view_options
def demo_command(
    uavs: int,
    seed: int,
    out: Path | None,
    policy: str | None,
    mission_file: Path | None,
    speedup: float,
    targets: int | None,
    end_action: str,
    time_limit: float,
    gcs: str | None,
    fence: bool,
    channel: str,
    loss: float,
    no_detectors: bool,
    finish: str | None,
    expected_targets: int | None,
    on_find: str | None,
    pod: float | None,
    quiet: bool,
    no_live: bool,
    web: str | None,
    web_token_file: str | None,
) -> None:
    """Fly a search mission with mock vehicles over loopback UDP at the Chicago Loop.

    Targets are hidden in the mock vehicles' simulated detectors; the controller finds them with the
    policy, hovers over them, then carries out the end action. The vehicles' agents share knowledge in
    this process (--channel: with the simulator's losses). Writes the recording (mission.tlog,
    events.jsonl, knowledge.jsonl, inputs.jsonl, summary.json, grid.npz) and mission.png to --out.
    """
    from swarmctl.geo.grid import GeoGrid
    from swarmctl.mission.decide import FieldPolicy
    from swarmctl.mission.plan import check_grid_size, load_grid
    from swarmctl.mission.service import LiveView, draw_mission, run_controller
    from swarmctl.mission.spec import GroundStation, MissionFinish, load_spec, parse_option
    from swarmctl.replay.truth import write_truth
    from swarmctl.sim.swarm import SimSwarm
    from swarmctl.world.channel import Channel

    page = web_from(web, web_token_file)
    settings: dict[str, Any] = dict(end_action=end_action, time_limit=time_limit)
    if gcs is not None:
        settings["gcs"] = parse_option(GroundStation, gcs, "--gcs")
    if fence:
        settings["fence"] = True
    if finish is not None:
        finish = parse_option(MissionFinish, finish, "--finish")
    note = None
    if policy is None:
        field_policy, note = default_policy(seed)
    else:
        field_policy = FieldPolicy(policy, seed=seed)  # bad policies fail here, before anything starts
    base = None
    if mission_file is not None:
        base = load_spec(mission_file)
        grid = load_grid(base)
        at: dict[str, Any] = dict(mission_id=base.mission.id, altitude=base.mission.altitude)
    else:
        grid_file = _find(DEMO_GRID)
        if grid_file is None:
            raise InputError(f"{DEMO_GRID} not found: run the demo from the project folder, or give --mission FILE")
        grid = GeoGrid.load(grid_file)
        settings["grid"] = grid_file
        at = {}
    check_grid_size(grid, f"demo: the grid of {mission_file or DEMO_GRID}")
    settings.update(_finish_options(base, uavs, finish, expected_targets, on_find))
    room = int(grid.largest_free_region().sum()) - uavs  # targets hide there, never on a launch cell
    if targets is not None and targets > room:
        raise InputError(f"--targets {targets}: the grid's largest free region holds {room} besides the launch cells")
    if targets is None and uavs > room:  # one target a vehicle by default
        raise InputError(
            f"demo: the grid's largest free region has {room + uavs} cells, too few for {uavs} vehicles and "
            f"{uavs} hidden targets; use fewer --uavs or a larger grid"
        )
    if pod is not None:
        settings["pod"] = pod
    detection = pod if pod is not None else (base.sensing.pod if base is not None else 1.0)
    folder = _out_folder(out, "demo")
    model = Channel(channel, cell_size=grid.cell, loss=loss)
    try:
        swarm = SimSwarm(
            grid,
            uavs=uavs,
            seed=seed,
            speedup=speedup,
            channel=model,
            carry_detectors=not no_detectors,
            pod=detection,
            **at,
        )
        if targets is not None and targets != uavs:
            from swarmctl.sim.swarm import hide_targets

            swarm.targets = hide_targets(grid, targets, seed, swarm.starts)
    except ValueError as exc:
        raise InputError(f"demo: {exc}; use fewer --uavs or another grid") from None
    hidden = swarm.targets
    assert hidden is not None  # drawn by SimSwarm
    with swarm:
        plan = swarm.plan(field_policy, base=base, mission_file=mission_file, **settings)
        if note and not quiet:
            click.echo(f"demo: {note}", err=True)
        if not quiet:
            click.echo(
                f"demo: {uavs} mock vehicles at {grid.width} x {grid.height} cells, {len(hidden)} "
                f"hidden targets (seed {seed}){', no detectors: a coverage search' if no_detectors else ''}, "
                f"policy {field_policy.spec}, knowledge channel {channel}, speed-up {speedup:g}x"
                f"{_finish_text(plan.spec.mission)}"
                f"{', geofence on' if plan.spec.mission.fence else ''} -> {folder}",
                err=True,
            )
        write_truth(folder, swarm, seed)
        code, summary = run_controller(
            plan,
            folder,
            LiveView(live=not no_live, quiet=quiet),
            extra_summary=lambda c: {
                "hidden_targets": hidden.tolist(),
                "speedup": speedup,
                "seed": seed,
                "knowledge_bus": c.bus.counters(),
            },
            extra_files={"mission.png": lambda at: draw_mission(at, grid, swarm.targets)},
            web=page,
        )
    _finish(code, folder, summary, quiet)


def _finish_options(
    base: MissionSpec | None, uavs: int, finish: str | None, expected: int | None, on_find: str | None
) -> dict[str, Any]:
    """The demo's finish-line options as mission settings (those given only), checked with the
    --mission file's as the options name them: on_find mark with finish held, and more targets to hold
    than vehicles, are refused here rather than as the spec's keys."""
    m = base.mission if base is not None else None
    rule = finish or (m.finish if m else "held")
    marks = (on_find or (m.on_find if m else "hold")) == "mark"
    n = expected if expected is not None else (m.expected_targets if m else None)
    if rule == "held" and marks:
        what = "--on-find mark" if on_find else 'the --mission file\'s on_find = "mark"'
        held = "--finish held" if finish else ("the --mission file's finish held" if m else "the default finish held")
        raise InputError(
            f"{what} with {held}: a marking vehicle never hovers, so no target is ever held; "
            "add --finish found or --finish covered, or --on-find hold"
        )
    if rule == "held" and n is not None and n > uavs:
        raise InputError(
            f"--expected-targets {n}: more than the {uavs} vehicles (--uavs), and with --finish held each holds one "
            f"target; give at most {uavs}, or --finish found"
        )
    out = dict(finish=finish, expected_targets=expected, on_find=on_find)
    return {k: v for k, v in out.items() if v is not None}


def _finish_text(m: MissionTable) -> str:
    """The finish line for the demo's first line ("" for the default)."""
    if m.finish == "held" and m.expected_targets is None and m.on_find == "hold":
        return ""
    n = "" if m.expected_targets is None else f" {m.expected_targets}"
    return f", finish {m.finish}{n}, on find {m.on_find}"


@click.command("fly")
@click.argument("mission_file", type=click.Path(path_type=Path))
@click.option("--yes", is_flag=True, help="Fly without asking for confirmation.")
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default=None,
    help="Recording folder (default runs/<mission name>-YYYYmmdd-HHMMSS).",
)
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the policy's random draws.")
@view_options
def fly_command(
    mission_file: Path,
    yes: bool,
    out: Path | None,
    seed: int,
    quiet: bool,
    no_live: bool,
    web: str | None,
    web_token_file: str | None,
) -> None:
    """Fly a mission with real vehicles (ground mode: this process flies every vehicle)."""
    from swarmctl.mission import failsafes
    from swarmctl.mission.plan import make_plan
    from swarmctl.mission.service import LiveView, describe, run_controller
    from swarmctl.mission.spec import load_spec

    page = web_from(web, web_token_file)
    spec = load_spec(mission_file)
    folder = _out_folder(out, spec.mission.name)  # the command line before the mission's contents
    plan = make_plan(spec, seed=seed, mission_file=mission_file)
    for line in [*describe(plan), *failsafes.describe(plan)]:
        click.echo(line)
    if not yes and not click.confirm("Fly this mission?", default=False):
        click.echo("not flown", err=True)
        raise click.exceptions.Exit(EXIT_FAILED)
    code, summary = run_controller(plan, folder, LiveView(live=not no_live, quiet=quiet), web=page)
    _finish(code, folder, summary, quiet)


@click.command("agent")
@click.argument("mission_file", type=click.Path(path_type=Path))
@click.option(
    "--vehicle",
    "vehicles",
    multiple=True,
    required=True,
    help="Name of the vehicle (from the mission's [[vehicles]]) this process flies; repeatable.",
)
@click.option(
    "--detector",
    default=None,
    help="The vehicle's detector: mavlink (its TUNNEL reports come on the vehicle's MAVLink link) or "
    "udp:HOST:PORT (a local socket it writes them to). Default: the mission's [[vehicles]] detector; "
    "none there: a coverage search.",
)
@click.option("--yes", is_flag=True, help="Fly without asking for confirmation.")
@click.option("--out", type=click.Path(path_type=Path), default=None, help="Recording folder.")
@click.option("--seed", type=SEED, default=0, show_default=True)
@view_options
def agent_command(
    mission_file: Path,
    vehicles: tuple[str, ...],
    detector: str | None,
    yes: bool,
    out: Path | None,
    seed: int,
    quiet: bool,
    no_live: bool,
    web: str | None,
    web_token_file: str | None,
) -> None:
    """Onboard mode: fly one vehicle (on its companion computer); peers over the [knowledge] channel,
    which the mission must give."""
    from swarmctl.mission import failsafes
    from swarmctl.mission.plan import make_plan
    from swarmctl.mission.service import LiveView, describe, run_controller
    from swarmctl.mission.spec import load_spec

    page = web_from(web, web_token_file)
    spec = load_spec(mission_file)
    folder = _out_folder(out, f"{spec.mission.name}-{'-'.join(vehicles)}")  # the command line first
    plan = make_plan(spec, only=list(vehicles), detector=detector, seed=seed, mission_file=mission_file)
    for line in [*describe(plan), *failsafes.describe(plan)]:
        click.echo(line)
    if not yes and not click.confirm("Fly?", default=False):
        click.echo("not flown", err=True)
        raise click.exceptions.Exit(EXIT_FAILED)
    code, summary = run_controller(plan, folder, LiveView(live=not no_live, quiet=quiet), web=page)
    _finish(code, folder, summary, quiet)
