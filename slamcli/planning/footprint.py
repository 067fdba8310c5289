"""A robot's footprint polygon checked exactly against the blocked cells of an occupancy grid.

The rules, exactly:

- A :class:`Footprint` is a convex polygon in the body frame (metres, x forward, y left), with
  the pose's reference point at the origin; its vertices run counter-clockwise.
- A pose ``(x, y, yaw)`` (world metres and radians) places the footprint in the world. It is
  **in collision** when the closed polygon meets the closed square of a blocked cell (a shared
  edge or corner counts). Cells outside the grid count as blocked, so a footprint that reaches
  the map's edge collides.
- The **clearance** of a pose is the Euclidean distance (m) between the polygon and the nearest
  blocked cell square (outside cells included): 0 in collision, capped at ``cap_m``.

Everything is computed in continuous grid coordinates ``(u, v)`` in cells (see
:func:`slamcli.planning.costmap.world_to_uv`: cell (row, col) is the square
``col <= u <= col + 1``, ``row <= v <= row + 1``). The grid frame is the world frame turned by
the map origin's yaw and scaled by the resolution, so a pose with world heading ``yaw`` has the
grid heading ``yaw - origin_yaw``, and body vertices in cells are the metres divided by the
resolution.

The exact test is a separating-axis test between the polygon and each blocked cell square in
the polygon's bounding box: the two grid axes (the bounding box itself) and the polygon's edge
normals. Two shortcuts, both decided by the field of :func:`square_distance_field` (the exact
distance from each cell's square to the nearest blocked square), skip it without changing the
answer:

- the reference point lies in cell c, the polygon lies within ``r_out`` (its circumradius) of
  the reference point, and every blocked square is at least ``dist[c]`` from every point of c:
  if ``dist[c] > r_out`` the pose is free;
- the disc of radius ``r_in`` (the inradius) about the reference point lies inside the polygon,
  and the nearest blocked square is within ``dist[c] + sqrt(2)`` (the diagonal of cell c) of
  the reference point: if ``dist[c] + sqrt(2) < r_in`` the pose collides.

The kernels are numba functions on plain arrays, so a search compiled with numba can call
:func:`pose_free_uv` and :func:`pose_clearance_uv` per pose; :class:`FootprintChecker` holds the
arrays they need and wraps them for batches of world poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.errors import ConfigError, InputError, MapError
from slamcli.planning.costmap import check_positive, world_to_uv
from slamcli.types import OccupancyGrid

__all__ = [
    "Footprint",
    "FootprintChecker",
    "footprint_cells",
    "parse_footprint",
    "pose_clearance_uv",
    "pose_free_uv",
    "poses_clearance_uv",
    "poses_free_uv",
    "square_distance_field",
]

_SHORTCUT_MARGIN = 1e-9
"""Slack (cells) by which a shortcut must hold, so rounding in the field never decides a tie."""

_COLLINEAR_TOL = 1e-12
"""Relative size of a cross product below which two polygon edges count as parallel."""

_SQRT2 = math.sqrt(2.0)


# --- the footprint ------------------------------------------------------------------------------


def _check_polygon(vertices: ArrayLike, option: str) -> NDArray[np.float64]:
    """(K, 2) float64 counter-clockwise vertices of a convex polygon with positive area.

    Either orientation is accepted. Repeated vertices and vertices lying on the straight line
    between their neighbours are dropped. Raises ConfigError naming ``option`` for fewer than 3
    vertices, non-finite numbers, zero area, a non-convex polygon and a self-intersecting one.
    """
    hint = "give the vertices of the robot's convex hull in order round its outline"
    try:
        p = np.array(vertices, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{option}: not a list of (x, y) vertices: {exc}", hint=hint) from None
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 3:
        raise ConfigError(
            f"{option}: a footprint needs at least 3 (x, y) vertices, got shape {p.shape}",
            hint=hint,
        )
    if not np.all(np.isfinite(p)):
        raise ConfigError(f"{option}: vertices must be finite numbers, got {p.tolist()}", hint=hint)
    keep: list[int] = list(range(len(p)))
    j = 0
    while len(keep) >= 3 and j < len(keep):
        a, b, c = p[keep[j - 1]], p[keep[j]], p[keep[(j + 1) % len(keep)]]
        e1, e2 = b - a, c - b
        n1, n2 = float(np.hypot(*e1)), float(np.hypot(*e2))
        turn = float(e1[0] * e2[1] - e1[1] * e2[0])
        straight = abs(turn) <= _COLLINEAR_TOL * n1 * n2 and float(e1 @ e2) > 0
        if n1 == 0.0 or n2 == 0.0 or straight:
            del keep[j]
            j = 0
        else:
            j += 1
    q = p[keep]
    e = np.roll(q, -1, axis=0) - q
    cross = e[:, 0] * np.roll(e[:, 1], -1) - e[:, 1] * np.roll(e[:, 0], -1)
    scale = float(np.max(np.abs(p)))
    if len(q) < 3 or np.all(np.abs(cross) <= _COLLINEAR_TOL * scale * scale):
        raise ConfigError(f"{option}: the polygon {p.tolist()} has zero area", hint=hint)
    if np.all(cross < 0):
        q = q[::-1]
        e = np.roll(q, -1, axis=0) - q
        cross = e[:, 0] * np.roll(e[:, 1], -1) - e[:, 1] * np.roll(e[:, 0], -1)
    if np.any(cross <= 0):
        raise ConfigError(
            f"{option}: the polygon {p.tolist()} is not convex (or crosses itself)", hint=hint
        )
    # A star polygon turns left at every vertex but winds round more than once.
    turning = np.arctan2(cross, np.sum(e * np.roll(e, -1, axis=0), axis=1))
    if float(np.sum(turning)) > 3.0 * math.pi:
        raise ConfigError(f"{option}: the polygon {p.tolist()} crosses itself", hint=hint)
    q = np.ascontiguousarray(q)
    q.setflags(write=False)
    return q


@dataclass(frozen=True, eq=False)
class Footprint:
    """A robot's outline: a convex polygon in the body frame.

    Attributes:
        vertices: (K, 2) float64 metres, x forward and y left of the pose's reference point,
            counter-clockwise (a clockwise list is reversed; repeated and collinear vertices are
            dropped). ConfigError for a non-convex, self-intersecting or zero-area polygon.
    """

    vertices: NDArray[np.float64]

    def __post_init__(self) -> None:
        object.__setattr__(self, "vertices", _check_polygon(self.vertices, "footprint"))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Footprint):
            return NotImplemented
        return bool(np.array_equal(self.vertices, other.vertices))

    def __hash__(self) -> int:
        return hash(self.vertices.tobytes())

    @classmethod
    def rectangle(
        cls, length_m: float, width_m: float, *, rear_m: float | None = None
    ) -> Footprint:
        """A ``length_m`` x ``width_m`` rectangle along the body's x axis.

        The reference point lies on the centre line, ``rear_m`` ahead of the rear edge
        (``length_m / 2`` by default: the centre; the distance to the rear axle for a car whose
        reference point is the rear axle).
        """
        length = check_positive("footprint length_m", length_m)
        width = check_positive("footprint width_m", width_m)
        rear = length / 2 if rear_m is None else float(rear_m)
        if not math.isfinite(rear):
            raise ConfigError(f"footprint rear_m: must be a finite number, got {rear_m!r}")
        front, half = length - rear, width / 2
        return cls(np.array([[-rear, -half], [front, -half], [front, half], [-rear, half]]))

    @property
    def circumradius_m(self) -> float:
        """Largest distance from the reference point to a vertex (m)."""
        return float(np.max(np.hypot(self.vertices[:, 0], self.vertices[:, 1])))

    @property
    def inradius_m(self) -> float:
        """Distance from the reference point to the nearest edge (m); 0 if it lies outside."""
        a = self.vertices
        e = np.roll(a, -1, axis=0) - a
        # Signed distance of the origin to each edge's line, positive on the inner (left) side.
        inside = (e[:, 0] * -a[:, 1] - e[:, 1] * -a[:, 0]) / np.hypot(e[:, 0], e[:, 1])
        return max(float(np.min(inside)), 0.0)

    def offset(self, margin_m: float) -> Footprint:
        """This outline with every edge moved ``margin_m`` outwards (corners mitred): it
        contains every point within ``margin_m`` of the original polygon."""
        margin = float(margin_m)
        if not (math.isfinite(margin) and margin >= 0):
            raise ConfigError(f"footprint margin: must be a finite number >= 0, got {margin_m!r}")
        a = self.vertices
        e = np.roll(a, -1, axis=0) - a
        # Outward normal of a counter-clockwise edge (dx, dy) is (dy, -dx).
        n = np.stack((e[:, 1], -e[:, 0]), axis=1) / np.hypot(e[:, 0], e[:, 1])[:, None]
        prev = np.roll(n, 1, axis=0)
        # Vertex i joins edge i-1 and edge i; the mitred corner moves along the bisector.
        bis = prev + n
        scale = margin / np.maximum((bis * n).sum(axis=1), 1e-12)
        return Footprint(a + bis * scale[:, None])


def parse_footprint(text: str, option: str = "--footprint") -> Footprint:
    """A footprint from ``"x1,y1;x2,y2;..."`` (metres, body frame, either orientation).

    Raises ConfigError naming ``option`` for malformed text, fewer than 3 vertices, and a
    non-convex, self-intersecting or zero-area polygon.
    """
    example = "e.g. --footprint '-0.45,-0.3;0.45,-0.3;0.45,0.3;-0.45,0.3'"
    vertices: list[tuple[float, float]] = []
    for part in str(text).split(";"):
        if not part.strip():
            continue
        xy = part.split(",")
        try:
            if len(xy) != 2:
                raise ValueError
            vertices.append((float(xy[0]), float(xy[1])))
        except ValueError:
            raise ConfigError(
                f"{option}: {part.strip()!r} in {text!r} is not an 'x,y' pair of numbers",
                hint=f"give vertices as x,y pairs in metres separated by ';', {example}",
            ) from None
    if len(vertices) < 3:
        raise ConfigError(
            f"{option}: a footprint needs at least 3 vertices, got {len(vertices)} in {text!r}",
            hint=f"give vertices as x,y pairs in metres separated by ';', {example}",
        )
    return Footprint(_check_polygon(vertices, option))


# --- the distance field -------------------------------------------------------------------------


def square_distance_field(blocked: NDArray[np.bool_]) -> NDArray[np.float64]:
    """(H, W) float64: exact distance (cells) from each cell's square to the nearest blocked one.

    The distance between the closed squares of cells ``a`` and ``b`` with offset ``(di, dj)`` is
    ``hypot(max(|di| - 1, 0), max(|dj| - 1, 0))`` (0 when they touch). Cells outside the grid
    count as blocked, so the cells on the grid's edge have 0. It equals the Euclidean distance
    transform (between cell centres) to the blocked cells grown by one cell in all 8 directions:
    growing ``b`` by the offsets ``{-1, 0, 1}^2`` lowers each ``|di|``, ``|dj|`` by one, or to 0.
    Multiply by the resolution for metres.
    """
    from scipy.ndimage import binary_dilation, distance_transform_edt

    b = np.asarray(blocked, dtype=bool)
    padded = np.ones((b.shape[0] + 2, b.shape[1] + 2), dtype=bool)
    padded[1:-1, 1:-1] = b
    grown = binary_dilation(padded, structure=np.ones((3, 3), dtype=bool))
    dist = np.asarray(distance_transform_edt(~grown), dtype=np.float64)
    return np.ascontiguousarray(dist[1:-1, 1:-1])


# --- kernels (grid coordinates, cells) ----------------------------------------------------------


@numba.njit(cache=True, nogil=True)
def _place(u: float, v: float, yaw: float, verts: NDArray[np.float64]) -> NDArray[np.float64]:
    """(K, 2) grid vertices of the polygon ``verts`` (cells, body frame) at pose (u, v, yaw)."""
    c, s = math.cos(yaw), math.sin(yaw)
    p = np.empty((verts.shape[0], 2))
    for i in range(verts.shape[0]):
        p[i, 0] = u + c * verts[i, 0] - s * verts[i, 1]
        p[i, 1] = v + s * verts[i, 0] + c * verts[i, 1]
    return p


@numba.njit(cache=True, nogil=True)
def _edges(
    p: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """For each edge p_i -> p_i+1 of a counter-clockwise polygon: (K, 2) its outward normal
    (as long as the edge), (K,) the polygon's support ``n_i . p_i`` along it and (K,) a unit
    square's half-extent ``(|n_u| + |n_v|) / 2`` along it."""
    k = p.shape[0]
    n = np.empty((k, 2))
    h = np.empty(k)
    half = np.empty(k)
    for i in range(k):
        j = i + 1 if i + 1 < k else 0
        # Counter-clockwise: the outward normal of edge (du, dv) is (dv, -du).
        n[i, 0] = p[j, 1] - p[i, 1]
        n[i, 1] = p[i, 0] - p[j, 0]
        h[i] = n[i, 0] * p[i, 0] + n[i, 1] * p[i, 1]
        half[i] = 0.5 * (abs(n[i, 0]) + abs(n[i, 1]))
    return n, h, half


@numba.njit(cache=True, nogil=True)
def _box(p: NDArray[np.float64]) -> tuple[float, float, float, float]:
    """(umin, umax, vmin, vmax) of a vertex list."""
    umin, umax, vmin, vmax = p[0, 0], p[0, 0], p[0, 1], p[0, 1]
    for i in range(1, p.shape[0]):
        umin = min(umin, p[i, 0])
        umax = max(umax, p[i, 0])
        vmin = min(vmin, p[i, 1])
        vmax = max(vmax, p[i, 1])
    return umin, umax, vmin, vmax


@numba.njit(cache=True, nogil=True)
def _cell_range(umin: float, umax: float, vmin: float, vmax: float) -> tuple[int, int, int, int]:
    """(c0, c1, r0, r1): the cells whose closed squares overlap [umin, umax] x [vmin, vmax],
    columns c0..c1 and rows r0..r1 inclusive (a square touching the box's edge counts)."""
    return math.ceil(umin) - 1, math.floor(umax), math.ceil(vmin) - 1, math.floor(vmax)


@numba.njit(cache=True, nogil=True)
def _meets(
    n: NDArray[np.float64], h: NDArray[np.float64], half: NDArray[np.float64], col: int, row: int
) -> bool:
    """Separating-axis test of the polygon and cell (row, col)'s closed square, for a cell whose
    square already overlaps the polygon's bounding box (the two grid axes).

    A convex polygon and a square are disjoint exactly when one of the square's edges or one of
    the polygon's edges has them on opposite sides; for a polygon edge with outward normal n
    that means the square's lowest projection on n exceeds the polygon's highest, ``n . p_i``.
    """
    cu, cv = col + 0.5, row + 0.5
    i = 0
    while i < n.shape[0] and n[i, 0] * cu + n[i, 1] * cv - half[i] <= h[i]:
        i += 1
    return i == n.shape[0]


@numba.njit(cache=True, nogil=True)
def _sat_free(
    blocked_u8: NDArray[np.uint8],
    p: NDArray[np.float64],
    n: NDArray[np.float64],
    h: NDArray[np.float64],
    half: NDArray[np.float64],
) -> bool:
    """True when the placed polygon meets no blocked cell and stays strictly inside the grid."""
    rows, cols = blocked_u8.shape
    umin, umax, vmin, vmax = _box(p)
    # A point with u <= 0 (or u >= W, ...) lies in the closed square of a cell outside the grid.
    if not (umin > 0.0 and vmin > 0.0 and umax < cols and vmax < rows):
        return False
    # Cells whose closed squares overlap [umin, umax] x [vmin, vmax].
    c0, c1, r0, r1 = _cell_range(umin, umax, vmin, vmax)
    for r in range(r0, r1 + 1):
        for c in range(c0, c1 + 1):
            if blocked_u8[r, c] != 0 and _meets(n, h, half, c, r):
                return False
    return True


@numba.njit(cache=True, nogil=True)
def pose_free_uv(
    blocked_u8: NDArray[np.uint8],
    dist: NDArray[np.float64],
    u: float,
    v: float,
    yaw_grid: float,
    verts_cells: NDArray[np.float64],
    r_in: float,
    r_out: float,
) -> bool:
    """True when the footprint at grid pose (u, v, yaw_grid) meets no blocked cell.

    Args:
        blocked_u8: (H, W) uint8, non-zero = blocked; cells outside count as blocked.
        dist: (H, W) float64 :func:`square_distance_field` of ``blocked_u8`` (cells).
        u, v: the reference point in grid coordinates (cells, finite).
        yaw_grid: heading in the grid frame (rad): world yaw minus the map origin's yaw.
        verts_cells: (K, 2) float64 counter-clockwise body-frame vertices in cells (metres /
            resolution).
        r_in, r_out: the footprint's inradius and circumradius in cells. With a field of zeros
            and ``r_in = 0`` no shortcut applies and every pose gets the exact test.
    """
    rows, cols = blocked_u8.shape
    if 0.0 <= u < cols and 0.0 <= v < rows:
        d = dist[int(v), int(u)]
        if d > r_out + _SHORTCUT_MARGIN:
            return True
        if d + _SQRT2 < r_in - _SHORTCUT_MARGIN:
            return False
    p = _place(u, v, yaw_grid, verts_cells)
    n, h, half = _edges(p)
    return _sat_free(blocked_u8, p, n, h, half)


@numba.njit(cache=True, nogil=True)
def _point_segment(px: float, py: float, ax: float, ay: float, bx: float, by: float) -> float:
    """Distance from point p to segment a-b."""
    dx, dy = bx - ax, by - ay
    ll = dx * dx + dy * dy
    t = 0.0
    if ll > 0.0:
        t = min(max(((px - ax) * dx + (py - ay) * dy) / ll, 0.0), 1.0)
    return math.hypot(px - ax - t * dx, py - ay - t * dy)


@numba.njit(cache=True, nogil=True)
def _square_gap(p: NDArray[np.float64], col: int, row: int) -> float:
    """Distance between the polygon and a cell square it does not meet: the least distance from
    a vertex of either to the other's boundary."""
    best = np.inf
    k = p.shape[0]
    for i in range(k):
        du = max(col - p[i, 0], p[i, 0] - (col + 1.0), 0.0)
        dv = max(row - p[i, 1], p[i, 1] - (row + 1.0), 0.0)
        best = min(best, math.hypot(du, dv))
    for corner in range(4):
        qx = col + (corner & 1)
        qy = row + (corner >> 1)
        for i in range(k):
            j = i + 1 if i + 1 < k else 0
            best = min(best, _point_segment(qx, qy, p[i, 0], p[i, 1], p[j, 0], p[j, 1]))
    return best


@numba.njit(cache=True, nogil=True)
def pose_clearance_uv(
    blocked_u8: NDArray[np.uint8],
    dist: NDArray[np.float64],
    u: float,
    v: float,
    yaw_grid: float,
    verts_cells: NDArray[np.float64],
    r_in: float,
    r_out: float,
    cap: float,
) -> float:
    """Distance (cells) between the footprint at grid pose (u, v, yaw_grid) and the nearest
    blocked cell square (outside cells included); 0 in collision, ``cap`` when none is nearer.

    Arguments as in :func:`pose_free_uv`; ``cap`` >= 0 in cells. Cells are visited in rings
    round the polygon's bounding box: every cell of ring k is at least k - 1 cells away, so the
    walk stops once that bound reaches the best distance found.
    """
    if not pose_free_uv(blocked_u8, dist, u, v, yaw_grid, verts_cells, r_in, r_out):
        return 0.0
    rows, cols = blocked_u8.shape
    # Every point of the polygon is within r_out of (u, v); every blocked square at least dist.
    if 0.0 <= u < cols and 0.0 <= v < rows and dist[int(v), int(u)] - r_out >= cap:
        return cap
    p = _place(u, v, yaw_grid, verts_cells)
    umin, umax, vmin, vmax = _box(p)
    # The cells outside the grid fill everything beyond the grid's edges.
    best = min(cap, umin, vmin, cols - umax, rows - vmax)
    c0, c1, r0, r1 = _cell_range(umin, umax, vmin, vmax)
    k = 0
    while k - 1 < best:
        for r in range(max(r0 - k, 0), min(r1 + k, rows - 1) + 1):
            if k == 0 or r == r0 - k or r == r1 + k:
                lo, hi, step = max(c0 - k, 0), min(c1 + k, cols - 1), 1
            else:
                # Inside the ring's rows only its first and last column belong to it.
                lo, hi, step = c0 - k, c1 + k, c1 - c0 + 2 * k
            for c in range(lo, hi + 1, step):
                if 0 <= c < cols and blocked_u8[r, c] != 0:
                    du = max(c - umax, umin - (c + 1.0), 0.0)
                    dv = max(r - vmax, vmin - (r + 1.0), 0.0)
                    if math.hypot(du, dv) < best:
                        best = min(best, _square_gap(p, c, r))
        k += 1
    return best


@numba.njit(cache=True, nogil=True)
def poses_free_uv(
    blocked_u8: NDArray[np.uint8],
    dist: NDArray[np.float64],
    uvyaw: NDArray[np.float64],
    verts_cells: NDArray[np.float64],
    r_in: float,
    r_out: float,
) -> NDArray[np.bool_]:
    """(N,) bool :func:`pose_free_uv` for each row (u, v, yaw_grid) of ``uvyaw`` (N, 3)."""
    out = np.empty(uvyaw.shape[0], dtype=np.bool_)
    for i in range(uvyaw.shape[0]):
        out[i] = pose_free_uv(
            blocked_u8, dist, uvyaw[i, 0], uvyaw[i, 1], uvyaw[i, 2], verts_cells, r_in, r_out
        )
    return out


@numba.njit(cache=True, nogil=True)
def poses_clearance_uv(
    blocked_u8: NDArray[np.uint8],
    dist: NDArray[np.float64],
    uvyaw: NDArray[np.float64],
    verts_cells: NDArray[np.float64],
    r_in: float,
    r_out: float,
    cap: float,
) -> NDArray[np.float64]:
    """(N,) float64 :func:`pose_clearance_uv` (cells) for each row of ``uvyaw`` (N, 3)."""
    out = np.empty(uvyaw.shape[0])
    for i in range(uvyaw.shape[0]):
        out[i] = pose_clearance_uv(
            blocked_u8,
            dist,
            uvyaw[i, 0],
            uvyaw[i, 1],
            uvyaw[i, 2],
            verts_cells,
            r_in,
            r_out,
            cap,
        )
    return out


@numba.njit(cache=True, nogil=True)
def _touched(p: NDArray[np.float64]) -> NDArray[np.int64]:
    """(M, 2) (row, col) of every cell whose closed square the placed polygon meets."""
    n, h, half = _edges(p)
    umin, umax, vmin, vmax = _box(p)
    c0, c1, r0, r1 = _cell_range(umin, umax, vmin, vmax)
    out = np.empty(((r1 - r0 + 1) * (c1 - c0 + 1), 2), dtype=np.int64)
    m = 0
    for r in range(r0, r1 + 1):
        for c in range(c0, c1 + 1):
            if _meets(n, h, half, c, r):
                out[m, 0] = r
                out[m, 1] = c
                m += 1
    return out[:m]


# --- the world-frame wrapper --------------------------------------------------------------------


def _grid_poses(grid: OccupancyGrid, poses: ArrayLike) -> NDArray[np.float64]:
    """(N, 3) world poses (x m, y m, yaw rad) -> (N, 3) C-contiguous (u, v, yaw_grid)."""
    q = np.asarray(poses, dtype=np.float64)
    if q.ndim == 1 and q.shape == (3,):
        q = q[None, :]
    if q.ndim != 2 or q.shape[1] != 3:
        raise InputError(f"poses must be an (N, 3) array of x, y, yaw, got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        i = int(np.flatnonzero(~np.all(np.isfinite(q), axis=1))[0])
        raise InputError(f"pose {i} is not finite: {q[i].tolist()}", hint="drop or fix that pose")
    out = np.empty_like(q)
    out[:, :2] = world_to_uv(grid, q[:, :2])
    out[:, 2] = q[:, 2] - float(grid.origin_xy_yaw[2])
    return out


def _verts_cells(footprint: Footprint, grid: OccupancyGrid) -> NDArray[np.float64]:
    res = float(grid.resolution_m)
    if not math.isfinite(res) or res <= 0:
        raise MapError(f"map resolution must be > 0 m, got {grid.resolution_m!r}")
    return np.ascontiguousarray(footprint.vertices / res)


class FootprintChecker:
    """Collision and clearance of one footprint at many world poses on one map.

    ``blocked`` (H, W) bool are the cells the footprint may not touch (e.g.
    ``build_costmap(grid, 0.0).blocked``: occupied and unknown cells, not inflated); ``grid``
    gives the resolution and origin. A compiled search can call :func:`pose_free_uv` with this
    object's ``blocked_u8``, ``dist``, ``verts_cells``, ``r_in`` and ``r_out`` directly.

    Attributes:
        grid: the map.
        footprint: the robot's outline.
        blocked_u8: (H, W) uint8 C-contiguous, 1 = blocked.
        dist: (H, W) float64 :func:`square_distance_field` of ``blocked`` (cells).
        verts_cells: (K, 2) float64 footprint vertices in cells.
        r_in, r_out: the footprint's inradius and circumradius in cells.
    """

    def __init__(
        self,
        blocked: NDArray[np.bool_],
        grid: OccupancyGrid,
        footprint: Footprint,
        *,
        dist: NDArray[np.float64] | None = None,
    ) -> None:
        b = np.asarray(blocked)
        shape = np.asarray(grid.prob).shape
        if b.shape != shape:
            raise MapError(f"blocked cells have shape {b.shape}, the map has {shape}")
        self.grid = grid
        self.footprint = footprint
        self.blocked_u8 = np.ascontiguousarray(b.astype(np.uint8))
        # Another checker's field of the same cells may be passed to skip recomputing it.
        self.dist = square_distance_field(b.astype(bool)) if dist is None else dist
        self.verts_cells = _verts_cells(footprint, grid)
        res = float(grid.resolution_m)
        self.r_in = footprint.inradius_m / res
        self.r_out = footprint.circumradius_m / res

    def to_grid(self, poses: ArrayLike) -> NDArray[np.float64]:
        """(N, 3) world poses (x m, y m, yaw rad) -> (N, 3) grid poses (u, v cells, yaw rad)."""
        return _grid_poses(self.grid, poses)

    def free(self, poses: ArrayLike) -> NDArray[np.bool_]:
        """(N,) bool: the footprint at each world pose (N, 3) meets no blocked cell."""
        return self.free_uv(self.to_grid(poses))

    def free_uv(self, uvyaw: NDArray[np.float64]) -> NDArray[np.bool_]:
        """(N,) bool, as :meth:`free` for grid poses (N, 3) ``u, v`` (cells), yaw in the
        grid frame."""
        uvyaw = np.ascontiguousarray(np.asarray(uvyaw, dtype=np.float64).reshape(-1, 3))
        return np.asarray(
            poses_free_uv(
                self.blocked_u8, self.dist, uvyaw, self.verts_cells, self.r_in, self.r_out
            ),
            dtype=bool,
        )

    def clearance(self, poses: ArrayLike, cap_m: float = 2.0) -> NDArray[np.float64]:
        """(N,) float64 metres from the footprint at each world pose (N, 3) to the nearest
        blocked cell square: 0 in collision, ``cap_m`` when none lies within ``cap_m``."""
        cap = float(cap_m)
        if not math.isfinite(cap) or cap < 0:
            raise ConfigError(f"cap_m: must be a finite number >= 0, got {cap_m!r}")
        res = float(self.grid.resolution_m)
        uvyaw = self.to_grid(poses)
        cells = poses_clearance_uv(
            self.blocked_u8,
            self.dist,
            uvyaw,
            self.verts_cells,
            self.r_in,
            self.r_out,
            cap / res,
        )
        return np.minimum(np.asarray(cells, dtype=np.float64) * res, cap)


def footprint_cells(
    footprint: Footprint, pose: ArrayLike, grid: OccupancyGrid
) -> NDArray[np.int64]:
    """(M, 2) int64 (row, col) of the grid's cells whose closed squares the footprint at world
    pose (x m, y m, yaw rad) meets, row by row; cells outside the grid are left out."""
    uvyaw = _grid_poses(grid, pose)
    if uvyaw.shape[0] != 1:
        raise InputError(f"footprint_cells takes one pose (x, y, yaw), got {uvyaw.shape[0]}")
    u, v, yaw = (float(a) for a in uvyaw[0])
    cells = _touched(_place(u, v, yaw, _verts_cells(footprint, grid)))
    rows, cols = np.asarray(grid.prob).shape
    inside = (cells[:, 0] >= 0) & (cells[:, 0] < rows) & (cells[:, 1] >= 0) & (cells[:, 1] < cols)
    return np.asarray(cells[inside], dtype=np.int64)
