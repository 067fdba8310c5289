"""plan.png: the map with the inflated zone, the paths, start, goal and dynamic obstacles.

Drawn on matplotlib's Agg canvas without pyplot (as :mod:`slamcli.report`), in world
metres with y up. The map is drawn from an image the size of the figure, not of the map:
:func:`draw_grid` crops the cells in view, averages them down to about one pixel of the figure
each and places the image with the origin's yaw, so a map of millions of cells costs no more
to draw than a small one.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ExportError
from slamcli.planning.costmap import map_bounds, world_to_uv
from slamcli.planning.planner import PlanResult
from slamcli.types import OccupancyGrid

FIG_WIDTH_IN = 8.0
"""Width of plan.png in inches (at :data:`DPI`); the height follows the view's aspect."""

DPI = 100

UNKNOWN_GREY = 0.8
"""Grey level (0 black .. 1 white) of unknown cells in plan.png."""

INFLATED_RGB = (1.0, 0.78, 0.72)
"""Colour of the cells the robot's radius blocks around obstacles."""

_MARGIN_IN = {"left": 0.75, "right": 0.25, "top": 0.4, "bottom": 1.05}
"""Room around the map (inches) for the title, the tick labels and the legend below."""


def plot_plan(path: str | Path, result: PlanResult) -> Path:
    """Write :func:`plan_figure` to ``path`` (PNG)."""
    fig = plan_figure(result)
    try:
        fig.savefig(path, format="png", dpi=DPI)
    except OSError as exc:
        raise ExportError(f"{path}: cannot write the plot ({exc.strerror})") from exc
    return Path(path)


def plan_figure(result: PlanResult) -> Any:
    """The picture as a matplotlib Figure (Agg canvas attached). The view is cropped to the
    known part of the map, the paths and the obstacles, with a margin."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle

    cm = result.costmap
    view = _view(result)
    # A fixed layout sized to the view: no layout engine, so the figure is drawn only once.
    axes_w = FIG_WIDTH_IN - _MARGIN_IN["left"] - _MARGIN_IN["right"]
    aspect = (view[3] - view[2]) / max(view[1] - view[0], 1e-9)
    axes_h = min(max(axes_w * aspect, 1.5), 9.0)
    fig_h = axes_h + _MARGIN_IN["top"] + _MARGIN_IN["bottom"]
    fig = Figure(figsize=(FIG_WIDTH_IN, fig_h))
    FigureCanvasAgg(fig)
    ax = fig.add_axes(
        (
            _MARGIN_IN["left"] / FIG_WIDTH_IN,
            _MARGIN_IN["bottom"] / fig_h,
            axes_w / FIG_WIDTH_IN,
            axes_h / fig_h,
        )
    )
    draw_grid(ax, cm.grid, _plan_colours(result), view, axes_w * DPI)

    ax.plot(*result.grid_xy.T, color="tab:orange", lw=1.0, ls="--", label="grid path")
    for k, (_, pts) in enumerate(result.tracking.paths[1:]):
        ax.plot(*pts.T, color="tab:purple", lw=1.0, ls=":", label="replanned" if k == 0 else None)
    ax.plot(*result.smooth_xy.T, color="tab:blue", lw=1.6, label="smoothed path")
    states = result.tracking.states
    if len(states):
        ax.plot(states[:, 1], states[:, 2], color="tab:green", lw=0.9, label="tracked")
    for ob in result.obstacles:
        ax.add_patch(Circle((ob.x, ob.y), ob.radius, color="tab:purple", alpha=0.5))
        ax.add_patch(
            Circle(
                (ob.x, ob.y),
                ob.radius + cm.robot_radius_m,
                fill=False,
                ls="--",
                color="tab:purple",
                lw=0.8,
            )
        )
        until = "" if math.isinf(ob.vanish_s) else f"-{ob.vanish_s:g}"
        ax.annotate(
            f"{ob.appear_s:g}{until or '+'} s",
            (ob.x, ob.y),
            fontsize="x-small",
            ha="center",
            va="center",
        )
    events = result.tracking.events
    if events:
        ex = [e["x"] for e in events]
        ey = [e["y"] for e in events]
        ax.plot(ex, ey, "x", color="k", ms=7, label="replan / wait")
    ax.plot(*result.start_xy, "o", color="tab:green", ms=8, label="start")
    ax.plot(*result.goal_xy, "*", color="tab:red", ms=12, label="goal")

    ax.set_xlim(view[0], view[1])
    ax.set_ylim(view[2], view[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(
        f"grid cost {result.grid_cost_m:.2f} m, smoothed {result.length_m:.2f} m, "
        f"radius {cm.robot_radius_m:g} m (inflated zone shaded)"
    )
    # Below the map, where it hides nothing (and costs no search for a free corner).
    fig.legend(loc="lower center", ncols=4, fontsize="small", frameon=False)
    ax.grid(alpha=0.25)
    return fig


def draw_grid(
    ax: Any,
    grid: OccupancyGrid,
    colours: Callable[[slice, slice], NDArray[np.uint8]],
    view: tuple[float, float, float, float],
    max_pixels: float,
) -> Any:
    """Draw the grid's cells on ``ax`` where they lie in the world.

    ``colours(rows, cols)`` gives the (h, w, 4) uint8 RGBA colours of a block of cells (row 0
    the lowest y); ``view`` is (xmin, xmax, ymin, ymax) in world metres; ``max_pixels`` about
    the most pixels the view spans on screen. Only the cells in view are coloured, averaged
    in blocks of whole cells so the image has about one pixel per screen pixel, and the image
    is turned by the origin's yaw about the origin (the cell frame of
    :func:`slamcli.planning.costmap.world_to_uv`). Returns the AxesImage, or None when no cell
    is in view.
    """
    import cv2
    from matplotlib.transforms import Affine2D

    h, w = np.asarray(grid.prob).shape
    res = float(grid.resolution_m)
    x0, y0, yaw = (float(v) for v in grid.origin_xy_yaw)
    xmin, xmax, ymin, ymax = view
    corners = world_to_uv(grid, [[xmin, ymin], [xmax, ymin], [xmin, ymax], [xmax, ymax]])
    c0 = max(math.floor(corners[:, 0].min()) - 1, 0)
    r0 = max(math.floor(corners[:, 1].min()) - 1, 0)
    c1 = min(math.ceil(corners[:, 0].max()) + 1, w)
    r1 = min(math.ceil(corners[:, 1].max()) + 1, h)
    if c0 >= c1 or r0 >= r1:
        return None
    image = np.ascontiguousarray(colours(slice(r0, r1), slice(c0, c1)), dtype=np.uint8)
    block = max(1, round(max(xmax - xmin, ymax - ymin) / res / max_pixels))
    if block > 1:
        size = (math.ceil((c1 - c0) / block), math.ceil((r1 - r0) / block))
        image = np.asarray(cv2.resize(image, size, interpolation=cv2.INTER_AREA), dtype=np.uint8)
    drawn = ax.imshow(
        image,
        origin="lower",
        extent=(x0 + c0 * res, x0 + c1 * res, y0 + r0 * res, y0 + r1 * res),
        interpolation="nearest",
        zorder=0,
    )
    if yaw:
        drawn.set_transform(Affine2D().rotate_around(x0, y0, yaw) + ax.transData)
    return drawn


def grid_view(grid: OccupancyGrid, margin_m: float = 0.0) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax): the map's area in the world (yaw included), plus a margin."""
    xmin, xmax, ymin, ymax = map_bounds(grid)
    return xmin - margin_m, xmax + margin_m, ymin - margin_m, ymax + margin_m


def occupancy_colours(
    prob: NDArray[np.floating], rows: slice, cols: slice, unknown_grey: float = UNKNOWN_GREY
) -> NDArray[np.uint8]:
    """(h, w, 4) uint8 RGBA of a block of cells: grey ``1 - prob`` (free white, occupied
    black), ``unknown_grey`` where prob is NaN."""
    p = np.asarray(prob[rows, cols], dtype=np.float32)
    grey = np.where(np.isnan(p), np.float32(unknown_grey), 1.0 - p)
    out = np.empty((*p.shape, 4), dtype=np.uint8)
    out[..., :3] = np.rint(grey * 255.0).astype(np.uint8)[..., None]
    out[..., 3] = 255
    return out


def _plan_colours(result: PlanResult) -> Callable[[slice, slice], NDArray[np.uint8]]:
    """Cell colours of plan.png: :func:`occupancy_colours`, inflated cells pink."""
    cm = result.costmap
    pink = np.rint(np.array(INFLATED_RGB) * 255.0).astype(np.uint8)

    def colours(rows: slice, cols: slice) -> NDArray[np.uint8]:
        out = occupancy_colours(cm.grid.prob, rows, cols)
        inflated = cm.blocked[rows, cols] & ~cm.occupied[rows, cols] & ~cm.unknown[rows, cols]
        out[inflated, :3] = pink
        return out

    return colours


def _view(result: PlanResult) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax): the known cells, paths and obstacles, plus a margin."""
    from slamcli.planning.costmap import uv_to_world

    cm = result.costmap
    rows = np.flatnonzero((~cm.unknown).any(axis=1))
    cols = np.flatnonzero((~cm.unknown).any(axis=0))
    pts = [result.smooth_xy, result.grid_xy, np.array([result.start_xy, result.goal_xy])]
    if len(rows):
        # The four corners of the known cells' box: with a yaw, any of them may be extreme.
        u0, u1, v0, v1 = cols[0], cols[-1] + 1, rows[0], rows[-1] + 1
        pts.append(uv_to_world(cm.grid, [[u0, v0], [u1, v0], [u0, v1], [u1, v1]]))
    if len(result.tracking.states):
        pts.append(result.tracking.states[:, 1:3])
    for ob in result.obstacles:
        pts.append(
            np.array([[ob.x - ob.radius, ob.y - ob.radius], [ob.x + ob.radius, ob.y + ob.radius]])
        )
    allp = np.concatenate(pts)
    margin = max(0.5, 10 * cm.resolution_m)
    lo = allp.min(axis=0) - margin
    hi = allp.max(axis=0) + margin
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])
