"""plan.png for a car-like plan: the map, the path coloured by gear, the footprint along it.

Drawn with OpenCV on a :class:`slamcli.planning.canvas.Canvas`, in world metres with y up. The
map is reduced to the picture's pixels with darker colours winning, so blocked cells stay
visible however coarse the pixels are, and its cost does not grow with the map's size.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from slamcli.planning.car import CarPlanResult

if TYPE_CHECKING:
    from slamcli.planning.canvas import Canvas

BLOCKED_GREY = 38
"""Grey level (0..255) of blocked cells; free cells are white, outside the map light grey."""

OUTSIDE_GREY = 217

FOOTPRINT_GREY = 115


def _view(result: CarPlanResult, margin_m: float) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax): the path, start and goal, plus ``margin_m`` metres."""
    pts = np.vstack(
        (result.poses[:, :2], np.asarray([result.start[:2], result.goal[:2]], dtype=np.float64))
    )
    lo = pts.min(axis=0) - margin_m
    hi = pts.max(axis=0) + margin_m
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def _blocked_colours(blocked: NDArray[np.bool_]) -> Callable[[slice, slice], NDArray[np.uint8]]:
    """Cell colours: blocked dark grey, free white."""
    lut = np.array([255, BLOCKED_GREY], dtype=np.uint8)

    def colours(rows: slice, cols: slice) -> NDArray[np.uint8]:
        grey = lut[blocked[rows, cols].view(np.uint8)]
        return np.repeat(grey[..., None], 3, axis=2)

    return colours


def _footprints(result: CarPlanResult) -> list[NDArray[np.float64]]:
    """The footprint's outline (K, 2) metres about every two circumradii along the path, and
    at its end."""
    fp = result.settings.footprint
    seg = np.hypot(*np.diff(result.poses[:, :2], axis=0).T)
    s = np.concatenate(([0.0], np.cumsum(seg)))
    marks = np.searchsorted(s, np.arange(0.0, s[-1], 2.0 * fp.circumradius_m))
    idx = np.unique(np.concatenate((marks, [len(s) - 1])))
    v = fp.vertices
    outlines = []
    for x, y, yaw in result.poses[idx]:
        c, si = math.cos(yaw), math.sin(yaw)
        outlines.append(
            np.column_stack((x + c * v[:, 0] - si * v[:, 1], y + si * v[:, 0] + c * v[:, 1]))
        )
    return outlines


def car_plan_canvas(result: CarPlanResult) -> Canvas:
    """The picture: the map around the path, the footprints along it, the path blue forward
    and red in reverse, the tracked path, and start and goal with arrows along their
    headings."""
    from slamcli.planning.canvas import BLUE, GREEN, RED, Canvas

    fp = result.settings.footprint
    title = (
        f"{result.length_m:.2f} m, gear changes {result.reversals}, min clearance "
        f"{result.min_clearance_m:.3f} m, turn radius {result.settings.min_turn_radius_m:g} m"
    )
    grey = (OUTSIDE_GREY, OUTSIDE_GREY, OUTSIDE_GREY)
    c = Canvas(_view(result, max(2.0 * fp.circumradius_m, 1.0)), title, background=grey)
    c.draw_map(result.grid, _blocked_colours(result.blocked))
    c.grid_lines()
    footprint = (FOOTPRINT_GREY, FOOTPRINT_GREY, FOOTPRINT_GREY)
    c.polylines(_footprints(result), footprint, closed=True, label="footprint")
    # One line per run of one gear, each sharing its end pose with the next run's start.
    gear = result.direction[:-1]
    cuts = np.flatnonzero(np.diff(gear)) + 1
    bounds = np.concatenate(([0], cuts, [len(gear)])) if len(gear) else np.zeros(1, int)
    runs: dict[bool, list[NDArray[np.float64]]] = {True: [], False: []}
    for a, b in itertools.pairwise(bounds):
        runs[bool(gear[a] > 0)].append(result.poses[a : b + 1, :2])
    c.polylines(runs[True], BLUE, width=2)
    c.polylines(runs[False], RED, width=2)
    c.legend("forward", "line", BLUE, width=2)
    c.legend("reverse", "line", RED, width=2)
    states = result.tracking.states
    if len(states):
        c.polyline(states[:, 1:3], GREEN, style="dashed", label="tracked")
    arrow = 1.5 * fp.circumradius_m
    for (x, y, yaw), colour, label in (
        (result.start, GREEN, "start"),
        (result.goal, RED, "goal"),
    ):
        c.arrow((x, y), (x + arrow * math.cos(yaw), y + arrow * math.sin(yaw)), colour)
        c.markers((x, y), "o", colour, size_px=9, label=label)
    return c


def plot_car_plan(path: str | Path, result: CarPlanResult) -> Path:
    """Write :func:`car_plan_canvas` to ``path`` (PNG, about 800 pixels wide)."""
    return car_plan_canvas(result).save(path)
