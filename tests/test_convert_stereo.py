"""``slamcli convert`` of KITTI and EuRoC stereo folders to MCAP: pairs and stamps, images as
recorded, camera infos that rectify the raw images, IMU window, tf_static, ground truth,
determinism, skipped pairs and refused options."""

from __future__ import annotations

import shutil
from collections import defaultdict
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import shared_path
from mcap.reader import make_reader
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.convert import convert
from slamcli.errors import ConfigError
from slamcli.formats import open_source
from slamcli.formats.euroc import EurocSource, read_imu_csv
from slamcli.formats.kitti import KittiSource
from slamcli.formats.mcap.decode import decoder_for
from slamcli.formats.mcap.records import ChannelInfo
from slamcli.formats.mcap.write.stereo import IMU_MARGIN_NS, write_stereo_mcap
from slamcli.formats.trajectory import read_trajectory
from slamcli.types import StereoFrame

runner = CliRunner()

Log = dict[str, list[tuple[int, Any]]]


def _kitti() -> Path:
    return shared_path("stereo", "kitti_excerpt_1")


def _euroc() -> Path:
    return shared_path("stereo", "euroc_V1_01_micro")


def _read(path: Path) -> Log:
    """topic -> [(log_time, decoded message)] in log-time order."""
    out: Log = defaultdict(list)
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            decode = decoder_for(ChannelInfo.from_records(channel, schema))
            out[channel.topic].append((message.log_time, decode(message.data)))
    return dict(out)


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _stereo_frames(path: Path) -> list[StereoFrame]:
    with open_source(path) as source:
        return [f for f in source.frames(("stereo",)) if isinstance(f, StereoFrame)]


@pytest.fixture(scope="module")
def kitti_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Log]:
    out = tmp_path_factory.mktemp("kitti") / "kitti.mcap"
    result = convert(_kitti(), out)
    assert result.kind == "stereo"
    assert result.summary is not None and result.summary.frames == 51
    return out, _read(out)


@pytest.fixture(scope="module")
def euroc_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Log]:
    out = tmp_path_factory.mktemp("euroc") / "euroc.mcap"
    truth = _euroc() / "groundtruth_body.txt"
    result = convert(_euroc(), out, source_options={"groundtruth": str(truth)})
    assert result.summary is not None and result.summary.frames == 95
    assert result.skipped == 0
    return out, _read(out)


@pytest.fixture(scope="module")
def euroc_frames() -> list[StereoFrame]:
    return _stereo_frames(_euroc())


def _check_pairs(log: Log, frames: list[StereoFrame]) -> None:
    """Both cameras' images and infos: one per pair, at the source's stamps, log time = stamp."""
    left = [f.stamp_ns for f in frames]
    right = [f.right_stamp_ns if f.right_stamp_ns is not None else f.stamp_ns for f in frames]
    for topic, stamps, frame_id in (
        ("/cam0/image_raw", left, "cam0"),
        ("/cam0/camera_info", left, "cam0"),
        ("/cam1/image_raw", right, "cam1"),
        ("/cam1/camera_info", right, "cam1"),
    ):
        messages = log[topic]
        assert [_stamp(m) for _, m in messages] == stamps, topic
        assert [t for t, _ in messages] == stamps, topic
        assert {m.header.frame_id for _, m in messages} == {frame_id}


def test_kitti_pairs_stamps_and_image_bytes(kitti_log: tuple[Path, Log]) -> None:
    _, log = kitti_log
    frames = _stereo_frames(_kitti())
    assert len(frames) == 51
    _check_pairs(log, frames)
    for frame, (_, left), (_, right) in zip(
        frames, log["/cam0/image_raw"], log["/cam1/image_raw"], strict=True
    ):
        for msg, image in ((left, frame.left), (right, frame.right)):
            assert msg.encoding == "mono8"
            assert (msg.height, msg.width, msg.step) == (*image.shape, image.shape[1])
            assert bytes(msg.data) == image.tobytes()


def test_kitti_camera_info_is_rectified_with_the_baseline(kitti_log: tuple[Path, Log]) -> None:
    _, log = kitti_log
    with KittiSource(_kitti()) as source:
        rig = source.rig
    left, right = log["/cam0/camera_info"][0][1], log["/cam1/camera_info"][0][1]
    for info in (left, right):
        p = info.p.reshape(3, 4)
        assert np.array_equal(info.k.reshape(3, 3), p[:, :3])
        assert np.allclose(info.k.reshape(3, 3), rig.camera.K)
        assert np.array_equal(info.r.reshape(3, 3), np.eye(3))
        assert info.distortion_model == "plumb_bob" and not np.any(info.d)
        assert (info.width, info.height) == (1226, 370)
    assert left.p[3] == 0.0
    assert right.p[3] / -right.p[0] == pytest.approx(rig.baseline_m, rel=1e-6)
    assert right.p[3] / -right.p[0] == pytest.approx(379.8145 / 707.0912, rel=1e-6)


def test_kitti_tf_static_and_groundtruth(kitti_log: tuple[Path, Log]) -> None:
    _, log = kitti_log
    (stamp, tf), *more = log["/tf_static"]
    assert not more and stamp == 0
    by_child = {t.child_frame_id: t for t in tf.transforms}
    assert sorted(by_child) == ["cam0", "cam1"]
    assert {t.header.frame_id for t in tf.transforms} == {"base_link"}
    cam1 = by_child["cam1"].transform.translation
    assert (cam1.x, cam1.y, cam1.z) == pytest.approx((379.8145 / 707.0912, 0.0, 0.0))
    with KittiSource(_kitti()) as source:
        truth = source.groundtruth()
    assert truth is not None
    poses = log["/groundtruth"]
    assert len(poses) == len(truth) == 51
    assert poses[1][0] == 100_000_000
    assert [t for t, _ in poses] == truth.stamps_ns.tolist()
    last = poses[-1][1]
    assert last.header.frame_id == "world"
    position = last.pose.position
    assert (position.x, position.y, position.z) == pytest.approx(
        truth.world_from_body[-1, :3, 3].tolist()
    )
    assert "/imu0" not in log


def test_euroc_pairs_and_raw_images(
    euroc_log: tuple[Path, Log], euroc_frames: list[StereoFrame]
) -> None:
    _, log = euroc_log
    assert len(euroc_frames) == 95
    _check_pairs(log, euroc_frames)
    # The raw images, not the rectified ones: the bytes of the recorded PNG.
    first = log["/cam1/image_raw"][0][1]
    png = _euroc() / "mav0" / "cam1" / "data" / f"{_stamp(first)}.png"
    raw = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    assert raw is not None
    assert first.encoding == "mono8"
    assert bytes(first.data) == raw.tobytes()
    assert not np.array_equal(raw, euroc_frames[0].right)


def test_euroc_camera_info_rectifies_the_raw_images(
    euroc_log: tuple[Path, Log], euroc_frames: list[StereoFrame]
) -> None:
    _, log = euroc_log
    rig = euroc_frames[0].rig
    right_p = log["/cam1/camera_info"][0][1].p
    assert right_p[3] / -right_p[0] == pytest.approx(rig.baseline_m, rel=1e-6)
    k = 40
    for side, rectified in (("cam0", euroc_frames[k].left), ("cam1", euroc_frames[k].right)):
        info = log[f"/{side}/camera_info"][k][1]
        image = log[f"/{side}/image_raw"][k][1]
        assert info.distortion_model == "plumb_bob" and len(info.d) == 5
        raw = np.frombuffer(bytes(image.data), np.uint8).reshape(image.height, image.width)
        k_raw, r, p = info.k.reshape(3, 3), info.r.reshape(3, 3), info.p.reshape(3, 4)
        assert not np.allclose(r, np.eye(3))
        size = (int(info.width), int(info.height))
        mx, my = cv2.initUndistortRectifyMap(k_raw, info.d, r, p[:, :3], size, cv2.CV_32FC1)
        remapped = cv2.remap(raw, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        diff = np.abs(remapped.astype(np.float64) - rectified.astype(np.float64))
        assert diff.mean() < 1.0, side
        # Unrectified, the raw image is far from the source's rectified one.
        assert np.abs(raw.astype(np.float64) - rectified).mean() > 5.0


def test_euroc_imu_is_the_pairs_span_widened_by_a_second(
    euroc_log: tuple[Path, Log], euroc_frames: list[StereoFrame]
) -> None:
    _, log = euroc_log
    t, gyro, accel = read_imu_csv(_euroc() / "mav0" / "imu0" / "data.csv")
    first, last = euroc_frames[0].stamp_ns, euroc_frames[-1].stamp_ns
    inside = (t >= first - IMU_MARGIN_NS) & (t <= last + IMU_MARGIN_NS)
    imu = log["/imu0"]
    # The csv starts with the first image, so only the second after the last pair is added.
    assert len(imu) == int(inside.sum()) == 1141 < t.size
    assert [s for s, _ in imu] == t[inside].tolist()
    msg = imu[-1][1]
    assert msg.header.frame_id == "imu0"
    assert msg.orientation_covariance[0] == -1.0
    w, a = msg.angular_velocity, msg.linear_acceleration
    assert [w.x, w.y, w.z] == gyro[inside][-1].tolist()
    assert [a.x, a.y, a.z] == accel[inside][-1].tolist()


def test_euroc_tf_static_and_groundtruth(euroc_log: tuple[Path, Log]) -> None:
    _, log = euroc_log
    with EurocSource(_euroc()) as source:
        t_bs0 = source.left_sensor.body_from_sensor
        t_bs1 = source.right_sensor.body_from_sensor
    ((stamp, tf),) = log["/tf_static"]
    assert stamp == min(t for topic in log.values() for t, _ in topic)
    by_child = {t.child_frame_id: t.transform.translation for t in tf.transforms}
    assert sorted(by_child) == ["cam0", "cam1", "imu0"]
    for child, pose in (("cam0", t_bs0), ("cam1", t_bs1), ("imu0", np.eye(4))):
        v = by_child[child]
        assert [v.x, v.y, v.z] == pytest.approx(pose[:3, 3].tolist(), abs=1e-12)
    truth = read_trajectory(_euroc() / "groundtruth_body.txt")
    poses = log["/groundtruth"]
    assert len(poses) == len(truth) == 115
    assert [t for t, _ in poses] == truth.stamps_ns.tolist()
    q = poses[0][1].pose.orientation
    assert [q.x, q.y, q.z, q.w] == pytest.approx([-0.824237, -0.106942, -0.551702, 0.069433])


def test_same_input_gives_the_same_bytes(kitti_log: tuple[Path, Log], tmp_path: Path) -> None:
    again = tmp_path / "again.mcap"
    convert(_kitti(), again)
    assert again.read_bytes() == kitti_log[0].read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["again.mcap"]


def test_cli_converts_and_reports_skipped_pairs(tmp_path: Path) -> None:
    folder = tmp_path / "kitti3"
    (folder / "image_l").mkdir(parents=True)
    (folder / "image_r").mkdir()
    shutil.copy(_kitti() / "calib.txt", folder)
    for k in range(3):
        for side in ("image_l", "image_r"):
            shutil.copy(_kitti() / side / f"{k:06d}.png", folder / side)
    (folder / "image_r" / "000001.png").write_bytes(b"not a png")
    out = tmp_path / "three.mcap"
    result = runner.invoke(app, ["convert", str(folder), str(out)])
    assert result.exit_code == 3, result.output
    assert "1 frame(s) skipped" in result.output
    assert "/cam1/camera_info" in result.output
    log = _read(out)
    assert [_stamp(m) for _, m in log["/cam0/image_raw"]] == [0, 200_000_000]
    assert "/groundtruth" not in log


def test_cli_refuses_rgbd_options_and_a_missing_groundtruth(tmp_path: Path) -> None:
    out = tmp_path / "x.mcap"
    result = runner.invoke(app, ["convert", str(_kitti()), str(out), "--flavor", "foxglove"])
    assert result.exit_code == 1
    assert "--flavor foxglove is for RGB-D inputs, not stereo folders" in result.output
    result = runner.invoke(
        app, ["convert", str(_euroc()), str(out), "--groundtruth", str(tmp_path / "none.txt")]
    )
    assert result.exit_code == 1
    assert "none.txt: no such file" in result.output
    assert not out.exists()


def test_writer_refuses_a_source_that_is_not_a_stereo_folder(tmp_path: Path) -> None:
    with (
        open_source(shared_path("tum", "rgbd_dataset_freiburg1_rpy_excerpt")) as source,
        pytest.raises(ConfigError, match="tum source is not a stereo folder"),
    ):
        write_stereo_mcap(source, tmp_path / "tum.mcap")
    assert not (tmp_path / "tum.mcap").exists()
