"""Stereo visual SLAM (``run visual`` on a stereo source): the KITTI excerpt against its ground
truth, the static EuRoC excerpt against the body-frame ground truth, determinism, the mode
choice, and the grouped descriptor matching it triangulates far points with.

Each real-data run is made once per session (the fixtures below) and read by several tests.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from conftest import shared_path
from visual_data import SLOW_LOOP_KEY, render_slow_loop

from slamcli.errors import ConfigError, InputError
from slamcli.evaluation import align
from slamcli.evaluation import ate as position_errors
from slamcli.formats import open_source
from slamcli.formats.kitti import KittiSource
from slamcli.formats.trajectory import read_trajectory
from slamcli.pipelines.visual import VisualConfig, VisualSlam
from slamcli.run import RunOutcome, run_pipeline
from slamcli.types import StereoFrame
from slamcli.vision.matching import match_ratio, match_ratio_grouped

KITTI = ("stereo", "kitti_excerpt_1")
EUROC = ("stereo", "euroc_V1_01_micro")

# Accuracy thresholds, shared with the perturbed runs of tests/robust.
KITTI_ATE_M = 0.12
KITTI_DRIFT_PER_PATH = 0.0125
"""Endpoint drift over the path length."""
KITTI_SIM3_ATE_M = 0.04
KITTI_SCALE_ERROR = 0.01
"""|scale - 1| of the Sim(3) alignment, and of the path length's ratio."""
EUROC_STATIC_M = 0.005
"""ATE, and every excursion from the first pose, of the static start."""
SYNTH_ATE_PER_PATH = 0.01
SYNTH_SCALE_ERROR = 0.005


@pytest.fixture(scope="session")
def kitti_run(tmp_path_factory: pytest.TempPathFactory) -> RunOutcome:
    out = tmp_path_factory.mktemp("stereo") / "kitti"
    return run_pipeline(shared_path(*KITTI), "visual", out)


@pytest.fixture(scope="session")
def euroc_run(shared_run: Any) -> Any:
    """The docs' EuRoC example (made once per session, also read by the visual-inertial
    tests), as these tests read a run: ``run_dir``, ``metrics`` (run.json's) and ``result``'s
    ``metrics`` and ``trajectory`` (trajectory.tum's)."""
    folder = shared_path(*EUROC)
    run = shared_run("run", "visual", folder, "--groundtruth", folder / "groundtruth_body.txt")
    assert run.exit_code == 0 and run.exception is None, run.output + run.traceback
    metrics = json.loads((run.out / "run.json").read_text())["metrics"]
    trajectory = read_trajectory(run.out / "trajectory.tum")
    result = SimpleNamespace(metrics=metrics, trajectory=trajectory)
    return SimpleNamespace(run_dir=run.out, metrics=metrics, result=result)


def _positions(outcome: RunOutcome) -> np.ndarray:
    return outcome.result.trajectory.world_from_body[:, :3, 3]


def test_kitti_every_pair_is_posed_at_metric_scale(kitti_run: RunOutcome) -> None:
    result = kitti_run.result
    assert result.metrics["mode"] == "stereo"
    assert len(result.trajectory) == 51
    assert result.counts["frames_lost"] == 0
    assert kitti_run.evaluation == "se3"
    # The scale comes from the stereo baseline: the path is the ground truth's within 1 %.
    gt = KittiSource(shared_path(*KITTI)).groundtruth()
    assert gt is not None
    est_len = np.linalg.norm(np.diff(_positions(kitti_run), axis=0), axis=1).sum()
    assert abs(est_len / gt.path_length() - 1.0) < KITTI_SCALE_ERROR


def test_kitti_accuracy_against_ground_truth(kitti_run: RunOutcome) -> None:
    rmse = kitti_run.metrics["evaluation"]["ate"]["rmse"]
    # 60 m of driving; ORB-SLAM3 gives 0.047-0.066 m on these frames.
    assert rmse < KITTI_ATE_M
    gt = KittiSource(shared_path(*KITTI)).groundtruth()
    assert gt is not None
    est = _positions(kitti_run)
    ref = gt.world_from_body[:, :3, 3]
    # Endpoint drift: the end's offset from the start, compared in each one's own first frame.
    r0 = kitti_run.result.trajectory.world_from_body[0, :3, :3]
    g0 = gt.world_from_body[0, :3, :3]
    drift = np.linalg.norm(r0.T @ (est[-1] - est[0]) - g0.T @ (ref[-1] - ref[0]))
    assert drift / gt.path_length() < KITTI_DRIFT_PER_PATH
    # Shape and scale: after a similarity alignment the error is a few centimetres.
    traj = kitti_run.result.trajectory.world_from_body
    aligned, _, _, scale = align(gt.world_from_body, traj, "sim3")
    sim3_rmse = float(np.sqrt(np.mean(position_errors(gt.world_from_body, aligned) ** 2)))
    assert sim3_rmse < KITTI_SIM3_ATE_M
    assert abs(scale - 1.0) < KITTI_SCALE_ERROR


def test_euroc_static_start_stays_within_5mm(euroc_run: RunOutcome) -> None:
    result = euroc_run.result
    assert result.metrics["mode"] == "stereo"
    assert len(result.trajectory) == 95
    ev = euroc_run.metrics["evaluation"]
    assert ev["ate"]["rmse"] < EUROC_STATIC_M
    # The drone sits on the floor: the body moves less than 5 mm over the excerpt.
    pos = _positions(euroc_run)
    assert np.linalg.norm(pos[-1] - pos[0]) < EUROC_STATIC_M
    assert np.max(np.linalg.norm(pos - pos[0], axis=1)) < EUROC_STATIC_M


def test_keyframes_come_at_least_every_keyframe_max_seconds(tmp_path: Path) -> None:
    # The drone sits still: tracking never weakens, so only the time and frame limits make
    # keyframes. With the frame limit out of the way, the time limit alone keeps them coming.
    config = VisualConfig(keyframe_max_frames=1000, keyframe_max_seconds=0.25)
    outcome = run_pipeline(
        shared_path(*EUROC), "visual", tmp_path / "run", config=config, max_frames=40
    )
    stamps = outcome.result.trajectory.stamps_ns
    duration = (stamps[-1] - stamps[0]) * 1e-9
    made = outcome.result.counts["keyframes_made"]
    assert 0.75 * duration / 0.25 <= made - 1 <= duration / 0.25
    assert made > stamps.size // 10 + 1  # what every 10 frames (0.5 s at 20 Hz) would make


def test_stereo_runs_are_deterministic(euroc_run: RunOutcome, tmp_path: Path) -> None:
    gt = shared_path(*EUROC) / "groundtruth_body.txt"
    again = run_pipeline(
        shared_path(*EUROC),
        "visual",
        tmp_path / "again",
        config=VisualConfig(threads=1),
        source_options={"groundtruth": str(gt)},
    )
    first = (euroc_run.run_dir / "trajectory.tum").read_bytes()
    assert (again.run_dir / "trajectory.tum").read_bytes() == first
    assert len(read_trajectory(again.run_dir / "trajectory.tum")) == 95


def test_auto_mode_picks_stereo_and_refuses_impossible_modes() -> None:
    info = open_source(shared_path(*KITTI)).info()
    slam = VisualSlam(VisualConfig())
    assert slam.frame_kinds(info) == ("stereo",)
    assert slam.evaluation == "se3"
    with pytest.raises(ConfigError, match="no depth stream"):
        VisualSlam(VisualConfig(mode="rgbd")).frame_kinds(info)
    tum = open_source(shared_path("tum", "rgbd_dataset_freiburg1_rpy_excerpt")).info()
    with pytest.raises(ConfigError, match="no stereo pairs"):
        VisualSlam(VisualConfig(mode="stereo")).frame_kinds(tum)


def test_pairs_of_different_sizes_are_refused() -> None:
    source = open_source(shared_path(*KITTI))
    frame = next(iter(source.frames(kinds=("stereo",))))
    cropped = type(frame)(frame.stamp_ns, frame.left, frame.right[:, :-8], frame.rig, name="pair 0")
    slam = VisualSlam(VisualConfig(threads=1))
    slam.frame_kinds(source.info())
    with pytest.raises(InputError, match="pair 0"):
        slam.process(cropped)
    slam.close()


def test_pairs_without_stereo_matches_make_no_map_and_say_why() -> None:
    from slamcli.errors import PipelineError

    source = open_source(shared_path(*KITTI))
    frames = [f for _, f in zip(range(3), source.frames(kinds=("stereo",)), strict=False)]
    slam = VisualSlam(VisualConfig(threads=1))
    slam.frame_kinds(source.info())
    # A right camera that sees nothing: no keypoint finds its match, so no depth at all.
    for f in frames:
        slam.process(type(f)(f.stamp_ns, f.left, np.zeros_like(f.right), f.rig, name=f.name))
    with pytest.raises(PipelineError) as err:
        slam.finish()
    assert "no map could be made from 3 stereo pairs" in err.value.msg
    assert "among the 100 nearest" in err.value.msg and "stereo_min_near" in err.value.hint


def test_grouped_matching_is_brute_force_within_groups() -> None:
    rng = np.random.default_rng(3)
    a = rng.integers(0, 256, (400, 32), dtype=np.uint8)
    b = a[rng.permutation(400)[:250]].copy()
    b[:, :2] ^= rng.integers(0, 16, (250, 2), dtype=np.uint8)
    # One group for all: the same pairs as the brute-force matcher.
    one = match_ratio_grouped(a, np.zeros(400, int), b, np.zeros(250, int), 0.8, 50)
    assert np.array_equal(one, match_ratio(a, b, 0.8, 50))
    # Groups: every pair stays within its group, and each a and b is used once at most.
    ga, gb = rng.integers(0, 5, 400), rng.integers(0, 5, 250)
    pairs = match_ratio_grouped(a, ga, b, gb, 0.8, 50)
    assert len(pairs) > 0
    assert np.all(ga[pairs[:, 0]] == gb[pairs[:, 1]])
    assert len(set(pairs[:, 0].tolist())) == len(pairs) == len(set(pairs[:, 1].tolist()))


@pytest.fixture(scope="session")
def synthetic_loop(
    tmp_path_factory: pytest.TempPathFactory, shared_artefact: Any
) -> tuple[Path, RunOutcome]:
    """18 s of the rendered stereo rig (one turn around the room, back to the start), with
    noise, at 10 Hz as KITTI's cameras (twice the steps of EuRoC's 20 Hz between pairs), and
    its run."""
    rig = shared_artefact(SLOW_LOOP_KEY, render_slow_loop) / "rig"
    return rig, run_pipeline(rig, "visual", tmp_path_factory.mktemp("synth_stereo") / "run")


def test_synthetic_loop_is_closed_at_metric_scale(
    synthetic_loop: tuple[Path, RunOutcome],
) -> None:
    from slamcli.evaluation import associate

    folder, outcome = synthetic_loop
    result = outcome.result
    assert result.metrics["mode"] == "stereo"
    assert len(result.trajectory) == 180
    assert result.counts["loop_closures_accepted"] >= 1
    gt = open_source(folder).groundtruth()
    assert gt is not None
    matched = associate(gt, result.trajectory)
    ref, est = matched.gt, matched.est
    path = np.linalg.norm(np.diff(ref[:, :3, 3], axis=0), axis=1).sum()
    # ATE (SE(3)) within 1 % of the path; the body frame is not the camera's (T_BS), so a
    # mistake in the body pose would show here.
    aligned, _, _, _ = align(ref, est, "se3")
    rmse = float(np.sqrt(np.mean(position_errors(ref, aligned) ** 2)))
    assert rmse < SYNTH_ATE_PER_PATH * path
    # Metric scale from the baseline alone.
    _, _, _, scale = align(ref, est, "sim3")
    assert abs(scale - 1.0) < SYNTH_SCALE_ERROR


@pytest.fixture(scope="session")
def euroc_logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The EuRoC excerpt as a converted MCAP log; that log as a ROS 1 bag (a bag's IMU topic
    carries no noise model); a bare bag of the images and the IMU alone (no CameraInfo, no
    tf, as EuRoC's own bags); and the rig's Kalibr files."""
    from bag_files import ros1_bag
    from kalibr_files import write_kalibr

    from slamcli.formats.mcap.write.stereo import write_stereo_mcap

    out = tmp_path_factory.mktemp("euroc_logs")
    folder = shared_path(*EUROC)
    gt = read_trajectory(folder / "groundtruth_body.txt")
    log = out / "euroc.mcap"
    write_stereo_mcap(open_source(folder), log, groundtruth=gt)
    camchain, imu = write_kalibr(folder, out / "kalibr")
    bare = ("/cam0/image_raw", "/cam1/image_raw", "/imu0")
    return {
        "mcap": log,
        "bag": ros1_bag(log, out / "euroc.bag"),
        "bare": ros1_bag(log, out / "bare.bag", topics=bare),
        "camchain": camchain,
        "imu": imu,
    }


def _same_trajectory(outcome: RunOutcome, reference: RunOutcome) -> float:
    """The largest distance between two runs' positions (they must pose the same frames)."""
    ours = outcome.result.trajectory.world_from_body[:, :3, 3]
    theirs = reference.result.trajectory.world_from_body[:, :3, 3]
    assert ours.shape == theirs.shape
    return float(np.max(np.linalg.norm(ours - theirs, axis=1)))


def test_euroc_through_a_converted_mcap_poses_every_pair(
    euroc_run: RunOutcome, euroc_logs: dict[str, Path], tmp_path: Path
) -> None:
    outcome = run_pipeline(euroc_logs["mcap"], "visual", tmp_path / "run")
    assert outcome.result.metrics["mode"] == "stereo"
    assert len(outcome.result.trajectory) == 95
    assert outcome.metrics["evaluation"]["ate"]["rmse"] < 0.005
    # The log holds the raw images, their calibration, the IMU with its noise model (the
    # channel's metadata) and its mounting (tf): the same visual-inertial run as the folder's.
    assert outcome.result.metrics["inertial"]["initialised"]
    assert euroc_run.result.metrics["inertial"]["initialised"]
    assert _same_trajectory(outcome, euroc_run) < 1e-6


def test_euroc_as_a_ros1_bag_with_kalibr_imu_yaml_is_read_as_the_folder(
    euroc_logs: dict[str, Path],
) -> None:
    # The bag's CameraInfo and tf place the cameras and the IMU; imu.yaml gives the noise a
    # ROS 1 bag cannot carry: the pipeline gets what the folder gives it, so the same run.
    folder = open_source(shared_path(*EUROC))
    with open_source(euroc_logs["bag"], calib=[str(euroc_logs["imu"])]) as bag:
        info, want = bag.info(), folder.info()
        assert VisualSlam(VisualConfig()).frame_kinds(info) == ("stereo", "imu")
        for key, value in want.details["imu"].items():
            assert np.allclose(info.details["imu"][key], value, atol=1e-12), key
        got = [f for f in bag.frames(("stereo", "imu"))][:300]
    ref = [f for f in folder.frames(("stereo", "imu"))][:300]
    assert [type(f).__name__ for f in got] == [type(f).__name__ for f in ref]
    assert [f.stamp_ns for f in got] == [f.stamp_ns for f in ref]
    for a, b in zip(got, ref, strict=True):
        if isinstance(a, StereoFrame):
            assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
            assert np.allclose(a.rig.body_from_left, b.rig.body_from_left, atol=1e-12)
        else:
            assert np.array_equal(a.gyro_radps, b.gyro_radps)


def test_a_bare_ros1_bag_runs_visual_inertial_on_the_kalibr_files(
    euroc_run: RunOutcome, euroc_logs: dict[str, Path], tmp_path: Path
) -> None:
    # Images and IMU alone: the cameras, their mounting on the IMU and its noise all come
    # from camchain-imucam.yaml and imu.yaml; the body is the IMU, as EuRoC's.
    calib = (str(euroc_logs["camchain"]), str(euroc_logs["imu"]))
    gt = shared_path(*EUROC) / "groundtruth_body.txt"
    options = {"calib": calib, "groundtruth": str(gt)}
    with open_source(euroc_logs["bare"], calib=list(calib)) as bare:
        chosen = bare.info().details["stereo_topics_chosen"]
    assert chosen == f"the rostopic of {euroc_logs['camchain']}"
    outcome = run_pipeline(euroc_logs["bare"], "visual", tmp_path / "run", source_options=options)
    assert outcome.result.metrics["inertial"]["initialised"]
    assert len(outcome.result.trajectory) == 95
    assert outcome.metrics["evaluation"]["ate"]["rmse"] < 0.002
    assert _same_trajectory(outcome, euroc_run) < 1e-6


def test_info_deep_lines_a_logs_imu_up_with_its_images(euroc_logs: dict[str, Path]) -> None:
    # The pairs --deep reads give the images' header stamps the IMU's are checked against.
    with open_source(euroc_logs["mcap"]) as log:
        check = log.info(deep=True).details["imu_check"]
    assert check["images"] == 95
    assert check["camera_offset_s"] == 0.0 and check["uncovered_images"] == 0
    assert check["imu_after_last_image_s"] == pytest.approx(1.0, abs=0.01)


def test_a_bag_imu_without_a_noise_model_is_named_and_left_out(
    euroc_logs: dict[str, Path],
) -> None:
    with open_source(euroc_logs["bag"]) as source:
        info = source.info()
    assert "imu" not in info.details  # no channel metadata in a ROS 1 bag
    slam = VisualSlam(VisualConfig())
    assert "imu" not in slam.frame_kinds(info)
    assert "--calib" in slam.imu_unused
