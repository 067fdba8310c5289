"""Property test of `slamcli plan` on random occupancy grids, with and without inflation.

The reference is independent of the planner: the blocked cells are computed by brute force
from the documented rule (a cell is blocked when its centre lies within the robot radius of
an occupied cell's centre), the graph is built here by hand, and the shortest path cost comes
from ``scipy.sparse.csgraph.dijkstra``.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from slamcli.errors import NoPathError
from slamcli.planning.planner import plan
from slamcli.types import OccupancyGrid

RES = 0.1


def _blocked_reference(occupied: np.ndarray, radius_m: float) -> np.ndarray:
    h, w = occupied.shape
    rows, cols = np.nonzero(occupied)
    blocked = occupied.copy()
    rr, cc = np.mgrid[0:h, 0:w]
    for r, c in zip(rows.tolist(), cols.tolist(), strict=True):
        d = np.hypot(rr - r, cc - c) * RES
        blocked |= d <= radius_m + 1e-9
    return blocked


def _graph(blocked: np.ndarray) -> coo_matrix:
    h, w = blocked.shape
    src, dst, cost = [], [], []
    for r in range(h):
        for c in range(w):
            if blocked[r, c]:
                continue
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    if dr == dc == 0:
                        continue
                    r2, c2 = r + dr, c + dc
                    if not (0 <= r2 < h and 0 <= c2 < w) or blocked[r2, c2]:
                        continue
                    # A diagonal move may not pass between two blocked cells.
                    if dr and dc and blocked[r + dr, c] and blocked[r, c + dc]:
                        continue
                    src.append(r * w + c)
                    dst.append(r2 * w + c2)
                    cost.append(RES * (math.sqrt(2.0) if dr and dc else 1.0))
    return coo_matrix((cost, (src, dst)), shape=(h * w, h * w))


def _touches_blocked(a: np.ndarray, b: np.ndarray, blocked: np.ndarray) -> bool:
    """Dense sampling of a segment (world metres, origin 0): does it meet a blocked cell?"""
    n = max(2, int(np.ceil(np.hypot(*(b - a)) / (RES / 20))) + 1)
    pts = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    cols = np.floor(pts[:, 0] / RES + 1e-9).astype(int)
    rows = np.floor(pts[:, 1] / RES + 1e-9).astype(int)
    h, w = blocked.shape
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    return bool(np.any(blocked[rows[inside], cols[inside]]))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 10_000),
    size=st.integers(8, 24),
    density=st.floats(0.02, 0.25),
    radius_cells=st.sampled_from([0.0, 1.0, 1.5, 2.0]),
)
def test_grid_cost_equals_dijkstra_and_paths_stay_free(
    seed: int, size: int, density: float, radius_cells: float
) -> None:
    rng = np.random.default_rng(seed)
    occupied = rng.random((size, size)) < density
    prob = np.where(occupied, 1.0, 0.0).astype(np.float32)
    grid = OccupancyGrid(prob, RES, (0.0, 0.0, 0.0))
    radius = radius_cells * RES
    blocked = _blocked_reference(occupied, radius)
    free = np.argwhere(~blocked)
    if len(free) < 2:
        return
    i, j = rng.choice(len(free), size=2, replace=False)
    start, goal = free[i], free[j]
    w = size
    dist = dijkstra(_graph(blocked), indices=int(start[0] * w + start[1]))
    expected = dist[goal[0] * w + goal[1]]
    sxy = ((start[1] + 0.5) * RES, (start[0] + 0.5) * RES)
    gxy = ((goal[1] + 0.5) * RES, (goal[0] + 0.5) * RES)
    if not np.isfinite(expected):
        with pytest.raises(NoPathError):
            plan(grid, sxy, gxy, robot_radius_m=radius)
        return
    result = plan(grid, sxy, gxy, robot_radius_m=radius)
    assert result.grid_cost_m == pytest.approx(expected, abs=1e-9)
    assert np.array_equal(result.costmap.blocked, blocked)
    cells = np.floor(result.grid_xy[:, ::-1] / RES).astype(int)
    assert not blocked[cells[:, 0], cells[:, 1]].any()
    path = result.smooth_xy
    for a, b in itertools.pairwise(path):
        assert not _touches_blocked(a, b, blocked)
