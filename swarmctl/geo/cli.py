"""`swarmctl plan`: a real area (and buildings) to a grid, its GeoJSON, a QGC plan and a preview."""

from __future__ import annotations

import math
import re
from pathlib import Path

import click

from swarmctl.bounds import new_recording_folder, real, whole
from swarmctl.errors import InputError, printable
from swarmctl.geo.defaults import (
    DEFAULT_ALTITUDE,
    DEFAULT_CELL,
    DEFAULT_MARGIN,
    DEFAULT_MAX_CELLS,
    MAX_ALTITUDE_M,
    MAX_CELL_M,
    MAX_GRID_CELLS,
    MIN_ALTITUDE_M,
    MIN_CELL_M,
    UNKNOWN_RULES,
)

PATTERNS = ("expanding-square", "sector", "parallel")  # swarmctl.geo.patterns.plan_pattern plans each
DEFAULT_PATTERN_UAVS = 3
MAX_PATTERN_UAVS = 50

# shapely, pyproj, scipy and matplotlib load inside the command, so other commands start fast.


def _warn(message: str) -> None:
    click.echo(f"swarmctl: warning: {printable(message)}", err=True)  # it may quote a file's names


def summary_lines(grid, report, with_buildings: bool) -> list[str]:
    """The human summary `plan` prints: grid size, blocked fraction, buildings, free regions."""
    n = grid.width * grid.height
    lines = [
        f"grid: {grid.width} x {grid.height} = {n} cells of {grid.cell:g} m, rotation {grid.rotation:.2f} deg, "
        f"altitude {grid.altitude:g} m",
        f"blocked: {int(grid.blocked.sum())} cells ({100 * grid.blocked_fraction:.1f} %): outside the area "
        f"{report.outside}, no-fly {report.nofly}, buildings {report.buildings}",
    ]
    if with_buildings:
        unknown = "obstacles" if report.unknown_rule == "block" else "ignored"
        threshold = f"{report.threshold:g} m"
        lines.append(
            f"buildings: {report.buildings_total} in file, {report.buildings_used} in the area: "
            f"{report.buildings_tall} >= {threshold} (obstacles), {report.buildings_low} below {threshold}, "
            f"{report.unknown_height} of unknown height ({unknown}); "
            f"{report.buildings_outside} outside the area ignored"
        )
    _, regions = grid.free_regions()
    largest = int(grid.largest_free_region().sum())
    lines.append(
        f"largest connected free region: {largest} cells ({100 * largest / n:.1f} % of the grid, "
        f"{regions} free region(s) in all)"
    )
    return lines


@click.command("plan")
@click.argument("area", type=click.Path(path_type=Path))
@click.option(
    "--buildings",
    "buildings_file",
    type=click.Path(path_type=Path),
    default=None,
    help="GeoJSON building footprints with height or levels.",
)
@click.option(
    "--cell", type=real(MIN_CELL_M, MAX_CELL_M), default=DEFAULT_CELL, show_default=True, help="Cell side in metres."
)
@click.option(
    "--altitude",
    type=real(MIN_ALTITUDE_M, MAX_ALTITUDE_M),
    default=DEFAULT_ALTITUDE,
    show_default=True,
    help="Flight altitude in metres relative to home.",
)
@click.option(
    "--margin",
    type=real(0, 10_000),
    default=DEFAULT_MARGIN,
    show_default=True,
    help="Safety margin in metres: buildings >= altitude - margin are obstacles.",
)
@click.option("--rotate", is_flag=True, help="Align the grid with the area's main axis.")
@click.option(
    "--unknown-height",
    type=click.Choice(UNKNOWN_RULES),
    default=UNKNOWN_RULES[0],
    show_default=True,
    help="Buildings with no height: obstacles (block) or ignored.",
)
@click.option(
    "--max-cells",
    type=whole(1, MAX_GRID_CELLS),
    default=DEFAULT_MAX_CELLS,
    show_default=True,
    help="Refuse grids with more cells than this.",
)
@click.option(
    "--pattern",
    type=click.Choice(PATTERNS),
    default=None,
    help="Also plan an IAMSAR search pattern from --lkp: one QGroundControl OUT/<vehicle>.plan per vehicle.",
)
@click.option("--lkp", default=None, metavar="LAT,LON", help="The last known point, degrees (with --pattern).")
@click.option(
    "--uavs",
    type=whole(1, MAX_PATTERN_UAVS),
    default=DEFAULT_PATTERN_UAVS,
    show_default=True,
    help="Vehicles sharing the pattern (with --pattern), and the [[vehicles]] of OUT/mission.toml.",
)
@click.option(
    "--spacing",
    type=real(0, MAX_CELL_M * 100, above=True),
    default=None,
    help="Track spacing in metres (with --pattern); default the sensor footprint's diameter, 2 x fov x --cell.",
)
@click.option("--out", "out_dir", type=click.Path(path_type=Path), required=True, help="Output folder.")
def plan_command(
    area: Path,
    buildings_file: Path | None,
    cell: float,
    altitude: float,
    margin: float,
    rotate: bool,
    unknown_height: str,
    max_cells: int,
    pattern: str | None,
    lkp: str | None,
    uavs: int,
    spacing: float | None,
    out_dir: Path,
) -> None:
    """Turn a search AREA (GeoJSON, KML or QGroundControl .plan) into a cell grid.

    Writes OUT/grid.npz (the grid the controller loads), OUT/grid.geojson (cells with a blocked
    flag), OUT/area.plan (QGroundControl geofence), OUT/preview.png and OUT/mission.toml (a mission
    for `swarmctl fly` with --uavs vehicles whose connections are to be filled in: the coordinated
    planner, or with --pattern the pattern flown cell by cell). With --pattern and --lkp, also
    OUT/uav1.plan .. OUT/uavN.plan: each vehicle's share of the search pattern as waypoints.
    """
    if not margin < altitude:
        raise InputError(f"--margin {margin:g}: the safety margin must be below --altitude ({altitude:g} m)")
    lkp_point = _lkp(lkp) if lkp is not None else None
    if (pattern is None) != (lkp_point is None):
        raise InputError("--pattern and --lkp go together: give both (e.g. --pattern sector --lkp 41.88,-87.63)")
    new_recording_folder(out_dir, "--out")  # a recording's grid.npz is its own: never replaced
    from shapely import Point

    from swarmctl.geo.buildings import BuildingRule, load_buildings
    from swarmctl.geo.export import write_grid_geojson
    from swarmctl.geo.grid import make_grid
    from swarmctl.geo.load import load_area
    from swarmctl.geo.plan_io import write_plan
    from swarmctl.geo.preview import render_preview

    the_area = load_area(area)
    if lkp_point is not None and not the_area.geometry.covers(Point(lkp_point[1], lkp_point[0])):
        raise InputError(
            f"--lkp {lkp_point[0]:g},{lkp_point[1]:g}: the last known point lies outside the area {area} "
            "(or in a hole of it); give LAT,LON of a point inside it"
        )
    for message in the_area.warnings:
        _warn(message)
    bset = load_buildings(buildings_file) if buildings_file is not None else None
    rule = BuildingRule(altitude=altitude, margin=margin, unknown=unknown_height)
    grid, report = make_grid(the_area, cell, altitude, rotate, bset, rule, max_cells)
    for message in report.warnings:
        _warn(message)
    if grid.blocked.all():
        raise InputError(
            f"{area}: every cell of the {grid.width} x {grid.height} grid is blocked; use a smaller --cell"
            + (", --unknown-height ignore or a higher --altitude" if bset is not None else "")
        )
    planned = None
    if pattern is not None and lkp_point is not None:  # planned before anything is written
        from swarmctl.geo.patterns import plan_pattern

        planned = plan_pattern(grid, pattern, lkp_point, uavs, spacing)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        written = [
            grid.save(out_dir / "grid.npz"),
            write_grid_geojson(grid, out_dir / "grid.geojson"),
            write_plan(the_area, out_dir / "area.plan"),
            render_preview(grid, the_area, out_dir / "preview.png", bset, rule),
        ]
        if planned is not None:
            written += _write_routes(the_area, planned, out_dir)
        written.append(write_mission_file(out_dir, area, uavs, pattern, lkp_point, spacing))
    except OSError as exc:
        raise InputError(
            f"{exc.filename or out_dir}: cannot write the output ({exc.strerror}); choose another --out"
        ) from None
    click.echo(f"area: {area} ({the_area.describe()})")
    click.echo(f"projection: {grid.proj}")
    for line in summary_lines(grid, report, bset is not None):
        click.echo(line)
    free = int((~grid.blocked).sum())
    unreachable = free - int(grid.largest_free_region().sum())
    if unreachable:
        _warn(
            f"{unreachable} free cell(s) ({100 * unreachable / free:.1f} % of the free cells) cannot be reached "
            "from the largest free region; vehicles starting there stay cut off"
        )
    if planned is not None and lkp_point is not None:
        click.echo(
            f"pattern: {planned.pattern} from {lkp_point[0]:.6f},{lkp_point[1]:.6f}, track spacing "
            f"{planned.spacing:g} m, {len(planned.cells)} free cells covered; {planned.split}"
        )
        for route in planned.routes:
            click.echo(
                f"{route.name}: {len(route.waypoints)} waypoints, {route.length:,.0f} m, altitude {route.altitude:g} m"
            )
        if planned.straight:
            _warn(
                f"{planned.straight} way(s) between waypoints join parts of the area that no free cells connect; "
                "they are flown straight, over blocked cells or outside the area"
            )
    click.echo("wrote: " + ", ".join(str(p) for p in written))


def _lkp(text: str) -> tuple[float, float]:
    """--lkp LAT,LON as two finite numbers in range."""
    parts = text.split(",")
    fix = "give it as LAT,LON in degrees, e.g. --lkp 41.8819,-87.6278"
    try:
        lat, lon = (float(p) for p in parts)
    except ValueError:
        raise InputError(f"--lkp {printable(text)!r}: not two numbers; {fix}") from None
    if not (math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90 and -180 <= lon <= 180):
        raise InputError(f"--lkp {printable(text)!r}: latitude must lie in -90..90 and longitude in -180..180; {fix}")
    return lat, lon


def _write_routes(area, planned, out_dir: Path) -> list[Path]:
    """One QGroundControl .plan per vehicle: the area's fences and the vehicle's waypoints."""
    from swarmctl.geo.plan_io import Waypoint, write_mission_plan

    return [
        write_mission_plan(
            area, [Waypoint(lat, lon, route.altitude) for lat, lon in route.waypoints], out_dir / f"{route.name}.plan"
        )
        for route in planned.routes
    ]


MISSION_POLICY = "coordinated"  # the policy docs/RESULTS.md measured best on real maps


def write_mission_file(
    out_dir: Path,
    area: Path,
    uavs: int,
    pattern: str | None = None,
    lkp: tuple[float, float] | None = None,
    spacing: float | None = None,
) -> Path:
    """OUT/mission.toml: a mission over OUT/grid.npz for `swarmctl fly`, with `uavs` vehicles whose
    connections are placeholders (swarmctl.mission.spec refuses them, naming the vehicle): the pattern
    flown cell by cell from `lkp`, or the coordinated planner."""
    from swarmctl.mission.spec import CONNECTION_PLACEHOLDER, NAME_PATTERN

    name = re.sub(r"[^A-Za-z0-9_.-]", "-", out_dir.resolve().name).lstrip("-_.")[:64]
    name = name if re.match(NAME_PATTERN, name) else "search"
    lines = [
        f"# A search of {printable(area.name)} planned by `swarmctl plan` (docs/geo.md). Fill in each vehicle's",
        "# connection (and check its sysid), then: swarmctl fly mission.toml",
        "# Every key of every table, with its default: docs/mission.md. Paths are relative to this file.",
        "",
        "[mission]",
        f'name = "{name}"',
        'grid = "grid.npz"            # written beside this file by `swarmctl plan`',
    ]
    if pattern is not None and lkp is not None:
        lines += [
            f'policy = "pattern:{pattern}"  # the {pattern} search from lkp, cell by cell (docs/geo.md); '
            'or "coordinated"',
            f"lkp = [{lkp[0]!r}, {lkp[1]!r}]  # the last known point [LAT, LON], degrees",
            f"spacing_m = {spacing!r}  # track spacing, metres"
            if spacing is not None
            else "# spacing_m = 60.0           # track spacing, metres; left out: the footprint's diameter",
        ]
    else:
        lines += [
            f'policy = "{MISSION_POLICY}"       # the best measured on real maps (docs/RESULTS.md); or "frontier", '
            '"la:4", or a search pattern: "pattern:parallel" with lkp = [LAT, LON]',
        ]
    lines += [
        'end_action = "rtl"           # land | rtl | hover (vehicles on a target hold, the others come home)',
        'finish = "covered"           # complete once every cell the vehicles can reach is explored; or "held"',
        '                             # (expected_targets targets hovered on), "found" (that many found) or',
        '                             # "pos >= 0.9" (the probability of success against the prior)',
        "# expected_targets = 1       # N for held and found",
        '# prior = "prior.geojson"    # where the missing person is likely to be (docs/mission.md); left out: every',
        "                             # free cell equally likely",
        "# fence = true               # upload the area's boundary to each vehicle as its geofence",
        "",
        "[timing]",
        "step_period = 1.0            # seconds between decisions, at least",
        "time_limit = 900.0           # seconds of search",
    ]
    for k in range(1, uavs + 1):
        lines += [
            "",
            "[[vehicles]]",
            f'name = "uav{k}"' + (f"  # flies uav{k}.plan's share of the pattern" if pattern else ""),
            f'connection = "{CONNECTION_PLACEHOLDER}"  # its MAVLink link, e.g. "udpin:0.0.0.0:{14550 + k}" (a '
            'radio or router sending there), "tcp:127.0.0.1:5760" (SITL) or a serial "/dev/ttyUSB0:57600"',
            f"sysid = {k}                    # its MAVLink system id: the vehicle's MAV_SYSID (PX4: MAV_SYS_ID); "
            "unique in the swarm",
            '# autopilot = "ardupilot"    # refuse a vehicle whose heartbeat says otherwise',
            '# detector = "mavlink"       # its detector reports on its link; none: a coverage search',
        ]
    path = out_dir / "mission.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
