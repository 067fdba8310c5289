"""2-D lidar SLAM (``slamcli run lidar``): the shared laser logs with drifting odometry, and the
scan-matching parts against answers worked out by hand or by brute force."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path
from lidar_data import drifted_log

from slamcli.formats.occupancy.map_server_read import read_map_yaml
from slamcli.formats.trajectory import read_trajectory
from slamcli.geometry.planar import transform_points_planar
from slamcli.pipelines.lidar import LidarConfig, LidarSlam
from slamcli.planar_eval import evaluate_planar
from slamcli.run import run_pipeline
from slamcli.scans.grid import ProbabilityGrid
from slamcli.scans.matching import Pyramid, angular_step, refine, search
from slamcli.scans.points import voxel_filter
from slamcli.types import ScanFrame

LOGS = ("intel", "aces", "csail")

# Accuracy thresholds, shared with the perturbed runs of tests/robust.
LOG_ATE_M = 0.15
LOG_RPE_1S_M = 0.1
"""Mean translation error over 1 s."""
SYNTH_ATE_M = 0.05


def _segments() -> np.ndarray:
    """(S, 2, 2) wall segments of an L-shaped room with a round pillar (a 60-gon), off the
    5 cm cell boundaries (walls exactly on them would fall in either cell by rounding)."""
    corners = np.array([(0, 0), (8, 0), (8, 4), (4, 4), (4, 7), (0, 7), (0, 0)], float) + 0.013
    a = np.linspace(0, 2 * np.pi, 61)
    pillar = np.column_stack([6 + 0.3 * np.cos(a), 2 + 0.3 * np.sin(a)])
    return np.concatenate(
        [np.stack([corners[:-1], corners[1:]], 1), np.stack([pillar[:-1], pillar[1:]], 1)]
    )


def _room() -> np.ndarray:
    """Points on the walls, every 2 cm."""
    pts = []
    for (x0, y0), (x1, y1) in _segments():
        n = max(1, int(math.hypot(x1 - x0, y1 - y0) / 0.02))
        t = np.linspace(0, 1, n, endpoint=False)
        pts.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    return np.vstack(pts)


def _ranges(pose: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Exact ranges of beams at ``angles`` (sensor frame) from ``pose`` to the walls."""
    seg = _segments()
    d = np.stack([np.cos(angles + pose[2]), np.sin(angles + pose[2])], 1)[:, None, :]
    p, q = seg[None, :, 0, :], seg[None, :, 1, :]
    e = q - p
    w = p - pose[:2]
    den = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / den
        u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / den
    hit = (np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
    return np.where(hit, t, np.inf).min(axis=1)


def _scan_of(walls: np.ndarray, pose: np.ndarray, beams: int = 360) -> np.ndarray:
    """Body-frame end points a 360-degree scanner at ``pose`` sees."""
    angles = -np.pi + (np.arange(beams) + 0.5) * 2 * np.pi / beams
    r = _ranges(pose, angles)
    keep = np.isfinite(r)
    return np.column_stack([r * np.cos(angles), r * np.sin(angles)])[keep]


def _grid_of(points_world: np.ndarray, sensor: np.ndarray) -> ProbabilityGrid:
    grid = ProbabilityGrid(0.05)
    grid.insert(points_world, sensor)
    return grid


def test_insertion_frees_the_beam_and_occupies_its_end() -> None:
    grid = ProbabilityGrid(0.1)
    grid.insert(np.array([[2.05, 0.05]]), np.array([0.05, 0.05]))
    p = grid.probabilities()
    cell = grid.cell_of(np.array([[2.05, 0.05], [1.05, 0.05], [0.05, 1.05]]))
    assert p[cell[0, 0], cell[0, 1]] > 0.5  # the end point
    assert p[cell[1, 0], cell[1, 1]] < 0.5  # on the beam
    assert np.isnan(p[cell[2, 0], cell[2, 1]])  # never reached


def test_no_return_beams_free_space_without_a_hit() -> None:
    grid = ProbabilityGrid(0.1)
    grid.insert(np.empty((0, 2)), np.array([0.05, 0.05]), misses=np.array([[3.05, 0.05]]))
    assert not grid.occupied().any()
    assert grid.seen.sum() >= 29


def test_voxel_filter_keeps_one_mean_point_per_cell() -> None:
    pts = np.array([[0.01, 0.01], [0.03, 0.05], [0.51, 0.01], [0.02, 0.02]])
    out = voxel_filter(pts, 0.1)
    np.testing.assert_allclose(out, [[0.02, 0.08 / 3], [0.51, 0.01]])


def test_branch_and_bound_finds_the_brute_force_best() -> None:
    walls = _room()
    truth = np.array([2.0, 2.0, 0.3])
    grid = _grid_of(walls, np.array([2.0, 2.0]))
    pyramid = Pyramid(grid.likelihood_field(0.1), 3)
    pts = _scan_of(walls, truth)[::3]
    guess = truth + np.array([0.17, -0.12, math.radians(6)])
    found = search(pyramid, pts, guess, 0.4, math.radians(10))
    assert found is not None
    # Brute force over the same grid of poses.
    res, step = 0.05, angular_step(pts, 0.05)
    n_lin, n_ang = math.ceil(0.4 / res), math.ceil(math.radians(10) / step)
    best = -1.0
    field = pyramid.field
    for k in range(-n_ang, n_ang + 1):
        yaw = guess[2] + k * step
        for i in range(-n_lin, n_lin + 1):
            for j in range(-n_lin, n_lin + 1):
                pose = np.array([guess[0] + j * res, guess[1] + i * res, yaw])
                world = transform_points_planar(pose, pts)
                ij = np.floor((world - field.origin) / res).astype(int)
                h, w = field.values.shape
                ok = (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
                vals = np.zeros(len(pts))
                vals[ok] = field.values[ij[ok, 1], ij[ok, 0]]
                best = max(best, float(vals.mean()))
    assert found.score == pytest.approx(best, abs=1e-6)
    assert np.hypot(*(found.pose[:2] - truth[:2])) <= 0.05
    assert abs(found.pose[2] - truth[2]) <= 2 * step


def test_refinement_recovers_a_small_offset() -> None:
    walls = _room()
    truth = np.array([1.5, 5.0, -0.4])
    grid = _grid_of(walls, np.array([1.5, 5.0]))
    field = grid.likelihood_field(0.1)
    pts = _scan_of(walls, truth)
    start = truth + np.array([0.03, -0.04, 0.01])
    refined = refine(field, pts, start, translation_weight=0.0, rotation_weight=0.0)
    # Within half a cell of the truth (the walls are drawn in 5 cm cells), from a start a
    # cell away.
    assert np.hypot(*(refined.pose[:2] - truth[:2])) < 0.025
    assert abs(refined.pose[2] - truth[2]) < 0.004


def test_scans_only_room_tour_follows_the_truth() -> None:
    """A 360-beam scanner carried round the room at 10 Hz, no odometry: constant-velocity
    guesses and matching keep the path within a few centimetres."""
    _room()
    t = np.linspace(0, 1, 120)
    xs = np.where(t < 0.5, 1.0 + 12 * t, 7.0)
    ys = np.where(t < 0.5, 1.0, 1.0 + 4 * (t - 0.5))
    yaws = 0.5 * np.sin(4 * np.pi * t)
    slam = LidarSlam(LidarConfig())
    truth = np.column_stack([xs, ys, yaws])
    angles = -np.pi + (np.arange(360) + 0.5) * 2 * np.pi / 360
    for k, pose in enumerate(truth):
        ranges = _ranges(pose, angles).astype(np.float32)
        slam.process(
            ScanFrame(int(1e9 + k * 1e8), ranges, float(angles[0]), 2 * np.pi / 360, 0.05, 20.0)
        )
    result = slam.finish()
    assert result.trajectory is not None and len(result.trajectory) == len(truth)
    est = result.trajectory.world_from_body[:, :2, 3]
    # Start at the origin: compare motion from the first pose, in the first pose's frame.
    c, s = math.cos(yaws[0]), math.sin(yaws[0])
    moved = (truth[:, :2] - truth[0, :2]) @ np.array([[c, -s], [s, c]])
    assert float(np.max(np.hypot(*(est - moved).T))) < 0.05


@pytest.fixture(scope="module", params=LOGS)
def carmen_run(request: pytest.FixtureRequest, shared_artefact) -> tuple[str, Path]:  # type: ignore[no-untyped-def]
    name = request.param
    log = shared_path("lidar", "carmen", f"{name}-corrected.log.gz")

    def make(folder: Path) -> None:
        drifted, reference = drifted_log(log, folder)
        run_pipeline(
            drifted,
            "lidar",
            folder / "run",
            source_options={"groundtruth": str(reference)},
        )

    return name, shared_artefact(f"lidar-drifted-{name}", make)


@pytest.mark.slow
def test_real_log_with_drifting_odometry_is_within_15_cm(carmen_run: tuple[str, Path]) -> None:
    name, folder = carmen_run
    record = json.loads((folder / "run" / "run.json").read_text())
    ate = record["metrics"]["evaluation"]["ate"]["rmse"]
    assert ate <= LOG_ATE_M, f"{name}: ATE {ate:.3f} m"
    # The odometry alone is far off: the run's accuracy is the scan matching's.
    reference = read_trajectory(folder / "reference.tum")
    from slamcli.formats.carmen import CarmenSource

    with CarmenSource.open(folder / "drifted.log", groundtruth="log") as source:
        odometry = source.groundtruth()
    assert odometry is not None
    assert evaluate_planar(reference, odometry).ate.rmse > 3.0
    counts = record["counts"]
    assert counts["loops_closed"] >= 1
    est = read_trajectory(folder / "run" / "trajectory.tum")
    assert len(est) == counts["scans"] == len(reference)
    rpe = record["metrics"]["evaluation"]["rpe"]
    assert rpe["1s"]["trans"]["mean"] < LOG_RPE_1S_M


@pytest.mark.slow
def test_real_log_map_is_a_map_server_map(carmen_run: tuple[str, Path]) -> None:
    _, folder = carmen_run
    grid = read_map_yaml(folder / "run" / "map.yaml")
    known = ~np.isnan(grid.prob)
    occupied = np.nan_to_num(grid.prob) >= 0.65
    assert grid.resolution_m == pytest.approx(0.05)
    assert 0.05 < known.mean() < 0.95
    assert occupied.sum() > 1000
    # Every pose of the path lies in free space of the map it made.
    est = read_trajectory(folder / "run" / "trajectory.tum").world_from_body[:, :2, 3]
    cells = np.floor((est - np.array(grid.origin_xy_yaw[:2])) / grid.resolution_m).astype(int)
    on = grid.prob[cells[:, 1], cells[:, 0]]
    assert np.mean(np.nan_to_num(on, nan=1.0) < 0.5) > 0.95
    assert (folder / "run" / "graph.g2o").read_text().startswith("VERTEX_SE2")


CCNY = ("lidar", "rosbag1", "ccny_scan_matcher_demo.bag")


@pytest.fixture(scope="module")
def ccny_run(shared_run):  # type: ignore[no-untyped-def]
    bag = shared_path(*CCNY)
    return shared_run("run", "lidar", bag, "--out", "runs/ccny")


def test_scans_only_bag_gives_a_map_and_a_pose_per_scan(ccny_run) -> None:  # type: ignore[no-untyped-def]
    assert ccny_run.exit_code == 0, ccny_run.output
    out = ccny_run.out
    est = read_trajectory(out / "trajectory.tum")
    assert len(est) == 360
    record = json.loads((out / "run.json").read_text())
    assert record["counts"]["scans"] == 360
    assert record["counts"].get("scans_not_matched", 0) == 0
    # The bag's broken index is said, and its records were walked instead.
    assert record["source"]["details"]["bag"]["records_walked"] is True
    assert any("index" in p for p in record["source"]["problems"])
    grid = read_map_yaml(out / "map.yaml")
    occupied = np.nan_to_num(grid.prob) >= 0.65
    free = np.nan_to_num(grid.prob, nan=1.0) <= 0.196
    # A small room: a few square metres of free space walled in.
    area = free.sum() * grid.resolution_m**2
    assert 5.0 < area < 60.0
    assert occupied.sum() * grid.resolution_m > 10.0  # metres of wall, roughly
    # A hand-held sweep in a small room: the path stays within a few metres.
    xy = est.world_from_body[:, :2, 3]
    assert np.ptp(xy, axis=0).max() < 4.0


def test_the_same_bag_gives_the_same_trajectory_bytes(ccny_run, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    again = run_pipeline(shared_path(*CCNY), "lidar", tmp_path / "again")
    assert (again.run_dir / "trajectory.tum").read_bytes() == (
        ccny_run.out / "trajectory.tum"
    ).read_bytes()
    assert (again.run_dir / "map.pgm").read_bytes() == (ccny_run.out / "map.pgm").read_bytes()


def test_plan_runs_on_the_map_the_bag_made(ccny_run, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from typer.testing import CliRunner

    from slamcli.cli.app import app

    grid = read_map_yaml(ccny_run.out / "map.yaml")
    free = np.argwhere(np.nan_to_num(grid.prob, nan=1.0) <= 0.196)
    # Two free cells far apart with room around them: the first and the farthest from it
    # among cells whose 7 x 7 neighbourhood is free.
    p = np.nan_to_num(grid.prob, nan=1.0)
    roomy = [
        (r, c) for r, c in free if (p[max(r - 3, 0) : r + 4, max(c - 3, 0) : c + 4] <= 0.196).all()
    ]
    cells = np.array(roomy)
    a = cells[0]
    b = cells[np.argmax(np.hypot(*(cells - a).T))]
    to_xy = lambda rc: (rc[::-1] + 0.5) * grid.resolution_m + np.array(grid.origin_xy_yaw[:2])  # noqa: E731
    start, goal = to_xy(a), to_xy(b)
    result = CliRunner().invoke(
        app,
        [
            "plan",
            str(ccny_run.out),
            "--start",
            f"{start[0]:.3f},{start[1]:.3f}",
            "--goal",
            f"{goal[0]:.3f},{goal[1]:.3f}",
            "--robot-radius",
            "0.1",
            "--out",
            str(tmp_path / "plan"),
        ],
    )
    assert result.exit_code == 0, result.output
    plan = json.loads((tmp_path / "plan" / "plan.json").read_text())
    assert plan["goal_reached"] is True
    assert plan["length_m"] >= np.hypot(*(goal - start)) - 1e-6

    # A small car-like robot on the same map, arriving turned around.
    heading = math.atan2(goal[1] - start[1], goal[0] - start[0])
    result = CliRunner().invoke(
        app,
        [
            "plan",
            str(ccny_run.out),
            "--motion",
            "ackermann",
            "--footprint",
            "0.2x0.14",
            "--min-turn-radius",
            "0.3",
            "--start",
            f"{start[0]:.3f},{start[1]:.3f},{heading:.3f}",
            "--goal",
            f"{goal[0]:.3f},{goal[1]:.3f},{heading + math.pi:.3f}",
            "--out",
            str(tmp_path / "car"),
        ],
    )
    assert result.exit_code == 0, result.output
    car = json.loads((tmp_path / "car" / "plan.json").read_text())
    assert car["goal_reached"] is True
    assert car["goal_error_m"] <= 0.05 and car["goal_error_deg"] <= 2.0
    assert car["max_curvature_per_m"] <= car["curvature_limit_per_m"] * 1.01
    assert car["length_m"] >= np.hypot(*(goal - start)) - 1e-6


def test_a_log_without_scans_is_refused_with_its_topics() -> None:
    from typer.testing import CliRunner

    from slamcli.cli.app import app

    log = shared_path("mcap", "nav2_turtlebot.mcap")
    result = CliRunner().invoke(app, ["run", "lidar", str(log), "--out", "unused"])
    assert result.exit_code == 1
    assert "scan" in result.output.lower() and "/odom" in result.output


SYNTH_SCANS = 400


@pytest.fixture(scope="module", params=[("building_31", "drift"), ("stata_basement", "none")])
def synth_run(request: pytest.FixtureRequest, shared_artefact):  # type: ignore[no-untyped-def]
    """A simulated drive through a shared building map (``synth lidar``), run with its drifting
    odometry or with scans alone, scored against its exact ground truth."""
    name, odometry = request.param
    building = shared_path("maps", f"{name}.yaml")

    def make(folder: Path) -> None:
        from slamcli.synth.lidar import generate_lidar_world

        generate_lidar_world(building, folder / "log", seed=3, scans=SYNTH_SCANS)
        options = {"groundtruth": str(folder / "log" / "groundtruth.tum")}
        if odometry == "none":
            options["odometry"] = "none"
        run_pipeline(folder / "log" / "scans.mcap", "lidar", folder / "run", source_options=options)

    return building, shared_artefact(f"lidar-synth-{name}-{odometry}", make)


@pytest.mark.slow
def test_simulated_drive_is_within_5_cm_and_closes_its_loop(synth_run) -> None:  # type: ignore[no-untyped-def]
    _, folder = synth_run
    record = json.loads((folder / "run" / "run.json").read_text())
    assert record["metrics"]["evaluation"]["ate"]["rmse"] <= SYNTH_ATE_M
    assert record["counts"]["scans"] == SYNTH_SCANS
    # The route comes back to its start: that revisit must close a loop.
    assert record["counts"]["loops_closed"] >= 1
    assert record["counts"].get("scans_not_matched", 0) == 0


@pytest.mark.slow
def test_simulated_drive_maps_the_walls_within_one_cell(synth_run) -> None:  # type: ignore[no-untyped-def]
    from scipy.spatial import cKDTree

    from slamcli.formats.occupancy.grid import cell_to_world

    building, folder = synth_run
    source = read_map_yaml(building)
    made = read_map_yaml(folder / "run" / "map.yaml")
    truth = read_trajectory(folder / "log" / "groundtruth.tum")
    est = read_trajectory(folder / "run" / "trajectory.tum")
    alignment = evaluate_planar(truth, est)
    walls = cell_to_world(source, np.argwhere(np.nan_to_num(source.prob) >= 0.65))
    ours = cell_to_world(made, np.argwhere(np.nan_to_num(made.prob) >= 0.65))
    assert len(ours) > 200
    distance, _ = cKDTree(walls).query(alignment.transform_xy(ours))
    # Cell centres of the same wall lie at most one cell apart along each axis.
    one_cell = math.sqrt(2) * source.resolution_m
    assert np.mean(distance <= one_cell) >= 0.97, np.percentile(distance, [50, 95, 99])


def test_the_odometry_read_is_not_taken_as_ground_truth(synth_run) -> None:  # type: ignore[no-untyped-def]
    """A log whose only pose topic is its odometry: scoring a run against its own input would
    measure nothing, so there is no ground truth unless the topic is named."""
    from slamcli.formats import open_source

    log = synth_run[1] / "log" / "scans.mcap"
    with open_source(log) as source:
        kinds = ("scan", "odometry")
        assert sum(1 for _ in source.frames(kinds)) > SYNTH_SCANS
        assert source.groundtruth() is None
    with open_source(log, gt_topic="/odom") as source:
        assert sum(1 for _ in source.frames(kinds)) > SYNTH_SCANS
        truth = source.groundtruth()
        assert truth is not None and len(truth) >= SYNTH_SCANS


def test_a_batch_runs_lidar_jobs_with_their_gates(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from slamcli.cli.app import app

    manifest = tmp_path / "lidar.toml"
    manifest.write_text(
        "[[job]]\n"
        'name = "ccny"\n'
        f'input = "{shared_path(*CCNY)}"\n'
        'pipeline = "lidar"\n'
        'fail_if = ["loops_closed < 1", "scans_not_matched > 0"]\n'
    )
    result = CliRunner().invoke(app, ["batch", str(manifest), "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    record = json.loads((tmp_path / "out" / "batch.json").read_text())
    (job,) = record["jobs"]
    assert job["status"] == "passed"
