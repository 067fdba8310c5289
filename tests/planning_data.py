"""Scenes and references for the car-like planner's tests and benchmark.

- :func:`yard`: a synthetic open yard (60 x 40 m at 0.1 m) with two long walls and a parking
  bay 3 m wide and 8 m deep, for a 4.5 x 1.9 m car with a 5 m turn radius.
- :func:`far_poses`: seeded far-apart start/goal poses in the open part of a real map.
- :func:`ompl_car_length`: OMPL's best path length for the same car, map and footprint test in a
  given time (RRT* or BIT* on a Reeds-Shepp or Dubins state space, then OMPL's simplifier).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from slamcli.planning.costmap import uv_to_world, world_to_uv
from slamcli.planning.footprint import Footprint, FootprintChecker
from slamcli.types import OccupancyGrid

YARD_CAR = Footprint.rectangle(4.5, 1.9, rear_m=1.0)
"""The yard's car: 4.5 x 1.9 m, reference point (rear axle) 1 m ahead of the rear bumper."""
YARD_RADIUS_M = 5.0
BAY_GOAL = (51.8, 4.0, math.pi / 2)
"""Inside the bay, nose out: reachable only by backing in."""
BAY_GOAL_NOSE_IN = (51.8, 4.0, -math.pi / 2)
YARD_START = (5.0, 5.0, 0.0)

SMALL_CAR = Footprint.rectangle(0.9, 0.6)
"""The building robot: 0.9 x 0.6 m, reference point at its centre, 1.2 m turn radius."""
SMALL_RADIUS_M = 1.2


def yard(res: float = 0.1) -> OccupancyGrid:
    """The synthetic yard of the module doc (walls are occupied cells, nothing unknown)."""
    w, h = round(60 / res), round(40 / res)
    p = np.zeros((h, w), np.float32)
    p[:2, :] = p[-2:, :] = p[:, :2] = p[:, -2:] = 1.0

    def box(x0: float, y0: float, x1: float, y1: float) -> None:
        p[round(y0 / res) : round(y1 / res), round(x0 / res) : round(x1 / res)] = 1.0

    box(20, 0, 22, 25)
    box(38, 15, 40, 40)
    box(50, 0, 50.3, 8)
    box(53.3, 0, 53.6, 8)
    return OccupancyGrid(p, res, (0.0, 0.0, 0.0))


def far_poses(
    grid: OccupancyGrid, blocked: np.ndarray, room_m: float, n: int, seed: int
) -> list[tuple[tuple[float, float, float], tuple[float, float, float]]]:
    """``n`` start/goal pose pairs: cell centres at least ``room_m`` from every blocked cell
    and from the map's edge (so the footprint fits at any heading) in the largest such region,
    the farthest apart of 100 random pairs each, with random headings."""
    from scipy import ndimage

    padded = np.pad(blocked, 1, constant_values=True)
    room = ndimage.distance_transform_edt(~padded)[1:-1, 1:-1] * grid.resolution_m
    labels, _ = ndimage.label(room > room_m)
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    if not sizes.any():
        raise ValueError(f"no cell lies {room_m} m from every blocked cell")
    rows, cols = np.nonzero(labels == sizes.argmax())
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        i, j = rng.integers(len(rows), size=(100, 2)).T
        k = int(np.argmax(np.hypot(rows[i] - rows[j], cols[i] - cols[j])))
        a = uv_to_world(grid, [cols[i[k]] + 0.5, rows[i[k]] + 0.5])
        b = uv_to_world(grid, [cols[j[k]] + 0.5, rows[j[k]] + 0.5])
        ya, yb = rng.uniform(-math.pi, math.pi, size=2)
        out.append(((float(a[0]), float(a[1]), float(ya)), (float(b[0]), float(b[1]), float(yb))))
    return out


_SEEDED = False


def ompl_car_length(
    grid: OccupancyGrid,
    blocked: np.ndarray,
    footprint: Footprint,
    radius_m: float,
    start: tuple[float, float, float],
    goal: tuple[float, float, float],
    *,
    reverse: bool = True,
    time_s: float = 2.0,
    planners: tuple[str, ...] = ("RRTstar", "BITstar"),
    seed: int = 1,
    cost: np.ndarray | None = None,
) -> dict[str, Any]:
    """The shortest path OMPL finds in ``time_s`` per planner, simplified; ``{planner: length
    m or None}`` plus ``best``. Validity is our exact footprint test; motions are checked
    every quarter cell.

    With ``cost`` (H, W: extra cost per metre of each cell, as the planner's centring cost),
    the objective is OMPL's ``StateCostIntegralObjective`` with state cost ``1 + cost`` at
    the state's cell (trapezoids between states), and the figures are path costs
    (:func:`path_cost`), not lengths; no simplification, which shortens without pricing."""
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    global _SEEDED
    if not _SEEDED:
        # OMPL takes one seed per process, before its first random number.
        ou.RNG.setSeed(seed)
        _SEEDED = True
    ou.setLogLevel(ou.LOG_ERROR)
    checker = FootprintChecker(blocked, grid, footprint)
    from slamcli.planning.costmap import map_bounds

    x0, x1, y0, y1 = map_bounds(grid)
    out: dict[str, Any] = {}
    for name in planners:
        space = ob.ReedsSheppStateSpace(radius_m) if reverse else ob.DubinsStateSpace(radius_m)
        bounds = ob.RealVectorBounds(2)
        bounds.setLow(0, x0)
        bounds.setHigh(0, x1)
        bounds.setLow(1, y0)
        bounds.setHigh(1, y1)
        space.setBounds(bounds)
        ss = og.SimpleSetup(space)

        def valid(state: Any) -> bool:
            pose = np.array([[state.getX(), state.getY(), state.getYaw()]])
            return bool(checker.free(pose)[0])

        ss.setStateValidityChecker(valid)
        si = ss.getSpaceInformation()
        extent = space.getMaximumExtent()
        si.setStateValidityCheckingResolution(0.25 * grid.resolution_m / extent)
        a, b = space.allocState(), space.allocState()
        for s, q in ((a, start), (b, goal)):
            s.setX(q[0])
            s.setY(q[1])
            s.setYaw(q[2])
        ss.setStartAndGoalStates(a, b)
        if cost is None:
            objective = ob.PathLengthOptimizationObjective(si)
        else:
            objective = _cell_cost_objective()(si, grid, cost)
        ss.getProblemDefinition().setOptimizationObjective(objective)
        ss.setPlanner(getattr(og, name)(si))
        solved = ss.solve(time_s)
        length = None
        if solved and ss.haveExactSolutionPath():
            if cost is None:
                ss.simplifySolution(max(0.2, 0.25 * time_s))
                length = float(ss.getSolutionPath().length())
            else:
                path = ss.getSolutionPath()
                path.interpolate(max(2, int(path.length() / (0.5 * grid.resolution_m))))
                states = [path.getState(i) for i in range(path.getStateCount())]
                poses = np.array([[q.getX(), q.getY(), q.getYaw()] for q in states])
                length = path_cost(grid, cost, poses)
        out[name] = length
    found = [v for v in out.values() if v is not None]
    out["best"] = min(found) if found else None
    return out


def path_cost(grid: OccupancyGrid, cost: np.ndarray, poses: np.ndarray) -> float:
    """Σ over consecutive poses of ``distance · (1 + mean cost of the two poses' cells)``:
    the centring cost of a path, the same way for ours and OMPL's."""
    uv = world_to_uv(grid, poses[:, :2]).astype(np.int64)
    h, w = cost.shape
    c = cost[np.clip(uv[:, 1], 0, h - 1), np.clip(uv[:, 0], 0, w - 1)]
    step = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    return float(np.sum(step * (1.0 + 0.5 * (c[1:] + c[:-1]))))


def _cell_cost_objective() -> Any:
    from ompl import base as ob

    class CellCost(ob.StateCostIntegralObjective):  # type: ignore[misc]
        """OMPL's integral objective with a state cost of 1 + the cell's extra cost."""

        def __init__(self, si: Any, grid: OccupancyGrid, cost: np.ndarray) -> None:
            super().__init__(si, False)
            self.grid = grid
            self.cost = cost

        def stateCost(self, state: Any) -> Any:
            u, v = world_to_uv(self.grid, [state.getX(), state.getY()])
            h, w = self.cost.shape
            c = self.cost[min(max(int(v), 0), h - 1), min(max(int(u), 0), w - 1)]
            return ob.Cost(1.0 + float(c))

    return CellCost


def clearance_ratios(
    grid: OccupancyGrid,
    blocked: np.ndarray,
    poses: np.ndarray,
    reach_m: float = 1.5,
    every_m: float = 0.1,
) -> np.ndarray:
    """The clearance ratio at points every ``every_m`` along a path's centre line: the point's
    exact distance to the nearest blocked cell centre, over the largest distance to a blocked
    cell centre from any cell centre within ``reach_m`` of the point (or the point's own, when
    larger). Independent of the planner's cost field: a k-d tree for the point, scipy's exact
    transform for the cells."""
    from scipy import ndimage
    from scipy.spatial import cKDTree

    res = float(grid.resolution_m)
    rows, cols = np.nonzero(blocked)
    tree = cKDTree(uv_to_world(grid, np.column_stack((cols + 0.5, rows + 0.5))))
    cell_room = ndimage.distance_transform_edt(~blocked) * res
    along = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))))
    pts = poses[np.searchsorted(along, np.arange(0.0, along[-1], every_m)), :2]
    room = tree.query(pts)[0]
    k = int(reach_m / res) + 1
    di, dj = np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1), indexing="ij")
    h, w = blocked.shape
    out = np.empty(len(pts))
    for n, ((u, v), p) in enumerate(zip(world_to_uv(grid, pts), pts, strict=True)):
        r, c = int(v) + di, int(u) + dj
        inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        r, c = r[inside], c[inside]
        centres = uv_to_world(grid, np.column_stack((c + 0.5, r + 0.5)))
        near = np.hypot(*(centres - p).T) <= reach_m
        out[n] = room[n] / max(float(cell_room[r[near], c[near]].max()), room[n])
    return out
