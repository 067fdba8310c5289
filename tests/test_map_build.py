"""Occupancy maps from run folders: known-answer checks on the synthetic room, the TUM excerpt
and the landmark world, planning over the results, and the error cases."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import shared_path
from numpy.typing import NDArray
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import ConfigError, InputError
from slamcli.formats.occupancy import read_map_yaml
from slamcli.mapping import (
    L_FREE,
    L_OCC,
    BuiltMap,
    LogOddsGrid,
    MapSettings,
    build_map,
    map_run,
    parse_height_band,
)
from slamcli.types import OccupancyGrid

REPO = Path(__file__).resolve().parents[1]
ROOM = REPO / "sample_data" / "rgbd_room"
LANDMARKS = REPO / "sample_data" / "landmarks"
runner = CliRunner()


def _run_folder(folder: Path, log: Path, trajectory: Path, pipeline: str = "dense") -> Path:
    """A run folder as 'slamcli run PIPELINE' writes it, with ``trajectory`` as its trajectory."""
    folder.mkdir(parents=True)
    shutil.copy(trajectory, folder / "trajectory.tum")
    record = {
        "command": f"run {pipeline}",
        "inputs": [{"path": str(log.resolve())}],
        "config": {pipeline: {}, "source": {}},
        "outputs": [],
    }
    (folder / "run.json").write_text(json.dumps(record), encoding="utf-8")
    return folder


def _occupied(grid: OccupancyGrid) -> NDArray[np.bool_]:
    prob = np.asarray(grid.prob)
    return ~np.isnan(prob) & (np.rint(prob * 100) >= 65)


def _free(grid: OccupancyGrid) -> NDArray[np.bool_]:
    prob = np.asarray(grid.prob)
    return ~np.isnan(prob) & (np.rint(prob * 100) <= 20)


def _plan_across(grid: OccupancyGrid) -> float:
    """Plan between two far-apart cells of the largest free component; the path's length."""
    from scipy.ndimage import label

    from slamcli.formats.occupancy import cell_to_world
    from slamcli.planning.costmap import build_costmap
    from slamcli.planning.planner import plan

    blocked = build_costmap(grid, 0.2).blocked
    # 4-connected: the search never cuts a blocked corner
    labels, n = label(~blocked)
    assert n > 0, "no free space the robot fits in"
    sizes = np.bincount(labels.ravel())[1:]
    cells = np.argwhere(labels == 1 + int(sizes.argmax()))
    a = cells[np.argmin(cells @ np.array([1, 1]))]
    b = cells[np.argmax(np.linalg.norm(cells - a, axis=1))]
    start, goal = cell_to_world(grid, [a, b])
    result = plan(grid, tuple(start), tuple(goal))
    assert result.length_m >= np.linalg.norm(goal - start) - 1e-9
    return float(np.linalg.norm(goal - start))


# --- the log-odds grid -----------------------------------------------------------------------


def test_one_ray_carves_its_cells_and_marks_its_hit() -> None:
    grid = LogOddsGrid((10, 20), 0.1, (0.0, 0.0))
    grid.integrate((0.05, 0.55), [[1.55, 0.55], [0.55, 0.95]], [True, False])
    row = grid.logodds[5]
    assert np.allclose(row[:15], L_FREE) and row[15] == pytest.approx(L_OCC)
    assert np.isnan(grid.probability()[0, 19])
    # the same scan many times: clamped
    for _ in range(20):
        grid.integrate((0.05, 0.55), [[1.55, 0.55]], [True])
    assert grid.logodds[5, 15] == pytest.approx(3.5) and grid.logodds[5, 0] == pytest.approx(-2)
    prob = grid.probability()
    assert prob[5, 15] > 0.95 and prob[5, 0] < 0.15


def test_height_band_parsing() -> None:
    assert parse_height_band("0.05, 1.2") == (0.05, 1.2)
    for bad in ("0.5,0.1", "1", "a,b"):
        with pytest.raises(ConfigError, match="--height-band"):
            parse_height_band(bad)
    with pytest.raises(ConfigError, match="--resolution"):
        MapSettings(resolution_m=0).checked()


# --- the synthetic room ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def room_map(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, BuiltMap]:
    run = _run_folder(tmp_path_factory.mktemp("room") / "run", ROOM, ROOM / "groundtruth.txt")
    built, _ = map_run(run)
    return run, built


def _true_obstacles(grid: OccupancyGrid, band: tuple[float, float]) -> NDArray[np.bool_]:
    """Cells of the room's walls and box sides between the band's heights, and of the box tops
    inside the band, rasterised by sampling every quarter cell."""
    from slamcli.formats.occupancy import world_to_cell
    from slamcli.synth.rgbd import room_scene

    res = grid.resolution_m
    samples = []
    for s in room_scene().surfaces:
        corners = s.corners()
        z = corners[:, 2]
        if abs(s.normal[2]) < 1e-6:  # vertical: its footprint where it meets the band
            if z.max() < band[0] or z.min() > band[1]:
                continue
            n = int(np.ceil(s.size_u / (res / 4))) + 1
            t = np.linspace(0.0, s.size_u, n)
            samples.append(s.origin[:2] + t[:, None] * s.u_axis[:2])
        elif band[0] <= z.mean() <= band[1]:  # a box top inside the band
            a, b = np.meshgrid(
                np.arange(0.0, s.size_u + 1e-9, res / 4), np.arange(0.0, s.size_v + 1e-9, res / 4)
            )
            samples.append(
                s.origin[:2] + a.reshape(-1, 1) * s.u_axis[:2] + b.reshape(-1, 1) * s.v_axis[:2]
            )
    rc = world_to_cell(grid, np.concatenate(samples))
    h, w = grid.prob.shape
    rc = rc[(rc[:, 0] >= 0) & (rc[:, 0] < h) & (rc[:, 1] >= 0) & (rc[:, 1] < w)]
    truth = np.zeros((h, w), dtype=bool)
    truth[rc[:, 0], rc[:, 1]] = True
    return truth


def test_room_map_matches_the_scene(room_map: tuple[Path, BuiltMap]) -> None:
    from scipy.ndimage import distance_transform_edt

    _, built = room_map
    grid, report = built.grid, built.report
    occupied = _occupied(grid)
    truth = _true_obstacles(grid, (0.1, 1.5))
    near = distance_transform_edt(~truth) <= 2.0 * np.sqrt(2) + 1e-9
    share = np.count_nonzero(occupied & near) / np.count_nonzero(occupied)
    assert np.count_nonzero(occupied) > 100
    assert share >= 0.95, f"only {share:.1%} of occupied cells lie near a true obstacle"
    normal = np.asarray(report["floor"]["normal_world"])
    assert np.degrees(np.arccos(normal @ [0.0, 0.0, 1.0])) < 2.0
    assert report["up"]["method"] == "accelerometer"
    assert report["frames"] == {
        "read": 30,
        "used": 30,
        "without_pose": 0,
        "frame_step": 1,
        "pixel_step": 4,
    }
    assert np.count_nonzero(_free(grid)) > 1000
    assert report["cells"]["free"] == np.count_nonzero(_free(grid))


def test_room_map_plans_and_loads_back_as_written(room_map: tuple[Path, BuiltMap]) -> None:
    from slamcli.planning.planner import load_map

    run, built = room_map
    loaded = read_map_yaml(run / "map.yaml")
    assert loaded.prob.shape == built.grid.prob.shape
    assert loaded.resolution_m == built.grid.resolution_m
    assert np.allclose(loaded.origin_xy_yaw, built.grid.origin_xy_yaw)
    assert np.array_equal(_occupied(loaded), _occupied(built.grid))
    assert np.array_equal(_free(loaded), _free(built.grid))
    unknown = ~_occupied(built.grid) & ~_free(built.grid)
    assert np.array_equal(np.isnan(loaded.prob), unknown)
    assert _plan_across(load_map(run)[0]) > 1.0
    record = json.loads((run / "run.json").read_text())
    assert record["outputs"][-5:] == ["map.yaml", "map.pgm", "map.png", "map.json", "run.json"]


def test_map_build_cli_writes_elsewhere_and_refuses_to_overwrite(
    room_map: tuple[Path, BuiltMap], tmp_path: Path
) -> None:
    run, _ = room_map
    out = tmp_path / "map"
    res = runner.invoke(app, ["map", "build", str(run), "--out", str(out), "--frame-step", "3"])
    assert res.exit_code == 0, res.output
    assert {p.name for p in out.iterdir()} == {"map.yaml", "map.pgm", "map.png", "map.json"}
    assert json.loads((out / "map.json").read_text())["frames"]["used"] == 10
    res = runner.invoke(app, ["map", "build", str(run)])
    assert res.exit_code == 1 and "--force" in res.output
    res = runner.invoke(app, ["map", "show", str(out / "map.yaml")])
    assert res.exit_code == 0 and "occupied" in res.output


# --- the TUM excerpt -------------------------------------------------------------------------


def test_tum_excerpt_map_from_ground_truth(tmp_path: Path) -> None:
    tum = shared_path("tum", "rgbd_dataset_freiburg1_rpy_excerpt")
    run = _run_folder(tmp_path / "run", tum, tum / "groundtruth.txt")
    built = build_map(run)
    assert built.report["frames"]["used"] >= 140
    # TUM's Kinect accelerometer is not in the colour camera's axes; the remapped mounting
    # agrees with the mocap's z axis (up) and the floor lies about at the mocap's z = 0.
    up = np.asarray(built.report["up"]["direction_world"])
    assert up[2] > np.cos(np.radians(5))
    assert abs(built.report["floor"]["offset_m"]) < 0.15
    assert np.count_nonzero(_occupied(built.grid)) > 200
    assert np.count_nonzero(_free(built.grid)) > 500
    assert _plan_across(built.grid) > 1.0


# --- the landmark world ----------------------------------------------------------------------


def test_ekf_run_with_map(shared_run: Any) -> None:
    from slamcli.formats.landmark_map import read_landmarks_csv
    from slamcli.formats.occupancy import world_to_cell
    from slamcli.formats.trajectory import read_trajectory
    from slamcli.geometry import umeyama

    # Once per session: the next test and the help examples run the same command.
    res = shared_run("run", "ekf", LANDMARKS, "--map")
    run = res.out
    assert res.exit_code == 0, res.output
    assert "map.yaml" in res.output
    grid = read_map_yaml(run / "map.yaml")
    occ_cells = np.argwhere(_occupied(grid))
    # The map is in the run's frame, which the EKF's drift rotates by a few degrees from the
    # truth's: the true landmarks are compared after an SE(2) alignment to the mapped ones.
    truth = read_landmarks_csv(LANDMARKS / "landmarks.csv")
    mapped = read_landmarks_csv(run / "landmarks.csv")
    order = [int(np.flatnonzero(mapped.ids == i)[0]) for i in truth.ids]
    rot, shift, _ = umeyama(truth.xy, mapped.xy[order])
    for rc in world_to_cell(grid, truth.xy @ rot.T + shift):
        assert np.abs(occ_cells - rc).max(axis=1).min() <= 2, rc
    path = read_trajectory(run / "trajectory.tum", "tum").positions[:, :2]
    path_rc = world_to_cell(grid, path)
    assert np.all(_free(grid)[path_rc[:, 0], path_rc[:, 1]])
    assert _plan_across(grid) > 5.0
    report = json.loads((run / "map.json").read_text())
    assert report["kind"] == "landmarks" and report["landmarks"] == 40


# --- errors ----------------------------------------------------------------------------------


def test_a_folder_without_a_trajectory(tmp_path: Path) -> None:
    (tmp_path / "run.json").write_text("{}")
    with pytest.raises(InputError, match=r"trajectory\.tum"):
        build_map(tmp_path)
    res = runner.invoke(app, ["map", "build", str(tmp_path)])
    assert res.exit_code == 1 and "trajectory.tum" in res.output


def test_a_run_whose_input_moved(tmp_path: Path) -> None:
    moved = tmp_path / "gone"
    run = _run_folder(tmp_path / "run", moved, ROOM / "groundtruth.txt")
    res = runner.invoke(app, ["map", "build", str(run)])
    assert res.exit_code == 1
    assert str(moved) in res.output and "--input" in res.output
    res = runner.invoke(app, ["map", "build", str(run), "--input", str(ROOM), "--frame-step", "10"])
    assert res.exit_code == 0, res.output


def test_a_bad_height_band(tmp_path: Path) -> None:
    run = _run_folder(tmp_path / "run", ROOM, ROOM / "groundtruth.txt")
    res = runner.invoke(app, ["map", "build", str(run), "--height-band", "0.5,0.1"])
    assert res.exit_code == 1 and "--height-band" in res.output
    assert not (run / "map.yaml").exists()


# --- the pipeline the run declares chooses the map --------------------------------------------


def test_an_ekf_run_without_landmarks_csv_is_still_an_ekf_run(tmp_path: Path) -> None:
    run = _run_folder(tmp_path / "run", LANDMARKS, LANDMARKS / "groundtruth.tum", "ekf")
    with pytest.raises(InputError, match=r"ekf pipeline without landmarks\.csv"):
        build_map(run)
    res = runner.invoke(app, ["map", "build", str(run)])
    assert res.exit_code == 1 and "landmarks.csv" in res.output
    assert not (run / "map.yaml").exists()


def test_a_stray_landmarks_csv_does_not_make_a_dense_run_an_ekf_run(tmp_path: Path) -> None:
    run = _run_folder(tmp_path / "run", ROOM, ROOM / "groundtruth.txt")
    shutil.copy(LANDMARKS / "landmarks.csv", run / "landmarks.csv")
    built = build_map(run, settings=MapSettings(frame_step=10))
    assert built.report["kind"] == "depth"


def test_a_run_that_names_no_pipeline(tmp_path: Path) -> None:
    run = _run_folder(tmp_path / "run", ROOM, ROOM / "groundtruth.txt")
    (run / "run.json").write_text(json.dumps({"inputs": [{"path": str(ROOM)}]}))
    with pytest.raises(InputError, match="does not say which pipeline"):
        build_map(run)


def test_depth_of_a_distorted_camera_is_lifted_along_the_true_rays() -> None:
    """fr1 frames read without --undistort keep their lens distortion; OpenCV's forward model
    must put every lifted point back on the raw pixel it came from."""
    import cv2

    from slamcli.formats.camera import PRESETS
    from slamcli.mapping.build import _back_project

    cam = PRESETS["fr1"]
    depth = np.full((cam.height, cam.width), 2.0, dtype=np.float32)
    pts = _back_project(depth, cam, 40, 5.0)
    assert pts.shape == (12 * 16, 3) and np.all(pts[:, 2] == 2.0)
    raw, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K, np.asarray(cam.distortion))
    v, u = np.mgrid[0 : cam.height : 40, 0 : cam.width : 40]
    grid = np.column_stack([u.ravel(), v.ravel()])
    np.testing.assert_allclose(raw.reshape(-1, 2), grid, atol=1e-6)


def test_run_with_map_is_one_folder_that_names_itself(shared_run: Any) -> None:
    res = shared_run("run", "ekf", LANDMARKS, "--map")
    run = res.out
    assert res.exit_code == 0, res.output
    record = json.loads((run / "run.json").read_text())
    assert {"map.yaml", "map.pgm", "map.png", "map.json"} <= set(record["outputs"])
    # map.json names the run's final folder, not the staging folder it was built in.
    text = (run / "map.json").read_text()
    assert ".staging" not in text
    # A shared run's folder holds its --out alone.
    assert [p.name for p in run.parent.iterdir()] == [run.name]


def test_run_with_map_refuses_a_monocular_run_before_its_frames(tmp_path: Path) -> None:
    out = tmp_path / "mono"
    res = runner.invoke(
        app,
        ["run", "visual", str(ROOM), "--out", str(out), "--map", "--set", "mode=mono"],
    )
    assert res.exit_code == 1, res.output
    assert "monocular" in res.output and "Traceback" not in res.output
    assert not out.exists()
