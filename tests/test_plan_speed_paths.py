"""`slamcli plan`'s fast paths against independent references, the unknown-space policy, the
stage timings in plan.json, and the map origin's yaw in planning, `map show` and the plots.

The references are the slow, obvious computations: scipy's Euclidean distance transform for the
blocking rule, brute force over every cell or every later point, numpy's vectorised profile
methods and :func:`slamcli.geometry.planar.unicycle_step` for the tracker's scalar loop,
``numpy.savetxt`` for the CSV text.
"""

from __future__ import annotations

import io
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy import ndimage
from typer.testing import CliRunner

import slamcli.planning.costmap as costmap_module
from slamcli.cli.app import app
from slamcli.errors import MapError, NoPathError
from slamcli.formats.occupancy import cell_to_world, world_to_cell, write_map_yaml
from slamcli.geometry.planar import unicycle_step
from slamcli.planning.costmap import (
    TIE_TOL_M,
    build_costmap,
    distance_at,
    map_bounds,
    nearest_free_cell,
    world_to_uv,
)
from slamcli.planning.output import _csv
from slamcli.planning.planner import PlanResult, min_clearance, plan, reachable_cells
from slamcli.planning.plot import INFLATED_RGB, plan_canvas, plot_plan
from slamcli.planning.smooth import SegmentChecker, segment_costs, shortcut, touched_cells
from slamcli.planning.tracker import _Track, unicycle_step_scalar
from slamcli.planning.trajectory import Limits, time_parameterise
from slamcli.types import OccupancyGrid, SlamResult, Trajectory

runner = CliRunner()


def _grid(prob: np.ndarray, res: float = 0.1, origin=(0.0, 0.0, 0.0)) -> OccupancyGrid:
    return OccupancyGrid(np.asarray(prob, dtype=np.float32), res, tuple(origin))


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


# --- free space -------------------------------------------------------------------------------


def test_inflation_follows_the_distance_transform_rule() -> None:
    rng = np.random.default_rng(11)
    for trial in range(60):
        h, w = (int(v) for v in rng.integers(1, 50, 2))
        res = float(rng.choice([0.05, 0.0504, 0.1, 0.3]))
        occupied = rng.random((h, w)) < rng.uniform(0.0, 0.1)
        # Radii on exact multiples (ties), just off them, and beyond the map's size.
        k = float(rng.choice([0, 1, 2, 2.5, 5, 3 * math.sqrt(2), 60]))
        radius = k * res + float(rng.choice([0.0, 1e-7, -1e-7])) if k else 0.0
        cm = build_costmap(_grid(occupied.astype(np.float32), res), max(radius, 0.0))
        if occupied.any():
            d = ndimage.distance_transform_edt(~occupied, sampling=res)
            want = occupied | (d <= max(radius, 0.0) + TIE_TOL_M)
        else:
            want = occupied
        np.testing.assert_array_equal(cm.blocked, want, err_msg=f"trial {trial}")


def test_distances_are_computed_only_when_asked(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(2)
    occupied = rng.random((40, 30)) < 0.05
    grid = _grid(occupied.astype(np.float32), 0.05)
    want = ndimage.distance_transform_edt(~occupied, sampling=0.05)
    np.testing.assert_array_equal(build_costmap(grid).distance_m, want)

    def forbidden(*_: Any) -> None:
        raise AssertionError("a distance transform of the whole map")

    monkeypatch.setattr(costmap_module, "occupied_distance_m", forbidden)
    cm = build_costmap(grid)
    for cell in np.argwhere(cm.blocked & ~cm.occupied)[:20]:
        r, c = (int(v) for v in cell)
        assert distance_at(cm, (r, c), 0.2 + TIE_TOL_M) == want[r, c]
    for cell in np.argwhere(want > 0.3)[:20]:
        assert distance_at(cm, (int(cell[0]), int(cell[1])), 0.3) == math.inf


def test_nearest_free_cell_is_the_nearest() -> None:
    rng = np.random.default_rng(5)
    for _ in range(200):
        h, w = (int(v) for v in rng.integers(1, 80, 2))
        blocked = rng.random((h, w)) < rng.choice([0.5, 0.98, 0.999, 1.0])
        cell = (int(rng.integers(h)), int(rng.integers(w)))
        free = np.argwhere(~blocked)
        got = nearest_free_cell(blocked, cell)
        if len(free) == 0:
            assert got is None
            continue
        d2 = ((free - np.array(cell)) ** 2).sum(axis=1)
        best = free[d2 == d2.min()]
        # Ties go to the smallest (row, col).
        assert got == tuple(int(v) for v in best[np.lexsort((best[:, 1], best[:, 0]))[0]])


def test_reachable_cells_are_the_4_connected_component() -> None:
    rng = np.random.default_rng(8)
    for _ in range(50):
        blocked = rng.random((30, 40)) < 0.45
        free = np.argwhere(~blocked)
        cell = tuple(int(v) for v in free[rng.integers(len(free))])
        labels, _ = ndimage.label(~blocked)
        assert reachable_cells(blocked, cell) == np.count_nonzero(labels == labels[cell])


# --- smoothing --------------------------------------------------------------------------------


def _free_by_cells(blocked: np.ndarray, p: np.ndarray, q: np.ndarray) -> bool:
    cells = touched_cells(p, q)
    h, w = blocked.shape
    inside = (cells[:, 0] >= 0) & (cells[:, 0] < h) & (cells[:, 1] >= 0) & (cells[:, 1] < w)
    return bool(inside.all() and not blocked[cells[:, 0], cells[:, 1]].any())


def _random_segments(rng: np.random.Generator, n: int, size: int) -> tuple[np.ndarray, ...]:
    p = rng.uniform(-1, size + 1, (n, 2))
    q = rng.uniform(-1, size + 1, (n, 2))
    exact = rng.random(n) < 0.4  # on cell edges and corners, and axis-aligned
    p[exact] = np.round(p[exact] * 2) / 2
    q[exact] = np.round(q[exact] * 2) / 2
    upright = exact & (rng.random(n) < 0.5)
    q[upright, 0] = p[upright, 0]
    short = rng.random(n) < 0.3
    q[short] = p[short] + rng.normal(0, 1.5, (int(short.sum()), 2))
    return p, q


def test_segment_checks_agree_with_the_touched_cells() -> None:
    rng = np.random.default_rng(3)
    for _ in range(15):
        size = int(rng.integers(4, 40))
        blocked = rng.random((size, size)) < rng.uniform(0.0, 0.3)
        p, q = _random_segments(rng, 150, size)
        checker = SegmentChecker(blocked)
        want = np.array([_free_by_cells(blocked, a, b) for a, b in zip(p, q, strict=True)])
        np.testing.assert_array_equal(checker.free(p, q), want)
        # The sampled pre-check only ever rules out segments that are not free.
        assert not (want & ~checker.maybe_free(p, q)).any()


def _shortcut_reference(points: np.ndarray, blocked: np.ndarray, extra: np.ndarray | None):
    """Every later point checked, the farthest that qualifies kept."""
    cum = None
    if extra is not None:
        cum = np.concatenate(([0.0], np.cumsum(segment_costs(points[:-1], points[1:], extra))))
    kept, i = [0], 0
    while i < len(points) - 1:
        j = i + 1
        for k in range(len(points) - 1, i, -1):
            if not _free_by_cells(blocked, points[i], points[k]):
                continue
            if cum is not None and extra is not None:
                cost = segment_costs(points[i : i + 1], points[k : k + 1], extra)[0]
                if cost > cum[k] - cum[i] + 1e-9 * (1.0 + cum[-1]):
                    continue
            j = k
            break
        kept.append(j)
        i = j
    return points[kept]


def test_shortcut_keeps_the_farthest_point_in_sight() -> None:
    rng = np.random.default_rng(4)
    for trial in range(12):
        blocked = rng.random((30, 30)) < 0.12
        free = np.argwhere(~blocked)[:, ::-1] + 0.5
        # A walk over free cell centres; its own steps need not be free for the comparison.
        points = free[rng.choice(len(free), 20, replace=False)]
        points = points[np.argsort(points[:, 0] + 0.3 * points[:, 1])]
        extra = rng.random(blocked.shape) * 2 if trial % 2 else None
        got = shortcut(points, SegmentChecker(blocked), extra)
        np.testing.assert_array_equal(got, _shortcut_reference(points, blocked, extra))


# --- tracker ----------------------------------------------------------------------------------


def test_scalar_unicycle_step_is_the_vectorised_one_bit_for_bit() -> None:
    rng = np.random.default_rng(6)
    args = rng.normal(size=(2000, 6)) * [5, 5, 3, 1, 2, 0.05]
    args[::7, 4] = 0.0  # straight steps
    args[:, 5] = np.abs(args[:, 5])
    for x, y, yaw, v, omega, dt in args:
        want = np.array(unicycle_step(x, y, yaw, v, omega, dt), dtype=np.float64)
        got = np.array(unicycle_step_scalar(x, y, yaw, v, omega, dt))
        np.testing.assert_array_equal(_bits(got), _bits(want))


def test_track_gives_what_the_profile_gives() -> None:
    rng = np.random.default_rng(9)
    for _ in range(10):
        pts = np.cumsum(rng.normal(size=(int(rng.integers(2, 9)), 2)), axis=0)
        profile = time_parameterise(pts, Limits(0.7, 1.2, 0.4))
        track = _Track(profile)
        s = np.concatenate(
            (rng.uniform(-1, profile.length_m + 1, 300), profile.vertex_s, profile.s[:50])
        )
        want = profile.xy_at_s(s)
        got = np.array([track.xy_at(float(v)) for v in s])
        np.testing.assert_array_equal(_bits(got), _bits(want))
        t = np.concatenate((rng.uniform(-1, profile.duration_s + 1, 300), profile.t[:50]))
        rows = profile.sample(t)
        got = np.array([track.reference(float(v)) for v in t])
        np.testing.assert_array_equal(_bits(got), _bits(rows[:, [6, 4]]))
        for _ in range(100):
            xy = profile.xy_at_s(rng.uniform(0, profile.length_m)) + rng.normal(0, 0.3, 2)
            lo = float(rng.uniform(0, profile.length_m))
            hi = lo + float(rng.uniform(0, 1.5))
            # Reference: the nearest of many points of the path between lo and hi.
            dense = profile.xy_at_s(np.linspace(lo, min(hi, profile.length_m), 4001))
            s_got, d_got = track.project(float(xy[0]), float(xy[1]), lo, hi)
            assert d_got <= np.linalg.norm(dense - xy, axis=1).min() + 1e-9
            assert lo - 1e-12 <= s_got <= hi + 1e-12
            assert d_got == pytest.approx(float(np.linalg.norm(profile.xy_at_s(s_got) - xy)))


# --- clearance --------------------------------------------------------------------------------


def _clearance_reference(grid: OccupancyGrid, occupied: np.ndarray, path: np.ndarray) -> float:
    centres = cell_to_world(grid, np.argwhere(occupied))
    if len(path) == 1:
        return float(np.linalg.norm(centres - path[0], axis=1).min())
    a, b = path[:-1], path[1:]
    ab = b - a
    t = np.clip(((centres[:, None] - a[None]) * ab[None]).sum(2) / (ab**2).sum(1)[None], 0, 1)
    foot = a[None] + t[..., None] * ab[None]
    return float(np.linalg.norm(centres[:, None] - foot, axis=2).min())


def test_min_clearance_is_exact() -> None:
    rng = np.random.default_rng(10)
    for trial in range(40):
        occupied = rng.random((60, 50)) < rng.choice([0.0005, 0.01, 0.05])
        if not occupied.any():
            occupied[int(rng.integers(60)), int(rng.integers(50))] = True
        origin = (rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-math.pi, math.pi))
        grid = _grid(occupied.astype(np.float32), 0.1, origin)
        cm = build_costmap(grid, float(rng.choice([0.0, 0.2])))
        uv = rng.uniform(0, 50, (int(rng.choice([1, 2, 8])), 2))
        path = cell_to_world(grid, uv[:, ::-1] - 0.5)
        assert min_clearance(cm, path) == pytest.approx(
            _clearance_reference(grid, occupied, path), abs=1e-12
        ), trial
    empty = build_costmap(_grid(np.zeros((5, 5))))
    assert min_clearance(empty, np.array([[0.1, 0.1], [0.3, 0.2]])) == math.inf


# --- output -----------------------------------------------------------------------------------


def test_csv_text_is_what_savetxt_writes() -> None:
    rng = np.random.default_rng(12)
    for rows in (
        rng.normal(size=(500, 6)) * 1e3,
        np.array([[-0.0, 1e-7, -4e-7, 0.5e-6]]),
        np.zeros((0, 6)),
        np.array([1.25, -2.5]),
    ):
        buf = io.StringIO()
        np.savetxt(buf, np.atleast_2d(rows), fmt="%.6f", delimiter=",", header="t,x", comments="")
        assert _csv("t,x", rows) == buf.getvalue()


STAGES = [
    "read_map",
    "kernels",
    "costmap",
    "search",
    "smooth",
    "trajectory",
    "simulate",
    "clearance",
    "plot",
    "write",
    "total",
]


def _cli(args: list[str]) -> Any:
    return runner.invoke(app, args, env={"NO_COLOR": "1", "COLUMNS": "200"})


def test_plan_json_times_every_stage(tmp_path: Path) -> None:
    map_file = _write_map(tmp_path / "maze.yaml", _maze())
    out = tmp_path / "plan"
    start, goal = _maze_ends(_maze())
    args = ["--start", start, "--goal", goal, "--robot-radius", "0.1", "--out", str(out)]
    res = _cli(["plan", str(map_file), *args])
    assert res.exit_code == 0, res.output
    record = json.loads((out / "plan.json").read_text())
    timings = record["timings_ms"]
    assert list(timings) == STAGES
    assert all(v >= 0 for v in timings.values())
    assert timings["total"] >= sum(v for k, v in timings.items() if k != "total")
    stages = ("costmap", "search", "smooth", "trajectory")
    assert record["plan_ms"] >= sum(timings[k] for k in stages) - 0.01


# --- unknown space ----------------------------------------------------------------------------


def _gap_map() -> OccupancyGrid:
    """4 x 2 m, a wall at x = 2 m whose only opening is unknown space."""
    prob = np.zeros((20, 40), dtype=np.float32)
    prob[:, 19:21] = 1.0
    prob[8:12, 19:21] = np.nan
    prob[0, 30:36] = np.nan  # unknown cells by the far side's edge
    return _grid(prob, 0.1)


def _write_map(path: Path, grid: OccupancyGrid) -> Path:
    write_map_yaml(path, grid)
    return path


def test_unknown_policy_both_ways(tmp_path: Path) -> None:
    map_file = str(_write_map(tmp_path / "gap.yaml", _gap_map()))
    args = ["plan", map_file, "--start", "0.55,1.05", "--goal", "3.45,1.05", "--robot-radius", "0"]

    res = _cli([*args, "--out", str(tmp_path / "a")])
    assert res.exit_code == 1
    assert "no path" in res.output and "--unknown free" in res.output
    res = _cli([*args, "--unknown", "blocked", "--out", str(tmp_path / "b")])
    assert res.exit_code == 1 and "--unknown free" in res.output

    res = _cli([*args, "--unknown", "free", "--out", str(tmp_path / "c")])
    assert res.exit_code == 0, res.output
    record = json.loads((tmp_path / "c" / "plan.json").read_text())
    assert record["settings"]["unknown"] == "free"
    path = np.loadtxt(tmp_path / "c" / "path.csv", delimiter=",", skiprows=1)
    cells = world_to_cell(_gap_map(), path)
    assert np.isnan(_gap_map().prob[cells[:, 0], cells[:, 1]]).any()  # through the gap

    # The deprecated flag is --unknown free, with a warning; it cannot be mixed with blocked.
    res = _cli([*args, "--allow-unknown", "--out", str(tmp_path / "d")])
    assert res.exit_code == 0, res.output
    assert "deprecated" in res.output and "--unknown free" in res.output
    same = np.loadtxt(tmp_path / "d" / "path.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(same, path)
    res = _cli([*args, "--allow-unknown", "--unknown", "blocked", "--out", str(tmp_path / "e")])
    assert res.exit_code == 1 and "contradicts" in res.output
    res = _cli([*args, "--unknown", "maybe", "--out", str(tmp_path / "f")])
    assert res.exit_code == 2
    assert "--allow-unknown" not in _cli(["plan", "--help"]).output


def test_start_in_unknown_space_names_the_option_for_the_policy() -> None:
    grid = _gap_map()
    goal = (0.55, 1.05)
    # Unknown and 0.5 m from any obstacle: only --unknown free frees it.
    with pytest.raises(MapError, match="is in unknown space") as info:
        plan(grid, (3.25, 0.05), goal, robot_radius_m=0.1)
    assert "--unknown free" in (info.value.hint or "")
    assert "--robot-radius" not in (info.value.hint or "")
    # Unknown and 0.1 m from the wall: both must change.
    with pytest.raises(MapError, match="is in unknown space") as info:
        plan(grid, (2.0, 0.85), goal, robot_radius_m=0.15)
    assert "--unknown free with a smaller --robot-radius" in (info.value.hint or "")
    # With --unknown free the same cell is blocked by the radius alone.
    with pytest.raises(MapError, match="within the robot radius") as info:
        plan(grid, (2.0, 0.85), goal, robot_radius_m=0.15, unknown_policy="free")
    assert "--robot-radius" in (info.value.hint or "")
    assert "--unknown" not in (info.value.hint or "")
    with pytest.raises(NoPathError, match="reached"):
        plan(grid, goal, (3.45, 1.05), robot_radius_m=0.0)


def _big_map() -> OccupancyGrid:
    """1300 x 1730 cells (2.2 M) of unknown space around a 10 x 6 m room at 0.05 m."""
    prob = np.full((1300, 1730), np.nan, dtype=np.float32)
    prob[600:720, 800:1000] = 1.0
    prob[602:718, 802:998] = 0.0
    return _grid(prob, 0.05, (-43.0, -30.0, 0.0))


def test_start_errors_on_a_big_map_need_no_distance_transform(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    grid = _big_map()

    def forbidden(*_: Any) -> None:
        raise AssertionError("a distance transform of the whole map")

    monkeypatch.setattr(costmap_module, "occupied_distance_m", forbidden)
    cm = build_costmap(grid, 0.2)
    free = np.argwhere(~cm.blocked)
    goal = tuple(float(v) for v in cell_to_world(grid, free[len(free) // 2]))
    cases = (
        ((-40.0, -28.0), "unknown space", "--unknown free"),
        ((-2.825, 0.525), "robot radius", "--robot-radius"),
    )
    for start, why, option in cases:
        with pytest.raises(MapError, match=why) as info:
            plan(grid, start, goal)
        assert option in (info.value.hint or "")
        m = re.search(r"centred at \((-?[\d.]+), (-?[\d.]+)\) m", info.value.msg)
        assert m, info.value.msg
        cell = np.array(world_to_cell(grid, (float(m.group(1)), float(m.group(2)))))
        assert not cm.blocked[tuple(cell)]
        here = np.array(world_to_cell(grid, start))
        d2 = ((free - here) ** 2).sum(axis=1)
        assert ((cell - here) ** 2).sum() == d2.min()


# --- the origin's yaw -------------------------------------------------------------------------


def _maze() -> OccupancyGrid:
    """A 6 x 4 m block of wall with three 0.3 m corridors carved in a Z, a thick wall between
    them and a patch of unknown space; with a 0.1 m radius each corridor is one cell wide."""
    prob = np.ones((40, 60), dtype=np.float32)
    prob[5:8, 5:51] = 0.0
    prob[5:31, 48:51] = 0.0
    prob[28:31, 10:51] = 0.0
    prob[14:22, 10:20] = np.nan
    return _grid(prob, 0.1, (-2.0, 1.0, 0.0))


def _maze_ends(grid: OccupancyGrid) -> tuple[str, str]:
    s = cell_to_world(grid, (6, 6))
    g = cell_to_world(grid, (29, 11))
    return f"{s[0]:.6f},{s[1]:.6f}", f"{g[0]:.6f},{g[1]:.6f}"


def _turned(grid: OccupancyGrid, quarter_turns: int) -> OccupancyGrid:
    """The same world, stored with the image turned counter-clockwise by 90° steps and the
    origin moved and turned to match."""
    prob = np.asarray(grid.prob)
    h, w = prob.shape
    res = grid.resolution_m
    x0, y0, _ = grid.origin_xy_yaw
    if quarter_turns == 1:
        return _grid(np.rot90(prob, 1), res, (x0 + w * res, y0, math.pi / 2))
    return _grid(prob[::-1, ::-1], res, (x0 + w * res, y0 + h * res, math.pi))


@pytest.mark.parametrize("quarter_turns", [1, 2])
def test_a_turned_map_plans_the_same_world_path(quarter_turns: int) -> None:
    plain = _maze()
    turned = _turned(plain, quarter_turns)
    # The construction: every cell of the turned map holds the plain map's value there.
    rc = np.argwhere(np.ones(np.asarray(turned.prob).shape, dtype=bool))
    back = world_to_cell(plain, cell_to_world(turned, rc))
    np.testing.assert_array_equal(
        np.asarray(turned.prob)[rc[:, 0], rc[:, 1]],
        np.asarray(plain.prob)[back[:, 0], back[:, 1]],
    )
    np.testing.assert_allclose(map_bounds(turned), map_bounds(plain), atol=1e-9)

    start, goal = (tuple(float(v) for v in e.split(",")) for e in _maze_ends(plain))
    a = plan(plain, start, goal, robot_radius_m=0.1)
    b = plan(turned, start, goal, robot_radius_m=0.1)
    assert b.grid_cost_m == pytest.approx(a.grid_cost_m, abs=1e-9)
    np.testing.assert_allclose(b.grid_xy, a.grid_xy, atol=1e-9)
    np.testing.assert_allclose(b.smooth_xy, a.smooth_xy, atol=1e-9)
    assert b.min_clearance_m == pytest.approx(a.min_clearance_m, abs=1e-9)
    # Timing splits each segment into knots by its length, and lengths that are whole
    # multiples of the knot spacing may round either way at 1e-15: the same motion to 1 mm.
    np.testing.assert_allclose(b.trajectory, a.trajectory, atol=1e-3)
    assert b.tracking.time_to_goal_s == pytest.approx(a.tracking.time_to_goal_s, abs=0.05)
    # The paths run along the corridors: through x = 2.95 m (the right-hand corridor).
    assert np.abs(a.smooth_xy[:, 0] - 2.95).min() < 0.1


def test_map_show_prints_the_world_extent(tmp_path: Path) -> None:
    plain = _maze()
    for name, grid in (("plain", plain), ("turned", _turned(plain, 1))):
        res = _cli(["map", "show", str(_write_map(tmp_path / f"{name}.yaml", grid))])
        assert res.exit_code == 0, res.output
        # 60 x 40 cells of 0.1 m from (-2, 1): the same area either way.
        assert re.search(r"extent +x -2 \.\. 4 m, y 1 \.\. 5 m", res.output), res.output


def _pixel(fig: Any, ax: Any, xy: tuple[float, float]) -> np.ndarray:
    """RGB of the figure's pixel at world point ``xy``."""
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())
    px, py = ax.transData.transform(xy)
    return image[int(image.shape[0] - py), int(px), :3].astype(int)


@pytest.mark.parametrize("quarter_turns", [0, 1, 2])
def test_plan_png_draws_cells_where_they_are(quarter_turns: int, tmp_path: Path) -> None:
    import cv2

    plain = _maze()
    grid = plain if quarter_turns == 0 else _turned(plain, quarter_turns)
    start, goal = (tuple(float(v) for v in e.split(",")) for e in _maze_ends(plain))
    result: PlanResult = plan(grid, start, goal, robot_radius_m=0.1)
    png = plot_plan(tmp_path / "plan.png", result)
    image = cv2.imread(str(png), cv2.IMREAD_COLOR)[..., ::-1]
    # The same picture as the canvas's, whose to_pixel finds the world points in it.
    canvas = plan_canvas(result)
    np.testing.assert_array_equal(image, canvas.render())

    def pixel(xy: tuple[float, float]) -> np.ndarray:
        col, row = np.rint(canvas.to_pixel(xy)).astype(int)
        return image[row, col].astype(int)

    wall = tuple(cell_to_world(plain, (24, 30)))  # between the corridors
    unknown = tuple(cell_to_world(plain, (18, 15)))
    inflated = tuple(cell_to_world(plain, (7, 20)))  # beside the path, inside the corridor
    assert (pixel(wall) < 40).all()
    assert (np.abs(pixel(unknown) - 204) <= 3).all()
    pink = np.rint(np.array(INFLATED_RGB) * 255)
    assert (np.abs(pixel(inflated) - pink) <= 3).all()
    # Outside the map (left of x = -2 m) the picture is white.
    assert (pixel((-2.5, 3.3)) == 255).all()


def test_report_map_honours_the_yaw(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    import slamcli.report as report

    plain = _maze()
    figures: list[Any] = []

    def keep(fig: Any, path: Any) -> Path:
        figures.append(fig)
        return Path(path)

    monkeypatch.setattr(report, "save_png", keep)
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, :2, 3] = cell_to_world(plain, np.array([[6, 6], [6, 45], [29, 45]]))
    trajectory = Trajectory(np.arange(3, dtype=np.int64) * 10**9, poses)
    for quarter_turns in (1, 2):
        grid = _turned(plain, quarter_turns)
        report.plot_scan_run(tmp_path / "r.png", SlamResult(trajectory=trajectory, grid=grid), None)
        fig = figures[-1]
        ax = fig.axes[0]
        assert (_pixel(fig, ax, tuple(cell_to_world(plain, (24, 30)))) < 40).all()
        free = _pixel(fig, ax, tuple(cell_to_world(plain, (29, 20))))
        assert (free > 215).all()
        unknown = _pixel(fig, ax, tuple(cell_to_world(plain, (18, 15))))
        assert (np.abs(unknown - 191) <= 3).all()


def test_world_to_uv_turns_with_the_yaw() -> None:
    plain = _maze()
    turned = _turned(plain, 1)
    xy = cell_to_world(plain, np.array([[6, 6], [29, 11], [20, 40]]))
    uv = world_to_uv(turned, xy)
    np.testing.assert_allclose(uv, world_to_uv(plain, xy)[:, ::-1] * [1, -1] + [0, 60], atol=1e-9)
