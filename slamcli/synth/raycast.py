"""Exact ranges of 2-D laser beams through an occupancy grid (:class:`RayCaster`).

A cell is an obstacle when its probability is at least 0.65
(:data:`slamcli.planning.costmap.OCCUPIED_THRESH`); unknown cells and the world beyond the map
reflect nothing. Cell ``(row, col)`` is the square whose lower-left corner lies at
``origin + (col, row) * resolution``, the grid's axes rotated by the origin's yaw, as
:func:`slamcli.formats.occupancy.world_to_cell` has it. A beam's range is where it first meets
an obstacle square (edges and corners included), exactly: the beam walks the cells it crosses
(Amanatides and Woo's traversal), jumping over open space by the distance transform.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import MapError
from slamcli.planning.costmap import OCCUPIED_THRESH, world_to_uv
from slamcli.types import OccupancyGrid

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

_JUMP_MARGIN = 1.5
"""Cells subtracted from the distance transform for a safe jump (more than sqrt 2: the
distance is between cell centres, the ray's point and the obstacle lie anywhere in theirs)."""
RAYS_PER_BATCH = 1 << 17
"""Beams cast at once (bounds the memory of a cast)."""


def occupied_cells(grid: OccupancyGrid) -> NDArray[np.bool_]:
    """(H, W) bool: the cells that reflect a beam (probability >= ``OCCUPIED_THRESH``)."""
    prob = np.asarray(grid.prob)
    occ = np.zeros(prob.shape, dtype=bool)
    np.greater_equal(prob, OCCUPIED_THRESH, out=occ, where=~np.isnan(prob))
    return occ


class RayCaster:
    """Exact ranges of beams through an occupancy grid's obstacle squares.

    A beam walks the cells it crosses (Amanatides and Woo's traversal) and, where the distance
    transform says no obstacle lies within more than a cell, jumps ahead by that distance; its
    range is where it first enters an obstacle cell's square. Beams leaving the map meet
    nothing more.

    Args:
        grid: the map; cells with probability >= ``OCCUPIED_THRESH`` are obstacles.
    """

    def __init__(self, grid: OccupancyGrid) -> None:
        from scipy.ndimage import distance_transform_edt

        self.grid = grid
        self.occupied = occupied_cells(grid)
        h, w = self.occupied.shape
        self.shape = (int(h), int(w))
        if self.occupied.any():
            edt = np.asarray(distance_transform_edt(~self.occupied), dtype=np.float64)
            self._skip = np.maximum(edt - _JUMP_MARGIN, 0.0).ravel()
        else:
            self._skip = np.full(h * w, np.inf)
        self._occ_flat = self.occupied.ravel()

    def cast(self, sensor_poses: F64, angles: F64, max_range_m: float) -> F64:
        """(N, B) ranges (m) of beams at ``angles`` (B,) rad from scanner poses (N, 3) x, y, yaw
        in the world; ``inf`` where nothing lies within ``max_range_m``.

        Raises:
            MapError: a scanner outside the map.
        """
        poses = np.asarray(sensor_poses, dtype=np.float64).reshape(-1, 3)
        beams = np.asarray(angles, dtype=np.float64).reshape(-1)
        res = float(self.grid.resolution_m)
        origin_uv = world_to_uv(self.grid, poses[:, :2])
        h, w = self.shape
        outside = ~(
            (origin_uv[:, 0] >= 0)
            & (origin_uv[:, 0] < w)
            & (origin_uv[:, 1] >= 0)
            & (origin_uv[:, 1] < h)
        )
        if outside.any():
            k = int(np.flatnonzero(outside)[0])
            raise MapError(
                f"scanner pose {k} ({poses[k, 0]:g}, {poses[k, 1]:g}) is outside the map",
                hint="cast from poses inside the map",
            )
        # Beam directions in grid coordinates: the grid's axes are turned by the origin's yaw.
        heading = poses[:, 2:3] + beams[None, :] - float(self.grid.origin_xy_yaw[2])
        dirs = np.stack([np.cos(heading), np.sin(heading)], axis=-1).reshape(-1, 2)
        starts = np.repeat(origin_uv, len(beams), axis=0)
        out = np.empty(len(dirs))
        for a in range(0, len(dirs), RAYS_PER_BATCH):
            b = min(a + RAYS_PER_BATCH, len(dirs))
            out[a:b] = self._cast_uv(starts[a:b], dirs[a:b], max_range_m / res) * res
        return out.reshape(len(poses), len(beams))

    def _cast_uv(self, start: F64, direction: F64, t_max: float) -> F64:
        """Parameters (cells) where rays ``start + t * direction`` (grid coordinates, unit
        directions) first enter an obstacle square; inf beyond ``t_max`` or the map."""
        h, w = self.shape
        n = len(start)
        result = np.full(n, np.inf)
        ox, oy = start[:, 0], start[:, 1]
        dx, dy = direction[:, 0], direction[:, 1]
        ix = np.floor(ox).astype(np.int64)
        iy = np.floor(oy).astype(np.int64)
        inside_hit = self._occ_flat[iy * w + ix]
        result[inside_hit] = 0.0
        sx = np.sign(dx).astype(np.int64)
        sy = np.sign(dy).astype(np.int64)
        with np.errstate(divide="ignore"):
            tdx = np.where(dx != 0, 1.0 / np.abs(dx), np.inf)
            tdy = np.where(dy != 0, 1.0 / np.abs(dy), np.inf)
        t = np.zeros(n)
        tmx = _next_boundary(ox, dx, ix, t)
        tmy = _next_boundary(oy, dy, iy, t)
        keep = ~inside_hit
        idx = np.flatnonzero(keep)
        # Static per-ray values in one float and one int block, so compaction is two takes.
        fstat = np.stack([ox, oy, dx, dy, tdx, tdy])[:, keep]
        istat = np.stack([sx, sy])[:, keep]
        fdyn = np.stack([t, tmx, tmy])[:, keep]
        idyn = np.stack([ix, iy])[:, keep]
        while idx.size:
            ox, oy, dx, dy, tdx, tdy = fstat
            sx, sy = istat
            t, tmx, tmy = fdyn
            ix, iy = idyn
            jump = self._skip[iy * w + ix]
            far_jump = jump >= 1.0
            if far_jump.any():
                j = np.flatnonzero(far_jump)
                tj = t[j] + jump[j]
                px, py = ox[j] + tj * dx[j], oy[j] + tj * dy[j]
                with np.errstate(invalid="ignore"):
                    jx, jy = np.floor(px), np.floor(py)
                jx = np.clip(jx, -1, w).astype(np.int64)
                jy = np.clip(jy, -1, h).astype(np.int64)
                t[j], ix[j], iy[j] = tj, jx, jy
                tmx[j] = _next_boundary(px, dx[j], jx, tj)
                tmy[j] = _next_boundary(py, dy[j], jy, tj)
            walk = ~far_jump
            step_x = walk & (tmx <= tmy)
            step_y = walk & ~step_x
            t[step_x] = tmx[step_x]
            ix[step_x] += sx[step_x]
            tmx[step_x] += tdx[step_x]
            t[step_y] = tmy[step_y]
            iy[step_y] += sy[step_y]
            tmy[step_y] += tdy[step_y]
            alive = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h) & (t <= t_max)
            hit = np.zeros(idx.size, dtype=bool)
            hit[alive] = self._occ_flat[iy[alive] * w + ix[alive]]
            result[idx[hit]] = t[hit]
            go_on = alive & ~hit
            idx = idx[go_on]
            fstat, istat = fstat[:, go_on], istat[:, go_on]
            fdyn, idyn = fdyn[:, go_on], idyn[:, go_on]
        return result


def _next_boundary(p: F64, d: F64, cell: I64, t: F64) -> F64:
    """Ray parameter of the next cell border along one axis from point ``p`` at ``t``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        up = t + (cell + 1 - p) / d
        down = t + (cell - p) / d
    return np.where(d > 0, up, np.where(d < 0, down, np.inf))
