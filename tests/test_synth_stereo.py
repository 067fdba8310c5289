"""``slamcli synth stereo``: the rendered stereo rig and IMU, read back as a EuRoC / ASL folder,
against the renderer's geometry."""

from __future__ import annotations

import hashlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import shared_path
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import ConfigError
from slamcli.formats import open_source
from slamcli.formats.euroc import EurocSource, read_sensor_yaml
from slamcli.geometry import inverse, rotation_angle, so3_exp
from slamcli.synth import stereo
from slamcli.synth.rgbd import camera_for_size
from slamcli.types import ImuFrame, StereoFrame

FRAMES = 8
SIZE = (320, 240)
BASELINE = 0.12

runner = CliRunner()


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth_stereo") / "seq"
    stereo.render_stereo_sequence(out, frames=FRAMES, size=SIZE, baseline_m=BASELINE, seed=2)
    return out


@pytest.fixture(scope="module")
def world() -> stereo.StereoWorld:
    return stereo.build_stereo_world(FRAMES, SIZE, BASELINE, seed=2)


def test_folder_reads_back_as_euroc_with_the_rig(folder: Path) -> None:
    with open_source(folder) as source:
        assert isinstance(source, EurocSource)
        info = source.info()
        assert len(source) == FRAMES
        assert info.problems == []
        rig = source.rig
        assert rig.baseline_m == pytest.approx(BASELINE, abs=1e-12)
        assert rig.camera == camera_for_size(*SIZE)
        np.testing.assert_allclose(source.left_sensor.body_from_sensor, stereo.BODY_FROM_LEFT)
        right = stereo.BODY_FROM_LEFT.copy()
        right[:3, 3] += stereo.BODY_FROM_LEFT[:3, 0] * BASELINE
        np.testing.assert_allclose(source.right_sensor.body_from_sensor, right, atol=1e-15)
        # Two parallel undistorted cameras rectify to themselves.
        np.testing.assert_allclose(rig.body_from_left, stereo.BODY_FROM_LEFT, atol=1e-12)
        assert source.imu_sensor is not None and source.imu_sensor.rate_hz == 200.0
        read = list(source.frames(["stereo"]))
    frames = [f for f in read if isinstance(f, StereoFrame)]
    assert len(frames) == len(read)
    steps = np.diff([f.stamp_ns for f in frames])
    assert np.all(steps == 50_000_000)
    for f in frames:
        assert f.right_stamp_ns == f.stamp_ns
        for cam, image in (("cam0", f.left), ("cam1", f.right)):
            written = cv2.imread(str(folder / f"mav0/{cam}/data/{f.stamp_ns}.png"), -1)
            assert written is not None
            assert written.dtype == np.uint8 and written.shape == SIZE[::-1]
            np.testing.assert_array_equal(image, written)


def test_sensor_files_carry_the_keys_of_real_euroc_ones(folder: Path) -> None:
    real = shared_path("stereo", "euroc_V1_01_micro", "mav0")
    for sensor in ("cam0", "cam1", "imu0"):
        ours = read_sensor_yaml(folder / "mav0" / sensor / "sensor.yaml")
        theirs = read_sensor_yaml(real / sensor / "sensor.yaml")
        assert set(theirs) <= set(ours), sensor
    cam = read_sensor_yaml(folder / "mav0" / "cam0" / "sensor.yaml")
    assert cam["distortion_model"] == "radial-tangential"
    assert cam["distortion_coefficients"] == [0.0, 0.0, 0.0, 0.0]
    assert cam["resolution"] == list(SIZE)


def test_written_images_are_the_noise_free_renders(folder: Path, world) -> None:
    left, right = world.render_pair(3)
    stamp = int(world.stamps_ns[3])
    np.testing.assert_array_equal(cv2.imread(str(folder / f"mav0/cam0/data/{stamp}.png"), -1), left)
    np.testing.assert_array_equal(
        cv2.imread(str(folder / f"mav0/cam1/data/{stamp}.png"), -1), right
    )


def _warp_error(left: np.ndarray, right: np.ndarray, disparity: np.ndarray, dx: float, dy: float):
    """Median |left - right sampled at (u - disparity + dx, v + dy)| over textured pixels."""
    h, w = left.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    map_x = (u - disparity + dx).astype(np.float32)
    map_y = (v + dy).astype(np.float32)
    warped = cv2.remap(right.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR, borderValue=-1)
    gradient = np.hypot(*np.gradient(left.astype(np.float32)))
    keep = (warped >= 0) & (gradient > 8) & (map_x > 1) & (map_x < w - 2)
    assert keep.mean() > 0.05
    return float(np.median(np.abs(warped - left)[keep]))


def test_a_point_shows_on_one_row_shifted_by_fx_b_over_z(folder: Path, world) -> None:
    with open_source(folder) as source:
        frame = next(iter(source.frames(["stereo"])))
    assert isinstance(frame, StereoFrame)
    depth, _ = world.room.cast(world.world_from_left()[0])
    disparity = (world.camera.fx * BASELINE / depth).astype(np.float32)
    assert 5.0 < float(np.median(disparity)) < 40.0
    exact = _warp_error(frame.left, frame.right, disparity, 0.0, 0.0)
    assert exact < 2.0
    # Half a pixel off along the row, or one row off, matches clearly worse.
    for dx, dy in ((0.5, 0.0), (-0.5, 0.0), (0.0, 1.0), (0.0, -1.0)):
        assert _warp_error(frame.left, frame.right, disparity, dx, dy) > 1.5 * exact + 1.0


def test_groundtruth_is_the_left_camera_moved_onto_the_body(folder: Path, world) -> None:
    with open_source(folder) as source:
        gt = source.groundtruth()
    assert gt is not None
    assert len(gt) == (FRAMES - 1) * 10 + 1
    at_pairs = np.searchsorted(gt.stamps_ns, world.stamps_ns)
    np.testing.assert_array_equal(gt.stamps_ns[at_pairs], world.stamps_ns)
    expected = world.world_from_left() @ inverse(stereo.BODY_FROM_LEFT)
    np.testing.assert_allclose(gt.world_from_body[at_pairs], expected, atol=1e-9)
    assert not np.allclose(gt.world_from_body[at_pairs], world.world_from_left(), atol=1e-3)


def _imu(folder: Path) -> list[ImuFrame]:
    with open_source(folder) as source:
        return [f for f in source.frames(["imu"]) if isinstance(f, ImuFrame)]


def test_integrated_gyro_gives_the_groundtruth_rotation(folder: Path) -> None:
    samples = _imu(folder)
    with open_source(folder) as source:
        gt = source.groundtruth()
    assert gt is not None
    np.testing.assert_array_equal([s.stamp_ns for s in samples], gt.stamps_ns)
    gyro = np.array([s.gyro_radps for s in samples])
    dt = np.diff(gt.stamps_s)
    rotation = np.eye(3)
    start = gt.world_from_body[0, :3, :3]
    worst = 0.0
    for k in range(len(samples) - 1):
        rotation = rotation @ so3_exp(0.5 * (gyro[k] + gyro[k + 1]) * dt[k])
        truth = start.T @ gt.world_from_body[k + 1, :3, :3]
        worst = max(worst, float(np.degrees(rotation_angle(rotation.T @ truth))))
    total = np.degrees(rotation_angle(start.T @ gt.world_from_body[-1, :3, :3]))
    assert total > 0.5
    assert worst < 0.1


def test_accelerometer_is_the_specific_force_of_the_groundtruth(folder: Path) -> None:
    samples = _imu(folder)
    with open_source(folder) as source:
        gt = source.groundtruth()
    assert gt is not None
    accel = np.array([s.accel_mps2 for s in samples])
    p = gt.positions
    dt = 1.0 / stereo.IMU_RATE_HZ
    acc_world = (p[2:] - 2 * p[1:-1] + p[:-2]) / dt**2
    rot = gt.world_from_body[1:-1, :3, :3]
    expected = np.einsum("nji,nj->ni", rot, acc_world + np.array([0.0, 0.0, 9.80665]))
    np.testing.assert_allclose(accel[1:-1], expected, atol=0.02)
    # The body's x axis points about up, as on EuRoC's rig: at rest it would read +9 m/s^2.
    at_rest = np.einsum("nji,j->ni", gt.world_from_body[:, :3, :3], [0.0, 0.0, 9.80665])
    assert np.all(at_rest[:, 0] > 9.0)


def test_noise_is_independent_per_camera_and_shifts_the_right_one(world) -> None:
    clean = world.render_pair(0)
    left_rng, right_rng = np.random.default_rng(0), np.random.default_rng(1)
    noisy = world.render_pair(0, left_rng, right_rng)
    diffs = [n.astype(float) - c for n, c in zip(noisy, clean, strict=True)]
    assert 0.7 < diffs[0].std() < 1.3 and abs(diffs[0].mean()) < 0.1
    assert 3.5 < diffs[1].mean() < 4.5
    assert abs(np.corrcoef(diffs[0].ravel(), diffs[1].ravel())[0, 1]) < 0.05


def test_imu_noise_follows_the_sensor_yaml(world) -> None:
    clean = world.imu_track()
    noisy = world.imu_track(noise=True, seed=4)
    assert np.all(clean.gyro_bias == 0.0)
    white = noisy.gyro_radps - clean.gyro_radps - noisy.gyro_bias
    sigma = stereo.GYRO_NOISE_DENSITY * np.sqrt(stereo.IMU_RATE_HZ)
    assert 0.7 * sigma < white.std() < 1.3 * sigma
    white = noisy.accel_mps2 - clean.accel_mps2 - noisy.accel_bias
    sigma = stereo.ACCEL_NOISE_DENSITY * np.sqrt(stereo.IMU_RATE_HZ)
    assert 0.7 * sigma < white.std() < 1.3 * sigma
    assert np.abs(noisy.accel_bias).max() > 0.0
    np.testing.assert_array_equal(noisy.world_from_body, clean.world_from_body)


def _digests(folder: Path) -> dict[str, str]:
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def test_same_seed_same_bytes_other_seed_other_images(tmp_path: Path) -> None:
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        stereo.render_stereo_sequence(tmp_path / name, 3, (64, 48), seed=seed, noise=True)
    a, b, c = (_digests(tmp_path / k) for k in "abc")
    assert a == b
    assert len(a) == 2 * 3 + 7
    assert all(a[k] != c[k] for k in a if k.endswith(".png"))
    assert a["mav0/imu0/data.csv"] != c["mav0/imu0/data.csv"]


def test_colour_without_depth_equals_the_rgbd_render(world) -> None:
    pose = world.world_from_left()[1]
    rgb, _ = world.room.render(pose)
    np.testing.assert_array_equal(
        np.clip(np.rint(world.room.render_colour(pose)), 0, 255).astype(np.uint8), rgb
    )


def test_a_slower_rate_flies_the_same_loop_with_an_imu_sample_on_every_pair(
    world: stereo.StereoWorld,
) -> None:
    slow = stereo.build_stereo_world(FRAMES // 2, SIZE, BASELINE, seed=2, fps=10.0)
    # The same loop in the same time: every second pose of the 20 Hz sequence, exactly.
    np.testing.assert_array_equal(np.diff(slow.stamps_ns), 100_000_000)
    stamps = slow.room.trajectory.stamps_ns
    twice = stereo.build_stereo_world(FRAMES, SIZE, BASELINE, seed=2)
    np.testing.assert_array_equal(stamps, twice.stamps_ns[::2])
    np.testing.assert_allclose(slow.world_from_left(), twice.world_from_left()[::2], atol=1e-12)
    assert slow.room.trajectory.path_length() < world.room.trajectory.path_length()
    imu = slow.imu_track()
    np.testing.assert_array_equal(np.diff(imu.stamps_ns), 5_000_000)
    at_pairs = np.searchsorted(imu.stamps_ns, stamps)
    np.testing.assert_array_equal(imu.stamps_ns[at_pairs], stamps)
    np.testing.assert_allclose(
        imu.world_from_body[at_pairs] @ slow.body_from_left, slow.world_from_left(), atol=1e-12
    )
    # The IMU sees the same motion as at 20 Hz where their samples meet.
    fast = twice.imu_track()
    common = np.intersect1d(imu.stamps_ns, fast.stamps_ns)
    assert len(common) == len(imu.stamps_ns)
    np.testing.assert_allclose(imu.gyro_radps, fast.gyro_radps[: len(common)], atol=1e-9)


@pytest.mark.parametrize(
    ("frames", "size", "baseline", "fps", "word"),
    [
        (1, (64, 48), 0.1, 20.0, "frames"),
        (4, (8, 48), 0.1, 20.0, "size"),
        (4, (64, 48), 0.0, 20.0, "baseline"),
        (4, (64, 48), 0.1, 30.0, "fps"),
        (4, (64, 48), 0.1, 400.0, "fps"),
        (4, (64, 48), 0.1, 0.0, "fps"),
        (4, (64, 48), 0.1, float("nan"), "fps"),
    ],
)
def test_bad_options_raise_config_errors(tmp_path, frames, size, baseline, fps, word) -> None:
    with pytest.raises(ConfigError, match=word):
        stereo.render_stereo_sequence(
            tmp_path / "x", frames=frames, size=size, baseline_m=baseline, fps=fps
        )
    assert not (tmp_path / "x").exists()


def test_cli_synth_stereo_writes_an_asl_folder(tmp_path: Path) -> None:
    out = tmp_path / "seq"
    args = ["synth", "stereo", "--out", str(out), "--frames", "3", "--size", "64x48"]
    result = runner.invoke(app, [*args, "--baseline", "0.2", "--noise"])
    assert result.exit_code == 0, result.output
    assert "Written" in result.output
    with open_source(out) as source:
        assert isinstance(source, EurocSource)
        assert len(source) == 3
        assert source.rig.baseline_m == pytest.approx(0.2)
    again = runner.invoke(app, args)
    assert again.exit_code == 1 and "not empty" in again.output
    bad = runner.invoke(app, [*args, "--force", "--baseline", "2"])
    assert bad.exit_code == 1 and "baseline" in bad.output


def test_cli_synth_stereo_at_10_hz_says_so_in_the_folder(tmp_path: Path) -> None:
    out = tmp_path / "seq"
    args = ["synth", "stereo", "--out", str(out), "--frames", "3", "--size", "64x48"]
    result = runner.invoke(app, [*args, "--fps", "10"])
    assert result.exit_code == 0, result.output
    assert "at 10 Hz" in result.output
    assert read_sensor_yaml(out / "mav0" / "cam0" / "sensor.yaml").get("rate_hz") == 10
    with open_source(out) as source:
        assert isinstance(source, EurocSource)
        stamps = [f.stamp_ns for f in source.frames(("stereo",)) if isinstance(f, StereoFrame)]
    assert np.diff(stamps).tolist() == [100_000_000, 100_000_000]
    bad = runner.invoke(app, [*args, "--force", "--fps", "30"])
    assert bad.exit_code == 1 and "fps" in bad.output and "200 Hz" in bad.output
