"""Visual-inertial SLAM on real EuRoC excerpts: MH_05 in flight (monocular + IMU, initialised
in motion) and V1_01's static start (stereo + IMU, initialised at rest); the IMU's outputs
(imu_states.csv, run.json, the report), the visual run with ``imu=false``, and the IMU's
prediction poses frames whose images are blank."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path

from slamcli.evaluation import evaluate
from slamcli.formats.euroc import EurocSource
from slamcli.formats.trajectory import read_trajectory
from slamcli.pipelines.visual import VisualConfig
from slamcli.run import RunOutcome, run_pipeline

MH05_FRAMES = 140
V1_01_FRAMES = 95


def _run(folder: Path, out: Path, **settings: object) -> RunOutcome:
    return run_pipeline(folder, "visual", out, config=VisualConfig(**settings))  # type: ignore[arg-type]


@pytest.fixture(scope="session")
def mh05(tmp_path_factory: pytest.TempPathFactory) -> RunOutcome:
    """One monocular-inertial run over the MH_05 excerpt, read by several tests."""
    return _run(shared_path("vi", "euroc_MH05_a"), tmp_path_factory.mktemp("mh05") / "run")


@pytest.fixture(scope="session")
def mh05_truth() -> object:
    return EurocSource(shared_path("vi", "euroc_MH05_a")).groundtruth()


def _record(outcome: RunOutcome) -> dict:
    return json.loads((outcome.run_dir / "run.json").read_text())


def test_mh05_initialises_in_flight_within_4_s(mh05: RunOutcome) -> None:
    inertial = _record(mh05)["metrics"]["inertial"]
    assert inertial["initialised"]
    first = inertial["events"][0]
    assert first["kind"] == "initialisation"
    assert first["after_s"] <= 4.0
    # The monocular map had no metric scale: the initialisation found one.
    assert first["scale"] > 0 and first["scale_std"] <= 0.05


def test_mh05_metric_trajectory(mh05: RunOutcome, mh05_truth: object) -> None:
    """SE(3) ATE (no scale fitted) at most 0.08 m, Sim(3) scale within 3 % of 1, at least
    95 % of the frames posed, scored as a metric (se3) run."""
    assert mh05.evaluation == "se3"
    estimate = read_trajectory(mh05.run_dir / "trajectory.tum")
    assert len(estimate) >= math.ceil(0.95 * MH05_FRAMES)
    se3 = evaluate(mh05_truth, estimate, align="se3")
    sim3 = evaluate(mh05_truth, estimate, align="sim3")
    assert se3.ate.rmse <= 0.08
    assert abs(sim3.scale - 1.0) <= 0.03
    # The world is gravity-aligned: the alignment to the (levelled) ground truth only turns
    # about z, up to a small tilt.
    tilt = math.degrees(math.acos(min(1.0, se3.rotation[2, 2])))
    assert tilt <= 2.0


def test_mh05_imu_outputs(mh05: RunOutcome, mh05_truth: object) -> None:
    """imu_states.csv has one row per keyframe, velocities near the ground truth's and the
    gyroscope bias near EuRoC's estimate; the report has its IMU panel's data."""
    path = mh05.run_dir / "imu_states.csv"
    header = path.read_text().splitlines()[0].split(",")
    assert header[0] == "stamp_ns" and len(header) == 10
    states = np.loadtxt(path, delimiter=",", skiprows=1)
    keyframes = read_trajectory(mh05.run_dir / "keyframes.tum")
    assert states.shape == (len(keyframes), 10)
    gt = np.loadtxt(
        shared_path("vi", "euroc_MH05_a", "mav0", "state_groundtruth_estimate0", "data.csv"),
        delimiter=",",
        comments="#",
    )
    nearest = np.searchsorted(gt[:, 0], states[:, 0])
    nearest = np.clip(nearest, 0, len(gt) - 1)
    speed_err = np.abs(
        np.linalg.norm(states[:, 1:4], axis=1) - np.linalg.norm(gt[nearest, 8:11], axis=1)
    )
    assert np.median(speed_err) <= 0.1
    # EuRoC's own gyroscope bias estimate (0.077 rad/s about z here).
    assert np.abs(states[-1, 4:7] - gt[nearest[-1], 11:14]).max() <= 0.01
    assert (mh05.run_dir / "report.png").stat().st_size > 0
    record = _record(mh05)
    assert "imu_states.csv" in record["outputs"]
    assert len(record["metrics"]["inertial"]["final_gyro_bias"]) == 3


def test_mh05_without_imu_is_the_visual_run(tmp_path: Path) -> None:
    """``imu=false``: no IMU read, no inertial record, scored after a similarity (sim3)."""
    outcome = _run(shared_path("vi", "euroc_MH05_a"), tmp_path / "run", imu=False)
    assert outcome.evaluation == "sim3"
    record = _record(outcome)
    assert "inertial" not in record["metrics"]
    assert not (outcome.run_dir / "imu_states.csv").exists()


def test_v1_01_stereo_inertial_from_rest(tmp_path: Path) -> None:
    """The drone sits on the floor for the whole excerpt: the IMU is initialised at rest,
    every pair is posed, ATE at most 2 mm."""
    folder = shared_path("stereo", "euroc_V1_01_micro")
    outcome = _run(folder, tmp_path / "run")
    inertial = _record(outcome)["metrics"]["inertial"]
    assert inertial["initialised"]
    estimate = read_trajectory(outcome.run_dir / "trajectory.tum")
    assert len(estimate) == V1_01_FRAMES
    truth = read_trajectory(folder / "groundtruth_body.txt")
    assert evaluate(truth, estimate, align="se3").ate.rmse <= 0.002


def test_blank_images_are_posed_on_the_imu(tmp_path: Path, mh05_truth: object) -> None:
    """A second of MH_05's images blanked (4.0-5.0 s, after the IMU's initialisation at
    3.4 s): those frames are posed on the IMU alone (state ``inertial``), tracking resumes
    on the map after, and the trajectory stays metric."""
    import cv2

    src = shared_path("vi", "euroc_MH05_a")
    copy = tmp_path / "mh05_blank"
    shutil.copytree(src, copy)
    images = sorted((copy / "mav0" / "cam0" / "data").glob("*.png"))
    first = int(images[0].stem)
    blanked = 0
    for png in images:
        if 4.0 <= (int(png.stem) - first) * 1e-9 < 5.0:
            grey = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
            cv2.imwrite(str(png), np.zeros_like(grey))
            blanked += 1
    assert blanked == 20
    outcome = _run(copy, tmp_path / "run")
    counts = outcome.counts
    assert blanked - 2 <= counts["frames_inertial"] <= blanked + 2
    estimate = read_trajectory(outcome.run_dir / "trajectory.tum")
    assert len(estimate) >= math.ceil(0.95 * MH05_FRAMES)
    assert evaluate(mh05_truth, estimate, align="se3").ate.rmse <= 0.08
    doubts = _record(outcome)["metrics"]["doubts"]
    assert any("posed on the IMU alone" in d for d in doubts)
