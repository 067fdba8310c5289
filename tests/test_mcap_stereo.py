"""Stereo pairs (and IMU) from MCAP logs and ROS bags: the logs are written here from pairs of
the shared KITTI and EuRoC folders, in the layout slamcli writes (``/cam0/image_raw``,
``/cam0/camera_info``, ``/cam1/...``, ``/imu0``, ``/tf_static``, ``/groundtruth``)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import shared_path
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import InputError, TopicNotFoundError
from slamcli.formats import open_source
from slamcli.formats.euroc import EurocSource, read_imu_csv
from slamcli.formats.kitti import KittiSource
from slamcli.formats.mcap.records import PoseRecord
from slamcli.formats.mcap.source import McapSource
from slamcli.formats.mcap.stereo import body_frame, stereo_pairs
from slamcli.formats.mcap.stereo_calibration import CameraInfo, calibrate_stereo
from slamcli.formats.mcap.tf import TfBuffer
from slamcli.formats.mcap.write.convert import pose_parts, split_ns
from slamcli.formats.mcap.write.layer import LogWriter, open_log
from slamcli.formats.rosbag.source import Ros1BagSource
from slamcli.formats.trajectory import read_trajectory
from slamcli.geometry import interpolate_poses, make_pose
from slamcli.types import ImuFrame, StereoFrame

runner = CliRunner()

KITTI = ("stereo", "kitti_excerpt_1")
EUROC = ("stereo", "euroc_V1_01_micro")
N_KITTI = 8
N_EUROC = 12
LATE_NS = 30_000_000
"""How late the one late right image is stamped (30 ms)."""


# -- writing logs -------------------------------------------------------------------------------


class _Ros2:
    """ROS 2 messages (CDR, ``ros2msg`` schemas) into an MCAP log."""

    def __init__(self, log: LogWriter) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.log = log
        self.store = get_typestore(Stores.ROS2_HUMBLE)
        self.t = self.store.types
        self.schemas: dict[str, tuple[str, str, bytes]] = {}

    def put(self, topic: str, stamp_ns: int, msg: Any) -> None:
        name = msg.__msgtype__
        if name not in self.schemas:
            text = self.store.generate_msgdef(name, ros_version=2)[0]
            self.schemas[name] = (name, "ros2msg", text.encode())
        data = bytes(self.store.serialize_cdr(msg, name))
        self.log.add(topic, self.schemas[name], "cdr", stamp_ns, data)

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        sec, nsec = split_ns(stamp_ns)
        time = self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        return self.t["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)

    def image(self, topic: str, stamp_ns: int, frame_id: str, image: np.ndarray) -> None:
        if topic.endswith("/compressed"):
            # image_transport's compressed layout: "png" or "jpeg" after the topic's last word.
            fmt = "png" if "png" in topic else "jpeg"
            ok, buf = cv2.imencode(f".{fmt}", image)
            assert ok
            msg = self.t["sensor_msgs/msg/CompressedImage"](
                header=self.header(stamp_ns, frame_id), format=fmt, data=buf.reshape(-1)
            )
            self.put(topic, stamp_ns, msg)
            return
        h, w = image.shape[:2]
        encoding = "mono8" if image.ndim == 2 else "rgb8"
        msg = self.t["sensor_msgs/msg/Image"](
            header=self.header(stamp_ns, frame_id),
            height=h,
            width=w,
            encoding=encoding,
            is_bigendian=0,
            step=image.nbytes // h,
            data=np.ascontiguousarray(image).reshape(-1).view(np.uint8),
        )
        self.put(topic, stamp_ns, msg)

    def camera_info(self, topic: str, stamp_ns: int, info: _Info) -> None:
        roi = self.t["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        msg = self.t["sensor_msgs/msg/CameraInfo"](
            header=self.header(stamp_ns, info.frame_id),
            height=info.size[1],
            width=info.size[0],
            distortion_model=info.model,
            d=np.asarray(info.d, dtype=np.float64),
            k=np.asarray(info.k, dtype=np.float64).reshape(-1),
            r=np.asarray(info.r, dtype=np.float64).reshape(-1),
            p=np.asarray(info.p, dtype=np.float64).reshape(-1),
            binning_x=0,
            binning_y=0,
            roi=roi,
        )
        self.put(topic, stamp_ns, msg)

    def tf_static(self, stamp_ns: int, edges: list[tuple[str, str, np.ndarray]]) -> None:
        vector3 = self.t["geometry_msgs/msg/Vector3"]
        transforms = []
        for parent, child, pose in edges:
            (x, y, z), (qx, qy, qz, qw) = pose_parts(pose)
            transforms.append(
                self.t["geometry_msgs/msg/TransformStamped"](
                    header=self.header(stamp_ns, parent),
                    child_frame_id=child,
                    transform=self.t["geometry_msgs/msg/Transform"](
                        translation=vector3(x=x, y=y, z=z),
                        rotation=self.t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
                    ),
                )
            )
        self.put("/tf_static", stamp_ns, self.t["tf2_msgs/msg/TFMessage"](transforms=transforms))

    def pose(self, topic: str, stamp_ns: int, pose: np.ndarray) -> None:
        (x, y, z), (qx, qy, qz, qw) = pose_parts(pose)
        msg = self.t["geometry_msgs/msg/PoseStamped"](
            header=self.header(stamp_ns, "world"),
            pose=self.t["geometry_msgs/msg/Pose"](
                position=self.t["geometry_msgs/msg/Point"](x=x, y=y, z=z),
                orientation=self.t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
            ),
        )
        self.put(topic, stamp_ns, msg)

    def imu(self, topic: str, stamp_ns: int, gyro: np.ndarray, accel: np.ndarray) -> None:
        vector3 = self.t["geometry_msgs/msg/Vector3"]
        unknown = np.zeros(9)
        unknown[0] = -1.0
        msg = self.t["sensor_msgs/msg/Imu"](
            header=self.header(stamp_ns, "imu0"),
            orientation=self.t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=unknown,
            angular_velocity=vector3(*gyro.tolist()),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=vector3(*accel.tolist()),
            linear_acceleration_covariance=np.zeros(9),
        )
        self.put(topic, stamp_ns, msg)


@dataclass
class _Info:
    """The fields of a CameraInfo."""

    frame_id: str
    size: tuple[int, int]
    k: np.ndarray
    d: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    r: np.ndarray = field(default_factory=lambda: np.eye(3))
    p: np.ndarray = field(default_factory=lambda: np.zeros((3, 4)))
    model: str = "plumb_bob"


@dataclass
class _Pair:
    stamp_ns: int
    left: np.ndarray
    right: np.ndarray
    right_stamp_ns: int


def _write(
    path: Path,
    pairs: list[_Pair],
    infos: tuple[_Info, _Info | None],
    tf: list[tuple[str, str, np.ndarray]],
    topics: tuple[str, str] = ("/cam0/image_raw", "/cam1/image_raw"),
    truth: Any = None,
    imu: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> Path:
    """A ROS 2 MCAP of stereo pairs with a CameraInfo beside each image topic."""
    with open_log(path, "ros2", force=True) as log:
        w = _Ros2(log)
        if tf:
            w.tf_static(pairs[0].stamp_ns, tf)
        for pair in pairs:
            for topic, info, image, stamp in (
                (topics[0], infos[0], pair.left, pair.stamp_ns),
                (topics[1], infos[1], pair.right, pair.right_stamp_ns),
            ):
                w.image(topic, stamp, info.frame_id if info else "cam1", image)
                if info is not None:
                    # /cam0/image_raw and /cam0/image_raw/compressed both sit beside
                    # /cam0/camera_info.
                    base = topic.removesuffix("/compressed")
                    w.camera_info(base.rsplit("/", 1)[0] + "/camera_info", stamp, info)
        if truth is not None:
            for stamp, pose in zip(truth.stamps_ns, truth.world_from_body, strict=True):
                w.pose("/groundtruth", int(stamp), pose)
        if imu is not None:
            for stamp, gyro, accel in zip(*imu, strict=True):
                w.imu("/imu0", int(stamp), gyro, accel)
    return path


# -- KITTI: rectified images, rectified CameraInfo ------------------------------------------------


@dataclass
class _Kitti:
    frames: list[StereoFrame]
    pairs: list[_Pair]
    infos: tuple[_Info, _Info]
    tf: list[tuple[str, str, np.ndarray]]


@pytest.fixture(scope="module")
def kitti() -> _Kitti:
    with KittiSource(shared_path(*KITTI)) as source:
        frames = [f for f in source.frames(("stereo",)) if isinstance(f, StereoFrame)][:N_KITTI]
        p_left, p_right = source.calibration.left, source.calibration.right
    size = (frames[0].rig.camera.width, frames[0].rig.camera.height)
    infos = (
        _Info("cam0", size, p_left[:, :3], p=p_left),
        _Info("cam1", size, p_right[:, :3], p=p_right),
    )
    baseline = frames[0].rig.baseline_m
    tf = [
        ("base_link", "cam0", np.eye(4)),
        ("base_link", "cam1", make_pose(np.eye(3), [baseline, 0.0, 0.0])),
    ]
    pairs = [_Pair(f.stamp_ns, f.left, f.right, f.stamp_ns) for f in frames]
    return _Kitti(frames, pairs, infos, tf)


def _stereo(path: Path, **options: Any) -> tuple[list[StereoFrame], McapSource]:
    source = open_source(path, **options)
    assert isinstance(source, McapSource)
    with source:
        frames = [f for f in source.frames(("stereo",)) if isinstance(f, StereoFrame)]
    return frames, source


def test_kitti_pairs_equal_the_folder_and_the_pair_is_chosen(kitti: _Kitti, tmp_path: Path) -> None:
    path = _write(tmp_path / "kitti.mcap", kitti.pairs, kitti.infos, kitti.tf)
    frames, source = _stereo(path)
    assert [f.stamp_ns for f in frames] == [f.stamp_ns for f in kitti.frames]
    want = kitti.frames[0].rig
    for got, exp in zip(frames, kitti.frames, strict=True):
        np.testing.assert_array_equal(got.left, exp.left)
        np.testing.assert_array_equal(got.right, exp.right)
        assert got.right_stamp_ns == exp.stamp_ns
    rig = frames[0].rig
    assert rig.baseline_m == pytest.approx(want.baseline_m, abs=1e-6)
    np.testing.assert_allclose(rig.camera.K, want.camera.K, atol=1e-9)
    assert not rig.camera.is_distorted
    np.testing.assert_allclose(rig.body_from_left, np.eye(4), atol=1e-12)
    assert source.stats.read == N_KITTI and source.stats.skipped == 0
    with open_source(path) as again:
        info = again.info()
    stereo = [s for s in info.streams if s.kind == "stereo"]
    assert len(stereo) == 1 and stereo[0].count == N_KITTI
    assert info.details["left_topic"] == "/cam0/image_raw"
    assert info.details["right_topic"] == "/cam1/image_raw"
    assert info.details["stereo_topics_chosen"] == "the only left/right pair of image topics"
    assert "the only left/right pair" in stereo[0].detail
    assert info.frames == N_KITTI
    assert info.camera is not None and info.camera.fx == pytest.approx(want.camera.fx)
    assert info.camera_source.startswith("already rectified")
    assert not any("RGB-D" in p for p in info.problems)


@pytest.mark.parametrize("fmt", ["png", "jpeg"])
def test_compressed_image_topics_pair_like_raw_ones(
    kitti: _Kitti, tmp_path: Path, fmt: str
) -> None:
    # As ROS 2 recorders often keep cameras: image_transport's compressed topics only (the
    # format is named in the topic here only so the test writer can tell which to encode).
    topics = (f"/left/{fmt}/image_rect/compressed", f"/right/{fmt}/image_rect/compressed")
    path = _write(tmp_path / f"{fmt}.mcap", kitti.pairs[:3], kitti.infos, kitti.tf, topics)
    frames, source = _stereo(path)
    assert [f.stamp_ns for f in frames] == [f.stamp_ns for f in kitti.frames[:3]]
    assert source.stats.read == 3 and source.stats.skipped == 0
    for got, exp in zip(frames, kitti.frames, strict=False):
        for a, b in ((got.left, exp.left), (got.right, exp.right)):
            assert a.shape == b.shape and a.dtype == np.uint8
            if fmt == "png":
                np.testing.assert_array_equal(a, b)
            else:
                assert np.abs(a.astype(float) - b).mean() < 2.0
    assert frames[0].rig.baseline_m == pytest.approx(kitti.frames[0].rig.baseline_m, abs=1e-6)
    with open_source(path) as again:
        info = again.info()
    assert (info.details["left_topic"], info.details["right_topic"]) == topics
    assert info.camera_source.startswith("already rectified")


def test_a_right_image_30_ms_late_still_pairs_at_10_hz(kitti: _Kitti, tmp_path: Path) -> None:
    pairs = list(kitti.pairs)
    late = pairs[3]
    pairs[3] = _Pair(late.stamp_ns, late.left, late.right, late.stamp_ns + LATE_NS)
    frames, source = _stereo(_write(tmp_path / "late.mcap", pairs, kitti.infos, kitti.tf))
    assert len(frames) == N_KITTI and source.stats.skipped == 0
    assert frames[3].right_stamp_ns == late.stamp_ns + LATE_NS


def test_without_the_right_camera_info_the_error_names_the_topic(
    kitti: _Kitti, tmp_path: Path
) -> None:
    path = _write(tmp_path / "no_info.mcap", kitti.pairs, (kitti.infos[0], None), kitti.tf)
    with open_source(path) as source, pytest.raises(TopicNotFoundError) as err:
        list(source.frames(("stereo",)))
    assert (
        "/cam1/camera_info: no CameraInfo for /cam1/image_raw; a stereo pair needs both "
        "cameras' calibration" in err.value.msg
    )
    with open_source(path) as source:
        info = source.info()
    assert any("no CameraInfo for /cam1/image_raw" in p for p in info.problems)


def test_a_right_p_without_baseline_takes_it_from_tf_or_fails(
    kitti: _Kitti, tmp_path: Path
) -> None:
    left, right = kitti.infos
    flat = _Info("cam1", right.size, right.k, p=left.p)  # P[0,3] = 0: no baseline term
    with_tf = _write(tmp_path / "tf.mcap", kitti.pairs[:2], (left, flat), kitti.tf)
    frames, _ = _stereo(with_tf)
    assert frames[0].rig.baseline_m == pytest.approx(kitti.frames[0].rig.baseline_m, abs=1e-9)
    without = _write(tmp_path / "no_tf.mcap", kitti.pairs[:2], (left, flat), [])
    with open_source(without) as source, pytest.raises(InputError) as err:
        list(source.frames(("stereo",)))
    assert "/cam1/camera_info has no P with a baseline term" in err.value.msg
    assert "tf has no transform between cam0 and cam1" in err.value.msg


def test_left_and_right_images_of_different_sizes_are_refused(
    kitti: _Kitti, tmp_path: Path
) -> None:
    pairs = [_Pair(p.stamp_ns, p.left, p.right[:, :-2].copy(), p.stamp_ns) for p in kitti.pairs]
    path = _write(tmp_path / "sizes.mcap", pairs[:2], kitti.infos, kitti.tf)
    with open_source(path) as source, pytest.raises(InputError) as err:
        list(source.frames(("stereo",)))
    assert "/cam0/image_raw images are 1226x370 but /cam1/image_raw images 1224x370" in (
        err.value.msg
    )


def test_a_kitti_log_as_a_ros1_bag_gives_the_same_pairs(kitti: _Kitti, tmp_path: Path) -> None:
    from bag_files import ros1_bag

    # This bag has no tf: rectified pairs need none.
    mcap = _write(tmp_path / "kitti.mcap", kitti.pairs[:3], kitti.infos, [])
    bag = ros1_bag(mcap, tmp_path / "kitti.bag")
    with open_source(bag) as source:
        assert isinstance(source, Ros1BagSource)
        frames = [f for f in source.frames(("stereo",)) if isinstance(f, StereoFrame)]
    assert [f.stamp_ns for f in frames] == [f.stamp_ns for f in kitti.frames[:3]]
    np.testing.assert_array_equal(frames[2].right, kitti.frames[2].right)
    assert frames[0].rig.baseline_m == pytest.approx(kitti.frames[0].rig.baseline_m, abs=1e-6)


# -- EuRoC: raw images, calibrated by R and P, or by tf -------------------------------------------


@dataclass
class _Euroc:
    frames: list[StereoFrame]
    pairs: list[_Pair]
    rp: tuple[_Info, _Info]
    raw: tuple[_Info, _Info]
    tf: list[tuple[str, str, np.ndarray]]
    truth: Any
    imu: tuple[np.ndarray, np.ndarray, np.ndarray]


@pytest.fixture(scope="module")
def euroc() -> _Euroc:
    folder = shared_path(*EUROC)
    with EurocSource(folder) as source:
        frames = [f for f in source.frames(("stereo",)) if isinstance(f, StereoFrame)][:N_EUROC]
        rect = source.rectification
        sensors = (source.left_sensor, source.right_sensor)
        pairs = []
        for k in range(N_EUROC):
            li, ri = int(source.left_index[k]), int(source.right_index[k])
            left = cv2.imread(str(source.left_csv.image(li)), cv2.IMREAD_UNCHANGED)
            right = cv2.imread(str(source.right_csv.image(ri)), cv2.IMREAD_UNCHANGED)
            stamps = (int(source.left_csv.stamps_ns[li]), int(source.right_csv.stamps_ns[ri]))
            pairs.append(_Pair(stamps[0], left, right, stamps[1]))
        imu_all = read_imu_csv(source.mav / "imu0" / "data.csv")
    cam = rect.rig.camera
    p1 = np.array([[cam.fx, 0, cam.cx, 0], [0, cam.fy, cam.cy, 0], [0, 0, 1, 0]], dtype=float)
    p2 = p1.copy()
    p2[0, 3] = -cam.fx * rect.rig.baseline_m
    rp, raw = [], []
    for name, sensor, r, p in (
        ("cam0", sensors[0], rect.left_from_raw, p1),
        ("cam1", sensors[1], rect.right_from_raw, p2),
    ):
        size = (sensor.camera.width, sensor.camera.height)
        d = tuple(sensor.coefficients)
        rp.append(_Info(name, size, sensor.camera.K, d, r, p))
        raw.append(_Info(name, size, sensor.camera.K, d))
    tf = [
        ("base_link", "cam0", sensors[0].body_from_sensor),
        ("base_link", "cam1", sensors[1].body_from_sensor),
        ("base_link", "imu0", np.eye(4)),
    ]
    truth = read_trajectory(folder / "groundtruth_body.txt", "tum")
    t, gyro, accel = imu_all
    keep = (t >= pairs[0].stamp_ns - 100_000_000) & (t <= pairs[-1].stamp_ns + 100_000_000)
    return _Euroc(
        frames,
        pairs,
        (rp[0], rp[1]),
        (raw[0], raw[1]),
        tf,
        truth,
        (t[keep], gyro[keep], accel[keep]),
    )


def _assert_like_euroc(frames: list[StereoFrame], euroc: _Euroc) -> None:
    assert [f.stamp_ns for f in frames] == [f.stamp_ns for f in euroc.frames]
    assert [f.right_stamp_ns for f in frames] == [f.right_stamp_ns for f in euroc.frames]
    want = euroc.frames[0].rig
    rig = frames[0].rig
    assert rig.baseline_m == pytest.approx(want.baseline_m, abs=1e-6)
    np.testing.assert_allclose(rig.camera.K, want.camera.K, atol=1e-6)
    np.testing.assert_allclose(rig.body_from_left, want.body_from_left, atol=1e-9)
    for got, exp in zip(frames, euroc.frames, strict=True):
        for a, b in ((got.left, exp.left), (got.right, exp.right)):
            assert a.shape == b.shape
            assert np.abs(a.astype(float) - b.astype(float)).mean() < 1.0


@pytest.mark.parametrize("calibration", ["rp", "tf"])
def test_euroc_pairs_are_rectified_like_the_folder(
    euroc: _Euroc, tmp_path: Path, calibration: str
) -> None:
    infos = euroc.rp if calibration == "rp" else euroc.raw
    path = _write(tmp_path / "euroc.mcap", euroc.pairs, infos, euroc.tf)
    frames, _ = _stereo(path)
    _assert_like_euroc(frames, euroc)
    with open_source(path) as again:
        info = again.info()
    method = "rectified with the R and P" if calibration == "rp" else "by stereoRectify from tf"
    assert method in info.camera_source
    assert info.details["body_frame"] == "base_link"


def test_euroc_pairs_with_imu_come_in_stamp_order(euroc: _Euroc, tmp_path: Path) -> None:
    path = _write(tmp_path / "imu.mcap", euroc.pairs, euroc.rp, euroc.tf, imu=euroc.imu)
    with open_source(path) as source:
        frames = list(source.frames(("stereo", "imu")))
        info = source.info()
    stamps = [f.stamp_ns for f in frames]
    assert stamps == sorted(stamps)
    imu = [f for f in frames if isinstance(f, ImuFrame)]
    pairs = [f for f in frames if isinstance(f, StereoFrame)]
    assert len(pairs) == N_EUROC
    t, gyro, accel = euroc.imu
    assert [f.stamp_ns for f in imu] == t.tolist()
    np.testing.assert_array_equal(np.stack([f.gyro_radps for f in imu]), gyro)
    np.testing.assert_array_equal(np.stack([f.accel_mps2 for f in imu]), accel)
    # IMU first at equal stamps: the sample stamped with a pair comes just before it.
    for k, frame in enumerate(frames):
        if isinstance(frame, StereoFrame) and frame.stamp_ns in set(t.tolist()):
            assert isinstance(frames[k - 1], ImuFrame) and frames[k - 1].stamp_ns == frame.stamp_ns
    imu_stream = next(s for s in info.streams if s.name == "/imu0")
    assert imu_stream.kind == "imu" and imu_stream.rate_hz == pytest.approx(200.0, rel=0.01)


def test_a_right_image_30_ms_late_is_skipped_and_counted_at_20_hz(
    euroc: _Euroc, tmp_path: Path
) -> None:
    pairs = list(euroc.pairs)
    late = pairs[5]
    pairs[5] = _Pair(late.stamp_ns, late.left, late.right, late.stamp_ns + LATE_NS)
    path = _write(tmp_path / "late.mcap", pairs, euroc.rp, euroc.tf)
    frames, source = _stereo(path)
    assert len(frames) == N_EUROC - 1
    assert late.stamp_ns not in [f.stamp_ns for f in frames]
    assert source.stats.skipped == 1
    assert source.stats.skipped_names == [f"/cam0/image_raw@{late.stamp_ns}"]
    for deep in (False, True):
        with open_source(path) as again:
            info = again.info(deep=deep)
        assert info.details["unpaired_left"] == 1
        assert next(s for s in info.streams if s.kind == "stereo").count == N_EUROC - 1
        assert any("1 left image(s) of /cam0/image_raw have no image" in p for p in info.problems)


def test_groundtruth_of_the_body_is_interpolated_to_the_pairs(
    euroc: _Euroc, tmp_path: Path
) -> None:
    path = _write(tmp_path / "gt.mcap", euroc.pairs, euroc.rp, euroc.tf, truth=euroc.truth)
    with open_source(path) as source:
        recorded = source.groundtruth()
        frames = [f for f in source.frames(("stereo",)) if isinstance(f, StereoFrame)]
        after = source.groundtruth()
    assert recorded is not None and after is not None
    np.testing.assert_array_equal(recorded.stamps_ns, euroc.truth.stamps_ns)
    stamps = np.array([f.stamp_ns for f in frames], dtype=np.int64)
    valid, want = interpolate_poses(euroc.truth.stamps_ns, euroc.truth.world_from_body, stamps)
    assert valid.all()
    np.testing.assert_array_equal(after.stamps_ns, stamps)
    np.testing.assert_allclose(after.world_from_body, want, atol=1e-9)


def test_info_and_run_options_reach_the_source(euroc: _Euroc, tmp_path: Path) -> None:
    path = _write(tmp_path / "cli.mcap", euroc.pairs[:4], euroc.rp, euroc.tf)
    res = runner.invoke(app, ["info", str(path), "--json", "--right-topic", "/cam1/image_raw"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["details"]["left_topic"] == "/cam0/image_raw"
    assert out["details"]["stereo_topics_chosen"] == "named like --right-topic"
    assert out["details"]["baseline_m"] == pytest.approx(euroc.frames[0].rig.baseline_m)
    res = runner.invoke(app, ["info", str(path), "--left-topic", "/nope"])
    assert res.exit_code == 0, res.output
    assert "no topic /nope (--left-topic)" in res.output


# -- choosing the pair ---------------------------------------------------------------------------


def _tiny(path: Path, topics: list[str]) -> Path:
    """A log of a few 8x6 rectified pairs on every topic given (pairs of topics in order)."""
    k = np.array([[10.0, 0, 4], [0, 10.0, 3], [0, 0, 1]])
    p_left = np.hstack([k, np.zeros((3, 1))])
    p_right = p_left.copy()
    p_right[0, 3] = -10.0 * 0.1
    with open_log(path, "ros2", force=True) as log:
        w = _Ros2(log)
        for i in range(3):
            stamp = 1_000_000_000 + i * 50_000_000
            for n, topic in enumerate(topics):
                image = np.full((6, 8), 10 * i + n, dtype=np.uint8)
                w.image(topic, stamp, f"f{n}", image)
                info = _Info(f"f{n}", (8, 6), k, p=p_left if n % 2 == 0 else p_right)
                w.camera_info(topic.rsplit("/", 1)[0] + "/camera_info", stamp, info)
    return path


def test_stereo_pairs_are_found_by_their_names() -> None:
    topics = [
        "/zed/left/image_rect_color",
        "/zed/right/image_rect_color",
        "/camera/infra1/image_rect_raw",
        "/camera/infra2/image_rect_raw",
        "/cam0/image_raw",
        "/cam1/image_raw",
        "/camera/color/image_raw",
        "/leftover/image",
        "/rightover/image",
    ]
    assert sorted(stereo_pairs(topics)) == [
        ("/cam0/image_raw", "/cam1/image_raw"),
        ("/camera/infra1/image_rect_raw", "/camera/infra2/image_rect_raw"),
        ("/zed/left/image_rect_color", "/zed/right/image_rect_color"),
    ]


def test_the_one_infra_pair_is_taken(tmp_path: Path) -> None:
    topics = ["/camera/infra1/image_rect_raw", "/camera/infra2/image_rect_raw"]
    frames, _ = _stereo(_tiny(tmp_path / "infra.mcap", topics))
    assert len(frames) == 3
    assert frames[0].name.startswith("/camera/infra1/image_rect_raw@")
    assert frames[1].left[0, 0] == 10 and frames[1].right[0, 0] == 11
    assert frames[0].rig.baseline_m == pytest.approx(0.1)


def test_several_pairs_need_a_choice(tmp_path: Path) -> None:
    topics = [
        "/zed/left/image_rect_color",
        "/zed/right/image_rect_color",
        "/zed/left/image_raw_color",
        "/zed/right/image_raw_color",
    ]
    path = _tiny(tmp_path / "zed.mcap", topics)
    with open_source(path) as source, pytest.raises(TopicNotFoundError) as err:
        list(source.frames(("stereo",)))
    assert "2 stereo pairs of image topics" in err.value.msg
    assert "/zed/left/image_raw_color + /zed/right/image_raw_color" in err.value.msg
    assert "--left-topic and --right-topic" in err.value.msg
    assert {row[0] for row in err.value.candidates} == set(topics)
    frames, _ = _stereo(path, left_topic="/zed/left/image_raw_color")
    assert frames[0].name.startswith("/zed/left/image_raw_color@")
    assert frames[0].left[0, 0] == 2 and frames[0].right[0, 0] == 3
    with open_source(path) as source:
        info = source.info()
    assert any("no stereo pairs: " in p and "2 stereo pairs" in p for p in info.problems)
    assert not any(s.kind == "stereo" for s in info.streams)


def test_a_log_without_pairs_has_no_stereo_summary(tmp_path: Path) -> None:
    path = _tiny(tmp_path / "mono.mcap", ["/camera/color/image_raw"])
    with open_source(path) as source:
        info = source.info()
        with pytest.raises(TopicNotFoundError) as err:
            list(source.frames(("stereo",)))
    assert not any(s.kind == "stereo" for s in info.streams)
    assert not any("stereo" in p for p in info.problems)
    assert "no stereo pair of image topics" in err.value.msg


def test_a_visual_run_over_a_log_that_lost_a_pair_exits_3(euroc: _Euroc, tmp_path: Path) -> None:
    pairs = list(euroc.pairs)
    late = pairs[5]
    pairs[5] = _Pair(late.stamp_ns, late.left, late.right, late.stamp_ns + LATE_NS)
    path = _write(tmp_path / "late.mcap", pairs, euroc.rp, euroc.tf, truth=euroc.truth)
    out = tmp_path / "run"
    res = runner.invoke(app, ["run", "visual", str(path), "--out", str(out)])
    assert res.exit_code == 3, res.output
    assert "1 frame(s) skipped" in res.output
    record = json.loads((out / "run.json").read_text())
    assert record["counts"]["frames_skipped"] == 1
    assert record["counts"]["frames_read"] == N_EUROC - 1


# -- calibration alone ---------------------------------------------------------------------------


def _tf(edges: list[tuple[str, str, np.ndarray]]) -> TfBuffer:
    tf = TfBuffer()
    for parent, child, pose in edges:
        tf.add_pose(PoseRecord(0, parent, child, pose), static=True)
    return tf


def _camera_info(frame: str, **fields: Any) -> CameraInfo:
    values: dict[str, Any] = {
        "topic": f"/{frame}/camera_info",
        "frame_id": frame,
        "width": 640,
        "height": 480,
        "model": "plumb_bob",
        "d": (0.0,) * 5,
        "k": np.array([[400.0, 0, 320], [0, 400.0, 240], [0, 0, 1]]),
        "r": None,
        "p": None,
    }
    values.update(fields)
    return CameraInfo(**values)


def test_an_equidistant_pair_is_rectified_from_tf() -> None:
    d = (0.01, -0.002, 0.0005, -0.0001)
    infos = tuple(_camera_info(f, model="equidistant", d=d) for f in ("left", "right"))
    tf = _tf(
        [
            ("base_link", "left", make_pose(np.eye(3), [0.0, 0.05, 0.0])),
            ("base_link", "right", make_pose(np.eye(3), [0.12, 0.05, 0.0])),
        ]
    )
    calib = calibrate_stereo(Path("log.mcap"), infos, tf, "base_link")
    assert calib.rectification is not None
    assert calib.rig.baseline_m == pytest.approx(0.12, rel=1e-9)
    assert "equidistant" in calib.method and "stereoRectify" in calib.method
    np.testing.assert_allclose(calib.rig.body_from_left[:3, 3], [0.0, 0.05, 0.0], atol=1e-12)
    image = np.full((480, 640), 128, dtype=np.uint8)
    left, right = calib.rectify(image, image)
    assert left.shape == right.shape == (480, 640)
    assert int(left[240, 320]) == 128


def test_image_rect_topics_are_taken_as_rectified_with_their_r() -> None:
    turn = make_pose(cv2.Rodrigues(np.array([0.0, 0.02, 0.0]))[0], [0.0, 0.0, 0.0])
    p_left = np.array([[390.0, 0, 300, 0], [0, 390.0, 250, 0], [0, 0, 1, 0]])
    p_right = p_left.copy()
    p_right[0, 3] = -390.0 * 0.07
    d = (0.1, -0.05, 0.0, 0.0, 0.0)
    infos = (
        _camera_info("left", d=d, r=turn[:3, :3], p=p_left),
        _camera_info("right", d=d, r=turn[:3, :3], p=p_right),
    )
    tf = _tf([("base_link", "left", np.eye(4))])
    raw = calibrate_stereo(Path("log.mcap"), infos, tf, "base_link")
    rect = calibrate_stereo(Path("log.mcap"), infos, tf, "base_link", rectified_topics=True)
    assert raw.rectification is not None and rect.rectification is None
    assert rect.rig.baseline_m == pytest.approx(0.07) == raw.rig.baseline_m
    assert rect.rig.camera.fx == 390.0 and rect.rig.camera.cx == 300.0
    np.testing.assert_allclose(rect.rig.body_from_left, raw.rig.body_from_left, atol=1e-12)
    np.testing.assert_allclose(rect.rig.body_from_left[:3, :3], turn[:3, :3].T, atol=1e-12)


def test_the_body_is_an_odometry_child_frame_else_base_link() -> None:
    frames = {"odom", "base_link", "base_footprint", "imu_link", "cam0"}
    assert body_frame(frames, ["imu_link"]) == "imu_link"
    assert body_frame(frames, ["not_in_tf"]) == "base_link"
    assert body_frame({"base_footprint", "cam0"}, []) == "base_footprint"
    assert body_frame({"cam0", "cam1"}, []) is None


# -- round trip through the stereo writer ---------------------------------------------------------


def test_the_euroc_folder_round_trips_through_write_stereo_mcap(tmp_path: Path) -> None:
    from slamcli.formats.mcap.write.stereo import write_stereo_mcap

    folder = shared_path(*EUROC)
    truth = read_trajectory(folder / "groundtruth_body.txt", "tum")
    with EurocSource(folder) as source:
        want = [f for f in source.frames(("stereo",)) if isinstance(f, StereoFrame)]
        written = write_stereo_mcap(source, tmp_path / "euroc.mcap", groundtruth=truth)
    assert len(want) == written.frames == 95
    with open_source(written.path) as log:
        assert isinstance(log, McapSource)
        info = log.info()
        frames = list(log.frames(("stereo", "imu")))
        after = log.groundtruth()
        skipped = log.stats.skipped
    pairs = [f for f in frames if isinstance(f, StereoFrame)]
    imu = [f for f in frames if isinstance(f, ImuFrame)]
    assert skipped == 0
    assert [f.stamp_ns for f in pairs] == [f.stamp_ns for f in want]
    assert [f.right_stamp_ns for f in pairs] == [f.right_stamp_ns for f in want]
    assert [f.stamp_ns for f in frames] == sorted(f.stamp_ns for f in frames)
    assert len(imu) == written.topics["/imu0"][1]
    rig, rig_want = pairs[0].rig, want[0].rig
    assert rig.baseline_m == pytest.approx(rig_want.baseline_m, abs=1e-6)
    np.testing.assert_allclose(rig.camera.K, rig_want.camera.K, atol=1e-6)
    np.testing.assert_allclose(rig.body_from_left, rig_want.body_from_left, atol=1e-9)
    for got, exp in zip(pairs, want, strict=True):
        assert np.abs(got.left.astype(float) - exp.left.astype(float)).mean() < 1.0
        assert np.abs(got.right.astype(float) - exp.right.astype(float)).mean() < 1.0
    assert info.details["left_topic"] == "/cam0/image_raw"
    assert info.details["unpaired_left"] == 0
    assert next(s for s in info.streams if s.kind == "stereo").count == 95
    assert after is not None and len(after) == 95
    valid, poses = interpolate_poses(
        truth.stamps_ns, truth.world_from_body, np.array([f.stamp_ns for f in pairs])
    )
    assert valid.all()
    np.testing.assert_allclose(after.world_from_body, poses, atol=1e-6)


def test_info_checks_the_imu_topic(euroc: _Euroc, tmp_path: Path) -> None:
    """``info --deep`` runs the IMU checks on a log's IMU topic: EuRoC's is clean; the same
    samples with the accelerometer in g are named, with the topic. A plain ``info`` (which
    every run calls) does not read the topic."""
    t, gyro, accel = euroc.imu
    clean = _write(tmp_path / "imu.mcap", euroc.pairs, euroc.rp, euroc.tf, imu=euroc.imu)
    in_g = _write(
        tmp_path / "g.mcap", euroc.pairs, euroc.rp, euroc.tf, imu=(t, gyro, accel / 9.80665)
    )
    with open_source(clean) as source:
        assert "imu_check" not in source.info().details
        info = source.info(deep=True)
    check = info.details["imu_check"]
    assert info.details["imu_topic"] == "/imu0" and check["samples"] == len(t)
    assert check["rate_hz"] == pytest.approx(200.0, rel=0.01) and check["problems"] == []
    with open_source(in_g) as source:
        bad = source.info(deep=True)
    assert bad.details["imu_check"]["accel_units_suspect"]
    assert any(p.startswith("/imu0") and " g" in p for p in bad.problems)
