"""Footprint polygons checked exactly against occupancy grids.

The reference here shares no code with the checker: the footprint is placed in the world by
hand and carried into grid coordinates with ``world_to_uv``, the grid is padded with blocked
cells (the cells outside count as blocked), and a polygon meets a cell square when a vertex of
either lies in the other or two of their edges cross. Distances are the least vertex-to-edge
distance either way, minimised over every blocked cell by brute force.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import pytest
from conftest import shared_path
from numpy.typing import NDArray

from slamcli.errors import ConfigError, InputError, MapError
from slamcli.planning.costmap import build_costmap, uv_to_world, world_to_uv
from slamcli.planning.footprint import (
    Footprint,
    FootprintChecker,
    footprint_cells,
    parse_footprint,
    pose_free_uv,
    poses_free_uv,
    square_distance_field,
)
from slamcli.types import OccupancyGrid

# --- the reference -----------------------------------------------------------------------------


def _cross(a: NDArray, b: NDArray) -> NDArray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _world_polygon(fp: Footprint, pose: NDArray) -> NDArray:
    """(K, 2) world vertices of the footprint at pose (x, y, yaw)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    v = fp.vertices
    return np.column_stack(
        (pose[0] + c * v[:, 0] - s * v[:, 1], pose[1] + s * v[:, 0] + c * v[:, 1])
    )


def _squares(cols: NDArray, rows: NDArray) -> NDArray:
    """(M, 4, 2) corners of cell squares, counter-clockwise."""
    du = np.array([0.0, 1.0, 1.0, 0.0])
    dv = np.array([0.0, 0.0, 1.0, 1.0])
    return np.stack((cols[:, None] + du, rows[:, None] + dv), axis=-1)


def _meets(poly: NDArray, cols: NDArray, rows: NDArray) -> NDArray:
    """(M,) bool: the closed polygon (K, 2), counter-clockwise, meets each closed cell square."""
    sq = _squares(cols.astype(float), rows.astype(float))
    pu, pv = poly[None, :, 0], poly[None, :, 1]
    c, r = cols[:, None], rows[:, None]
    vertex_in_square = ((c <= pu) & (pu <= c + 1) & (r <= pv) & (pv <= r + 1)).any(axis=1)
    a, b = poly, np.roll(poly, -1, axis=0)
    corner_in_poly = (_cross(b - a, sq[:, :, None, :] - a) >= 0).all(axis=2).any(axis=1)
    # Edges cross: each one's ends lie on both sides of (or on) the other's line.
    p, q = sq[:, :, None, :], np.roll(sq, -1, axis=1)[:, :, None, :]
    o1, o2 = _cross(b - a, p - a), _cross(b - a, q - a)
    o3, o4 = _cross(q - p, a - p), _cross(q - p, b - p)
    edges_cross = ((o1 * o2 <= 0) & (o3 * o4 <= 0)).any(axis=(1, 2))
    return vertex_in_square | corner_in_poly | edges_cross


def _point_segment(p: NDArray, a: NDArray, b: NDArray) -> NDArray:
    d = b - a
    t = np.clip(np.sum((p - a) * d, axis=-1) / np.sum(d * d, axis=-1), 0.0, 1.0)
    return np.hypot(*np.moveaxis(p - a - t[..., None] * d, -1, 0))


def _gap(poly: NDArray, cols: NDArray, rows: NDArray) -> NDArray:
    """(M,) distance between the polygon and each cell square (0 where they meet)."""
    sq = _squares(cols.astype(float), rows.astype(float))
    a, b = poly, np.roll(poly, -1, axis=0)
    corners_to_poly = _point_segment(sq[:, :, None, :], a, b).min(axis=(1, 2))
    s0, s1 = sq[:, None, :, :], np.roll(sq, -1, axis=1)[:, None, :, :]
    poly_to_square = _point_segment(poly[None, :, None, :], s0, s1).min(axis=(1, 2))
    return np.where(_meets(poly, cols, rows), 0.0, np.minimum(corners_to_poly, poly_to_square))


@dataclass
class Case:
    grid: OccupancyGrid
    blocked: NDArray
    fp: Footprint
    margin: int

    def __post_init__(self) -> None:
        m = self.margin
        h, w = self.blocked.shape
        self.pad = np.ones((h + 2 * m, w + 2 * m), dtype=bool)
        self.pad[m : m + h, m : m + w] = self.blocked

    def window(self, poly_uv: NDArray, grow: float) -> tuple[NDArray, NDArray]:
        """Blocked cells (cols, rows, grid indices) of the padded grid near a polygon."""
        pad = self.pad
        m = self.margin
        lo = np.floor(poly_uv.min(axis=0) - grow).astype(int) - 1
        hi = np.floor(poly_uv.max(axis=0) + grow).astype(int) + 1
        assert np.all(lo + m >= 0) and hi[0] + m < pad.shape[1] and hi[1] + m < pad.shape[0]
        rr, cc = np.nonzero(pad[lo[1] + m : hi[1] + m + 1, lo[0] + m : hi[0] + m + 1])
        return cc + lo[0], rr + lo[1]

    def reference_free(self, pose: NDArray) -> bool:
        poly = world_to_uv(self.grid, _world_polygon(self.fp, pose))
        cols, rows = self.window(poly, 0.0)
        return not bool(_meets(poly, cols, rows).any())

    def reference_clearance(self, pose: NDArray, cap_m: float) -> float:
        poly = world_to_uv(self.grid, _world_polygon(self.fp, pose))
        res = self.grid.resolution_m
        cols, rows = self.window(poly, cap_m / res)
        if cols.size == 0:
            return cap_m
        return min(float(_gap(poly, cols, rows).min()) * res, cap_m)

    def poses(self, n: int, rng: np.random.Generator) -> NDArray:
        """World poses whose footprint may leave the grid but stays within the padding."""
        h, w = self.blocked.shape
        r_out = self.fp.circumradius_m / self.grid.resolution_m
        reach = min(r_out / 2, self.margin - r_out - 3)
        uv = np.column_stack((rng.uniform(-reach, w + reach, n), rng.uniform(-reach, h + reach, n)))
        return np.column_stack((uv_to_world(self.grid, uv), rng.uniform(-math.pi, math.pi, n)))


def _random_blocked(shape: tuple[int, int], rng: np.random.Generator, boxes: int) -> NDArray:
    """Scattered cells (0.2 %) and rectangles of random size, none in the left third."""
    h, w = shape
    blocked = rng.random(shape) < 0.002
    for _ in range(boxes):
        r, c = rng.integers(0, h), rng.integers(0, w)
        blocked[r : r + rng.integers(1, 9), c : c + rng.integers(1, 9)] = True
    blocked[:, : w // 3] = False  # room for poses far from everything
    return blocked


def _random_convex(rng: np.random.Generator, radius: float, offset: NDArray) -> Footprint:
    """A convex polygon: points on an ellipse at sorted random angles, shifted by ``offset``."""
    t = np.sort(rng.uniform(0, 2 * math.pi, 7))
    xy = np.column_stack((radius * np.cos(t), 0.6 * radius * np.sin(t))) + offset
    return Footprint(xy)


def _cases() -> list[Case]:
    rng = np.random.default_rng(7)
    small = OccupancyGrid(np.zeros((120, 160), np.float32), 0.05, (1.3, -0.7, 0.0))
    car = OccupancyGrid(np.zeros((120, 150), np.float32), 0.25, (-2.0, 5.0, 3.14))
    odd = OccupancyGrid(np.zeros((63, 141), np.float32), 0.07, (0.4, 2.0, 1.0))
    return [
        Case(small, _random_blocked((120, 160), rng, 20), Footprint.rectangle(0.9, 0.6), 60),
        Case(
            car, _random_blocked((120, 150), rng, 25), Footprint.rectangle(4.5, 1.9, rear_m=1.0), 40
        ),
        # The reference point lies outside this polygon (inradius 0).
        Case(
            odd,
            _random_blocked((63, 141), rng, 20),
            _random_convex(rng, 0.5, np.array([0.6, 0.1])),
            60,
        ),
    ]


CASES = _cases()
CASE_IDS = ["0.9x0.6-yaw0", "4.5x1.9-yaw3.14", "polygon-yaw1-offset"]


# --- collision -----------------------------------------------------------------------------------


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_free_matches_the_reference(case: Case) -> None:
    rng = np.random.default_rng(11)
    poses = case.poses(1500, rng)
    checker = FootprintChecker(case.blocked, case.grid, case.fp)
    got = checker.free(poses)
    want = np.array([case.reference_free(p) for p in poses])
    np.testing.assert_array_equal(got, want)
    assert 0.15 < want.mean() < 0.85  # both answers are well represented


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_shortcuts_never_change_the_answer(case: Case) -> None:
    rng = np.random.default_rng(12)
    checker = FootprintChecker(case.blocked, case.grid, case.fp)
    uvyaw = checker.to_grid(case.poses(3000, rng))
    args = (checker.verts_cells, checker.r_in, checker.r_out)
    fast = poses_free_uv(checker.blocked_u8, checker.dist, uvyaw, *args)
    exact = poses_free_uv(
        checker.blocked_u8,
        np.zeros_like(checker.dist),
        uvyaw,
        checker.verts_cells,
        0.0,
        checker.r_out,
    )
    np.testing.assert_array_equal(fast, exact)
    # Which poses each shortcut decided: both fire, and only where the exact test agrees.
    h, w = case.blocked.shape
    inside = (uvyaw[:, 0] >= 0) & (uvyaw[:, 0] < w) & (uvyaw[:, 1] >= 0) & (uvyaw[:, 1] < h)
    d = np.full(len(uvyaw), np.nan)  # no shortcut for a reference point off the grid
    d[inside] = checker.dist[uvyaw[inside, 1].astype(int), uvyaw[inside, 0].astype(int)]
    far = d > checker.r_out
    deep = d + math.sqrt(2) < checker.r_in
    assert far.sum() > 100
    assert exact[far].all() and not exact[deep].any()
    if case.fp.inradius_m > 0:
        assert deep.sum() > 50


def test_square_distance_field_is_the_exact_square_to_square_distance() -> None:
    rng = np.random.default_rng(3)
    blocked = rng.random((23, 31)) < 0.02
    got = square_distance_field(blocked)
    m = 1
    pad = np.ones((23 + 2 * m, 31 + 2 * m), dtype=bool)
    pad[m:-m, m:-m] = blocked
    br, bc = np.nonzero(pad)
    rr, cc = np.mgrid[0:23, 0:31]
    # Gap between two unit squares along one axis: the offset less one, or 0 when they touch.
    gr = np.maximum(np.abs(rr[..., None] + m - br) - 1, 0)
    gc = np.maximum(np.abs(cc[..., None] + m - bc) - 1, 0)
    np.testing.assert_allclose(got, np.hypot(gr, gc).min(axis=-1), atol=1e-12)
    assert got.max() > 3  # the grid has cells far from every obstacle


def test_kernel_is_callable_from_compiled_code() -> None:
    case = CASES[0]
    checker = FootprintChecker(case.blocked, case.grid, case.fp)

    @numba.njit
    def count_free(blocked, dist, uvyaw, verts, r_in, r_out):  # type: ignore[no-untyped-def]
        n = 0
        for i in range(uvyaw.shape[0]):
            if pose_free_uv(
                blocked, dist, uvyaw[i, 0], uvyaw[i, 1], uvyaw[i, 2], verts, r_in, r_out
            ):
                n += 1
        return n

    poses = case.poses(500, np.random.default_rng(5))
    n = count_free(
        checker.blocked_u8,
        checker.dist,
        checker.to_grid(poses),
        checker.verts_cells,
        checker.r_in,
        checker.r_out,
    )
    assert n == int(checker.free(poses).sum())


def test_touching_the_map_edge_or_a_blocked_corner_collides() -> None:
    # Binary fractions throughout, so every coordinate below is exact.
    grid = OccupancyGrid(np.zeros((16, 16), np.float32), 0.25, (0.0, 0.0, 0.0))
    blocked = np.zeros((16, 16), dtype=bool)
    blocked[8, 8] = True  # the square [2, 2.25] x [2, 2.25] m
    checker = FootprintChecker(blocked, grid, Footprint.rectangle(0.5, 0.25))
    # Flush with x = 0 (the edge of the grid), then just inside it.
    assert not checker.free([[0.25, 3.0, 0.0]])[0]
    assert checker.free([[0.25 + 2**-20, 3.0, 0.0]])[0]
    # A diamond whose tip reaches the blocked square's corner (2, 2), or stops just short.
    diamond = Footprint(np.array([[0.5, 0.0], [0.0, 0.25], [-0.5, 0.0], [0.0, -0.25]]))
    tip = FootprintChecker(blocked, grid, diamond)
    assert not tip.free([[1.5, 2.0, 0.0]])[0]
    assert tip.free([[1.5 - 2**-20, 2.0, 0.0]])[0]
    assert tip.clearance([[1.5 - 2**-20, 2.0, 0.0]])[0] == pytest.approx(2**-20, rel=1e-9)


# --- clearance ----------------------------------------------------------------------------------


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_clearance_matches_brute_force(case: Case) -> None:
    rng = np.random.default_rng(21)
    poses = case.poses(300, rng)
    cap = 1.0 if case.grid.resolution_m < 0.2 else 3.0
    checker = FootprintChecker(case.blocked, case.grid, case.fp)
    got = checker.clearance(poses, cap_m=cap)
    want = np.array([case.reference_clearance(p, cap) for p in poses])
    np.testing.assert_allclose(got, want, atol=1e-9)
    np.testing.assert_array_equal(got > 0, checker.free(poses))
    assert ((got > 0) & (got < cap)).mean() > 0.2


def test_clearance_cap_and_empty_map() -> None:
    grid = OccupancyGrid(np.zeros((100, 100), np.float32), 0.1, (0.0, 0.0, 0.5))
    checker = FootprintChecker(
        np.zeros((100, 100), dtype=bool), grid, Footprint.rectangle(0.9, 0.6)
    )
    centre = uv_to_world(grid, [50.0, 50.0])
    pose = np.array([[centre[0], centre[1], 0.5]])
    # Axis-aligned with the grid, centred: 5 m to each edge less half the rectangle.
    np.testing.assert_allclose(checker.clearance(pose, cap_m=10.0), [5.0 - 0.45], atol=1e-9)
    np.testing.assert_allclose(checker.clearance(pose, cap_m=2.0), [2.0])
    with pytest.raises(ConfigError, match="cap_m"):
        checker.clearance(pose, cap_m=-1.0)


# --- cells and shapes ----------------------------------------------------------------------------


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_footprint_cells_match_the_reference_and_cover_sampled_points(case: Case) -> None:
    rng = np.random.default_rng(31)
    h, w = case.blocked.shape
    for pose in case.poses(40, rng):
        cells = footprint_cells(case.fp, pose, case.grid)
        poly = world_to_uv(case.grid, _world_polygon(case.fp, pose))
        lo = np.floor(poly.min(axis=0)).astype(int) - 1
        hi = np.floor(poly.max(axis=0)).astype(int) + 1
        cc, rr = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
        cc, rr = cc.ravel(), rr.ravel()
        keep = _meets(poly, cc, rr) & (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        assert {tuple(x) for x in cells.tolist()} == set(
            zip(rr[keep].tolist(), cc[keep].tolist(), strict=True)
        )
        # Points sampled densely inside the footprint fall in listed cells.
        bary = rng.dirichlet(np.ones(len(poly)), 2000)
        pts = bary @ poly
        inside = (pts[:, 0] >= 0) & (pts[:, 0] < w) & (pts[:, 1] >= 0) & (pts[:, 1] < h)
        got = {tuple(x) for x in cells.tolist()}
        assert {(int(v), int(u)) for u, v in pts[inside]} <= got


def test_free_agrees_with_footprint_cells_inside_the_grid() -> None:
    case = CASES[0]
    checker = FootprintChecker(case.blocked, case.grid, case.fp)
    for pose in case.poses(200, np.random.default_rng(41)):
        poly = world_to_uv(case.grid, _world_polygon(case.fp, pose))
        h, w = case.blocked.shape
        if poly.min() > 0 and poly[:, 0].max() < w and poly[:, 1].max() < h:
            cells = footprint_cells(case.fp, pose, case.grid)
            assert checker.free(pose)[0] == (not case.blocked[cells[:, 0], cells[:, 1]].any())


def test_rectangles() -> None:
    small = Footprint.rectangle(0.9, 0.6)
    np.testing.assert_allclose(
        small.vertices, [[-0.45, -0.3], [0.45, -0.3], [0.45, 0.3], [-0.45, 0.3]]
    )
    assert small.circumradius_m == pytest.approx(math.hypot(0.45, 0.3))
    assert small.inradius_m == pytest.approx(0.3)
    car = Footprint.rectangle(4.5, 1.9, rear_m=1.0)
    assert car.vertices[:, 0].min() == pytest.approx(-1.0)
    assert car.vertices[:, 0].max() == pytest.approx(3.5)
    assert car.circumradius_m == pytest.approx(math.hypot(3.5, 0.95))
    assert car.inradius_m == pytest.approx(0.95)
    assert Footprint.rectangle(4.5, 1.9, rear_m=-0.5).inradius_m == 0.0
    with pytest.raises(ConfigError, match="width"):
        Footprint.rectangle(1.0, 0.0)


def test_parse_footprint() -> None:
    fp = parse_footprint("-0.45,-0.3; 0.45,-0.3; 0.45,0.3; -0.45,0.3")
    assert fp == Footprint.rectangle(0.9, 0.6)
    # Clockwise input is reversed; a vertex on a straight edge is dropped.
    cw = parse_footprint("0,0;0,1;1,1;1,0.5;1,0")
    assert len(cw.vertices) == 4
    area = 0.5 * np.sum(_cross(cw.vertices, np.roll(cw.vertices, -1, axis=0)))
    assert area == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("0,0;1,0", "at least 3"),
        ("0,0;1,x;1,1", "not an 'x,y' pair"),
        ("0,0,0;1,0;1,1", "not an 'x,y' pair"),
        ("0,0;1,0;nan,1", "finite"),
        ("0,0;1,0;2,0", "zero area"),
        ("0,0;2,0;2,2;1,0.5;0,2", "not convex"),  # an arrowhead
        ("0,0;1,1;1,0;0,1", "not convex"),  # a bow tie
        ("0,1;0.59,-0.81;-0.95,0.31;0.95,0.31;-0.59,-0.81", "crosses itself"),  # a pentagram
    ],
)
def test_parse_errors_name_the_option(text: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match) as info:
        parse_footprint(text, option="--robot-footprint")
    assert "--robot-footprint" in str(info.value)
    assert info.value.hint


def test_bad_inputs() -> None:
    case = CASES[0]
    checker = FootprintChecker(case.blocked, case.grid, case.fp)
    with pytest.raises(InputError, match="not finite"):
        checker.free([[0.0, np.nan, 0.0]])
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        checker.free(np.zeros((4, 2)))
    with pytest.raises(MapError, match="shape"):
        FootprintChecker(case.blocked[:-1], case.grid, case.fp)


# --- a real map ---------------------------------------------------------------------------------


def test_stata_basement_matches_the_reference() -> None:
    """The Stata map's origin is turned by 3.14 rad; poses near its free space."""
    from slamcli.planning.planner import load_map

    grid, _ = load_map(shared_path("maps", "stata_basement.yaml"))
    blocked = build_costmap(grid, 0.0).blocked
    case = Case(grid, blocked, Footprint.rectangle(0.9, 0.6), 20)
    rng = np.random.default_rng(51)
    rows, cols = np.nonzero(~blocked)
    pick = rng.integers(0, len(rows), 1500)
    uv = np.column_stack((cols[pick], rows[pick])) + rng.random((1500, 2))
    poses = np.column_stack((uv_to_world(grid, uv), rng.uniform(-math.pi, math.pi, 1500)))
    checker = FootprintChecker(blocked, grid, case.fp)
    got = checker.free(poses)
    np.testing.assert_array_equal(got, [case.reference_free(p) for p in poses])
    assert 0.2 < got.mean() < 0.95
