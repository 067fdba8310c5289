"""plan.png: the map with the inflated zone, the paths, start, goal and dynamic obstacles.

Drawn with OpenCV on a :class:`slamcli.planning.canvas.Canvas`, in world metres with y up, so
the plan command never imports matplotlib. The map is drawn from the cells in view, reduced to
about one cell per pixel and placed with the origin's yaw, so a map of millions of cells costs
no more to draw than a small one.

:func:`draw_grid` draws a map in the same spirit (cells in view, reduced with darker winning, the
origin's yaw) on a matplotlib Axes, for the run reports (:mod:`slamcli.report`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from slamcli.planning.costmap import map_bounds
from slamcli.planning.planner import PlanResult
from slamcli.types import OccupancyGrid

if TYPE_CHECKING:
    from slamcli.planning.canvas import Canvas

UNKNOWN_GREY = 0.8
"""Grey level (0 black .. 1 white) of unknown cells in plan.png."""

INFLATED_RGB = (1.0, 0.78, 0.72)
"""Colour of the cells the robot's radius blocks around obstacles."""


def plot_plan(path: str | Path, result: PlanResult) -> Path:
    """Write :func:`plan_canvas` to ``path`` (PNG, about 800 pixels wide)."""
    return plan_canvas(result).save(path)


def plan_canvas(result: PlanResult) -> Canvas:
    """The picture: the map (inflated zone pink, unknown grey), the grid path, replanned
    paths, the smoothed path, the tracked path, the dynamic obstacles (disc, dashed zone the
    robot's centre must keep out of, and the times they are present), the replan / wait
    events, start and goal. The view is the known part of the map, the paths and the
    obstacles, with a margin."""
    from slamcli.planning.canvas import BLACK, BLUE, GREEN, ORANGE, PURPLE, RED, Canvas

    cm = result.costmap
    title = (
        f"grid cost {result.grid_cost_m:.2f} m, smoothed {result.length_m:.2f} m, "
        f"radius {cm.robot_radius_m:g} m (inflated zone shaded)"
    )
    c = Canvas(_view(result), title)
    c.draw_map(cm.grid, _plan_colours(result))
    c.grid_lines()
    c.polyline(result.grid_xy, ORANGE, style="dashed", label="grid path")
    c.polylines(
        [pts for _, pts in result.tracking.paths[1:]],
        PURPLE,
        style="dotted",
        width=2,
        label="replanned" if len(result.tracking.paths) > 1 else None,
    )
    c.polyline(result.smooth_xy, BLUE, width=2, label="smoothed path")
    states = result.tracking.states
    if len(states):
        c.polyline(states[:, 1:3], GREEN, label="tracked")
    for ob in result.obstacles:
        c.circle((ob.x, ob.y), ob.radius, PURPLE, alpha=0.5, label="obstacle")
        c.circle((ob.x, ob.y), ob.radius + cm.robot_radius_m, PURPLE, fill=False, style="dashed")
        until = "" if math.isinf(ob.vanish_s) else f"-{ob.vanish_s:g}"
        # Above the zone, where it hides neither the obstacle nor the path through it.
        above = (ob.radius + cm.robot_radius_m) * c.scale_px_per_m + 9.0
        c.text((ob.x, ob.y), f"{ob.appear_s:g}{until or '+'} s", offset_px=(0.0, -above))
    events = result.tracking.events
    if events:
        exy = np.array([[e["x"], e["y"]] for e in events], dtype=np.float64)
        c.markers(exy, "x", BLACK, size_px=9, label="replan / wait")
    c.markers(result.start_xy, "o", GREEN, size_px=11, label="start")
    c.markers(result.goal_xy, "*", RED, size_px=17, label="goal")
    r, g, b = (round(v * 255.0) for v in INFLATED_RGB)
    c.legend("inflated zone", "patch", (r, g, b))
    return c


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
    the most pixels the view spans on screen. Only the cells in view are coloured, reduced
    in blocks of whole cells (darker wins, so one-cell walls stay) so the image has about one
    pixel per screen pixel, and the image
    is turned by the origin's yaw about the origin (the cell frame of
    :func:`slamcli.planning.costmap.world_to_uv`). Returns the AxesImage, or None when no cell
    is in view.
    """
    from matplotlib.transforms import Affine2D

    from slamcli.planning.canvas import cells_in_view, darkest_blocks

    res = float(grid.resolution_m)
    x0, y0, yaw = (float(v) for v in grid.origin_xy_yaw)
    xmin, xmax, ymin, ymax = view
    window = cells_in_view(grid, view)
    if window is None:
        return None
    r0, r1, c0, c1 = window
    image = np.ascontiguousarray(colours(slice(r0, r1), slice(c0, c1)), dtype=np.uint8)
    block = max(1, round(max(xmax - xmin, ymax - ymin) / res / max_pixels))
    # Darker wins when cells are shrunk, so one-cell walls stay visible.
    image = darkest_blocks(image, block)
    c1 = c0 + image.shape[1] * block
    r1 = r0 + image.shape[0] * block
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
    import cv2

    p = np.asarray(prob[rows, cols], dtype=np.float32)
    grey = np.rint((1.0 - p) * 255.0)  # NaN where unknown
    np.copyto(grey, np.rint(np.float32(unknown_grey) * 255.0), where=np.isnan(p))
    level = grey.astype(np.uint8)
    opaque = np.full(p.shape, 255, dtype=np.uint8)
    return np.asarray(cv2.merge((level, level, level, opaque)), dtype=np.uint8)


def _plan_colours(result: PlanResult) -> Callable[[slice, slice], NDArray[np.uint8]]:
    """Cell colours of plan.png: :func:`occupancy_colours`, inflated cells pink."""
    cm = result.costmap
    pink = np.rint(np.array([*INFLATED_RGB, 1.0]) * 255.0).astype(np.uint8)

    def colours(rows: slice, cols: slice) -> NDArray[np.uint8]:
        out = np.ascontiguousarray(occupancy_colours(cm.grid.prob, rows, cols))
        inflated = cm.blocked[rows, cols] & ~cm.occupied[rows, cols] & ~cm.unknown[rows, cols]
        # Each RGBA pixel as one 32-bit word: one masked copy instead of a gather per channel.
        np.copyto(out.view(np.uint32)[..., 0], pink.view(np.uint32)[0], where=inflated)
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
