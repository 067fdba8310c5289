"""``plan()``: from a map, a start and a goal to a smoothed, timed and tracked path.

Steps: free space (:mod:`~slamcli.planning.costmap`), exact grid search
(:mod:`~slamcli.planning.search`), shortcutting and corner rounding
(:mod:`~slamcli.planning.smooth`), a speed profile (:mod:`~slamcli.planning.trajectory`) and
a pure-pursuit simulation with replanning around dynamic obstacles
(:mod:`~slamcli.planning.tracker`). The smoothed path runs from the exact start point to the
exact goal point; the grid path from the centre of the start's cell to the centre of the
goal's cell.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import InputError, MapError, NoPathError
from slamcli.planning.costmap import (
    CENTRING_RADIUS_M,
    COST_SCALING_PER_M,
    INFLATION_RADIUS_M,
    OCCUPIED_THRESH,
    TIE_TOL_M,
    Costmap,
    build_costmap,
    check_positive,
    disc_mask,
    distance_at,
    map_bounds,
    nearest_free_cell,
    uv_to_world,
    world_to_uv,
)
from slamcli.planning.obstacles import DynamicObstacle
from slamcli.planning.search import SearchResult, grid_search, load_kernels
from slamcli.planning.smooth import (
    SegmentChecker,
    densify,
    polyline_length,
    round_corners,
    shortcut,
)
from slamcli.planning.tracker import TrackerSettings, TrackingResult, simulate
from slamcli.planning.trajectory import Limits, SpeedProfile, time_parameterise
from slamcli.types import OccupancyGrid

RUN_MAP_NAME = "map.yaml"
"""The map file inside a run folder (written by ``slamcli map build``)."""


@dataclass
class PlanResult:
    """Everything one ``plan()`` produced; positions in the map's world frame (m).

    Attributes:
        start_xy, goal_xy: as asked.
        start_cell, goal_cell: (row, col) of the cells containing them.
        costmap: blocked cells and clearance cost used.
        search: the grid search's result (``cells`` (K, 2) row/col, ``cost_m``, ``expanded``).
        grid_xy: (K, 2) float64 centres of the grid path's cells.
        smooth_xy: (M, 2) float64 the smoothed path, start point to goal point.
        length_m: length of ``smooth_xy``.
        min_clearance_m: least distance from ``smooth_xy`` to an occupied cell centre (inf when
            the map has none).
        profile: the speed profile along ``smooth_xy``.
        trajectory: (N, 6) float64 ``t, x, y, theta, v, omega`` every ``dt_s``.
        tracking: the simulated robot's run.
        obstacles: the dynamic obstacles simulated.
        plan_ms: wall time from map to trajectory (costmap, search, smoothing, speed profile).
        timings_ms: wall time per stage, ms: ``costmap``, ``search``, ``smooth``,
            ``trajectory``, ``simulate``, ``clearance``.
        settings: every parameter, for plan.json.
    """

    start_xy: tuple[float, float]
    goal_xy: tuple[float, float]
    start_cell: tuple[int, int]
    goal_cell: tuple[int, int]
    costmap: Costmap
    search: SearchResult
    grid_xy: NDArray[np.float64]
    smooth_xy: NDArray[np.float64]
    length_m: float
    min_clearance_m: float
    profile: SpeedProfile
    trajectory: NDArray[np.float64]
    tracking: TrackingResult
    obstacles: tuple[DynamicObstacle, ...]
    plan_ms: float
    timings_ms: dict[str, float] = field(default_factory=dict)
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def grid_cost_m(self) -> float:
        return float(self.search.cost_m)


def resolve_map_path(path: str | Path) -> Path:
    """A map file, or a run folder's map.yaml; InputError when neither exists."""
    p = Path(path)
    if p.is_dir():
        inner = p / RUN_MAP_NAME
        if not inner.is_file():
            raise InputError(
                f"{p}: a folder without {RUN_MAP_NAME}",
                hint="pass a map .yaml/.npz file, or a run folder written by 'slamcli map build'",
            )
        return inner
    if not p.exists():
        raise InputError(f"{p}: no such map file or run folder")
    return p


def load_map(path: str | Path) -> tuple[OccupancyGrid, Path]:
    """Read a map (.yaml map_server map, .npz, or a run folder with map.yaml)."""
    from slamcli.formats.occupancy import read_map

    file = resolve_map_path(path)
    return read_map(file), file


def plan(
    grid: OccupancyGrid,
    start_xy: tuple[float, float],
    goal_xy: tuple[float, float],
    *,
    robot_radius_m: float = 0.2,
    unknown_policy: str = "blocked",
    clearance_weight: float = 0.0,
    limits: Limits | None = None,
    obstacles: Sequence[DynamicObstacle] = (),
    dt_s: float = 0.1,
    cost_scaling_per_m: float = COST_SCALING_PER_M,
    inflation_radius_m: float = INFLATION_RADIUS_M,
    tracker: TrackerSettings | None = None,
    cost_penalty: float = 0.0,
    centring_radius_m: float = CENTRING_RADIUS_M,
) -> PlanResult:
    """Plan, smooth, time and track a path from ``start_xy`` to ``goal_xy`` (world, m).

    ``unknown_policy`` is ``"blocked"`` (unknown cells are obstacles) or ``"free"``.
    ``cost_penalty`` > 0 adds the centring cost (:func:`~slamcli.planning.costmap.
    centring_cost` over ``centring_radius_m``) to the clearance cost.
    Raises MapError when start or goal is outside the map or not in free space (the message
    names the nearest free cell), NoPathError when the goal cannot be reached (with the number
    of cells reachable from the start) or a dynamic obstacle that never vanishes blocks the
    only way, ConfigError for a bad setting.
    """
    limits = (limits or Limits()).checked()
    check_positive("dt_s", dt_s)
    tracker = tracker or TrackerSettings()
    timings: dict[str, float] = {}
    tk = time.perf_counter()
    load_kernels()
    timings["kernels"] = _ms_since(tk)
    t0 = time.perf_counter()
    costmap = build_costmap(
        grid,
        robot_radius_m,
        unknown_policy=unknown_policy,
        clearance_weight=clearance_weight,
        cost_scaling_per_m=cost_scaling_per_m,
        inflation_radius_m=inflation_radius_m,
        cost_penalty=cost_penalty,
        centring_radius_m=centring_radius_m,
    )
    timings["costmap"] = _ms_since(t0)
    start = (float(start_xy[0]), float(start_xy[1]))
    goal = (float(goal_xy[0]), float(goal_xy[1]))
    start_cell = _free_cell_at(costmap, start, "start")
    goal_cell = _free_cell_at(costmap, goal, "goal")

    t1 = time.perf_counter()
    search = _search(costmap, costmap.blocked, start_cell, goal_cell)
    timings["search"] = _ms_since(t1)
    t2 = time.perf_counter()
    smooth_xy = smooth_path(costmap, costmap.blocked, search.cells, start, goal)
    timings["smooth"] = _ms_since(t2)
    t3 = time.perf_counter()
    profile = time_parameterise(smooth_xy, limits)
    trajectory = profile.sample_every(dt_s)[:, :6]
    timings["trajectory"] = _ms_since(t3)
    plan_ms = _ms_since(t0)

    t4 = time.perf_counter()
    obstacles = tuple(obstacles)

    def replan(
        xy: NDArray[np.float64], v: float, present: Sequence[DynamicObstacle]
    ) -> SpeedProfile:
        return _replan(costmap, goal, goal_cell, limits, xy, v, present)

    tracking = simulate(
        profile,
        limits,
        robot_radius_m=costmap.robot_radius_m,
        obstacles=obstacles,
        replan=replan,
        settings=tracker,
    )
    timings["simulate"] = _ms_since(t4)
    t5 = time.perf_counter()
    clearance = min_clearance(costmap, smooth_xy)
    timings["clearance"] = _ms_since(t5)

    settings = {
        "robot_radius_m": costmap.robot_radius_m,
        "unknown": costmap.unknown_policy,
        "occupied_thresh": OCCUPIED_THRESH,
        "clearance_weight": float(clearance_weight),
        "cost_scaling_per_m": float(cost_scaling_per_m),
        "inflation_radius_m": float(inflation_radius_m),
        "cost_penalty": float(cost_penalty),
        "centring_radius_m": float(centring_radius_m),
        "max_speed": limits.max_speed,
        "max_yaw_rate": limits.max_yaw_rate,
        "max_accel": limits.max_accel,
        "dt_s": dt_s,
        "tracker": {k: getattr(tracker, k) for k in tracker.__dataclass_fields__},
    }
    return PlanResult(
        start_xy=start,
        goal_xy=goal,
        start_cell=start_cell,
        goal_cell=goal_cell,
        costmap=costmap,
        search=search,
        grid_xy=cell_centres(grid, search.cells),
        smooth_xy=smooth_xy,
        length_m=polyline_length(smooth_xy),
        min_clearance_m=clearance,
        profile=profile,
        trajectory=trajectory,
        tracking=tracking,
        obstacles=obstacles,
        plan_ms=plan_ms,
        timings_ms=timings,
        settings=settings,
    )


def cell_centres(grid: OccupancyGrid, cells: NDArray[np.int64]) -> NDArray[np.float64]:
    """(K, 2) (row, col) -> (K, 2) world centres of those cells, metres."""
    from slamcli.formats.occupancy import cell_to_world

    return cell_to_world(grid, np.asarray(cells).reshape(-1, 2))


def cell_of(grid: OccupancyGrid, xy: tuple[float, float]) -> tuple[int, int] | None:
    """(row, col) of the cell containing a world point; None outside the map."""
    from slamcli.formats.occupancy import world_to_cell

    r, c = (int(i) for i in world_to_cell(grid, xy))
    h, w = np.asarray(grid.prob).shape
    return (r, c) if 0 <= r < h and 0 <= c < w else None


def smooth_path(
    costmap: Costmap,
    blocked: NDArray[np.bool_],
    cells: NDArray[np.int64],
    start_xy: tuple[float, float] | NDArray[np.float64],
    goal_xy: tuple[float, float],
) -> NDArray[np.float64]:
    """The grid path shortcut and rounded, from ``start_xy`` to ``goal_xy`` (world, m).

    An end point joins the path only if the segment to its cell's centre is free (always,
    unless the point lies on the edge of a blocked neighbour); otherwise the path ends at the
    centre.
    """
    grid = costmap.grid
    checker = SegmentChecker(blocked)
    uv = densify(cells, checker)
    s_uv = world_to_uv(grid, start_xy)
    g_uv = world_to_uv(grid, goal_xy)
    parts = [uv]
    if checker.free(s_uv[None], uv[:1])[0]:
        parts.insert(0, s_uv[None])
    if checker.free(uv[-1:], g_uv[None])[0]:
        parts.append(g_uv[None])
    pts = np.concatenate(parts)
    keep = np.concatenate(([True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-12))
    pts = shortcut(pts[keep], checker, costmap.extra_cost)
    # Corners are cut by at most 0.5 m per side, so the path keeps the shortcut's shape.
    pts = round_corners(pts, checker, max_cut=0.5 / costmap.resolution_m)
    return uv_to_world(grid, pts)


def min_clearance(costmap: Costmap, path_xy: NDArray[np.float64]) -> float:
    """Exact least distance (m) from a polyline (P, 2) (world, m) to the centre of an occupied
    cell; ``inf`` when the map has none.

    Only the occupied cells near the path are measured: those within ``r`` cells of it, with
    ``r`` doubling from the robot radius plus two cells until the nearest of them lies within
    ``r`` (no cell farther out can then be nearer).
    """
    occupied = costmap.occupied
    if not occupied.any():
        return math.inf
    grid = costmap.grid
    res = costmap.resolution_m
    pts = np.asarray(path_xy, dtype=np.float64).reshape(-1, 2)
    samples = _every_cell(world_to_uv(grid, pts))
    h, w = occupied.shape
    r = costmap.robot_radius_m / res + 2.0
    while True:
        half = math.ceil(r) + 2
        cells = _cells_near(occupied, samples, half)
        best = _polyline_distance(cell_centres(grid, cells), pts) if len(cells) else math.inf
        if best <= r * res or half >= max(h, w):
            return best
        r *= 2.0


def _every_cell(uv: NDArray[np.float64]) -> NDArray[np.float64]:
    """Points along a polyline (P, 2) in grid coordinates at most one cell apart, ends
    included."""
    if len(uv) < 2:
        return uv
    d = np.diff(uv, axis=0)
    n = np.maximum(np.ceil(np.sqrt((d**2).sum(axis=1))), 1).astype(np.int64)
    seg = np.repeat(np.arange(len(d)), n)
    t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / n[seg]
    return np.concatenate((uv[seg] + t[:, None] * d[seg], uv[-1:]))


def _cells_near(
    mask: NDArray[np.bool_], samples_uv: NDArray[np.float64], half: int
) -> NDArray[np.int64]:
    """(K, 2) (row, col) of the set cells of ``mask`` within ``half`` cells (Chebyshev) of
    the cell of any sample point."""
    import cv2

    h, w = mask.shape
    rows = np.clip(np.floor(samples_uv[:, 1]).astype(np.int64), 0, h - 1)
    cols = np.clip(np.floor(samples_uv[:, 0]).astype(np.int64), 0, w - 1)
    r0, r1 = max(int(rows.min()) - half, 0), min(int(rows.max()) + half + 1, h)
    c0, c1 = max(int(cols.min()) - half, 0), min(int(cols.max()) + half + 1, w)
    seeds = np.zeros((r1 - r0, c1 - c0), dtype=np.uint8)
    seeds[rows - r0, cols - c0] = 1
    kernel = np.ones((2 * half + 1, 2 * half + 1), dtype=np.uint8)
    near = cv2.dilate(seeds, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    found = np.argwhere(near.view(np.bool_) & mask[r0:r1, c0:c1])
    return found + np.array([r0, c0])


def _polyline_distance(points: NDArray[np.float64], poly: NDArray[np.float64]) -> float:
    """Least distance from any of ``points`` (K, 2) to a polyline (P, 2), same units."""
    if len(poly) == 1:
        return float(np.linalg.norm(points - poly[0], axis=1).min())
    a, b = poly[:-1], poly[1:]
    ab = b - a
    l2 = np.maximum((ab**2).sum(axis=1), 1e-300)
    best = math.inf
    step = max(1, (1 << 20) // len(a))
    for k in range(0, len(points), step):
        cand = points[k : k + step]
        t = np.clip(((cand[:, None, :] - a[None]) * ab[None]).sum(axis=2) / l2[None], 0.0, 1.0)
        foot = a[None] + t[..., None] * ab[None]
        best = min(best, float(np.linalg.norm(cand[:, None, :] - foot, axis=2).min()))
    return best


def _ms_since(t: float) -> float:
    return round((time.perf_counter() - t) * 1000.0, 3)


def _free_cell_at(costmap: Costmap, xy: tuple[float, float], name: str) -> tuple[int, int]:
    """The cell of ``xy``; MapError when it is outside the map or not free."""
    grid = costmap.grid
    flag = f"--{name}"
    where = f"{name} ({xy[0]:g}, {xy[1]:g})"
    if not all(math.isfinite(c) for c in xy):
        raise MapError(f"{where}: coordinates must be finite numbers")
    cell = cell_of(grid, xy)
    if cell is None:
        x0, x1, y0, y1 = map_bounds(grid)
        raise MapError(
            f"{where} is outside the map, which covers x {x0:g} .. {x1:g} m, y {y0:g} .. {y1:g} m",
            hint=f"pick a {flag} inside those bounds",
        )
    if not costmap.blocked[cell]:
        return cell
    # Only the remedies that can free this cell: a smaller radius frees only inflated cells,
    # --unknown free only unknown ones.
    radius = costmap.robot_radius_m
    near = math.inf if costmap.occupied[cell] else distance_at(costmap, cell, radius + TIE_TOL_M)
    fixes = []
    if costmap.occupied[cell]:
        why = "is in an obstacle"
    elif costmap.unknown[cell] and not costmap.allow_unknown:
        why = "is in unknown space"
        both = " with a smaller --robot-radius" if math.isfinite(near) else ""
        fixes.append(f"pass --unknown free{both}")
    else:
        fixes.append("lower --robot-radius")
        why = (
            f"is within the robot radius ({radius:g} m) of an obstacle "
            f"({near:.3f} m from the nearest occupied cell)"
        )
    free = nearest_free_cell(costmap.blocked, cell)
    if free is None:
        raise MapError(f"{where} {why}, and the map has no free cell at all")
    fx, fy = cell_centres(grid, np.array([free]))[0]
    dist = math.hypot(fx - xy[0], fy - xy[1])
    raise MapError(
        f"{where} {why}; the nearest free cell is centred at ({fx:.3f}, {fy:.3f}) m, "
        f"{dist:.3f} m away",
        hint=" or ".join([f"move {flag} to ({fx:.2f}, {fy:.2f})", *fixes]),
    )


def _search(
    costmap: Costmap,
    blocked: NDArray[np.bool_],
    start: tuple[int, int],
    goal: tuple[int, int],
) -> SearchResult:
    try:
        return grid_search(
            blocked,
            start,
            goal,
            resolution_m=costmap.resolution_m,
            extra_cost=costmap.extra_cost,
        )
    except NoPathError:
        reached = reachable_cells(blocked, start)
        hints = ["a smaller --robot-radius"] if costmap.robot_radius_m > 0 else []
        if not costmap.allow_unknown and costmap.unknown.any():
            hints.insert(0, "--unknown free")
        raise NoPathError(
            f"no path from cell {start} to cell {goal}: the goal is not connected to the start; "
            f"the search reached {reached} cells from the start",
            hint=f"try {' or '.join([*hints, 'a goal in the same free region'])}",
        ) from None


def reachable_cells(blocked: NDArray[np.bool_], cell: tuple[int, int]) -> int:
    """How many free cells are 4-connected to ``cell`` through free cells (the cells the grid
    search can reach: a legal diagonal move always has a free orthogonal cell beside it)."""
    import cv2

    h, w = blocked.shape
    image = np.ascontiguousarray(blocked, dtype=np.uint8)
    mask = np.zeros((h + 2, w + 2), dtype=np.uint8)
    flags = 4 | cv2.FLOODFILL_MASK_ONLY | (1 << 8)
    filled, *_ = cv2.floodFill(image, mask, (int(cell[1]), int(cell[0])), 1, 0, 0, flags)
    return int(filled)


def _replan(
    costmap: Costmap,
    goal_xy: tuple[float, float],
    goal_cell: tuple[int, int],
    limits: Limits,
    xy: NDArray[np.float64],
    v: float,
    present: Sequence[DynamicObstacle],
) -> SpeedProfile:
    """A new profile from the robot's position to the goal around the present obstacles."""
    grid = costmap.grid
    dynamic = np.zeros(costmap.shape, dtype=bool)
    for ob in present:
        dynamic |= disc_mask(grid, (ob.x, ob.y), ob.radius + costmap.robot_radius_m)
    blocked = costmap.blocked | dynamic
    here = (float(xy[0]), float(xy[1]))
    cell = cell_of(grid, here)
    if cell is None or dynamic[cell] or dynamic[goal_cell]:
        raise NoPathError("the robot or the goal is inside an obstacle's zone")
    start: tuple[float, float] | NDArray[np.float64] = here
    if blocked[cell]:
        # Tracking drifted into the inflated zone: set off from the nearest free cell.
        free = nearest_free_cell(blocked, cell)
        if free is None:
            raise NoPathError("no free cell left")
        cell = free
        start = cell_centres(grid, np.array([free]))[0]
    search = _search(costmap, blocked, cell, goal_cell)
    path = smooth_path(costmap, blocked, search.cells, start, goal_xy)
    return time_parameterise(path, limits, v0=v)
