"""``slamcli synth lidar``: ray casting against the map's geometry, the route's clearance and
loop, the odometry's errors, the written files read back, determinism and the CLI."""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path
from scipy.spatial import cKDTree
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import ConfigError, MapError
from slamcli.formats import open_source
from slamcli.formats.occupancy import read_map_yaml
from slamcli.formats.trajectory import read_trajectory
from slamcli.geometry import compose_planar, se3_to_planar, wrap_angle
from slamcli.synth.lidar import (
    LidarSensor,
    LidarWorld,
    WheelOdometry,
    generate_lidar_world,
    simulate_lidar_world,
)
from slamcli.synth.raycast import RayCaster, occupied_cells
from slamcli.synth.route import plan_route
from slamcli.types import OccupancyGrid, OdometryFrame, ScanFrame

runner = CliRunner()

# A short range, so that sweeps have both hits and beams with nothing in range.
SHORT = LidarSensor(beams=180, max_range=4.0).noiseless()


@pytest.fixture(scope="module")
def building_31() -> OccupancyGrid:
    return read_map_yaml(shared_path("maps", "building_31.yaml"))


@pytest.fixture(scope="module")
def stata() -> OccupancyGrid:
    return read_map_yaml(shared_path("maps", "stata_basement.yaml"))


@pytest.fixture(scope="module")
def short_world(building_31: OccupancyGrid) -> LidarWorld:
    return simulate_lidar_world(building_31, seed=2, scans=40, sensor=SHORT)


@pytest.fixture(scope="module")
def long_world(building_31: OccupancyGrid) -> LidarWorld:
    """A minute of driving (about 30 m), the default odometry errors."""
    return simulate_lidar_world(building_31, seed=5, scans=600, sensor=SHORT)


def _room(origin: tuple[float, float, float]) -> OccupancyGrid:
    """An 8 m x 6 m room at 0.1 m: one-cell walls, a 1 m pillar, unknown outside."""
    prob = np.full((62, 82), np.nan, dtype=np.float32)
    prob[1:61, 1:81] = 0.0
    prob[1, 1:81] = prob[60, 1:81] = prob[1:61, 1] = prob[1:61, 80] = 1.0
    prob[30:40, 50:60] = 1.0  # pillar: x in [5.0, 6.0], y in [3.0, 4.0] before the origin
    return OccupancyGrid(prob, 0.1, origin)


def _cells(grid: OccupancyGrid, xy: np.ndarray) -> np.ndarray:
    """(row, col) of world points, by the grid's rotation written out here."""
    x0, y0, yaw = grid.origin_xy_yaw
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = xy[..., 0] - x0, xy[..., 1] - y0
    u = (c * dx + s * dy) / grid.resolution_m
    v = (-s * dx + c * dy) / grid.resolution_m
    return np.stack([np.floor(v), np.floor(u)], axis=-1).astype(np.int64)


def _occupied_at(occ: np.ndarray, rc: np.ndarray, near: int = 0) -> np.ndarray:
    """Whether cell ``rc`` (or one within ``near`` cells of it) is occupied; False outside."""
    h, w = occ.shape
    found = np.zeros(rc.shape[:-1], dtype=bool)
    for dr in range(-near, near + 1):
        for dc in range(-near, near + 1):
            r, c = rc[..., 0] + dr, rc[..., 1] + dc
            inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
            found[inside] |= occ[r[inside], c[inside]]
    return found


def _beam_points(world: LidarWorld, ranges: np.ndarray) -> np.ndarray:
    """(N, B, 2) world points at ``ranges`` (N, B) along each beam."""
    sensor = world.sensor_poses()
    heading = sensor[:, 2:3] + world.sensor.angles()[None, :]
    return sensor[:, None, :2] + ranges[..., None] * np.stack(
        [np.cos(heading), np.sin(heading)], axis=-1
    )


def test_noiseless_end_points_lie_on_obstacles_and_no_return_beams_see_nothing(
    building_31: OccupancyGrid, short_world: LidarWorld
) -> None:
    occ = occupied_cells(building_31)
    ranges = short_world.ranges.astype(np.float64)
    hit = np.isfinite(ranges)
    assert not np.isnan(ranges).any()
    assert np.isposinf(ranges[~hit]).all()
    assert 0.05 < hit.mean() < 0.95  # both kinds are tested
    ends = _beam_points(short_world, np.where(hit, ranges, 0.0))[hit]
    assert _occupied_at(occ, _cells(building_31, ends), near=1).all()
    # Before its end point (and all the way to max range without one) a beam crosses only
    # free or unknown cells.
    res = building_31.resolution_m
    for fraction in np.linspace(0.0, 1.0, 41):
        along = np.where(hit, np.maximum(ranges - res / 2, 0.0), SHORT.max_range) * fraction
        points = _beam_points(short_world, along)
        assert not _occupied_at(occ, _cells(building_31, points)).any()


@pytest.mark.parametrize("yaw", [0.0, math.pi / 2, 3.14, -2.0])
def test_ranges_in_a_room_equal_the_geometry(yaw: float) -> None:
    origin = (3.0, -2.0, yaw)
    grid = _room(origin)
    caster = RayCaster(grid)
    # In the room's own frame (before the origin): walls' inner faces at x = 0.2, 8.0 and
    # y = 0.2, 6.0; the pillar covers x in [5.0, 6.0], y in [3.0, 4.0].
    local = np.array([[2.0, 3.5, 0.0], [2.0, 1.0, 0.0], [6.5, 3.2, math.pi / 4]])
    world = compose_planar(np.asarray(origin), local)
    angles = np.array([0.0, math.pi / 2, math.pi, -math.pi / 2])
    got = caster.cast(world, angles, max_range_m=20.0)
    r2 = math.sqrt(2.0)
    expected = [
        [3.0, 2.5, 1.8, 3.3],
        [6.0, 5.0, 1.8, 0.8],
        [1.5 * r2, 0.5 * r2, 3.0 * r2, 1.5 * r2],
    ]
    np.testing.assert_allclose(got, expected, atol=1e-9)
    short = caster.cast(world, angles, max_range_m=2.0)
    assert np.isposinf(short[0, [0, 1]]).all()
    np.testing.assert_allclose(short[0, 2], 1.8, atol=1e-9)


def test_a_beam_leaving_the_map_through_a_gap_sees_nothing() -> None:
    grid = _room((0.0, 0.0, 0.0))
    prob = np.array(grid.prob)
    prob[24, 80] = 0.0  # a hole in the east wall at y in [2.4, 2.5]
    caster = RayCaster(OccupancyGrid(prob, 0.1))
    got = caster.cast(np.array([[2.0, 2.45, 0.0], [2.0, 2.55, 0.0]]), np.zeros(1), 50.0)
    assert np.isposinf(got[0, 0])
    assert got[1, 0] == pytest.approx(6.0, abs=1e-9)
    with pytest.raises(MapError, match="outside the map"):
        caster.cast(np.array([[-1.0, 3.0, 0.0]]), np.array([0.0]), max_range_m=5.0)


def test_ground_truth_is_the_pose_each_scan_was_cast_from(
    building_31: OccupancyGrid, short_world: LidarWorld
) -> None:
    again = RayCaster(building_31).cast(short_world.sensor_poses(), SHORT.angles(), SHORT.max_range)
    np.testing.assert_array_equal(again.astype(np.float32), short_world.ranges)
    # A pose 2 cm off gives other ranges: the comparison above can fail.
    moved = short_world.sensor_poses() + np.array([0.02, 0.0, 0.0])
    other = RayCaster(building_31).cast(moved, SHORT.angles(), SHORT.max_range)
    assert not np.array_equal(other.astype(np.float32), short_world.ranges)


def _distance_to_squares(grid: OccupancyGrid, bad: np.ndarray, xy: np.ndarray) -> float:
    """Least distance (m) from points ``xy`` (world) to the squares of cells ``bad``."""
    from slamcli.planning.costmap import world_to_uv

    uv = world_to_uv(grid, xy)
    centres = bad[:, ::-1] + 0.5
    tree = cKDTree(centres)
    _, idx = tree.query(uv, k=8)
    gap = np.maximum(np.abs(uv[:, None, :] - centres[idx]) - 0.5, 0.0)
    return float(np.sqrt((gap**2).sum(axis=-1)).min() * grid.resolution_m)


def _densify(xy: np.ndarray, step: float) -> np.ndarray:
    parts = [xy[-1:]]
    for a, b in itertools.pairwise(xy):
        n = max(1, math.ceil(float(np.linalg.norm(b - a)) / step))
        parts.append(a + (b - a) * (np.arange(n) / n)[:, None])
    return np.concatenate(parts)


@pytest.mark.parametrize(("seed", "clearance"), [(0, 0.4), (7, 0.8)])
def test_route_keeps_its_clearance_and_returns_to_the_start(
    building_31: OccupancyGrid, seed: int, clearance: float
) -> None:
    route = plan_route(building_31, 40.0, np.random.default_rng(seed), clearance_m=clearance)
    prob = np.asarray(building_31.prob)
    bad = np.argwhere(np.isnan(prob) | (prob >= 0.65))
    path = _densify(route.xy, 0.01)
    assert _distance_to_squares(building_31, bad, path) > clearance
    np.testing.assert_array_equal(route.xy[0], route.xy[-1])
    np.testing.assert_array_equal(route.waypoints[0], route.waypoints[-1])
    assert len(route.waypoints) >= 4  # start, two waypoints at least, start
    assert 30.0 < route.length_m < 50.0


def test_the_drive_revisits_its_start_and_fits_the_scans(long_world: LidarWorld) -> None:
    world = long_world
    assert len(world.poses) == 600
    np.testing.assert_allclose(world.poses[-1, :2], world.poses[0, :2], atol=1e-9)
    steps = np.linalg.norm(np.diff(world.poses[:, :2], axis=0), axis=1)
    # At most the driven speed per period; about the asked 0.5 m/s.
    assert steps.max() <= world.speed_mps / SHORT.rate_hz + 1e-9
    assert abs(world.speed_mps - 0.5) < 0.05
    headings = np.diff(np.unwrap(world.poses[:, 2]))
    assert np.abs(headings).max() <= 1.0 * world.speed_mps / 0.5 / SHORT.rate_hz + 1e-9
    from slamcli.synth.route import revisits

    found = revisits(world.poses)
    assert found and found[-1]["scan"] > 500
    assert found[-1]["distance_m"] < 1.0


def test_odometry_has_the_asked_scale_error_and_drift(long_world: LidarWorld) -> None:
    from slamcli.synth.lidar import wheel_odometry

    poses = long_world.poses
    true_length = long_world.trajectory().path_length()
    model = WheelOdometry(scale_error=0.05, drift_per_m=0.02).noiseless()
    odo = wheel_odometry(poses, model, np.random.default_rng(0))
    odo_length = float(np.linalg.norm(np.diff(odo[:, :2], axis=0), axis=1).sum())
    assert odo_length / true_length == pytest.approx(1.05, abs=1e-9)
    turned = np.unwrap(odo[:, 2]) - np.unwrap(poses[:, 2])
    assert turned[-1] == pytest.approx(0.02 * true_length, abs=1e-9)
    np.testing.assert_array_equal(odo[0], poses[0])
    # The default model, with its white noise (about 0.05 % over this drive): 2 % long.
    assert long_world.odometry is not None
    noisy = np.linalg.norm(np.diff(long_world.odometry[:, :2], axis=0), axis=1).sum()
    assert noisy / true_length == pytest.approx(1.02, abs=0.002)
    heading_error = wrap_angle(long_world.odometry[-1, 2] - poses[-1, 2])
    assert heading_error == pytest.approx(0.01 * true_length, abs=0.05)


def test_carmen_log_reads_back_with_the_scans_and_odometry_poses(
    building_31: OccupancyGrid, tmp_path: Path
) -> None:
    map_file = shared_path("maps", "building_31.yaml")
    summary = generate_lidar_world(map_file, tmp_path / "log", seed=4, scans=50)
    world = simulate_lidar_world(building_31, seed=4, scans=50)
    assert world.odometry is not None
    with open_source(tmp_path / "log" / "scans.log") as src:
        assert src.info().format == "carmen"
        frames = list(src.frames())
    scans = [f for f in frames if isinstance(f, ScanFrame)]
    odometry = [f for f in frames if isinstance(f, OdometryFrame)]
    assert len(scans) == len(odometry) == 50 == summary["scans"]
    assert [s.stamp_ns for s in scans] == world.stamps_ns.tolist()
    read_poses = np.concatenate(
        [se3_to_planar(f.world_from_body) for f in odometry if f.world_from_body is not None]
    )
    np.testing.assert_allclose(read_poses[:, :2], world.odometry[:, :2], atol=1e-12)
    np.testing.assert_allclose(wrap_angle(read_poses[:, 2] - world.odometry[:, 2]), 0, atol=1e-12)
    np.testing.assert_allclose(scans[0].body_from_sensor, [0.1, 0.0, 0.0], atol=1e-12)
    ranges = np.stack([s.ranges_m for s in scans])
    readings = np.stack([s.readings() for s in scans])
    expected = world.ranges
    np.testing.assert_array_equal(readings, np.isfinite(expected))
    np.testing.assert_array_equal(ranges[readings], expected[readings])
    np.testing.assert_allclose(scans[0].angles(), world.sensor.angles(), atol=1e-12)


def test_mcap_and_groundtruth_hold_the_simulated_run(
    building_31: OccupancyGrid, tmp_path: Path
) -> None:
    map_file = shared_path("maps", "building_31.yaml")
    generate_lidar_world(map_file, tmp_path / "log", seed=4, scans=30)
    world = simulate_lidar_world(building_31, seed=4, scans=30)
    with open_source(tmp_path / "log" / "scans.mcap") as src:
        frames = list(src.frames(["scan", "odometry"]))
    scans = [f for f in frames if isinstance(f, ScanFrame)]
    odometry = [f for f in frames if isinstance(f, OdometryFrame)]
    assert len(scans) == len(odometry) == 30
    np.testing.assert_array_equal(np.stack([s.ranges_m for s in scans]), world.ranges)
    np.testing.assert_allclose(scans[0].body_from_sensor, [0.1, 0.0, 0.0], atol=1e-9)
    truth = read_trajectory(tmp_path / "log" / "groundtruth.tum")
    np.testing.assert_array_equal(truth.stamps_ns, world.stamps_ns)
    np.testing.assert_allclose(truth.positions[:, :2], world.poses[:, :2], atol=1e-9)
    assert np.all(truth.positions[:, 2] == 0.0)
    yaw = se3_to_planar(truth.world_from_body)[:, 2]
    np.testing.assert_allclose(wrap_angle(yaw - world.poses[:, 2]), 0.0, atol=1e-8)


def _digests(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def test_same_seed_same_bytes_other_seed_other_run(tmp_path: Path) -> None:
    map_file = shared_path("maps", "building_31.yaml")
    for name, seed in (("a", 3), ("b", 3), ("c", 8)):
        generate_lidar_world(map_file, tmp_path / name, seed=seed, scans=40)
    a, b, c = (_digests(tmp_path / n) for n in "abc")
    assert sorted(a) == ["groundtruth.tum", "scans.log", "scans.mcap", "world.json"]
    assert a == b
    assert all(a[name] != c[name] for name in a)


def test_stata_scans_follow_the_map_turned_by_its_origin_yaw(stata: OccupancyGrid) -> None:
    assert stata.origin_xy_yaw[2] == pytest.approx(3.14)
    sensor = LidarSensor(beams=90, max_range=8.0).noiseless()
    world = simulate_lidar_world(stata, seed=1, scans=20, sensor=sensor)
    ranges = world.ranges.astype(np.float64)
    hit = np.isfinite(ranges)
    assert hit.mean() > 0.5
    ends = _beam_points(world, np.where(hit, ranges, 0.0))[hit]
    occ = occupied_cells(stata)
    assert _occupied_at(occ, _cells(stata, ends), near=1).all()
    # Read without the yaw, the same end points mostly miss the walls: the check above can fail.
    unturned = OccupancyGrid(stata.prob, stata.resolution_m, (*stata.origin_xy_yaw[:2], 0.0))
    assert _occupied_at(occ, _cells(unturned, ends), near=1).mean() < 0.5
    # The route stays in the map's known free space.
    prob = np.asarray(stata.prob)
    rc = _cells(stata, world.poses[:, :2])
    assert np.all(prob[rc[:, 0], rc[:, 1]] == 0.0)


def test_bad_settings_raise_config_errors(building_31: OccupancyGrid) -> None:
    with pytest.raises(ConfigError, match="--beams"):
        simulate_lidar_world(building_31, scans=5, sensor=LidarSensor(beams=1, fov=math.pi))
    with pytest.raises(ConfigError, match="--max-range"):
        simulate_lidar_world(building_31, scans=5, sensor=LidarSensor(max_range=0.05))
    with pytest.raises(ConfigError, match="--scans"):
        simulate_lidar_world(building_31, scans=1)
    with pytest.raises(ConfigError, match="--clearance"):
        simulate_lidar_world(building_31, scans=5, clearance_m=-1.0)
    with pytest.raises(MapError, match="no free cell"):
        simulate_lidar_world(building_31, scans=5, clearance_m=30.0)


def test_cli_writes_the_folder_and_refuses_a_full_one(tmp_path: Path) -> None:
    map_file = str(shared_path("maps", "building_31.yaml"))
    out = tmp_path / "sim"
    argv = ["synth", "lidar", map_file, "--out", str(out), "--scans", "30"]
    res = runner.invoke(app, [*argv, "--odometry", "none", "--fov-deg", "270", "--beams", "271"])
    assert res.exit_code == 0, res.output
    record = json.loads((out / "world.json").read_text())
    assert record["odometry"] == {"model": "none"}
    assert record["counts"]["scans"] == 30 and record["counts"]["odometry"] == 0
    assert record["sensor"]["angle_min"] == pytest.approx(-math.radians(135))
    with open_source(out / "scans.log") as src:
        frames = list(src.frames())
    assert len(frames) == 30 and all(isinstance(f, ScanFrame) for f in frames)
    again = runner.invoke(app, argv)
    assert again.exit_code == 1
    assert "not empty" in again.output
    bad = runner.invoke(app, [*argv, "--force", "--odometry", "wheels"])
    assert bad.exit_code == 1
    assert "--odometry" in bad.output
