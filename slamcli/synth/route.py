"""A closed route through a map's free space, timed for a robot to drive (module docstring of
:mod:`slamcli.synth.lidar`, "Route" and "Driving")."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, MapError
from slamcli.planning.costmap import Costmap, build_costmap, uv_to_world, world_to_uv
from slamcli.planning.trajectory import Limits, SpeedProfile
from slamcli.types import OccupancyGrid

F64 = NDArray[np.float64]

YAW_RATE_RADPS = 1.0
"""Fastest turn of the route's timing (before the stretch to the scan count), rad/s."""
ACCEL_MPS2 = 0.5
"""Acceleration of the route's timing when starting and stopping, m/s^2."""
LEG_M = (2.0, 15.0)
"""Grid-path length from one waypoint to the next, metres (shorter for short routes)."""
REVISIT_RADIUS_M = 1.0
"""A pose revisits a place when it is this close to a pose driven well before it."""
REVISIT_GAP_M = 10.0
"""How far before, at most (see :func:`revisit_gap`), metres."""


@dataclass(frozen=True)
class Route:
    """A closed route through free space, timed.

    Attributes:
        waypoints: (K, 2) world positions, m: the start, the waypoints, the start again.
        xy: (M, 2) the driven polyline, m, from the start back to it.
        profile: its timing at the asked speed (before the stretch to the scan count).
        free: (H, W) bool cells the robot's centre may be in (the route touches no other).
        clearance: the clearance asked, m.
    """

    waypoints: F64
    xy: F64
    profile: SpeedProfile
    free: NDArray[np.bool_]
    clearance: float

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.diff(self.xy, axis=0), axis=1).sum())


def free_space(grid: OccupancyGrid, clearance_m: float) -> tuple[Costmap, NDArray[np.bool_]]:
    """The route's free cells (module docstring): a costmap of the map with unknown cells as
    obstacles, and (H, W) bool blocked cells, the map's edge zone included."""
    if not (math.isfinite(clearance_m) and clearance_m >= 0):
        raise ConfigError(f"--clearance: expected a distance >= 0 m, got {clearance_m}")
    prob = np.asarray(grid.prob, dtype=np.float32)
    solid = OccupancyGrid(
        np.where(np.isnan(prob), np.float32(1.0), prob), grid.resolution_m, grid.origin_xy_yaw
    )
    res = float(grid.resolution_m)
    radius = clearance_m + math.sqrt(2.0) * res
    costmap = build_costmap(solid, radius)
    h, w = prob.shape
    edge_u = np.minimum(np.arange(w) + 0.5, w - np.arange(w) - 0.5) * res <= radius
    edge_v = np.minimum(np.arange(h) + 0.5, h - np.arange(h) - 0.5) * res <= radius
    blocked = costmap.blocked | edge_u[None, :] | edge_v[:, None]
    return replace(costmap, blocked=blocked), blocked


def plan_route(
    grid: OccupancyGrid,
    length_m: float,
    rng: np.random.Generator,
    *,
    clearance_m: float = 0.4,
    speed_mps: float = 0.5,
    duration_s: float | None = None,
) -> Route:
    """A closed route through free space about ``length_m`` long (module docstring).

    With ``duration_s`` the last waypoint is picked again (twice at most) so that the route's
    timing at ``speed_mps`` comes as close to it as the map allows.

    Raises:
        MapError: no free space with that clearance.
    """
    from scipy import ndimage

    costmap, blocked = free_space(grid, clearance_m)
    labels, count = ndimage.label(~blocked)
    if count == 0:
        raise MapError(
            f"the map has no free cell more than {clearance_m:g} m from obstacles, unknown "
            "cells and its edge",
            hint="lower --clearance, or check the map's occupied and free thresholds",
        )
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    region = labels == int(np.argmax(sizes))
    rows = np.flatnonzero(region.any(axis=1))
    cols = np.flatnonzero(region.any(axis=0))
    r0, c0 = int(rows[0]), int(cols[0])
    box = region[r0 : int(rows[-1]) + 1, c0 : int(cols[-1]) + 1]
    planner = _LegPlanner(costmap, blocked, ~box, (r0, c0))
    cells = np.argwhere(box)
    if len(cells) < 2:
        raise MapError(
            f"the largest free region {clearance_m:g} m from obstacles is a single cell",
            hint="lower --clearance",
        )
    start = tuple(int(v) for v in cells[rng.integers(len(cells))])
    waypoints, fields = _pick_waypoints(planner, (start[0], start[1]), length_m, rng)
    limits = Limits(max_speed=speed_mps, max_yaw_rate=YAW_RATE_RADPS, max_accel=ACCEL_MPS2)
    route = planner.route(waypoints, limits)
    if duration_s is not None and len(waypoints) >= 3:
        # Refit the last waypoint to the timing: turns and starts cost time, smoothing length.
        target = length_m
        for _ in range(2):
            error = duration_s - route.profile.duration_s
            if abs(error) * speed_mps < 0.5 * planner.res:
                break
            target += error * speed_mps
            last = _closest_total(fields, target)
            if last is None:
                break
            other = planner.route([*waypoints[:-2], last, waypoints[-1]], limits)
            if abs(other.profile.duration_s - duration_s) < abs(error):
                route, waypoints = other, [*waypoints[:-2], last, waypoints[-1]]
    return replace(route, clearance=clearance_m)


class _LegPlanner:
    """Shortest paths and distance fields within one free region (cells of a bounding box)."""

    def __init__(
        self,
        costmap: Costmap,
        blocked: NDArray[np.bool_],
        box_blocked: NDArray[np.bool_],
        offset: tuple[int, int],
    ) -> None:
        from slamcli.planning.search import grid_graph

        self.costmap = costmap
        self.blocked = blocked
        self.box_blocked = box_blocked
        self.offset = offset
        self.res = float(costmap.grid.resolution_m)
        self.graph = grid_graph(box_blocked, self.res)

    def field(self, cell: tuple[int, int]) -> F64:
        """(h, w) grid-path lengths (m) from a box cell to every box cell; inf if unreachable."""
        from scipy.sparse.csgraph import dijkstra

        h, w = self.box_blocked.shape
        dist = dijkstra(self.graph, indices=cell[0] * w + cell[1])
        return np.asarray(dist, dtype=np.float64).reshape(h, w)

    def leg(self, a: tuple[int, int], b: tuple[int, int]) -> F64:
        """The smoothed leg between two box cells' centres, (M, 2) world m."""
        from slamcli.planning.planner import cell_centres, smooth_path
        from slamcli.planning.search import grid_search

        found = grid_search(self.box_blocked, a, b, resolution_m=self.res)
        cells = found.cells + np.asarray(self.offset, dtype=np.int64)
        ends = cell_centres(self.costmap.grid, cells[[0, -1]])
        start = (float(ends[0, 0]), float(ends[0, 1]))
        goal = (float(ends[1, 0]), float(ends[1, 1]))
        return smooth_path(self.costmap, self.blocked, cells, start, goal)

    def route(self, waypoints: list[tuple[int, int]], limits: Limits) -> Route:
        """The legs through box cells ``waypoints``, joints rounded, and their timing."""
        from slamcli.planning.planner import cell_centres
        from slamcli.planning.smooth import SegmentChecker, round_corners
        from slamcli.planning.trajectory import time_parameterise

        legs = [self.leg(a, b) for a, b in itertools.pairwise(waypoints)]
        xy = np.concatenate([legs[0]] + [leg[1:] for leg in legs[1:]])
        grid = self.costmap.grid
        uv = round_corners(
            world_to_uv(grid, xy), SegmentChecker(self.blocked), max_cut=0.5 / self.res
        )
        xy = uv_to_world(grid, uv)
        keep = np.concatenate(([True], np.linalg.norm(np.diff(xy, axis=0), axis=1) > 1e-9))
        xy = xy[keep]
        cells = np.asarray(waypoints, dtype=np.int64) + np.asarray(self.offset, dtype=np.int64)
        return Route(
            waypoints=cell_centres(grid, cells),
            xy=xy,
            profile=time_parameterise(xy, limits),
            free=~self.blocked,
            clearance=0.0,
        )


@dataclass(frozen=True)
class _Fields:
    """What refitting the last waypoint needs: the route's length before it (m), grid-path
    lengths from the waypoint before it and from the start, and which cells may be it."""

    length: float
    from_last: F64
    from_start: F64
    allowed: NDArray[np.bool_]


def _closest_total(fields: _Fields, target: float) -> tuple[int, int] | None:
    """The allowed cell whose route total comes closest to ``target`` m (first in row order)."""
    total = fields.length + fields.from_last + fields.from_start
    score = np.where(fields.allowed, np.abs(total - target), np.inf)
    k = int(np.argmin(score))
    if not np.isfinite(score.flat[k]):
        return None
    r, c = np.unravel_index(k, score.shape)
    return int(r), int(c)


def _pick_waypoints(
    planner: _LegPlanner, start: tuple[int, int], length_m: float, rng: np.random.Generator
) -> tuple[list[tuple[int, int]], _Fields]:
    """Box cells start, waypoints..., start whose grid-path tour is about ``length_m`` long."""
    from_start = planner.field(start)
    min_leg = min(LEG_M[0], length_m / 4)
    tol = max(2 * planner.res, 0.02 * length_m)
    waypoints = [start]
    length = 0.0
    while True:
        here = waypoints[-1]
        from_here = planner.field(here)
        total = length + from_here + from_start
        legal = np.isfinite(from_here) & (from_here > 0)
        in_range = legal & (from_here >= min_leg) & (from_here <= LEG_M[1])
        finish = in_range & (np.abs(total - length_m) <= tol)
        fields = _Fields(length, from_here, from_start, in_range if in_range.any() else legal)
        onward = in_range & (total < length_m - tol)
        # Two waypoints at least, where they fit: one alone is driven out and back.
        if (finish.any() and len(waypoints) > 1) or not onward.any():
            if finish.any():
                last = _draw(finish, rng)
            else:
                closest = _closest_total(fields, length_m)
                if closest is None:
                    raise MapError(
                        "the largest free region has no second cell to drive to",
                        hint="lower --clearance",
                    )
                last = closest
            return [*waypoints, last, start], fields
        nxt = _draw(onward, rng)
        length += float(from_here[nxt])
        waypoints.append(nxt)


def _draw(mask: NDArray[np.bool_], rng: np.random.Generator) -> tuple[int, int]:
    cells = np.argwhere(mask)
    r, c = cells[rng.integers(len(cells))]
    return int(r), int(c)


def drive(route: Route, scans: int, rate_hz: float) -> tuple[F64, float]:
    """Body poses (scans, 3) at ``scans`` instants one period apart along the route, its
    timing stretched to fit them exactly; and the stretch (driven speed / asked speed)."""
    duration = route.profile.duration_s
    if duration <= 0:
        raise MapError("the route has no length: the free region is too small to drive in")
    span = (scans - 1) / rate_hz
    samples = route.profile.sample(np.linspace(0.0, duration, scans))
    return samples[:, 1:4].copy(), duration / span


def revisit_gap(path_length_m: float) -> float:
    """Driving (m) that must lie between two passes of a place for the second to count as a
    revisit: :data:`REVISIT_GAP_M`, or half the route when that is shorter."""
    return min(REVISIT_GAP_M, path_length_m / 2)


def revisits(poses: F64) -> list[dict[str, Any]]:
    """Where the route comes back to a place it passed: runs of consecutive poses (N, 3) each
    within :data:`REVISIT_RADIUS_M` of a pose driven :func:`revisit_gap` metres or more
    before. Per run, the pose closest to such an earlier pose: ``scan`` and ``earlier_scan``
    (indices) and ``distance_m``."""
    from scipy.spatial import cKDTree

    xy = poses[:, :2]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    gap = revisit_gap(float(s[-1]))
    if gap <= 0:
        return []
    best: list[tuple[float, int, int]] = []
    for i, near in enumerate(cKDTree(xy).query_ball_point(xy, REVISIT_RADIUS_M)):
        earlier = np.asarray([j for j in near if s[i] - s[j] >= gap], dtype=np.int64)
        best.append((math.inf, i, -1))
        if earlier.size:
            d = np.linalg.norm(xy[earlier] - xy[i], axis=1)
            best[-1] = (float(d.min()), i, int(earlier[int(np.argmin(d))]))
    events: list[dict[str, Any]] = []
    for found, run in itertools.groupby(best, key=lambda b: math.isfinite(b[0])):
        if found:
            d, i, j = min(run)
            events.append({"scan": i, "earlier_scan": j, "distance_m": round(d, 6)})
    return events
