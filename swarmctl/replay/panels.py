"""The paper's picture of a search at one step, and the animation of the whole mission.

Three panels side by side, in grid cells (x east, y north, as the controller counts them):
1. positions: blocked cells, each vehicle's cells so far in its colour and where it is now, the targets
   found so far;
2. the known map: what the shown vehicles knew together: explored cells in their value phi (pale 0 to
   dark red 1), the obstacles among them dark grey, unexplored cells mid grey (the network reads them as
   phi = 1), the known targets;
3. the true map (only with the simulator's truth file): the true value map, the obstacles, the hidden
   targets (red crosses).
The known map needs knowledge (snapshots or TUNNEL frames); without it that panel is left out too.
The animation draws the same figure for each frame: a GIF always (Pillow), an MP4 when an ffmpeg is
found (imageio-ffmpeg's, else one on PATH).
With `--vehicle`, the replay holds only those vehicles: the known map is what they knew together.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from swarmctl.figures import pyplot
from swarmctl.replay.recording import Replay

UNEXPLORED = "#a6a6a6"
OBSTACLE = "#404040"


def _plt():
    return pyplot()


def known_phi(replay: Replay) -> np.ndarray | None:
    """(W, H) phi of the cells as the vehicles learnt them: from the TUNNEL reports, else the truth."""
    k = replay.knowledge
    if k is not None and k.phi is not None and np.isfinite(k.phi).any():
        return np.nan_to_num(k.phi, nan=0.0)
    if replay.truth is not None:
        return replay.truth.value_map()
    return None


class PanelFigure:
    """The figure, built once and updated per frame (fast enough for an animation)."""

    def __init__(self, replay: Replay, dpi: int = 80):
        plt = _plt()
        from matplotlib.colors import ListedColormap

        self.replay = replay
        g = replay.grid
        self.phi = known_phi(replay)
        kinds = ["positions"] + (["known"] if replay.knowledge is not None else [])
        kinds += ["true"] if replay.truth is not None else []
        self.kinds = kinds
        self.fig, axes = plt.subplots(1, len(kinds), figsize=(3.6 * len(kinds), 4.0), dpi=dpi, squeeze=False)
        self.axes = dict(zip(kinds, axes[0]))
        extent = (-0.5, g.width - 0.5, -0.5, g.height - 0.5)
        blocked_cmap = ListedColormap(["#ffffff", OBSTACLE])
        self.value_cmap = plt.get_cmap("YlOrRd").with_extremes(bad=UNEXPLORED, under=OBSTACLE)
        for ax in self.axes.values():
            ax.set_xlim(extent[0], extent[1])
            ax.set_ylim(extent[2], extent[3])
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
        ax = self.axes["positions"]
        ax.imshow(
            g.blocked.T, origin="lower", cmap=blocked_cmap, vmin=0, vmax=1, extent=extent, interpolation="nearest"
        )
        self.paths, self.dots = [], []
        for v in replay.vehicles:
            (line,) = ax.plot([], [], "-", color=v.colour, lw=1.2, alpha=0.8)
            (dot,) = ax.plot([], [], "o", color=v.colour, ms=6, mec="black", mew=0.6, label=v.name, zorder=3)
            self.paths.append(line)
            self.dots.append(dot)
        (self.found,) = ax.plot([], [], "*", color="gold", mec="black", ms=11, ls="none", zorder=2.5)
        if len(replay.vehicles) <= 10:
            ax.legend(loc="upper right", fontsize=6, framealpha=0.8)
        self.known_img = self.known_targets = None
        if "known" in self.axes:
            ax = self.axes["known"]
            self.known_img = self._cells(ax, np.full((g.width, g.height), np.nan), extent)
            (self.known_targets,) = ax.plot([], [], "*", color="gold", mec="black", ms=11, ls="none")
        if "true" in self.axes:
            ax, truth = self.axes["true"], replay.truth
            assert truth is not None  # the panel is there only with the truth
            true_value = np.where(g.blocked, -1.0, truth.value_map())
            self._cells(ax, true_value, extent)
            if len(truth.targets):
                ax.plot(truth.targets[:, 0], truth.targets[:, 1], "x", color="red", ms=8, mew=2, ls="none")
            ax.set_title(f"true map: {len(truth.targets)} hidden targets", fontsize=9)
        self.title = self.fig.suptitle(f"{replay.name}: step 0", fontsize=10)
        self.axes["positions"].set_title("positions", fontsize=9)
        if "known" in self.axes:
            self.axes["known"].set_title("known map", fontsize=9)
        self.fig.tight_layout(rect=(0, 0, 1, 0.94))
        self._background = None

    def _cells(self, ax: Any, value: np.ndarray, extent: tuple) -> Any:
        """A [x, y] array of values in [0, 1] (-1: obstacle, NaN: unexplored) drawn as cells."""
        return ax.imshow(
            value.T, origin="lower", cmap=self.value_cmap, vmin=0.0, vmax=1.0, extent=extent, interpolation="nearest"
        )

    def _dynamic(self) -> list:
        out = [self.found, *self.paths, *self.dots, self.title, self.axes["positions"].title]
        if self.known_img is not None:
            out += [self.known_img, self.known_targets, self.axes["known"].title]
        return out

    def blit(self) -> None:
        """Draw the still parts once; from now on `rgb` redraws only what changes per frame."""
        for a in self._dynamic():
            a.set_animated(True)
        self.fig.canvas.draw()
        self._background = self.fig.canvas.copy_from_bbox(self.fig.bbox)

    def draw(self, frame: int) -> None:
        """Update every artist to frame `frame`."""
        r = self.replay
        for v, line, dot in zip(r.vehicles, self.paths, self.dots):
            c = v.cells[: frame + 1]
            c = c[c[:, 0] >= 0]
            line.set_data(c[:, 0], c[:, 1])
            now = v.cells[frame]
            dot.set_data([now[0]] if now[0] >= 0 else [], [now[1]] if now[0] >= 0 else [])
        found = np.array([t.cell for t in r.targets if t.frame <= frame], dtype=float).reshape(-1, 2)
        self.found.set_data(found[:, 0], found[:, 1])
        self.axes["positions"].set_title(
            f"positions: {len(found)} target{'s' if len(found) != 1 else ''} found", fontsize=9
        )
        if self.known_img is not None:
            k = r.knowledge
            assert k is not None and self.known_targets is not None  # the panel is there only with knowledge
            explored = k.explored(frame)
            value = self.phi if self.phi is not None else np.zeros(explored.shape)
            shown = np.where(explored, np.where(r.grid.blocked, -1.0, value), np.nan)
            self.known_img.set_data(shown.T)
            known = np.array([c for c, (f, _v) in k.targets.items() if f <= frame], dtype=float).reshape(-1, 2)
            if not len(known):
                known = found
            self.known_targets.set_data(known[:, 0], known[:, 1])
            self.axes["known"].set_title(f"known map: {int(explored.sum())} cells explored", fontsize=9)
        self.title.set_text(f"{r.name}: {r.frame_label(frame)}")

    def save(self, path: Path) -> Path:
        self.fig.savefig(path)
        return path

    def rgb(self) -> np.ndarray:
        """The drawn figure as an (H, W, 3) uint8 image."""
        canvas = self.fig.canvas
        if self._background is None:
            canvas.draw()
        else:
            canvas.restore_region(self._background)
            for a in self._dynamic():
                self.fig.draw_artist(a)
        return np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        _plt().close(self.fig)


def write_panels(replay: Replay, frames: list[int], out: Path) -> list[Path]:
    """panels-step-N.png (panels-t-N.png for time frames) for each frame."""
    fig = PanelFigure(replay, dpi=110)
    paths = []
    try:
        for f in frames:
            fig.draw(f)
            tag = f"step-{int(replay.frame_step[f])}" if replay.frame_step is not None else f"t-{f}"
            paths.append(fig.save(out / f"panels-{tag}.png"))
    finally:
        fig.close()
    return paths


def ffmpeg_exe() -> str | None:
    """The ffmpeg the animation's MP4 is written with: imageio-ffmpeg's, else one on PATH, else None."""
    try:
        import imageio_ffmpeg
    except ImportError:
        return shutil.which("ffmpeg")
    try:
        return imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError:  # the package is there without a binary for this platform
        return None


class _Mp4:
    """MP4 frames into ffmpeg: through imageio-ffmpeg when installed (its own ffmpeg binary), else through
    matplotlib's FFMpegWriter with an ffmpeg on PATH; `None` from `open` when there is neither."""

    def __init__(self, path: Path, fps: float, fig: Any):
        self.path, self.gen, self.writer, self.fig = path, None, None, fig
        try:
            import imageio_ffmpeg
        except ImportError:
            from matplotlib.animation import FFMpegWriter

            self.writer = FFMpegWriter(
                fps=fps,  # type: ignore[arg-type]  # matplotlib's stub says int; ffmpeg takes any rate
                codec="libx264",
                extra_args=["-pix_fmt", "yuv420p"],
            )
            self.writer.setup(fig, str(path), dpi=fig.dpi)
            return
        w, h = (int(v) // 2 * 2 for v in fig.canvas.get_width_height())
        self.size = (w, h)
        self.gen = imageio_ffmpeg.write_frames(str(path), (w, h), fps=fps, macro_block_size=2, quality=6)
        self.gen.send(None)

    @classmethod
    def open(cls, path: Path, fps: float, fig: Any) -> _Mp4 | None:
        return cls(path, fps, fig) if ffmpeg_exe() is not None else None

    def add(self, rgb: np.ndarray) -> None:
        if self.gen is not None:
            w, h = self.size
            self.gen.send(np.ascontiguousarray(rgb[:h, :w]).tobytes())
        else:
            assert self.writer is not None  # no imageio-ffmpeg: matplotlib's writer
            self.writer.grab_frame()

    def close(self) -> None:
        if self.gen is not None:
            self.gen.close()
        else:
            assert self.writer is not None
            self.writer.finish()


def write_animation(
    replay: Replay,
    frames: list[int],
    out: Path,
    fps: float,
    progress: Callable[[int], object] | None = None,
) -> list[Path]:
    """animation.gif (and animation.mp4 when ffmpeg is found) over the given frames."""
    from PIL import Image

    fig = PanelFigure(replay, dpi=80)
    gif_frames: list[Any] = []
    palette = None
    paths = [out / "animation.gif"]
    mp4 = None
    failed: str | None = None

    def mp4_failed(exc: Exception) -> None:  # ffmpeg is optional: a failure costs the MP4, not the replay
        nonlocal mp4, failed
        failed = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        if mp4 is not None:
            try:
                mp4.close()
            except Exception:  # noqa: BLE001  ffmpeg already failed; its second complaint adds nothing
                pass
        mp4 = None
        (out / "animation.mp4").unlink(missing_ok=True)

    try:
        try:
            mp4 = _Mp4.open(out / "animation.mp4", fps, fig.fig)
        except Exception as exc:  # noqa: BLE001  whatever ffmpeg (or imageio) raises on start
            mp4_failed(exc)
        if mp4 is None or mp4.gen is not None:  # matplotlib's own ffmpeg writer draws the whole figure
            fig.blit()
        for f in frames:
            fig.draw(f)
            rgb = fig.rgb()
            image = Image.fromarray(rgb)
            if palette is None:  # one palette for every frame: colours do not flicker
                palette = image.quantize(colors=255, method=Image.Quantize.MEDIANCUT)
            gif_frames.append(image.quantize(palette=palette, dither=Image.Dither.NONE))
            if mp4 is not None:
                try:
                    mp4.add(rgb)
                except Exception as exc:  # noqa: BLE001  a broken pipe: ffmpeg stopped
                    mp4_failed(exc)
            if progress is not None:
                progress(1)
    finally:
        if mp4 is not None:
            try:
                mp4.close()
                paths.append(mp4.path)
            except Exception as exc:  # noqa: BLE001  ffmpeg's exit status or its last complaint
                mp4 = None
                mp4_failed(exc)
        fig.close()
    if failed is not None:
        replay.notes.append(f"animation.mp4 not written: ffmpeg failed ({failed}); animation.gif has the animation")
    duration = max(20, int(round(1000 / fps)))
    gif_frames[0].save(paths[0], save_all=True, append_images=gif_frames[1:], duration=duration, loop=0)
    return paths
