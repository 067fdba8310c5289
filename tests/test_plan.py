"""Path planning: free space, smoothing, timing, tracking, dynamic obstacles and the CLI."""

from __future__ import annotations

import itertools
import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import ConfigError, FormatError, MapError, NoPathError
from slamcli.formats.occupancy import cell_to_world, read_map, world_to_cell
from slamcli.planning.costmap import build_costmap, world_to_uv
from slamcli.planning.obstacles import DynamicObstacle, read_obstacles
from slamcli.planning.planner import PlanResult, plan, smooth_path
from slamcli.planning.search import grid_search
from slamcli.planning.smooth import SegmentChecker, touched_cells
from slamcli.planning.trajectory import Limits, time_parameterise
from slamcli.types import OccupancyGrid

runner = CliRunner()

MAPS = ("turtlebot3_world.yaml", "tb3_sandbox.yaml")
# Start/goal pairs in free space of the Nav2 TurtleBot3 world (both maps hold the same image).
PAIRS = (
    ((-2.0, -0.5), (2.0, 0.5)),
    ((0.0, -1.8), (0.0, 1.8)),
    ((-1.5, -1.5), (1.5, 1.5)),
    ((-2.4, 0.2), (1.9, -1.2)),
)


def _grid(prob: np.ndarray, res: float = 0.05, origin=(0.0, 0.0, 0.0)) -> OccupancyGrid:
    return OccupancyGrid(np.asarray(prob, dtype=np.float32), res, origin)


def _centre(grid: OccupancyGrid, xy: tuple[float, float]) -> tuple[float, float]:
    x, y = cell_to_world(grid, world_to_cell(grid, xy))
    return float(x), float(y)


def _touches_blocked(grid: OccupancyGrid, blocked: np.ndarray, pts: np.ndarray) -> int:
    """Independent check: cells under points every resolution/10 along each segment."""
    step = grid.resolution_m / 10
    samples = [pts[-1:]]
    for a, b in itertools.pairwise(pts):
        n = max(1, math.ceil(np.linalg.norm(b - a) / step))
        samples.append(a + (b - a) * (np.arange(n) / n)[:, None])
    cells = world_to_cell(grid, np.concatenate(samples))
    h, w = blocked.shape
    inside = (cells[:, 0] >= 0) & (cells[:, 0] < h) & (cells[:, 1] >= 0) & (cells[:, 1] < w)
    assert inside.all(), "the path leaves the map"
    return int(blocked[cells[:, 0], cells[:, 1]].sum())


def _distance_to_polyline(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    a, b = poly[:-1], poly[1:]
    ab = b - a
    l2 = np.maximum((ab**2).sum(axis=1), 1e-300)
    t = np.clip(((points[:, None] - a[None]) * ab[None]).sum(axis=2) / l2, 0.0, 1.0)
    foot = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None] - foot, axis=2).min(axis=1)


# --- free space -------------------------------------------------------------------------------


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5, 7])
def test_inflation_blocks_centres_at_or_within_the_radius(k: int) -> None:
    # One occupied cell; radius = k cells exactly. Blocked iff di² + dj² <= k² (integers).
    res = 0.05
    prob = np.zeros((31, 31))
    prob[15, 15] = 1.0
    cm = build_costmap(_grid(prob, res), robot_radius_m=k * res)
    di, dj = np.mgrid[-15:16, -15:16]
    np.testing.assert_array_equal(cm.blocked, di**2 + dj**2 <= k * k)


def test_inflation_tie_on_a_pythagorean_distance() -> None:
    res = 0.05
    prob = np.zeros((21, 21))
    prob[10, 10] = 1.0
    cm = build_costmap(_grid(prob, res), robot_radius_m=0.25)
    assert cm.blocked[13, 14]  # (3, 4) cells: exactly 0.25 m
    assert cm.blocked[10, 15]  # (0, 5) cells: exactly 0.25 m
    assert not cm.blocked[10, 16]
    assert not cm.blocked[14, 14]  # sqrt(32) * 0.05 = 0.283 m
    cm = build_costmap(_grid(prob, res), robot_radius_m=0.25 - 1e-6)
    assert not cm.blocked[13, 14]


def test_occupied_threshold_and_unknown_cells() -> None:
    prob = np.zeros((5, 5))
    prob[1, 1] = 0.65
    prob[1, 3] = 0.6499
    prob[3, 3] = np.nan
    cm = build_costmap(_grid(prob), robot_radius_m=0.0)
    assert cm.occupied[1, 1] and not cm.occupied[1, 3]
    assert cm.blocked[3, 3] and not cm.occupied[3, 3]
    assert cm.blocked.sum() == 2
    cm = build_costmap(_grid(prob), robot_radius_m=0.05, unknown_policy="free")
    # Unknown cells are free then, and never inflated.
    assert not cm.blocked[3, 3] and not cm.blocked[3, 4]
    assert cm.blocked[1, 2] and cm.blocked[0, 1]


def test_clearance_cost_falls_off_like_nav2_inflation() -> None:
    prob = np.zeros((1, 40))
    prob[0, 0] = 1.0
    cm = build_costmap(_grid(prob, 0.05), robot_radius_m=0.1, clearance_weight=2.0)
    assert cm.extra_cost is not None
    d = cm.distance_m[0]
    expect = np.where((d > 0.1) & (d <= 1.0), 2.0 * np.exp(-3.0 * (d - 0.1)), 0.0)
    np.testing.assert_allclose(cm.extra_cost[0], expect)
    assert build_costmap(_grid(prob), clearance_weight=0.0).extra_cost is None


def test_bad_settings_are_config_errors() -> None:
    grid = _grid(np.zeros((5, 5)))
    with pytest.raises(ConfigError, match="--robot-radius"):
        build_costmap(grid, robot_radius_m=-0.1)
    with pytest.raises(ConfigError, match="--max-speed"):
        plan(grid, (0.1, 0.1), (0.2, 0.2), limits=Limits(max_speed=0.0))


# --- segment traversal ------------------------------------------------------------------------


def _box_hit(p: np.ndarray, q: np.ndarray, r: int, c: int) -> bool:
    """Segment p-q meets the closed square [c, c+1] x [r, r+1] (Liang-Barsky clipping)."""
    t0, t1 = 0.0, 1.0
    d = q - p
    for lo, hi, x, dx in ((c, c + 1, p[0], d[0]), (r, r + 1, p[1], d[1])):
        if abs(dx) < 1e-15:
            if x < lo or x > hi:
                return False
            continue
        a, b = (lo - x) / dx, (hi - x) / dx
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    return t0 <= t1 + 1e-12


def test_supercover_matches_brute_force_on_random_segments() -> None:
    rng = np.random.default_rng(7)
    for _ in range(200):
        p, q = rng.uniform(0, 12, size=(2, 2))
        if rng.random() < 0.3:  # exact grid-aligned and corner-crossing cases
            p, q = np.round(p * 2) / 2, np.round(q * 2) / 2
        got = {tuple(x) for x in touched_cells(p, q).tolist()}
        want = {(r, c) for r in range(-1, 14) for c in range(-1, 14) if _box_hit(p, q, r, c)}
        assert got == want, (p, q)


def test_a_segment_through_a_corner_touches_all_four_cells() -> None:
    got = {tuple(x) for x in touched_cells([0.5, 0.5], [1.5, 1.5]).tolist()}
    assert got == {(0, 0), (0, 1), (1, 0), (1, 1)}
    blocked = np.zeros((3, 3), dtype=bool)
    blocked[0, 1] = True
    checker = SegmentChecker(blocked)
    assert not checker.free([[0.5, 0.5]], [[1.5, 1.5]])[0]
    assert checker.free([[0.5, 0.5]], [[0.5, 1.5]])[0]
    assert not checker.free([[0.5, 0.5]], [[5.5, 0.5]])[0]  # leaves the map


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    density=st.floats(0.05, 0.3),
    radius=st.sampled_from([0.0, 0.1, 0.15]),
    weight=st.sampled_from([0.0, 2.0]),
)
def test_smoothed_paths_never_touch_blocked_cells(
    seed: int, density: float, radius: float, weight: float
) -> None:
    rng = np.random.default_rng(seed)
    prob = (rng.random((24, 32)) < density).astype(float)
    grid = _grid(prob, 0.1, (-1.0, 0.5, 0.0))
    cm = build_costmap(grid, robot_radius_m=radius, clearance_weight=weight)
    free = np.argwhere(~cm.blocked)
    if len(free) < 2:
        return
    a, b = free[rng.choice(len(free), 2, replace=False)]
    try:
        found = grid_search(
            cm.blocked, tuple(a), tuple(b), resolution_m=0.1, extra_cost=cm.extra_cost
        )
    except NoPathError:
        return
    # Random points inside the start and goal cells, not just their centres.
    start = cell_to_world(grid, a) + rng.uniform(-0.05, 0.05, 2)
    goal = cell_to_world(grid, b) + rng.uniform(-0.05, 0.05, 2)
    pts = smooth_path(cm, cm.blocked, found.cells, start, tuple(goal))
    assert _touches_blocked(grid, cm.blocked, pts) == 0
    checker = SegmentChecker(cm.blocked)
    uv = world_to_uv(grid, pts)
    assert checker.free(uv[:-1], uv[1:]).all()
    ends = math.dist(start, cell_to_world(grid, a)) + math.dist(goal, cell_to_world(grid, b))
    length = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
    assert length <= found.cost_m + ends + 1e-9


# --- real maps --------------------------------------------------------------------------------


def _check_plan(result: PlanResult, limits: Limits) -> None:
    grid = result.costmap.grid
    blocked = result.costmap.blocked
    cells = result.search.cells
    assert not blocked[cells[:, 0], cells[:, 1]].any()
    assert _touches_blocked(grid, blocked, result.smooth_xy) == 0
    np.testing.assert_allclose(result.smooth_xy[0], result.start_xy)
    np.testing.assert_allclose(result.smooth_xy[-1], result.goal_xy)
    assert result.length_m <= result.grid_cost_m + 1e-9
    assert result.min_clearance_m > result.costmap.robot_radius_m

    traj = result.trajectory
    t, x, y, v, w = traj[:, 0], traj[:, 1], traj[:, 2], traj[:, 4], traj[:, 5]
    dt = np.diff(t)
    np.testing.assert_allclose(dt[:-1], 0.1, atol=1e-9)
    assert dt[-1] <= 0.1 + 1e-9
    assert np.all(np.abs(v) <= limits.max_speed + 1e-9)
    assert np.all(np.abs(w) <= limits.max_yaw_rate + 1e-9)
    assert np.all(np.abs(np.diff(v)) <= limits.max_accel * dt + 1e-9)
    assert v[0] == 0 and v[-1] == pytest.approx(0, abs=1e-12)
    np.testing.assert_allclose([x[-1], y[-1]], result.goal_xy, atol=1e-9)
    # Every sample lies on the smoothed path.
    assert _distance_to_polyline(traj[:, 1:3], result.smooth_xy).max() < 1e-9

    tr = result.tracking
    assert tr.reached_goal
    assert tr.cross_track_rms_m < 0.1
    assert tr.cross_track_max_m < 0.2
    st = tr.states
    assert np.all(np.abs(st[:, 4]) <= limits.max_speed + 1e-9)
    assert np.all(np.abs(st[:, 5]) <= limits.max_yaw_rate + 1e-9)
    assert np.all(np.abs(np.diff(st[:, 4])) <= limits.max_accel * np.diff(st[:, 0]) + 1e-9)


@pytest.mark.parametrize("name", MAPS)
def test_plans_on_nav2_maps(name: str) -> None:
    grid = read_map(shared_path("maps", name))
    limits = Limits()
    for start, goal in PAIRS:
        # Cell centres, so the smoothed path must not be longer than the grid path.
        result = plan(grid, _centre(grid, start), _centre(grid, goal), limits=limits)
        _check_plan(result, limits)


def test_plan_with_other_limits_and_clearance_weight() -> None:
    grid = read_map(shared_path("maps", "turtlebot3_world.yaml"))
    limits = Limits(max_speed=0.8, max_yaw_rate=0.6, max_accel=0.3)
    start, goal = _centre(grid, (-2.0, -0.5)), _centre(grid, (2.0, 0.5))
    plain = plan(grid, start, goal, limits=limits, robot_radius_m=0.15)
    _check_plan(plain, limits)
    weighted = plan(grid, start, goal, limits=limits, robot_radius_m=0.15, clearance_weight=1.0)
    _check_plan(weighted, limits)
    assert weighted.search.method == "astar"
    assert weighted.grid_cost_m > plain.grid_cost_m


def test_off_centre_start_and_goal_bound_the_length() -> None:
    grid = read_map(shared_path("maps", "turtlebot3_world.yaml"))
    start, goal = (-2.013, -0.488), (1.987, 0.522)
    result = plan(grid, start, goal)
    slack = math.dist(start, _centre(grid, start)) + math.dist(goal, _centre(grid, goal))
    assert result.length_m <= result.grid_cost_m + slack + 1e-9
    assert _touches_blocked(grid, result.costmap.blocked, result.smooth_xy) == 0


def _two_corridors() -> OccupancyGrid:
    """6 x 4 m room, a block in the middle: a 0.35 m corridor above it, 1.55 m below."""
    res = 0.05
    prob = np.zeros((80, 120))
    prob[0, :] = prob[-1, :] = prob[:, 0] = prob[:, -1] = 1.0
    prob[32:72, 30:90] = 1.0  # x 1.5 .. 4.5 m, y 1.6 .. 3.6 m
    return _grid(prob, res)


def test_clearance_weight_prefers_the_wide_corridor() -> None:
    grid = _two_corridors()
    start, goal = (0.525, 3.025), (5.475, 3.025)
    narrow = plan(grid, start, goal, robot_radius_m=0.1)
    wide = plan(grid, start, goal, robot_radius_m=0.1, clearance_weight=3.0)
    assert narrow.smooth_xy[:, 1].max() > 3.6  # over the block
    assert wide.smooth_xy[:, 1].min() < 1.6  # under it
    assert wide.min_clearance_m > narrow.min_clearance_m + 0.1
    assert narrow.min_clearance_m < 0.25
    for r in (narrow, wide):
        _check_plan(r, Limits())


# --- errors -----------------------------------------------------------------------------------


def test_start_outside_the_map_names_the_bounds() -> None:
    grid = read_map(shared_path("maps", "turtlebot3_world.yaml"))
    with pytest.raises(MapError, match=r"outside the map.*x -10 \.\. 9\.2 m, y -10 \.\. 9\.2 m"):
        plan(grid, (12.0, 0.0), (0.0, 1.8))


def _nearest_free_from(message: str) -> tuple[float, float]:
    m = re.search(r"nearest free cell is centred at \((-?[\d.]+), (-?[\d.]+)\) m", message)
    assert m, message
    return float(m.group(1)), float(m.group(2))


def test_start_in_an_obstacle_or_the_inflated_zone_names_the_nearest_free_cell() -> None:
    grid = read_map(shared_path("maps", "turtlebot3_world.yaml"))
    cm = build_costmap(grid, robot_radius_m=0.2)
    wall = tuple(float(c) for c in cell_to_world(grid, np.argwhere(cm.occupied)[0]))
    zone = np.argwhere(cm.blocked & ~cm.occupied & ~cm.unknown)[0]
    near = tuple(float(c) for c in cell_to_world(grid, zone))
    for where, why in ((wall, "is in an obstacle"), (near, "within the robot radius")):
        with pytest.raises(MapError, match=why) as info:
            plan(grid, where, (0.0, 1.8))
        fx, fy = _nearest_free_from(info.value.msg)
        r, c = world_to_cell(grid, (fx, fy))
        assert not cm.blocked[r, c]
        assert "--start" in (info.value.hint or "")
        # A smaller radius frees only cells that the radius blocked.
        assert ("--robot-radius" in (info.value.hint or "")) == (why != "is in an obstacle")
    with pytest.raises(MapError, match=r"goal .* is in unknown space") as info:
        plan(grid, (0.0, 1.8), (-9.0, -9.0))
    assert "--unknown free" in (info.value.hint or "")
    assert "--robot-radius" not in (info.value.hint or "")


def test_no_path_reports_the_cells_reached() -> None:
    prob = np.zeros((20, 30))
    prob[:, 10] = 1.0  # a wall: 10 columns on the left, 19 on the right
    grid = _grid(prob, 0.1)
    with pytest.raises(NoPathError, match=r"reached 200 cells") as info:
        plan(grid, (0.25, 1.0), (2.5, 1.0), robot_radius_m=0.0)
    # The radius is 0 already: no hint to lower it.
    assert "--robot-radius" not in (info.value.hint or "")
    with pytest.raises(NoPathError, match=r"reached 200 cells") as info:
        plan(grid, (0.25, 1.0), (2.5, 1.0), robot_radius_m=0.05)
    assert "--robot-radius" in (info.value.hint or "")
    prob[5, 10] = np.nan  # an unknown gap
    with pytest.raises(NoPathError, match="reached 200 cells") as info:
        plan(_grid(prob, 0.1), (0.25, 1.0), (2.5, 1.0), robot_radius_m=0.0)
    assert "--unknown free" in (info.value.hint or "")
    ok = plan(_grid(prob, 0.1), (0.25, 1.0), (2.5, 1.0), robot_radius_m=0.0, unknown_policy="free")
    assert ok.tracking.reached_goal


# --- trajectory -------------------------------------------------------------------------------


def test_sharp_corner_turns_in_place_within_limits() -> None:
    limits = Limits(max_speed=0.5, max_yaw_rate=1.0, max_accel=0.5)
    prof = time_parameterise(np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0]]), limits)
    traj = prof.sample_every(0.1)
    v, w = traj[:, 4], traj[:, 5]
    turning = np.abs(w) > 0
    assert np.all(v[turning] == 0)  # a 90-degree corner: stop and rotate
    assert np.abs(w).max() == pytest.approx(1.0)
    # 2 m each way: accelerate to 0.5 m/s (0.25 m), cruise, brake; 4 + 1 + ... seconds.
    assert prof.duration_s == pytest.approx(2 * (2.0 / 0.5 + 0.5 / 0.5) + (math.pi / 2) / 1.0)


# --- dynamic obstacles ------------------------------------------------------------------------


def test_obstacle_on_the_path_forces_a_replan_and_is_avoided() -> None:
    grid = read_map(shared_path("maps", "turtlebot3_world.yaml"))
    start, goal = (-2.0, -0.5), (2.0, 0.5)
    first = plan(grid, start, goal)
    ox, oy = first.profile.xy_at_s(0.6 * first.length_m)
    ob = DynamicObstacle(float(ox), float(oy), 0.15, 0.0, math.inf, name="box")
    result = plan(grid, start, goal, obstacles=[ob])
    tr = result.tracking
    assert tr.replans >= 1 and tr.reached_goal
    assert tr.events[0]["kind"] == "replan" and tr.events[0]["obstacle"] == "box"
    gap = np.hypot(tr.states[:, 1] - ob.x, tr.states[:, 2] - ob.y)
    assert gap.min() > ob.radius + result.costmap.robot_radius_m - 0.05
    # The replanned path itself keeps the robot's radius off the obstacle.
    for _, pts in tr.paths[1:]:
        prof = time_parameterise(pts, Limits())
        dense = prof.xy_at_s(np.linspace(0.0, prof.length_m, 5000))
        d = np.hypot(dense[:, 0] - ob.x, dense[:, 1] - ob.y)
        assert d.min() > ob.radius + result.costmap.robot_radius_m
        assert _touches_blocked(grid, result.costmap.blocked, pts) == 0


def test_robot_waits_for_an_obstacle_on_the_goal_then_continues() -> None:
    grid = read_map(shared_path("maps", "turtlebot3_world.yaml"))
    ob = DynamicObstacle(2.0, 0.5, 0.3, 3.0, 12.0, name="cart")
    result = plan(grid, (-2.0, -0.5), (2.0, 0.5), obstacles=[ob])
    tr = result.tracking
    assert tr.waits == 1 and tr.reached_goal
    assert [e["kind"] for e in tr.events] == ["wait", "resume"]
    assert tr.events[1]["t_s"] == pytest.approx(12.0)
    assert tr.time_to_goal_s is not None and tr.time_to_goal_s > 12.0


def test_obstacle_that_never_vanishes_is_a_no_path_error_naming_it() -> None:
    grid = read_map(shared_path("maps", "turtlebot3_world.yaml"))
    ob = DynamicObstacle(2.0, 0.5, 0.3, 3.0, math.inf, name="obstacles.csv:2")
    with pytest.raises(NoPathError, match=r"obstacle obstacles\.csv:2 at \(2, 0\.5\) m"):
        plan(grid, (-2.0, -0.5), (2.0, 0.5), obstacles=[ob])


def test_read_obstacles(tmp_path: Path) -> None:
    f = tmp_path / "obs.csv"
    f.write_text(
        "x,y,radius,appear_s,vanish_s\n# comment\n1,2,0.3,,\n-1,0.5,0.2,4,inf\n3,3,0.1,1,2\n"
    )
    obs = read_obstacles(f)
    assert [(o.x, o.y, o.radius, o.appear_s, o.vanish_s) for o in obs] == [
        (1, 2, 0.3, 0, math.inf),
        (-1, 0.5, 0.2, 4, math.inf),
        (3, 3, 0.1, 1, 2),
    ]
    assert obs[0].name == "obs.csv:3"
    assert obs[2].present(1.5) and not obs[2].present(2.0)
    for text, match in (
        ("x,y,r\n", "expected the header"),
        ("x,y,radius,appear_s,vanish_s\n1,2,abc,,\n", r"obs\.csv:2: radius 'abc'"),
        ("x,y,radius,appear_s,vanish_s\n1,2,0,,\n", "radius must be > 0"),
        ("x,y,radius,appear_s,vanish_s\n1,2,1,5,3\n", "must come after appear_s"),
        ("", "empty file"),
    ):
        f.write_text(text)
        with pytest.raises(FormatError, match=match):
            read_obstacles(f)


# --- CLI --------------------------------------------------------------------------------------

PLAN_KEYS = {
    "map",
    "start",
    "goal",
    "robot_radius_m",
    "settings",
    "grid_cost_m",
    "length_m",
    "min_clearance_m",
    "expanded",
    "plan_ms",
    "replans",
    "waits",
    "events",
    "tracking",
    "time_to_goal_s",
}


def test_cli_writes_every_file(tmp_path: Path) -> None:
    map_file = shared_path("maps", "turtlebot3_world.yaml")
    out = tmp_path / "plan"
    obstacles = tmp_path / "obs.csv"
    obstacles.write_text("x,y,radius,appear_s,vanish_s\n1.0,0.5,0.3,2,8\n")
    args = ["plan", str(map_file), "--start", "-2,-0.5", "--goal", "2,0.5", "--out", str(out)]
    res = runner.invoke(app, [*args, "--obstacles", str(obstacles)])
    assert res.exit_code == 0, res.output
    for word in ("grid cost", "smoothed length", "min clearance", "expanded", "plan time"):
        assert word in res.stdout
    headers = {
        "path.csv": "x,y",
        "path_smooth.csv": "x,y",
        "trajectory.csv": "t,x,y,theta,v,omega",
        "tracked.csv": "t,x,y,theta,v,omega",
    }
    for name, header in headers.items():
        lines = (out / name).read_text().splitlines()
        assert lines[0] == header and len(lines) > 2
        assert str(out / name) in res.stdout
    assert (out / "plan.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    record = json.loads((out / "plan.json").read_text())
    assert set(record) >= PLAN_KEYS
    assert record["replans"] >= 1
    assert record["events"][0]["kind"] == "replan"
    assert len(record["map"]["sha256"]) == 64 and "image" in record["map"]
    path = np.loadtxt(out / "path.csv", delimiter=",", skiprows=1)
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    assert record["grid_cost_m"] == pytest.approx(steps.sum(), abs=1e-4)

    res = runner.invoke(app, args)
    assert res.exit_code == 1
    assert "not empty" in res.output and "--force" in res.output
    res = runner.invoke(app, [*args, "--force"])
    assert res.exit_code == 0, res.output


def test_cli_accepts_a_run_folder(tmp_path: Path) -> None:
    src = shared_path("maps", "turtlebot3_world.yaml")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    shutil.copy(src, run_dir / "map.yaml")
    shutil.copy(src.with_suffix(".pgm"), run_dir / "turtlebot3_world.pgm")
    out = tmp_path / "p"
    res = runner.invoke(
        app, ["plan", str(run_dir), "--start", "0,-1.8", "--goal", "0,1.8", "--out", str(out)]
    )
    assert res.exit_code == 0, res.output
    assert json.loads((out / "plan.json").read_text())["map"]["path"].endswith("map.yaml")


def test_cli_errors_have_exit_1_and_a_hint(tmp_path: Path) -> None:
    map_file = str(shared_path("maps", "turtlebot3_world.yaml"))
    out = str(tmp_path / "p")
    res = runner.invoke(
        app, ["plan", map_file, "--start", "0,0,1,2", "--goal", "1,1", "--out", out]
    )
    assert res.exit_code == 1 and "--start: expected x,y or x,y,yaw" in res.output
    res = runner.invoke(app, ["plan", map_file, "--start", "0,0,1", "--goal", "1,1", "--out", out])
    assert res.exit_code == 1 and "heading is used only with --motion ackermann" in res.output
    res = runner.invoke(app, ["plan", map_file, "--start", "50,0", "--goal", "1,1", "--out", out])
    assert res.exit_code == 1
    assert "outside the map" in res.output and "hint:" in res.output
    res = runner.invoke(app, ["plan", str(tmp_path), "--start", "0,0", "--goal", "1,1"])
    assert res.exit_code == 1 and "map.yaml" in res.output
    assert not (tmp_path / "p").exists()


def test_help_documents_free_space_and_has_an_example() -> None:
    res = runner.invoke(app, ["plan", "--help"])
    assert res.exit_code == 0
    text = " ".join(res.stdout.split())
    assert "0.65" in text and "robot-radius" in text and "slamcli plan" in text


def test_world_to_uv_agrees_with_the_map_cells() -> None:
    grid = _grid(np.zeros((10, 10)), 0.1, (1.0, -2.0, 0.3))
    rng = np.random.default_rng(3)
    xy = rng.uniform(-1, 2, size=(100, 2))
    uv = world_to_uv(grid, xy)
    np.testing.assert_array_equal(np.floor(uv[:, ::-1]).astype(np.int64), world_to_cell(grid, xy))


def test_round_robot_centring_is_optional_and_clears_the_walls() -> None:
    """--cost-penalty on the grid planner: off by default (the exact shortest path stays), on
    it keeps the path farther from the walls, measured by the grid path's clearance ratio."""
    from planning_data import clearance_ratios

    grid = read_map(shared_path("maps", "turtlebot3_world.yaml"))
    shortest = plan(grid, (-2.0, -0.5), (2.0, 0.5))
    again = plan(grid, (-2.0, -0.5), (2.0, 0.5), cost_penalty=0.0)
    assert again.grid_cost_m == shortest.grid_cost_m
    centred = plan(grid, (-2.0, -0.5), (2.0, 0.5), cost_penalty=2.0)
    assert centred.search.method == "astar"
    assert centred.min_clearance_m > shortest.min_clearance_m
    blocked = shortest.costmap.blocked

    def ratio(result: PlanResult) -> float:
        xy = np.asarray(result.smooth_xy)
        poses = np.column_stack((xy, np.zeros(len(xy))))
        return float(np.median(clearance_ratios(grid, blocked, poses)))

    assert ratio(centred) > ratio(shortest)
