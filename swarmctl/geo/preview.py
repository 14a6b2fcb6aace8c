"""`preview.png`: the grid over the area, drawn in the grid's own frame (metres from cell (0, 0))."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import shapely
from matplotlib.colors import ListedColormap
from matplotlib.patches import PathPatch, Rectangle
from matplotlib.path import Path as MplPath
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

from swarmctl.figures import pyplot
from swarmctl.geo.areas import Area
from swarmctl.geo.buildings import BuildingRule, BuildingSet
from swarmctl.geo.grid import GeoGrid

plt = pyplot()

COLOURS = {"blocking": "#c0392b", "low": "#2e86c1", "unknown": "#e67e22", "nofly": "#8e44ad"}


def _path(geom) -> MplPath | None:
    """One matplotlib path for every polygon of a shapely geometry (holes included)."""
    verts, codes = [], []
    for poly in shapely.get_parts(geom):
        if not isinstance(poly, shapely.Polygon) or poly.is_empty:
            continue
        for ring in [poly.exterior, *poly.interiors]:
            xy = np.asarray(ring.coords)[:, :2]
            verts.append(xy)
            codes.append([MplPath.MOVETO] + [MplPath.LINETO] * (len(xy) - 2) + [MplPath.CLOSEPOLY])
    if not verts:
        return None
    return MplPath(np.concatenate(verts), np.concatenate(codes))


def _draw(ax, geom, **style) -> None:
    path = _path(geom)
    if path is not None:  # add_artist, not add_patch: the limits are set by hand, and that is faster
        ax.add_artist(PathPatch(path, **style))


def _nice_length(span: float) -> float:
    """A round scale-bar length of about a fifth of `span` metres."""
    target = span / 5.0
    base = 10 ** np.floor(np.log10(target))
    return float(max(b * base for b in (1, 2, 5) if b * base <= target))


def render_preview(
    grid: GeoGrid, area: Area, path: str | Path, buildings: BuildingSet | None = None, rule: BuildingRule | None = None
) -> Path:
    """Draw area outline, no-fly zones, buildings (by outcome), blocked cells and grid extent."""
    path = Path(path)
    proj, c = grid.projection, grid.cell

    def frame(geom):  # lon/lat -> metres in the grid frame
        return shapely.affinity.scale(grid.geometry_to_grid(proj.geometry_to_metres(geom)), c, c, origin=(0, 0))

    w_m, h_m = grid.width * c, grid.height * c
    fig, ax = plt.subplots(figsize=(8, 8 * min(1.6, max(0.6, h_m / w_m))), dpi=110)
    ax.imshow(
        grid.blocked.T,
        origin="lower",
        extent=(0, w_m, 0, h_m),
        interpolation="nearest",
        cmap=ListedColormap(["#ffffff", "#9e9e9e"]),
        vmin=0,
        vmax=1,
        zorder=0,
    )
    if max(grid.width, grid.height) <= 80:
        ax.set_xticks(np.arange(0, w_m + c / 2, c), minor=True)
        ax.set_yticks(np.arange(0, h_m + c / 2, c), minor=True)
        ax.grid(which="minor", color="#dddddd", linewidth=0.3)
    ax.add_patch(Rectangle((0, 0), w_m, h_m, fill=False, linestyle="--", edgecolor="#555555", linewidth=1))
    _draw(ax, frame(area.geometry), fill=False, edgecolor="black", linewidth=1.5, zorder=3)
    if grid.nofly_wkt:
        _draw(
            ax,
            frame(shapely.from_wkt(grid.nofly_wkt)),
            facecolor="none",
            edgecolor=COLOURS["nofly"],
            hatch="///",
            linewidth=1.2,
            zorder=3,
        )
    handles = [
        Rectangle((0, 0), 1, 1, facecolor="#9e9e9e", label="blocked cell"),
        Rectangle((0, 0), 1, 1, fill=False, edgecolor="black", label="area"),
    ]
    if grid.nofly_wkt:
        handles.append(
            Rectangle(
                (0, 0), 1, 1, facecolor="none", edgecolor=COLOURS["nofly"], hatch="///", label="no-fly zone / hole"
            )
        )
    if buildings is not None and buildings.buildings:
        rule = rule or BuildingRule(altitude=grid.altitude)
        groups: dict[str, list] = {"blocking": [], "low": [], "unknown": []}
        for b in buildings.buildings:
            kind = "unknown" if b.height is None else ("blocking" if rule.blocks(b.height) else "low")
            groups[kind].append(b.geometry)
        labels = {
            "blocking": f"building >= {rule.threshold:g} m (obstacle)",
            "low": f"building < {rule.threshold:g} m",
            "unknown": f"building, height unknown ({'obstacle' if rule.unknown == 'block' else 'ignored'})",
        }
        for kind, geoms in groups.items():
            if geoms:
                _draw(
                    ax,
                    frame(shapely.union_all(geoms)),
                    facecolor=COLOURS[kind],
                    edgecolor=COLOURS[kind],
                    alpha=0.55,
                    linewidth=0.5,
                    zorder=2,
                )
                handles.append(Rectangle((0, 0), 1, 1, facecolor=COLOURS[kind], alpha=0.55, label=labels[kind]))
    bar = _nice_length(w_m)
    ax.add_artist(
        AnchoredSizeBar(
            ax.transData, bar, f"{bar:g} m", "lower right", pad=0.5, frameon=True, size_vertical=max(h_m / 200, c / 10)
        )
    )
    pad = max(w_m, h_m) * 0.03
    ax.set_xlim(-pad, w_m + pad)
    ax.set_ylim(-pad, h_m + pad)
    ax.set_aspect("equal")
    axis = "east" if grid.rotation == 0 else f"{grid.rotation:+.1f} deg from east"
    ax.set_xlabel(f"x: metres along the grid's x axis ({axis})")
    ax.set_ylabel("y: metres along the grid's y axis")
    ax.set_title(
        f"{grid.area_name}: {grid.width} x {grid.height} cells of {c:g} m, "
        f"{100 * grid.blocked_fraction:.1f} % blocked, altitude {grid.altitude:g} m",
        fontsize=10,
    )
    ax.legend(handles=handles, loc="upper left", fontsize=7, framealpha=0.85)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
