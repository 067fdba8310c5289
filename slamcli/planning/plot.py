"""plan.png: the map with the inflated zone, the paths, start, goal and dynamic obstacles.

Drawn on matplotlib's Agg canvas without pyplot (as :mod:`slamcli.report`), in world
metres with y up.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from slamcli.errors import ExportError
from slamcli.planning.planner import PlanResult


def plot_plan(path: str | Path, result: PlanResult) -> Path:
    """Write the picture to ``path`` (PNG). The view is cropped to the known part of the map,
    the paths and the obstacles, with a margin."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle
    from matplotlib.transforms import Affine2D

    cm = result.costmap
    grid = cm.grid
    h, w = cm.shape
    res = cm.resolution_m
    x0, y0, yaw = (float(v) for v in grid.origin_xy_yaw)

    rgba = np.ones((h, w, 4), dtype=np.float32)
    known = ~cm.unknown
    grey = np.where(known, 1.0 - np.nan_to_num(np.asarray(grid.prob, dtype=np.float32)), 0.8)
    rgba[..., :3] = grey[..., None]
    inflated = cm.blocked & ~cm.occupied & known
    rgba[inflated] = (1.0, 0.78, 0.72, 1.0)

    fig = Figure(figsize=(8, 8), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    image = ax.imshow(
        rgba, origin="lower", extent=(x0, x0 + w * res, y0, y0 + h * res), interpolation="nearest"
    )
    if yaw:
        image.set_transform(Affine2D().rotate_around(x0, y0, yaw) + ax.transData)

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

    ax.set_xlim(*_view(result)[:2])
    ax.set_ylim(*_view(result)[2:])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(
        f"grid cost {result.grid_cost_m:.2f} m, smoothed {result.length_m:.2f} m, "
        f"radius {cm.robot_radius_m:g} m (inflated zone shaded)"
    )
    ax.legend(loc="best", fontsize="small")
    ax.grid(alpha=0.25)
    try:
        fig.savefig(path, format="png", dpi=100)
    except OSError as exc:
        raise ExportError(f"{path}: cannot write the plot ({exc.strerror})") from exc
    return Path(path)


def _view(result: PlanResult) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax): the known cells, paths and obstacles, plus a margin."""
    from slamcli.planning.planner import cell_centres

    cm = result.costmap
    known = np.argwhere(~cm.unknown)
    pts = [result.smooth_xy, result.grid_xy, np.array([result.start_xy, result.goal_xy])]
    if len(known):
        corners = np.array([known.min(axis=0), known.max(axis=0)])
        pts.append(cell_centres(cm.grid, corners))
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
