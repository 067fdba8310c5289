"""What every occupancy-grid file needs of the grid itself: the checks a grid passes before it
is written, and the mapping between its cells and the world.

:func:`world_to_cell` and :func:`cell_to_world` honour the origin's yaw
(the grid's axes are rotated by it about the origin). Nav2 ignores the yaw for lookups; for the
usual yaw of 0 both agree exactly.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.errors import MapError
from slamcli.types import OccupancyGrid


def check_grid(grid: OccupancyGrid) -> NDArray[np.float32]:
    """The grid's prob as a validated (H, W) float32 array."""
    prob = np.asarray(grid.prob)
    if prob.ndim != 2 or prob.size == 0:
        raise MapError(f"occupancy grid must be a non-empty (H, W) array, got shape {prob.shape}")
    if not np.issubdtype(prob.dtype, np.floating):
        raise MapError(f"occupancy grid prob must be floating point, got {prob.dtype}")
    prob = prob.astype(np.float32, copy=False)
    known = prob[~np.isnan(prob)]
    bad = int(np.count_nonzero(~((known >= 0.0) & (known <= 1.0))))
    if bad:
        raise MapError(f"occupancy grid has {bad} cells outside [0, 1] (or infinite)")
    res = float(grid.resolution_m)
    if not (math.isfinite(res) and res > 0):
        raise MapError(f"occupancy grid resolution must be a positive number, got {res}")
    if len(grid.origin_xy_yaw) != 3 or not all(math.isfinite(v) for v in grid.origin_xy_yaw):
        raise MapError(f"occupancy grid origin must be 3 finite numbers, got {grid.origin_xy_yaw}")
    return prob


def world_to_cell(grid: OccupancyGrid, xy: ArrayLike) -> NDArray[np.int64]:
    """World points (..., 2) in metres -> (..., 2) int64 ``(row, col)`` of the cell holding each.

    Row 0 is the lowest y. The grid's axes are rotated by the origin's yaw about the origin
    (Nav2 ignores the yaw; for yaw 0 the results agree). A point on a cell's lower or left edge
    belongs to that cell. Indices outside the grid are returned as they are: check them
    against ``grid.prob.shape``.
    """
    p = np.asarray(xy, dtype=np.float64)
    if p.shape[-1:] != (2,):
        raise ValueError(f"xy must have shape (..., 2), got {p.shape}")
    x0, y0, yaw = (float(v) for v in grid.origin_xy_yaw)
    dx, dy = p[..., 0] - x0, p[..., 1] - y0
    c, s = math.cos(yaw), math.sin(yaw)
    res = float(grid.resolution_m)
    col = np.floor((c * dx + s * dy) / res)
    row = np.floor((-s * dx + c * dy) / res)
    return np.stack([row, col], axis=-1).astype(np.int64)


def cell_to_world(grid: OccupancyGrid, rc: ArrayLike) -> NDArray[np.float64]:
    """``(row, col)`` cells (..., 2) -> (..., 2) world x, y of their centres in metres.

    The inverse of :func:`world_to_cell` for cell centres; honours the origin's yaw.
    """
    q = np.asarray(rc, dtype=np.float64)
    if q.shape[-1:] != (2,):
        raise ValueError(f"rc must have shape (..., 2), got {q.shape}")
    x0, y0, yaw = (float(v) for v in grid.origin_xy_yaw)
    res = float(grid.resolution_m)
    u, v = (q[..., 1] + 0.5) * res, (q[..., 0] + 0.5) * res
    c, s = math.cos(yaw), math.sin(yaw)
    return np.stack([x0 + c * u - s * v, y0 + s * u + c * v], axis=-1)
