"""`swarmctl replay`: a finished mission (or anyone's .tlog) as a map page, pictures, an animation,
tracks, plots and a summary."""

from __future__ import annotations

from pathlib import Path

import click

from swarmctl.bounds import real, require_memory, whole, writable_folder
from swarmctl.errors import InputError, printable

MAX_PANELS = 100  # pictures one --steps may ask for
MIN_FPS, MAX_FPS = 0.1, 60.0  # --fps: a frame every 10 s at the slowest (ffmpeg refuses rates near 0)
ANIMATION_FRAME_BYTES = 3 * 288 * 320  # one GIF frame of the three panels at 80 dpi, kept until it is written
MIN_PROBABILITY = 0.01  # --verify's default: a softmax move less likely than this (draw not reproduced) fails


def _steps(value: str | None) -> list[int] | None:
    if value is None:
        return None
    try:
        steps = [int(s) for s in value.split(",") if s.strip()]
    except ValueError:
        raise InputError(
            f"--steps {value!r}: give whole step numbers separated by commas, e.g. --steps 0,50,100"
        ) from None
    if not steps or min(steps) < 0:
        raise InputError(f"--steps {value!r}: give step numbers >= 0 separated by commas, e.g. --steps 0,50,100")
    if len(steps) > MAX_PANELS:
        raise InputError(f"--steps: {len(steps)} pictures asked for, over {MAX_PANELS}; give fewer steps")
    return steps


def _out_dir(path: Path, out: Path | None) -> Path:
    """The output folder (--out, or beside the recording), checked to be writable before the replay is read."""
    folder = out if out is not None else (path / "replay" if path.is_dir() else path.with_name(f"{path.stem}-replay"))
    return writable_folder(folder, "--out")


def _check_step(replay, name: str, value: int | None) -> None:
    if value is None:
        return
    if replay.frame_step is not None:
        top, unit = int(replay.frame_step[-1]), "steps"
    else:
        top, unit = int(replay.frame_time[-1] - replay.frame_time[0]), "seconds (this log has no decision steps)"
    if not 0 <= value <= top:
        raise InputError(f"{name} {value}: the replay has {unit} 0..{top}")


def _frame_range(replay, first: int | None, last: int | None) -> tuple[int, int]:
    _check_step(replay, "--from-step", first)
    _check_step(replay, "--to-step", last)
    a = replay.frame_of_step(first) if first is not None else 0
    b = replay.frame_of_step(last) if last is not None else replay.frames - 1
    if a > b:
        raise InputError(f"--from-step {first} is after --to-step {last}")
    return a, b


@click.command("replay")
@click.argument("recording", type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default=None,
    help="Output folder (default: RECORDING/replay, or NAME-replay beside a .tlog).",
)
@click.option(
    "--steps",
    default=None,
    help="Steps of the three-panel pictures, e.g. 0,50,100 (default: --from-step and --to-step: the first and "
    "the last step). A log without decision steps counts seconds from its start.",
)
@click.option("--from-step", type=whole(0), default=None, help="First step of the animation (default: the first).")
@click.option("--to-step", type=whole(0), default=None, help="Last step of the animation (default: the last).")
@click.option(
    "--vehicle",
    "--vehicles",
    "vehicles",
    multiple=True,
    help="Replay only this vehicle (its name, or a system id for a bare .tlog); repeatable. The known map "
    "shows what the chosen vehicles knew together.",
)
@click.option(
    "--fps",
    type=real(MIN_FPS, MAX_FPS),
    default=10.0,
    show_default=True,
    help="Frames per second of the animation (0.1 to 60).",
)
@click.option(
    "--grid",
    "grid_file",
    type=click.Path(path_type=Path),
    default=None,
    help="grid.npz for a bare .tlog (or a recording without grid.npz); a recording's own grid is always used.",
)
@click.option(
    "--buildings",
    type=click.Path(path_type=Path),
    default=None,
    help="Building footprints (GeoJSON) to draw on the map (default: the grid's buildings file when it is in the "
    "recording folder).",
)
@click.option(
    "--basemap",
    default=None,
    metavar="URL",
    help="Tile URL with {z}/{x}/{y} for a background map, e.g. https://tile.openstreetmap.org/{z}/{x}/{y}.png "
    "(the page then loads tiles from the network; without it the page is fully offline).",
)
@click.option("--attribution", default="", help="Attribution text shown with the basemap (e.g. (c) OpenStreetMap).")
@click.option(
    "--verify",
    is_flag=True,
    help="Instead of the outputs: decide every recorded decision again with the recorded policy on the recorded "
    "beliefs and list the mismatches (exit 1 when there are any, 2 when no decision could be checked); writes "
    "verify.json to --out.",
)
@click.option(
    "--model",
    type=click.Path(path_type=Path),
    default=None,
    help="--verify: the checkpoint the mission flew, when it is no longer where the recording names it (its "
    "weights must have the recorded sha256).",
)
@click.option(
    "--min-probability",
    type=real(0, 1),
    default=MIN_PROBABILITY,
    show_default=True,
    help="--verify, softmax policies: where the draw cannot be reproduced, a recorded move less likely than this "
    "under the model is a mismatch.",
)
@click.option(
    "--gaps",
    is_flag=True,
    help="Also write gaps.geojson, gaps.kml and gaps.prior.geojson: the cells still worth searching, merged into "
    "polygons with the probability left in each, and that as a prior for the next mission (docs/recording.md).",
)
@click.option(
    "--gaps-min",
    type=real(0, None),
    default=None,
    help="--gaps: a cell is left when it holds more than this times a uniform prior's cell before the search "
    "(default: any probability when pod is 1, else 0.1).",
)
@click.option("--quiet", "-q", is_flag=True, help="Print nothing; no progress bar.")
def replay_command(
    recording: Path,
    out: Path | None,
    steps: str | None,
    from_step: int | None,
    to_step: int | None,
    vehicles: tuple[str, ...],
    fps: float,
    grid_file: Path | None,
    buildings: Path | None,
    basemap: str | None,
    attribution: str,
    verify: bool,
    model: Path | None,
    min_probability: float,
    gaps: bool,
    gaps_min: float | None,
    quiet: bool,
) -> None:
    """Replay a recording folder (fly, agent, demo) or a .tlog (MAVProxy, QGroundControl, SITL).

    Writes map.html (offline map page with a time slider), panels-step-N.png (positions, known map,
    true map), animation.gif (and .mp4 with ffmpeg), tracks.geojson / tracks.kml, targets.geojson /
    targets.kml, the plots and summary.txt (with --gaps also gaps.geojson, gaps.kml and gaps.prior.geojson:
    what is left to search). Damaged logs are replayed as far as they can be read, and
    what was skipped is listed. With --verify: check the recorded decisions instead (docs/recording.md).
    """
    from tqdm import tqdm

    from swarmctl.replay import recording as rmod
    from swarmctl.replay.gaps import find_gaps, write_gaps

    if basemap is not None and not all(k in basemap for k in ("{z}", "{x}", "{y}")):
        raise InputError(f"--basemap {basemap!r}: the tile URL needs {{z}}, {{x}} and {{y}}")
    wanted = _steps(steps)
    if not recording.exists():
        raise InputError(f"{recording}: not found; give a recording folder (fly, agent, demo) or a .tlog file")
    folder = _out_dir(recording, out)
    if verify and (gaps or gaps_min is not None):
        raise InputError("--gaps writes the replay's outputs and --verify only checks the decisions: give one")
    if verify:
        _verify(recording, folder, model, min_probability, quiet)
        return
    if model is not None:
        raise InputError("--model is for --verify: give --verify too, or leave --model out")
    if gaps_min is not None and not gaps:
        raise InputError("--gaps-min is for --gaps: give --gaps too, or leave --gaps-min out")
    source = recording / "mission.tlog" if recording.is_dir() else recording
    size = source.stat().st_size if source.is_file() else 0
    with tqdm(
        total=size, unit="B", unit_scale=True, desc="reading", disable=quiet, delay=0.5, leave=False, mininterval=1.0
    ) as bar:
        replay = rmod.load(recording, list(vehicles) or None, grid_file, buildings, progress=bar.update)
    left = find_gaps(replay, gaps_min) if gaps else None  # a bad prior line fails before the pictures

    from swarmctl.replay.page import write_page
    from swarmctl.replay.panels import write_animation, write_panels
    from swarmctl.replay.plots import write_plots
    from swarmctl.replay.summary import summary_lines
    from swarmctl.replay.tracks import write_tracks  # the mission's target writers: a second or two to import

    first, last = _frame_range(replay, from_step, to_step)
    require_memory(
        (last - first + 1) * ANIMATION_FRAME_BYTES,
        f"the animation of {last - first + 1:,} frames",
        "animate a part of the replay with --from-step and --to-step",
    )
    folder.mkdir(parents=True, exist_ok=True)
    for s in wanted or []:
        _check_step(replay, "--steps", s)
    panel_frames = [replay.frame_of_step(s) for s in wanted] if wanted is not None else sorted({first, last})
    written = [write_page(replay, folder / "map.html", basemap, attribution)]
    written += write_panels(replay, panel_frames, folder)
    frames = list(range(first, last + 1))
    with tqdm(
        total=len(frames), unit="frame", desc="animation", disable=quiet, delay=0.5, leave=False, mininterval=1.0
    ) as bar:
        written += write_animation(replay, frames, folder, fps, progress=bar.update)
    written += write_tracks(replay, folder)
    written += write_plots(replay, folder)
    lines = summary_lines(replay)
    if left is not None:
        written += write_gaps(left, replay.name, folder)
        lines += left.summary_lines(replay.grid.cell)
    text = folder / "summary.txt"
    text.write_text("\n".join(lines) + "\n", encoding="utf-8")
    written.append(text)
    if not quiet:
        for line in lines:
            click.echo(printable(line))  # names and notes come from the recording
        click.echo(f"wrote {len(written)} files to {folder}: {', '.join(p.name for p in written)}")


def _verify(recording: Path, folder: Path, model: Path | None, min_probability: float, quiet: bool) -> None:
    """--verify: the report on stdout and in verify.json; exit 1 when a decision was not reproduced."""
    import json

    from tqdm import tqdm

    from swarmctl.errors import EXIT_FAILED
    from swarmctl.replay.verify import verify

    with tqdm(unit="round", desc="verify", disable=quiet, delay=0.5, leave=False, mininterval=1.0) as bar:

        def total(n: int) -> None:
            bar.total = n
            bar.refresh()

        report = verify(recording, model, min_probability, progress=bar.update, total=total)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "verify.json").write_text(json.dumps(report.as_dict(), indent=1) + "\n", encoding="utf-8")
    if not quiet:
        for line in report.lines():
            click.echo(printable(line))
    if report.nothing_checked:  # unreadable input: no decision could be decided again
        why = ", ".join(f"{n}: {w}" for w, n in report.unchecked.most_common(1)) or "no inputs line was read"
        raise InputError(
            f"{recording}: none of its {report.decisions} recorded decisions could be checked ({why}); the "
            "recording cannot be verified (inputs.jsonl is damaged or missing its lines)"
        )
    if not report.ok:
        raise click.exceptions.Exit(EXIT_FAILED)
