"""Visual-inertial SLAM on real EuRoC excerpts: MH_05 in flight (monocular + IMU, initialised
in motion) and V1_01's static start (stereo + IMU, initialised at rest); the IMU's outputs
(imu_states.csv, run.json, the report), the visual run with ``imu=false``, and the IMU's
prediction poses frames whose images are blank."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import shared_path
from visual_data import SLOW_LOOP_KEY, render_slow_loop

from slamcli.evaluation import evaluate
from slamcli.formats.euroc import EurocSource
from slamcli.formats.trajectory import read_trajectory
from slamcli.pipelines.visual import VisualConfig
from slamcli.pipelines.visual.inertial import SCALE_DOUBT_STD
from slamcli.run import RunOutcome, run_pipeline

MH05_FRAMES = 140
V1_01_FRAMES = 95


def _run(folder: Path, out: Path, **settings: object) -> RunOutcome:
    return run_pipeline(folder, "visual", out, config=VisualConfig(**settings))  # type: ignore[arg-type]


class Shared:
    """A shared run (``conftest.shared_run``) as these tests read it."""

    def __init__(self, run: Any) -> None:
        assert run.exception is None, run.traceback
        assert run.exit_code == 0, run.output
        self.run_dir: Path = run.out
        self.record = json.loads((run.out / "run.json").read_text())
        self.evaluation = self.record["metrics"]["evaluation"]["alignment"]


@pytest.fixture(scope="session")
def mh05(shared_run: Any) -> Shared:
    """One monocular-inertial run over the MH_05 excerpt, read by several tests: the docs'
    first visual-inertial example, made once per session."""
    return Shared(shared_run("run", "visual", shared_path("vi", "euroc_MH05_a")))


@pytest.fixture(scope="session")
def mh05_truth() -> object:
    return EurocSource(shared_path("vi", "euroc_MH05_a")).groundtruth()


def _record(outcome: RunOutcome | Shared) -> dict:
    return json.loads((outcome.run_dir / "run.json").read_text())


def test_mh05_initialises_in_flight_within_4_s(mh05: Shared) -> None:
    inertial = _record(mh05)["metrics"]["inertial"]
    assert inertial["initialised"]
    first = inertial["events"][0]
    assert first["kind"] == "initialisation"
    assert first["after_s"] <= 4.0
    # The monocular map had no metric scale: the initialisation found one.
    assert first["scale"] > 0 and first["scale_std"] <= 0.05
    # The flight accelerates hard: its 7 s fix the scale to a fraction of a per cent.
    assert inertial["scale_determination"]["std"] <= 0.005


def test_mh05_metric_trajectory(mh05: Shared, mh05_truth: object) -> None:
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


def test_mh05_imu_outputs(mh05: Shared, mh05_truth: object) -> None:
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


def test_mh05_without_imu_is_the_visual_run(shared_run: Any) -> None:
    """``imu=false``: no IMU read, no inertial record, scored after a similarity (sim3)."""
    outcome = Shared(
        shared_run("run", "visual", shared_path("vi", "euroc_MH05_a"), "--set", "imu=false")
    )
    assert outcome.evaluation == "sim3"
    record = _record(outcome)
    assert "inertial" not in record["metrics"]
    assert not (outcome.run_dir / "imu_states.csv").exists()


def test_v1_01_stereo_inertial_from_rest(shared_run: Any) -> None:
    """The drone sits on the floor for the whole excerpt: the IMU is initialised at rest,
    every pair is posed, ATE at most 2 mm (the docs' stereo example, made once per session)."""
    folder = shared_path("stereo", "euroc_V1_01_micro")
    truth_file = folder / "groundtruth_body.txt"
    outcome = Shared(shared_run("run", "visual", folder, "--groundtruth", truth_file))
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


# -- known answers: `synth stereo`, IMU noise at EuRoC's densities -------------------------------

STEREO_ATE_PER_PATH = 0.003
"""Stereo-inertial SE(3) ATE, as a share of the path (the issue's 0.3 %)."""
MONO_ATE_PER_PATH = 0.01
"""Monocular-inertial SE(3) ATE (no scale fitted), as a share of the path."""
MONO_SCALE_ERROR = 0.01
"""Monocular-inertial |Sim(3) scale - 1| on the 640x480 seeds of ``make test-robust`` (the
issue's 1 %; found 0.05-0.64 %). 10 s of the loop bound the scale's standard deviation at
1.0 % with perfect vision (slamcli.inertial.observability), so other seeds can miss it: seeds
7 and 9's IMU noise alone puts the truth 1.5-1.6 % off."""
SMALL_RIG_SCALE_ERROR = 0.04
"""The same on the suite's rig (8 s, 320x240, seed 0): its IMU noise alone puts the truth
1.2 % off (the bound is 0.76 %) and vision at half the resolution bends the path's shape;
found 3.0 %."""
GRAVITY_DEG = 0.5
"""Angle between the run's vertical and the ground truth's."""
BLANK_RATIO = 2.0
"""ATE with a second of blank images over the ATE without."""


def synth_scores(folder: Path, run_dir: Path) -> dict[str, float]:
    """SE(3) ATE over the path, the Sim(3) scale and the tilt between the run's z axis and
    the ground truth's, of a run on a ``synth stereo`` folder."""
    from slamcli.evaluation import align, associate
    from slamcli.evaluation import ate as position_errors

    truth = EurocSource(folder).groundtruth()
    estimate = read_trajectory(run_dir / "trajectory.tum")
    matched = associate(truth, estimate)
    path = float(np.linalg.norm(np.diff(matched.gt[:, :3, 3], axis=0), axis=1).sum())
    aligned, rotation, _, _ = align(matched.gt, matched.est, "se3")
    rmse = float(np.sqrt(np.mean(position_errors(matched.gt, aligned) ** 2)))
    _, _, _, scale = align(matched.gt, matched.est, "sim3")
    tilt = math.degrees(math.acos(min(1.0, float(rotation[2, 2]))))
    return {"ate": rmse, "path": path, "scale": scale, "tilt_deg": tilt, "frames": len(estimate)}


def blank_images(folder: Path, copy: Path, start_s: float, end_s: float) -> int:
    """A copy of an ASL folder with every camera's images in [start_s, end_s) after the first
    made black; returns how many of cam0's were."""
    import cv2

    shutil.copytree(folder, copy)
    blanked = 0
    for cam in sorted((copy / "mav0").glob("cam*")):
        images = sorted((cam / "data").glob("*.png"))
        first = int(images[0].stem)
        for png in images:
            if start_s <= (int(png.stem) - first) * 1e-9 < end_s:
                grey = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
                cv2.imwrite(str(png), np.zeros_like(grey))
                blanked += cam.name == "cam0"
    return blanked


@pytest.fixture(scope="session")
def rendered_rig(shared_artefact: object) -> Path:
    """`synth stereo` seed 0: 160 pairs (8 s), 320x240, with image and IMU noise."""
    from slamcli.synth.stereo import render_stereo_sequence

    def render(folder: Path) -> None:
        render_stereo_sequence(folder / "rig", frames=160, size=(320, 240), noise=True, seed=0)

    return shared_artefact("vi-rig-0", render) / "rig"  # type: ignore[operator]


def test_stereo_inertial_known_answer(rendered_rig: Path, tmp_path: Path) -> None:
    """Metric, gravity-aligned, and the biases the simulation put in the IMU."""
    outcome = _run(rendered_rig, tmp_path / "run")
    got = synth_scores(rendered_rig, outcome.run_dir)
    assert got["frames"] == 160
    # The stereo baseline gives the scale: nothing for the IMU to determine.
    assert _record(outcome)["metrics"]["inertial"]["scale_determination"] is None
    assert got["ate"] <= STEREO_ATE_PER_PATH * got["path"]
    assert got["tilt_deg"] <= GRAVITY_DEG
    states = np.loadtxt(outcome.run_dir / "imu_states.csv", delimiter=",", skiprows=1)
    truth = np.loadtxt(
        rendered_rig / "mav0" / "state_groundtruth_estimate0" / "data.csv",
        delimiter=",",
        comments="#",
    )
    at = np.clip(np.searchsorted(truth[:, 0], states[:, 0]), 0, len(truth) - 1)
    assert np.abs(states[:, 4:7] - truth[at, 11:14]).max() <= 0.002  # gyroscope, rad/s
    assert np.median(np.abs(states[:, 7:10] - truth[at, 14:17])) <= 0.05  # accelerometer
    # Velocity: the run's world has its own yaw, so its speed and vertical part, m/s.
    speed = np.linalg.norm(states[:, 1:4], axis=1) - np.linalg.norm(truth[at, 8:11], axis=1)
    assert np.median(np.abs(speed)) <= 0.02
    assert np.median(np.abs(states[:, 3] - truth[at, 10])) <= 0.02


def test_mono_inertial_known_answer(rendered_rig: Path, tmp_path: Path) -> None:
    outcome = _run(rendered_rig, tmp_path / "run", mode="mono")
    assert outcome.evaluation == "se3"
    got = synth_scores(rendered_rig, outcome.run_dir)
    assert got["frames"] >= 0.95 * 160
    assert got["ate"] <= MONO_ATE_PER_PATH * got["path"]
    assert got["tilt_deg"] <= 2 * GRAVITY_DEG
    assert abs(got["scale"] - 1.0) <= SMALL_RIG_SCALE_ERROR
    # How well 8 s of the loop fix the scale, and the IMU's own reading of the run's size.
    record = _record(outcome)["metrics"]
    scale = record["inertial"]["scale_determination"]
    assert 0.004 <= scale["std"] <= 0.012
    assert abs(scale["imu_scale"] - 1.0) <= 3 * scale["std"]
    assert not record["doubts"]


def test_mono_inertial_doubts_a_scale_its_motion_leaves_loose(
    shared_artefact: Any, tmp_path: Path
) -> None:
    """18 s of the loop at a steady pace: the IMU cannot tell the size well, and says so."""
    rig = shared_artefact(SLOW_LOOP_KEY, render_slow_loop) / "rig"
    outcome = _run(rig, tmp_path / "run", mode="mono")
    record = _record(outcome)["metrics"]
    scale = record["inertial"]["scale_determination"]
    assert scale["std"] > SCALE_DOUBT_STD
    assert any("determines the metric scale only to" in d for d in record["doubts"])
