"""plan.png for a car-like plan: the map, the path coloured by gear, the footprint along it.

Drawn on matplotlib's Agg canvas without pyplot, in world metres with y up. The map is
resampled to the picture's pixels first (occupied cells kept visible by a max filter), so the
cost does not grow with the map's size.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ExportError
from slamcli.planning.car import CarPlanResult
from slamcli.planning.costmap import world_to_uv
from slamcli.types import OccupancyGrid

PIXELS = 800
"""The picture's map raster is at most this many pixels on its longer side."""


def map_raster(
    grid: OccupancyGrid,
    blocked: NDArray[np.bool_],
    view: tuple[float, float, float, float],
    pixels: int = PIXELS,
) -> NDArray[np.float32]:
    """(rows, cols, 3) RGB of the map over ``view`` = (xmin, xmax, ymin, ymax) metres, row 0
    at ymin: blocked cells dark, free cells white, outside the map light grey. Any pixel that
    covers a blocked cell is dark, however coarse the pixels are."""
    import cv2

    xmin, xmax, ymin, ymax = view
    size = max(xmax - xmin, ymax - ymin) / pixels
    nx = max(1, math.ceil((xmax - xmin) / size))
    ny = max(1, math.ceil((ymax - ymin) / size))
    res = float(grid.resolution_m)
    k = math.ceil(size / res * math.sqrt(2.0))
    mask = np.asarray(
        cv2.dilate(blocked.astype(np.uint8), np.ones((k, k), np.uint8)) if k > 1 else blocked,
        dtype=bool,
    )
    xs = xmin + (np.arange(nx) + 0.5) * size
    ys = ymin + (np.arange(ny) + 0.5) * size
    gx, gy = np.meshgrid(xs, ys)
    uv = world_to_uv(grid, np.stack((gx, gy), axis=-1))
    cols = np.floor(uv[..., 0]).astype(np.int64)
    rows = np.floor(uv[..., 1]).astype(np.int64)
    h, w = mask.shape
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    rgb = np.full((ny, nx, 3), 0.85, dtype=np.float32)
    hit = mask[np.clip(rows, 0, h - 1), np.clip(cols, 0, w - 1)]
    rgb[inside & ~hit] = 1.0
    rgb[inside & hit] = 0.15
    return rgb


def _view(result: CarPlanResult, margin_m: float) -> tuple[float, float, float, float]:
    pts = np.vstack(
        (result.poses[:, :2], np.asarray([result.start[:2], result.goal[:2]], dtype=np.float64))
    )
    lo = pts.min(axis=0) - margin_m
    hi = pts.max(axis=0) + margin_m
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def plot_car_plan(path: str | Path, result: CarPlanResult) -> Path:
    """Write the picture to ``path`` (PNG)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    fp = result.settings.footprint
    view = _view(result, max(2.0 * fp.circumradius_m, 1.0))
    fig = Figure(figsize=(8, 8), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    ax.imshow(
        map_raster(result.grid, result.blocked, view),
        origin="lower",
        extent=view,
        interpolation="nearest",
    )
    # Footprints about every circumradius along the path, and at start and goal.
    seg = np.hypot(*np.diff(result.poses[:, :2], axis=0).T)
    s = np.concatenate(([0.0], np.cumsum(seg)))
    marks = np.searchsorted(s, np.arange(0.0, s[-1], 2.0 * fp.circumradius_m))
    idx = np.unique(np.concatenate((marks, [len(s) - 1])))
    outlines = []
    for x, y, yaw in result.poses[idx]:
        c, si = math.cos(yaw), math.sin(yaw)
        v = fp.vertices
        ring = np.vstack((v, v[:1]))
        outlines.append(
            np.column_stack(
                (x + c * ring[:, 0] - si * ring[:, 1], y + si * ring[:, 0] + c * ring[:, 1])
            )
        )
    ax.add_collection(LineCollection(outlines, colors="0.45", linewidths=0.6))
    lines = np.stack((result.poses[:-1, :2], result.poses[1:, :2]), axis=1)
    colours = np.where(result.direction[:-1] > 0, "tab:blue", "tab:red")
    ax.add_collection(LineCollection(list(lines), colors=colours, linewidths=1.8))
    ax.plot([], [], color="tab:blue", label="forward")
    ax.plot([], [], color="tab:red", label="reverse")
    states = result.tracking.states
    if len(states):
        ax.plot(states[:, 1], states[:, 2], color="tab:green", lw=0.8, ls="--", label="tracked")
    arrow = 1.5 * fp.circumradius_m
    for (x, y, yaw), colour, label in (
        (result.start, "tab:green", "start"),
        (result.goal, "tab:red", "goal"),
    ):
        ax.annotate(
            "",
            (x + arrow * math.cos(yaw), y + arrow * math.sin(yaw)),
            (x, y),
            arrowprops={"arrowstyle": "->", "color": colour, "lw": 2},
        )
        ax.plot(x, y, "o", color=colour, ms=6, label=label)
    ax.set_xlim(view[0], view[1])
    ax.set_ylim(view[2], view[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(
        f"{result.length_m:.2f} m, gear changes {result.reversals}, min clearance "
        f"{result.min_clearance_m:.3f} m, turn radius {result.settings.min_turn_radius_m:g} m"
    )
    ax.legend(loc="upper right", fontsize="small")
    ax.grid(alpha=0.25)
    try:
        fig.savefig(path, format="png", dpi=100)
    except OSError as exc:
        raise ExportError(f"{path}: cannot write the plot ({exc.strerror})") from exc
    return Path(path)
