"""Free space for a round robot on an occupancy grid, and the clearance cost.

The rules, exactly:

- A cell is **occupied** when its probability is at least :data:`OCCUPIED_THRESH` (0.65, the
  default ``occupied_thresh`` of ROS map_server). A NaN cell is **unknown**.
- ``d`` is the distance (m) from a cell's centre to the centre of the nearest occupied cell,
  ``sqrt((di * res)² + (dj * res)²)`` for the nearest one (row and column offsets ``di``,
  ``dj``), ``inf`` when the map has no occupied cell.
- A cell is **blocked** when it is occupied, when ``d <= robot_radius + TIE_TOL_M`` (so a centre
  lying exactly at the radius, up to floating-point rounding, is blocked and one just beyond it
  is free), or when it is unknown and the unknown-space policy is ``"blocked"`` (the default;
  ``"free"`` lets the robot cross unknown cells). Unknown cells are blocked themselves but not
  inflated.
- With a clearance weight ``w > 0`` a move into a free cell costs ``w * f(d)`` extra per metre
  moved, like Nav2's inflation layer: ``f(d) = exp(-k (d - robot_radius))`` for
  ``robot_radius < d <= inflation_radius`` and 0 beyond, with ``k`` =
  :data:`COST_SCALING_PER_M` (3 per metre) and ``inflation_radius`` =
  :data:`INFLATION_RADIUS_M` (1 m) by default. ``w`` is dimensionless: with ``w = 1`` a metre
  driven right at the edge of the blocked zone costs two metres.

The blocked cells come from a dilation of the occupied cells by the disc of the integer
offsets ``(di, dj)`` that satisfy the radius rule (OpenCV's ``dilate``), so they follow the
rule exactly without a distance transform. The distances themselves (an exact Euclidean
distance transform, :attr:`Costmap.distance_m`) are computed only when something asks for
them: the clearance cost, or a caller reading them.

All positions are in the map's world frame (m); cell (row, col) covers the square whose
lower-left corner lies at ``origin + (col, row) * resolution`` (rotated by the origin's yaw).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.errors import ConfigError, MapError
from slamcli.types import OccupancyGrid

OCCUPIED_THRESH = 0.65
"""A cell with occupancy probability >= this is an obstacle (map_server's default)."""

TIE_TOL_M = 1e-9
"""Distances within this of the robot radius count as equal to it (and so block the cell)."""

COST_SCALING_PER_M = 3.0
"""Default decay rate k of the clearance cost, per metre (Nav2's cost_scaling_factor)."""

INFLATION_RADIUS_M = 1.0
"""Default distance from an obstacle beyond which the clearance cost is zero, metres."""

CENTRING_RADIUS_M = 1.5
"""Default reach of the centring cost: how far around a point the free space is looked at."""

DILATE_MAX_CELLS = 40
"""Largest robot radius (in cells) :func:`inflate` dilates by; larger ones use a distance
transform."""

UNKNOWN_POLICIES = ("blocked", "free")
"""What unknown cells are to the robot: ``"blocked"`` (the default) or ``"free"``."""


@dataclass(frozen=True)
class Costmap:
    """Blocked cells and clearance cost of one map for one robot.

    Attributes:
        grid: the map.
        occupied: (H, W) bool, prob >= :data:`OCCUPIED_THRESH`.
        unknown: (H, W) bool, NaN cells.
        blocked: (H, W) bool, cells the robot's centre may not enter.
        extra_cost: (H, W) float64 clearance cost per metre moved into each cell, or None when
            the clearance weight is 0.
        robot_radius_m: the radius used for ``blocked``.
        unknown_policy: ``"blocked"`` or ``"free"`` (:data:`UNKNOWN_POLICIES`).
    """

    grid: OccupancyGrid
    occupied: NDArray[np.bool_]
    unknown: NDArray[np.bool_]
    blocked: NDArray[np.bool_]
    extra_cost: NDArray[np.float64] | None
    robot_radius_m: float
    unknown_policy: str = "blocked"

    @property
    def shape(self) -> tuple[int, int]:
        h, w = self.blocked.shape
        return int(h), int(w)

    @property
    def resolution_m(self) -> float:
        return float(self.grid.resolution_m)

    @property
    def allow_unknown(self) -> bool:
        """Whether unknown cells are free (``unknown_policy == "free"``)."""
        return self.unknown_policy == "free"

    @functools.cached_property
    def distance_m(self) -> NDArray[np.float64]:
        """(H, W) float64 distance from each cell centre to the nearest occupied cell centre
        (m); ``inf`` everywhere when nothing is occupied. Computed on first use."""
        return occupied_distance_m(self.occupied, self.resolution_m)


def check_nonnegative(name: str, value: float) -> float:
    """``value`` as a finite float >= 0, else ConfigError naming the option."""
    v = float(value)
    if not math.isfinite(v) or v < 0:
        raise ConfigError(f"{name}: must be a finite number >= 0, got {value!r}")
    return v


def check_positive(name: str, value: float) -> float:
    """``value`` as a finite float > 0, else ConfigError naming the option."""
    v = float(value)
    if not math.isfinite(v) or v <= 0:
        raise ConfigError(f"{name}: must be a finite number > 0, got {value!r}")
    return v


def check_unknown_policy(value: str) -> str:
    """``value`` if it is one of :data:`UNKNOWN_POLICIES`, else ConfigError naming --unknown."""
    if value not in UNKNOWN_POLICIES:
        raise ConfigError(
            f"--unknown: must be {' or '.join(UNKNOWN_POLICIES)}, got {value!r}",
            hint="--unknown blocked keeps the robot out of unknown cells, --unknown free lets "
            "it cross them",
        )
    return value


def build_costmap(
    grid: OccupancyGrid,
    robot_radius_m: float = 0.2,
    *,
    unknown_policy: str = "blocked",
    clearance_weight: float = 0.0,
    cost_scaling_per_m: float = COST_SCALING_PER_M,
    inflation_radius_m: float = INFLATION_RADIUS_M,
    cost_penalty: float = 0.0,
    centring_radius_m: float = CENTRING_RADIUS_M,
) -> Costmap:
    """Blocked cells and clearance cost following the rules in the module docstring, plus
    ``cost_penalty`` times :func:`centring_cost` when it is > 0."""
    radius = check_nonnegative("--robot-radius", robot_radius_m)
    weight = check_nonnegative("--clearance-weight", clearance_weight)
    k = check_nonnegative("cost_scaling_per_m", cost_scaling_per_m)
    inflation = check_nonnegative("inflation_radius_m", inflation_radius_m)
    penalty = check_nonnegative("--cost-penalty", cost_penalty)
    policy = check_unknown_policy(unknown_policy)
    prob = np.asarray(grid.prob)
    if prob.ndim != 2 or prob.size == 0:
        raise MapError(f"occupancy grid must be a non-empty (H, W) array, got shape {prob.shape}")
    res = float(grid.resolution_m)
    if not math.isfinite(res) or res <= 0:
        raise MapError(f"map resolution must be > 0 m, got {grid.resolution_m!r}")

    unknown = np.isnan(prob)
    # NaN compares as False, so unknown cells are never occupied.
    occupied = np.greater_equal(prob, OCCUPIED_THRESH)
    blocked = inflate(occupied, res, radius)
    if policy == "blocked":
        blocked |= unknown

    extra: NDArray[np.float64] | None = None
    if weight > 0:
        distance = occupied_distance_m(occupied, res)
        with np.errstate(over="ignore"):
            f = np.exp(-k * np.maximum(distance - radius, 0.0))
        f[distance > inflation] = 0.0
        f[blocked] = 0.0
        extra = weight * f
    if penalty > 0:
        centring = penalty * centring_cost(clearance_ratio(blocked, res, centring_radius_m))
        centring[blocked] = 0.0
        extra = centring if extra is None else extra + centring
    return Costmap(
        grid=grid,
        occupied=occupied,
        unknown=unknown,
        blocked=blocked,
        extra_cost=extra,
        robot_radius_m=radius,
        unknown_policy=policy,
    )


def disc_offsets(resolution_m: float, radius_m: float) -> NDArray[np.bool_]:
    """(2K+1, 2K+1) bool: the offsets (di, dj) from the centre with
    ``sqrt((di * res)² + (dj * res)²) <= radius_m + TIE_TOL_M`` (the blocking rule)."""
    k = math.floor((radius_m + TIE_TOL_M) / resolution_m) + 1
    off = np.arange(-k, k + 1, dtype=np.float64) * resolution_m
    disc = np.sqrt(off[:, None] ** 2 + off[None, :] ** 2) <= radius_m + TIE_TOL_M
    rows = np.flatnonzero(disc.any(axis=1))
    half = k - int(rows[0])
    return disc[k - half : k + half + 1, k - half : k + half + 1]


def inflate(occupied: NDArray[np.bool_], resolution_m: float, radius_m: float) -> NDArray[np.bool_]:
    """(H, W) bool: occupied cells and every cell whose centre lies within ``radius_m`` (m,
    ties included, see :func:`disc_offsets`) of an occupied cell's centre.

    A dilation by the disc of offsets; its cost grows with the disc's area, so beyond
    :data:`DILATE_MAX_CELLS` cells of radius the distance transform (whose cost does not) is
    used instead. Both follow the rule exactly.
    """
    import cv2

    if not occupied.any():
        return occupied.copy()
    if radius_m / resolution_m > DILATE_MAX_CELLS:
        return occupied | (occupied_distance_m(occupied, resolution_m) <= radius_m + TIE_TOL_M)
    disc = disc_offsets(resolution_m, radius_m)
    if disc.shape == (1, 1):
        return occupied.copy()
    h, w = occupied.shape
    half = disc.shape[0] // 2
    # Offsets beyond the map's size cannot join two of its cells.
    hr, hc = min(half, h - 1), min(half, w - 1)
    kernel = disc[half - hr : half + hr + 1, half - hc : half + hc + 1].astype(np.uint8)
    src = np.ascontiguousarray(occupied).view(np.uint8)
    out = cv2.dilate(src, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return np.asarray(out).view(np.bool_)


def occupied_distance_m(occupied: NDArray[np.bool_], resolution_m: float) -> NDArray[np.float64]:
    """(H, W) float64 exact distance (m) from each cell centre to the nearest occupied cell
    centre (scipy's Euclidean distance transform); ``inf`` everywhere when none is occupied."""
    if not occupied.any():
        return np.full(occupied.shape, np.inf)
    from scipy.ndimage import distance_transform_edt

    # The transform measures the distance of every non-zero cell to the nearest zero one.
    return np.asarray(distance_transform_edt(~occupied, sampling=resolution_m), dtype=np.float64)


def distance_at(costmap: Costmap, cell: tuple[int, int], within_m: float) -> float:
    """Distance (m) from ``cell``'s centre to the nearest occupied cell centre, if one lies
    within ``within_m``; else ``inf``. Looks only at a window around the cell, so it costs
    nothing like a whole distance transform."""
    res = costmap.resolution_m
    k = math.floor(within_m / res) + 1
    r, c = cell
    h, w = costmap.shape
    r0, c0 = max(r - k, 0), max(c - k, 0)
    rows, cols = np.nonzero(costmap.occupied[r0 : min(r + k + 1, h), c0 : min(c + k + 1, w)])
    if len(rows) == 0:
        return math.inf
    di = (rows + r0 - r).astype(np.float64) * res
    dj = (cols + c0 - c).astype(np.float64) * res
    d = float(np.sqrt(di**2 + dj**2).min())
    return d if d <= within_m else math.inf


def world_to_uv(grid: OccupancyGrid, xy: ArrayLike) -> NDArray[np.float64]:
    """World points (..., 2) in metres -> continuous grid coordinates (..., 2) in cells.

    ``u`` runs along columns and ``v`` along rows: cell (row, col) is the square
    ``col <= u <= col + 1``, ``row <= v <= row + 1``; its centre is ``(col + 0.5, row + 0.5)``.
    """
    p = np.asarray(xy, dtype=np.float64)
    x0, y0, yaw = (float(a) for a in grid.origin_xy_yaw)
    dx, dy = p[..., 0] - x0, p[..., 1] - y0
    c, s = math.cos(yaw), math.sin(yaw)
    res = float(grid.resolution_m)
    return np.stack(((c * dx + s * dy) / res, (-s * dx + c * dy) / res), axis=-1)


def uv_to_world(grid: OccupancyGrid, uv: ArrayLike) -> NDArray[np.float64]:
    """Continuous grid coordinates (..., 2) in cells -> world points (..., 2) in metres."""
    q = np.asarray(uv, dtype=np.float64) * float(grid.resolution_m)
    x0, y0, yaw = (float(a) for a in grid.origin_xy_yaw)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.stack((x0 + c * q[..., 0] - s * q[..., 1], y0 + s * q[..., 0] + c * q[..., 1]), -1)


def map_bounds(grid: OccupancyGrid) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) of the map's area in the world, metres."""
    h, w = np.asarray(grid.prob).shape
    corners = uv_to_world(grid, [[0, 0], [w, 0], [0, h], [w, h]])
    return (
        float(corners[:, 0].min()),
        float(corners[:, 0].max()),
        float(corners[:, 1].min()),
        float(corners[:, 1].max()),
    )


def nearest_free_cell(blocked: NDArray[np.bool_], cell: tuple[int, int]) -> tuple[int, int] | None:
    """The free cell nearest (Euclidean, in cells) to ``cell``; None when every cell is blocked.

    Ties go to the smallest (row, col). Looks in a window around the cell that grows until the
    answer inside it is certain, so a cell near free space costs microseconds on any map.
    """
    r, c = cell
    half = 16
    h, w = blocked.shape
    while True:
        r0, r1 = max(r - half, 0), min(r + half + 1, h)
        c0, c1 = max(c - half, 0), min(c + half + 1, w)
        whole = r0 == 0 and c0 == 0 and r1 == h and c1 == w
        rows, cols = np.nonzero(~blocked[r0:r1, c0:c1])
        if len(rows):
            d2 = (rows + r0 - r) ** 2 + (cols + c0 - c) ** 2
            k = int(np.argmin(d2))  # row-major order: the first of equals is the smallest
            # Inside the window the answer is exact only if no outside cell could be closer.
            if whole or d2[k] <= half * half:
                return int(rows[k]) + r0, int(cols[k]) + c0
        elif whole:
            return None
        half *= 2


def disc_mask(
    grid: OccupancyGrid, centre_xy: tuple[float, float], radius_m: float
) -> NDArray[np.bool_]:
    """(H, W) bool: cells whose square (edges included) comes within ``radius_m`` of a point.

    Used for dynamic obstacles: it covers the whole disc, so a path that touches no masked
    cell stays farther than ``radius_m`` from the centre everywhere, not only at cell centres.
    """
    h, w = np.asarray(grid.prob).shape
    u, v = world_to_uv(grid, centre_xy)
    rc = radius_m / float(grid.resolution_m)
    mask = np.zeros((h, w), dtype=bool)
    c0, c1 = max(math.floor(u - rc) - 1, 0), min(math.ceil(u + rc) + 1, w)
    r0, r1 = max(math.floor(v - rc) - 1, 0), min(math.ceil(v + rc) + 1, h)
    if c0 >= c1 or r0 >= r1:
        return mask
    cols = np.arange(c0, c1, dtype=np.float64)
    rows = np.arange(r0, r1, dtype=np.float64)
    du = np.maximum(np.maximum(cols - u, u - (cols + 1)), 0.0)
    dv = np.maximum(np.maximum(rows - v, v - (rows + 1)), 0.0)
    tol = TIE_TOL_M / float(grid.resolution_m)
    mask[r0:r1, c0:c1] = dv[:, None] ** 2 + du[None, :] ** 2 <= (rc + tol) ** 2
    return mask


def clearance_ratio(
    blocked: NDArray[np.bool_], resolution_m: float, radius_m: float = CENTRING_RADIUS_M
) -> NDArray[np.float64]:
    """(H, W) float64 in [0, 1]: ``d / m`` per cell, where ``d`` is the distance from the
    cell's centre to the nearest blocked cell's centre and ``m`` the largest such distance over
    the cells whose centres lie within ``radius_m`` of it (0 on blocked cells, 1 everywhere
    when nothing is blocked).

    1 on the middle line of a corridor (the free space's medial axis, as far as ``radius_m``
    sees), falling to 0 at the walls; in open space wider than ``2 radius_m`` it stays below 1,
    since ``m`` is then at most ``d + radius_m``. The distances are OpenCV's exact Euclidean
    transform (``DIST_MASK_PRECISE``), the local maximum one grey dilation by the disc of
    :func:`disc_offsets`.
    """
    import cv2

    radius_m = check_positive("--inflation-radius", radius_m)
    if not blocked.any():
        return np.ones(blocked.shape)
    free = np.ascontiguousarray(~np.asarray(blocked, dtype=bool)).view(np.uint8)
    d = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    disc = disc_offsets(resolution_m, radius_m).astype(np.uint8)
    local_max = cv2.dilate(d, disc, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    out = np.zeros(blocked.shape)
    room = local_max > 0
    out[room] = d[room] / local_max[room]
    return out


def centring_cost(ratio: NDArray[np.float64]) -> NDArray[np.float64]:
    """The centring cost ``(1 - r)²`` of a :func:`clearance_ratio` field ``r``: 0 on the middle
    line of the free space, 1 at a wall; squared, a little off the middle costs little (0.04
    at a ratio of 0.8) and the walls much. This is the normalised distance of Dolgov et al.'s
    Voronoi field, with the local maximum standing in for the Voronoi edge."""
    return (1.0 - ratio) ** 2
