"""Adapters: serialised ROS 1 / ROS 2 / Foxglove messages through decoder and adapter to records."""

from __future__ import annotations

import base64
import json
import struct
from typing import Any

import numpy as np
import pytest
from conftest import shared_path

from slamcli.formats.mcap.adapters import ADAPTERS, adapter_for, normalize_schema_name
from slamcli.formats.mcap.decode import DecodeError, decoder_for
from slamcli.formats.mcap.records import (
    CameraInfoRecord,
    ChannelInfo,
    ImageRecord,
    PoseRecord,
    TransformRecord,
    TwistRecord,
)
from slamcli.geometry import matrix_to_quat_xyzw
from slamcli.types import ImuFrame

LOG_NS = 1_700_000_000_123_456_789


def _store(ros1: bool = False) -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)


def _via_ros2(msg: Any, typename: str, topic: str = "/topic", log_ns: int = LOG_NS) -> Any:
    """Serialise with rosbags, decode through a ros2msg channel, adapt."""
    store = _store()
    text, _ = store.generate_msgdef(typename, ros_version=2)
    ch = ChannelInfo(1, topic, "cdr", typename, "ros2msg", text.encode())
    decoded = decoder_for(ch)(bytes(store.serialize_cdr(msg, typename)))
    adapter = adapter_for(typename)
    assert adapter is not None
    return adapter(decoded, log_ns, topic)


def _header(store: Any, sec: int = 100, nanosec: int = 5, frame: str = "cam", **kw: Any) -> Any:
    t = store.types
    stamp = t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    return t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **kw)


def _image_msg(
    encoding: str, pixels: np.ndarray, *, step: int | None = None, big_endian: bool = False
) -> Any:
    """A sensor_msgs/msg/Image; ``step`` larger than the row pads each row with 0xEE bytes."""
    store = _store()
    h, w = pixels.shape[:2]
    dtype = pixels.dtype.newbyteorder(">" if big_endian else "<")
    rows = np.ascontiguousarray(pixels.astype(dtype)).view(np.uint8).reshape(h, -1)
    step = step or rows.shape[1]
    padded = np.full((h, step), 0xEE, dtype=np.uint8)
    padded[:, : rows.shape[1]] = rows
    return store.types["sensor_msgs/msg/Image"](
        header=_header(store),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=int(big_endian),
        step=step,
        data=padded.reshape(-1),
    )


def _check_owned(a: np.ndarray) -> None:
    assert a.flags.c_contiguous
    assert a.flags.owndata or (
        a.base is not None and a.base.flags.owndata and a.base.size == a.size
    )


RNG = np.random.default_rng(7)
RGB = RNG.integers(0, 256, (5, 7, 3), dtype=np.uint8)


@pytest.mark.parametrize(
    ("encoding", "pixels"),
    [
        ("rgb8", RGB),
        ("bgr8", RGB[..., ::-1]),
        ("rgba8", np.dstack([RGB, np.full((5, 7), 9, np.uint8)])),
        ("bgra8", np.dstack([RGB[..., ::-1], np.full((5, 7), 9, np.uint8)])),
    ],
)
@pytest.mark.parametrize("pad", [0, 5])
def test_colour_images_come_out_rgb(encoding: str, pixels: np.ndarray, pad: int) -> None:
    step = pixels.shape[1] * pixels.shape[2] + pad
    rec = _via_ros2(_image_msg(encoding, pixels, step=step), "sensor_msgs/msg/Image")
    assert isinstance(rec, ImageRecord)
    assert (rec.kind, rec.encoding, rec.frame_id) == ("rgb", encoding, "cam")
    assert rec.stamp_ns == 100 * 10**9 + 5
    assert rec.array.dtype == np.uint8
    np.testing.assert_array_equal(rec.array, RGB)
    _check_owned(rec.array)


# Where each colour sits in a 2x2 cell of the mosaic, by the ROS encoding's name.
BAYER = {"bayer_rggb8": "RGGB", "bayer_bggr8": "BGGR", "bayer_gbrg8": "GBRG", "bayer_grbg8": "GRBG"}


@pytest.mark.parametrize("encoding", sorted(BAYER))
@pytest.mark.parametrize("pad", [0, 3])
def test_bayer_mosaics_are_demosaiced_to_their_colours(encoding: str, pad: int) -> None:
    colour = {"R": 200, "G": 90, "B": 20}
    mosaic = np.zeros((8, 10), np.uint8)
    for k, c in enumerate(BAYER[encoding]):
        mosaic[k // 2 :: 2, k % 2 :: 2] = colour[c]
    rec = _via_ros2(_image_msg(encoding, mosaic, step=10 + pad), "sensor_msgs/msg/Image")
    assert rec.kind == "rgb" and rec.array.shape == (8, 10, 3) and rec.array.dtype == np.uint8
    # A flat colour demosaics to itself away from the border.
    np.testing.assert_array_equal(rec.array[2:-2, 2:-2], np.broadcast_to([200, 90, 20], (4, 6, 3)))
    _check_owned(rec.array)


@pytest.mark.parametrize(
    ("encoding", "code"),
    [
        ("yuv422", "COLOR_RGB2YUV_UYVY"),
        ("uyvy", "COLOR_RGB2YUV_UYVY"),
        ("yuv422_yuy2", "COLOR_RGB2YUV_YUY2"),
        ("yuyv", "COLOR_RGB2YUV_YUY2"),
    ],
)
def test_yuv422_images_come_out_rgb(encoding: str, code: str) -> None:
    import cv2

    # Pairs of equal pixels: 4:2:2 shares one chroma sample between two neighbours.
    rgb = np.repeat(RNG.integers(40, 216, (6, 4, 3), dtype=np.uint8), 2, axis=1)
    packed = cv2.cvtColor(rgb, getattr(cv2, code))
    assert packed.shape == (6, 8, 2)
    rec = _via_ros2(_image_msg(encoding, packed, step=20), "sensor_msgs/msg/Image")
    assert rec.kind == "rgb" and rec.array.shape == (6, 8, 3)
    assert np.abs(rec.array.astype(int) - rgb).max() <= 3  # YUV rounding
    other = "yuv422_yuy2" if encoding in ("yuv422", "uyvy") else "yuv422"
    swapped = _via_ros2(_image_msg(other, packed), "sensor_msgs/msg/Image")
    assert np.abs(swapped.array.astype(int) - rgb).max() > 20  # the byte order matters


@pytest.mark.parametrize("encoding", ["mono8", "8UC1"])
def test_mono_image(encoding: str) -> None:
    gray = RGB[..., 1]
    rec = _via_ros2(_image_msg(encoding, gray, step=9), "sensor_msgs/msg/Image")
    assert rec.kind == "mono"
    np.testing.assert_array_equal(rec.array, gray)
    _check_owned(rec.array)


@pytest.mark.parametrize("big_endian", [False, True])
@pytest.mark.parametrize("pad", [0, 3])
def test_16uc1_millimetres_to_metres(big_endian: bool, pad: int) -> None:
    mm = np.array([[0, 1, 1234], [65535, 500, 999]], dtype=np.uint16)
    msg = _image_msg("16UC1", mm, step=6 + pad, big_endian=big_endian)
    rec = _via_ros2(msg, "sensor_msgs/msg/Image")
    assert rec.kind == "depth"
    assert rec.array.dtype == np.float32
    np.testing.assert_array_equal(rec.array, mm.astype(np.float32) / np.float32(1000))
    assert rec.array[0, 0] == 0.0
    assert rec.array[0, 2] == pytest.approx(1.234, abs=1e-6)
    _check_owned(rec.array)


def test_32fc1_metres_invalid_to_zero() -> None:
    depth = np.array([[1.5, np.nan, np.inf], [-1.0, 0.0, 2.25]], dtype=np.float32)
    rec = _via_ros2(_image_msg("32FC1", depth, big_endian=True), "sensor_msgs/msg/Image")
    assert rec.kind == "depth"
    assert rec.array.dtype == np.float32
    np.testing.assert_array_equal(rec.array, [[1.5, 0, 0], [0, 0, 2.25]])


def test_zero_header_stamp_falls_back_to_log_time() -> None:
    msg = _image_msg("mono8", RGB[..., 0])
    msg.header.stamp.sec = 0
    msg.header.stamp.nanosec = 0
    assert _via_ros2(msg, "sensor_msgs/msg/Image").stamp_ns == LOG_NS


def test_unknown_image_encoding_raises() -> None:
    msg = _image_msg("mono8", RGB[..., 0])
    msg.encoding = "nv21"
    with pytest.raises(DecodeError, match=r"/cam/image.*'nv21'"):
        _via_ros2(msg, "sensor_msgs/msg/Image", topic="/cam/image")


def test_short_image_buffer_raises() -> None:
    msg = _image_msg("rgb8", RGB)
    msg.data = msg.data[:-4]
    with pytest.raises(DecodeError, match=r"/cam.*needs 105 bytes.*101"):
        _via_ros2(msg, "sensor_msgs/msg/Image", topic="/cam")


def _compressed(fmt: str, payload: bytes) -> Any:
    store = _store()
    return store.types["sensor_msgs/msg/CompressedImage"](
        header=_header(store, frame="rgb_optical"),
        format=fmt,
        data=np.frombuffer(payload, dtype=np.uint8),
    )


def _encode(ext: str, image: np.ndarray, *params: int) -> bytes:
    import cv2

    ok, buf = cv2.imencode(ext, image, list(params))
    assert ok
    return buf.tobytes()


SCENE = np.zeros((16, 24, 3), dtype=np.uint8)
SCENE[:, :12] = (230, 20, 20)  # red left half (RGB)
SCENE[:, 12:] = (20, 20, 230)  # blue right half


@pytest.mark.parametrize("fmt", ["png", "bgr8; png compressed bgr8"])
def test_compressed_png_is_exact_rgb(fmt: str) -> None:
    payload = _encode(".png", SCENE[..., ::-1])  # OpenCV writes BGR
    rec = _via_ros2(_compressed(fmt, payload), "sensor_msgs/msg/CompressedImage")
    assert (rec.kind, rec.frame_id, rec.encoding) == ("rgb", "rgb_optical", fmt)
    np.testing.assert_array_equal(rec.array, SCENE)
    _check_owned(rec.array)


@pytest.mark.parametrize("fmt", ["jpeg", "rgb8; jpeg compressed bgr8"])
def test_compressed_jpeg_colour_order(fmt: str) -> None:
    import cv2

    payload = _encode(".jpg", SCENE[..., ::-1], cv2.IMWRITE_JPEG_QUALITY, 95)
    rec = _via_ros2(_compressed(fmt, payload), "sensor_msgs/msg/CompressedImage")
    assert rec.kind == "rgb"
    assert rec.array.shape == (16, 24, 3)
    assert np.abs(rec.array.astype(int) - SCENE).mean() < 4
    assert rec.array[8, 2, 0] > 200 and rec.array[8, 2, 2] < 60  # red stays red
    assert rec.array[8, 20, 2] > 200 and rec.array[8, 20, 0] < 60


def test_compressed_rgb_packed_is_not_swapped() -> None:
    payload = _encode(".png", SCENE)  # the encoder was handed RGB bytes
    rec = _via_ros2(
        _compressed("rgb8; png compressed rgb8", payload), "sensor_msgs/msg/CompressedImage"
    )
    np.testing.assert_array_equal(rec.array, SCENE)


def test_compressed_mono_png() -> None:
    gray = RGB[..., 2].copy()
    rec = _via_ros2(
        _compressed("mono8; png compressed mono8", _encode(".png", gray)),
        "sensor_msgs/msg/CompressedImage",
    )
    assert rec.kind == "mono"
    np.testing.assert_array_equal(rec.array, gray)


DEPTH_MM = np.array([[0, 400, 1234], [5000, 65535, 1]], dtype=np.uint16)


def test_compressed_depth_16uc1() -> None:
    payload = struct.pack("<iff", 0, 0.0, 0.0) + _encode(".png", DEPTH_MM)
    msg = _compressed("16UC1; compressedDepth png", payload)
    rec = _via_ros2(msg, "sensor_msgs/msg/CompressedImage")
    assert (rec.kind, rec.array.dtype) == ("depth", np.float32)
    np.testing.assert_array_equal(rec.array, DEPTH_MM.astype(np.float32) / np.float32(1000))


def test_compressed_depth_32fc1_inverse_depth() -> None:
    depth_max, quant = 10.0, 100.0
    a, b = quant, 1.0 - quant / depth_max
    metres = np.array([[0.5, 1.0, 0.0], [2.0, 9.5, np.nan]], dtype=np.float32)
    # compressed_depth_image_transport's encoder: value = A / depth + B, truncated; 0 = invalid.
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(
            np.isfinite(metres) & (metres > 0) & (metres < depth_max), a / metres + b, 0.0
        )
    values = inv.astype(np.uint16)
    payload = struct.pack("<iff", 0, a, b) + _encode(".png", values)
    rec = _via_ros2(
        _compressed("32FC1; compressedDepth png", payload), "sensor_msgs/msg/CompressedImage"
    )
    valid = values != 0
    expected = np.zeros_like(metres)
    expected[valid] = a / (values[valid].astype(np.float64) - b)
    np.testing.assert_allclose(rec.array, expected, rtol=1e-6)
    assert rec.array[0, 2] == 0.0 and rec.array[1, 2] == 0.0
    assert rec.array[0, 0] == pytest.approx(0.5, rel=0.01)
    assert rec.array[1, 0] == pytest.approx(2.0, rel=0.05)


def test_compressed_depth_rvl_raises() -> None:
    msg = _compressed("16UC1; compressedDepth rvl", b"\x00" * 20)
    with pytest.raises(DecodeError, match=r"/depth.*RVL"):
        _via_ros2(msg, "sensor_msgs/msg/CompressedImage", topic="/depth")


def test_undecodable_compressed_image_raises() -> None:
    msg = _compressed("jpeg", b"not an image at all")
    with pytest.raises(DecodeError, match=r"/cam/compressed.*'jpeg'"):
        _via_ros2(msg, "sensor_msgs/msg/CompressedImage", topic="/cam/compressed")


def _camera_info(store: Any, k_name: str = "k", d_name: str = "d", **extra: Any) -> Any:
    k = np.array([525.0, 0, 319.5, 0, 526.0, 239.5, 0, 0, 1])
    fields = {
        "header": _header(store, frame="cam", **extra),
        "height": 480,
        "width": 640,
        "distortion_model": "plumb_bob",
        d_name: np.array([0.1, -0.2, 0.001, 0.002, 0.05]),
        k_name: k,
        k_name.replace("k", "r").replace("K", "R"): np.eye(3).reshape(-1),
        k_name.replace("k", "p").replace("K", "P"): np.zeros(12),
        "binning_x": 0,
        "binning_y": 0,
        "roi": store.types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    }
    return store.types["sensor_msgs/msg/CameraInfo"](**fields)


def _assert_tum_camera(rec: Any) -> None:
    assert isinstance(rec, CameraInfoRecord)
    cam = rec.camera
    assert (cam.width, cam.height) == (640, 480)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (525.0, 526.0, 319.5, 239.5)
    assert cam.distortion == (0.1, -0.2, 0.001, 0.002, 0.05)


def test_camera_info_ros2() -> None:
    rec = _via_ros2(_camera_info(_store()), "sensor_msgs/msg/CameraInfo")
    _assert_tum_camera(rec)
    assert (rec.frame_id, rec.stamp_ns) == ("cam", 100 * 10**9 + 5)


def test_camera_info_ros1_uppercase_fields() -> None:
    store = _store(ros1=True)
    msg = _camera_info(store, "K", "D", seq=3)
    text, _ = store.generate_msgdef("sensor_msgs/msg/CameraInfo", ros_version=1)
    ch = ChannelInfo(2, "/cam/info", "ros1", "sensor_msgs/CameraInfo", "ros1msg", text.encode())
    decoded = decoder_for(ch)(bytes(store.serialize_ros1(msg, "sensor_msgs/msg/CameraInfo")))
    adapter = adapter_for("sensor_msgs/CameraInfo")
    assert adapter is not None
    _assert_tum_camera(adapter(decoded, LOG_NS, "/cam/info"))


def test_camera_info_rational_polynomial_keeps_eight_coefficients() -> None:
    msg = _camera_info(_store())
    msg.distortion_model = "rational_polynomial"
    msg.d = np.arange(1, 9, dtype=np.float64) * 0.01
    rec = _via_ros2(msg, "sensor_msgs/msg/CameraInfo")
    assert rec.camera.distortion == tuple(np.arange(1, 9) * 0.01)


def test_uncalibrated_camera_info_raises() -> None:
    msg = _camera_info(_store())
    msg.k = np.zeros(9)
    with pytest.raises(DecodeError, match=r"/info.*not calibrated"):
        _via_ros2(msg, "sensor_msgs/msg/CameraInfo", topic="/info")


def test_unsupported_distortion_model_raises() -> None:
    msg = _camera_info(_store())
    msg.distortion_model = "equidistant"
    msg.d = np.array([0.1, 0.01, 0.0, 0.0])
    with pytest.raises(DecodeError, match=r"/info.*'equidistant'"):
        _via_ros2(msg, "sensor_msgs/msg/CameraInfo", topic="/info")


def _pose_msg(store: Any, q: tuple[float, float, float, float]) -> Any:
    t = store.types
    return t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=1.0, y=-2.0, z=0.5),
        orientation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
    )


Q = (0.0, 0.0, np.sin(0.3), np.cos(0.3))  # 0.6 rad about z


def _assert_pose(m: np.ndarray) -> None:
    np.testing.assert_array_equal(m[:3, 3], [1.0, -2.0, 0.5])
    np.testing.assert_allclose(matrix_to_quat_xyzw(m), Q, atol=1e-15)
    np.testing.assert_allclose(m[:2, 0], [np.cos(0.6), np.sin(0.6)], atol=1e-15)


def test_pose_stamped() -> None:
    store = _store()
    msg = store.types["geometry_msgs/msg/PoseStamped"](
        header=_header(store, frame="map"), pose=_pose_msg(store, Q)
    )
    rec = _via_ros2(msg, "geometry_msgs/msg/PoseStamped")
    assert isinstance(rec, PoseRecord)
    assert (rec.frame_id, rec.child_frame_id, rec.twist) == ("map", "", None)
    _assert_pose(rec.parent_from_child)


def test_pose_with_covariance_stamped() -> None:
    store = _store()
    t = store.types
    msg = t["geometry_msgs/msg/PoseWithCovarianceStamped"](
        header=_header(store, frame="map"),
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=_pose_msg(store, Q), covariance=np.zeros(36)
        ),
    )
    rec = _via_ros2(msg, "geometry_msgs/msg/PoseWithCovarianceStamped")
    assert rec.frame_id == "map"
    _assert_pose(rec.parent_from_child)


def _vec(store: Any, x: float, y: float, z: float) -> Any:
    return store.types["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)


def test_imu() -> None:
    store = _store()
    cov = np.zeros(9)
    msg = store.types["sensor_msgs/msg/Imu"](
        header=_header(store, frame="imu"),
        orientation=store.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.r_[-1.0, np.zeros(8)],
        angular_velocity=_vec(store, 0.1, 0.2, 0.3),
        angular_velocity_covariance=cov,
        linear_acceleration=_vec(store, 0.0, 0.5, 9.81),
        linear_acceleration_covariance=cov,
    )
    rec = _via_ros2(msg, "sensor_msgs/msg/Imu")
    assert isinstance(rec, ImuFrame)
    assert rec.stamp_ns == 100 * 10**9 + 5
    assert rec.accel_mps2 is not None and rec.gyro_radps is not None
    np.testing.assert_array_equal(rec.accel_mps2, [0.0, 0.5, 9.81])
    np.testing.assert_array_equal(rec.gyro_radps, [0.1, 0.2, 0.3])
    msg.angular_velocity_covariance = np.r_[-1.0, np.zeros(8)]
    assert _via_ros2(msg, "sensor_msgs/msg/Imu").gyro_radps is None


def test_twist_and_twist_stamped() -> None:
    store = _store()
    twist = store.types["geometry_msgs/msg/Twist"](
        linear=_vec(store, 0.4, 0.0, 0.0), angular=_vec(store, 0.0, 0.0, -0.2)
    )
    rec = _via_ros2(twist, "geometry_msgs/msg/Twist")
    assert rec == TwistRecord(LOG_NS, 0.4, -0.2)
    stamped = store.types["geometry_msgs/msg/TwistStamped"](header=_header(store), twist=twist)
    assert _via_ros2(stamped, "geometry_msgs/msg/TwistStamped") == TwistRecord(
        100 * 10**9 + 5, 0.4, -0.2
    )


def _tf_message(store: Any, stamp_sec: int) -> Any:
    t = store.types
    transform = t["geometry_msgs/msg/Transform"](
        translation=_vec(store, 1.0, -2.0, 0.5),
        rotation=t["geometry_msgs/msg/Quaternion"](x=Q[0], y=Q[1], z=Q[2], w=Q[3]),
    )
    ts = t["geometry_msgs/msg/TransformStamped"](
        header=_header(store, sec=stamp_sec, nanosec=0, frame="odom"),
        child_frame_id="base_link",
        transform=transform,
    )
    return t["tf2_msgs/msg/TFMessage"](transforms=[ts, ts])


@pytest.mark.parametrize(
    ("topic", "static"), [("/tf", False), ("/tf_static", True), ("/robot1/tf_static", True)]
)
def test_tf_message(topic: str, static: bool) -> None:
    rec = _via_ros2(_tf_message(_store(), 0 if static else 42), "tf2_msgs/msg/TFMessage", topic)
    assert isinstance(rec, TransformRecord)
    assert rec.static is static
    assert len(rec.transforms) == 2
    pose = rec.transforms[0]
    assert (pose.frame_id, pose.child_frame_id) == ("odom", "base_link")
    assert pose.stamp_ns == (LOG_NS if static else 42 * 10**9)
    _assert_pose(pose.parent_from_child)


def test_real_odometry_matches_message_fields() -> None:
    from mcap.reader import make_reader

    path = shared_path("mcap", "nav2_turtlebot.mcap")
    n = 0
    with path.open("rb") as fh:
        reader = make_reader(fh)
        for schema, channel, message in reader.iter_messages(topics=["/odom", "/amcl_pose"]):
            assert schema is not None
            info = ChannelInfo.from_records(channel, schema)
            msg = decoder_for(info)(message.data)
            adapter = adapter_for(schema.name)
            assert adapter is not None
            rec = adapter(msg, message.log_time, channel.topic)
            assert isinstance(rec, PoseRecord)
            stamp = msg.header.stamp
            assert rec.stamp_ns == stamp.sec * 10**9 + stamp.nanosec
            assert rec.frame_id == msg.header.frame_id
            pose = msg.pose.pose
            p, q = pose.position, pose.orientation
            assert rec.parent_from_child[:3, 3].tolist() == [p.x, p.y, p.z]
            got = matrix_to_quat_xyzw(rec.parent_from_child)
            want = np.array([q.x, q.y, q.z, q.w]) * np.sign(q.w or 1.0)
            np.testing.assert_allclose(got, want, atol=1e-12)
            if channel.topic == "/odom":
                assert rec.frame_id == "odom" and rec.child_frame_id == "base_link"
                twist = msg.twist.twist
                assert rec.twist == (twist.linear.x, twist.angular.z)
                n += 1
    assert n == 2639


# -- Foxglove ---------------------------------------------------------------------------------


def _fds(message_class: Any) -> bytes:
    from google.protobuf.descriptor_pb2 import FileDescriptorSet

    fds = FileDescriptorSet()
    seen: set[str] = set()

    def add(file: Any) -> None:
        if file.name not in seen:
            seen.add(file.name)
            for dep in file.dependencies:
                add(dep)
            file.CopyToProto(fds.file.add())

    add(message_class.DESCRIPTOR.file)
    return fds.SerializeToString()


def _via_protobuf(msg: Any, topic: str = "/fox") -> Any:
    name = msg.DESCRIPTOR.full_name
    ch = ChannelInfo(3, topic, "protobuf", name, "protobuf", _fds(type(msg)))
    adapter = adapter_for(name)
    assert adapter is not None
    return adapter(decoder_for(ch)(msg.SerializeToString()), LOG_NS, topic)


def _via_json(name: str, payload: dict[str, Any], topic: str = "/fox_json") -> Any:
    ch = ChannelInfo(4, topic, "json", name, "jsonschema", b"{}")
    adapter = adapter_for(name)
    assert adapter is not None
    return adapter(decoder_for(ch)(json.dumps(payload).encode()), LOG_NS, topic)


@pytest.fixture
def fox() -> Any:
    return pytest.importorskip("foxglove_schemas_protobuf")


def _fox_raw(encoding: str, pixels: np.ndarray, step: int) -> Any:
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    h, w = pixels.shape[:2]
    rows = np.ascontiguousarray(pixels.astype(pixels.dtype.newbyteorder("<"))).view(np.uint8)
    rows = rows.reshape(h, -1)
    padded = np.zeros((h, max(step, rows.shape[1])), dtype=np.uint8)
    padded[:, : rows.shape[1]] = rows
    msg = RawImage(frame_id="cam", width=w, height=h, encoding=encoding, step=step)
    msg.data = padded.tobytes()
    msg.timestamp.seconds, msg.timestamp.nanos = 10, 20
    return msg


def test_foxglove_raw_image_protobuf(fox: Any) -> None:
    rec = _via_protobuf(_fox_raw("bgr8", RGB[..., ::-1], step=7 * 3 + 2))
    assert (rec.kind, rec.frame_id, rec.stamp_ns) == ("rgb", "cam", 10 * 10**9 + 20)
    np.testing.assert_array_equal(rec.array, RGB)
    depth = _via_protobuf(_fox_raw("16UC1", DEPTH_MM, step=6))
    assert depth.kind == "depth"
    np.testing.assert_array_equal(depth.array, DEPTH_MM.astype(np.float32) / np.float32(1000))
    metres = np.array([[1.0, np.nan]], dtype=np.float32)
    out = _via_protobuf(_fox_raw("32FC1", metres, step=0))
    np.testing.assert_array_equal(out.array, [[1.0, 0.0]])


def test_foxglove_raw_image_without_timestamp_uses_log_time(fox: Any) -> None:
    msg = _fox_raw("mono8", RGB[..., 0], step=7)
    msg.ClearField("timestamp")
    assert _via_protobuf(msg).stamp_ns == LOG_NS


def test_foxglove_compressed_image_protobuf(fox: Any) -> None:
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

    msg = CompressedImage(frame_id="cam", format="png", data=_encode(".png", SCENE[..., ::-1]))
    rec = _via_protobuf(msg)
    assert (rec.kind, rec.encoding) == ("rgb", "png")
    np.testing.assert_array_equal(rec.array, SCENE)


def test_foxglove_camera_calibration_protobuf(fox: Any) -> None:
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration

    msg = CameraCalibration(frame_id="cam", width=640, height=480, distortion_model="plumb_bob")
    msg.K.extend([525.0, 0, 319.5, 0, 526.0, 239.5, 0, 0, 1])
    msg.D.extend([0.1, -0.2, 0.001, 0.002, 0.05])
    rec = _via_protobuf(msg)
    _assert_tum_camera(rec)
    assert rec.stamp_ns == LOG_NS


def test_foxglove_pose_in_frame_protobuf(fox: Any) -> None:
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

    msg = PoseInFrame(frame_id="world")
    msg.timestamp.seconds = 3
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = 1.0, -2.0, 0.5
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = Q
    rec = _via_protobuf(msg)
    assert (rec.frame_id, rec.stamp_ns) == ("world", 3 * 10**9)
    _assert_pose(rec.parent_from_child)


def test_foxglove_frame_transforms_protobuf(fox: Any) -> None:
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
    from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms

    one = FrameTransform(parent_frame_id="world", child_frame_id="robot")
    one.timestamp.seconds = 4
    one.translation.x, one.translation.y, one.translation.z = 1.0, -2.0, 0.5
    one.rotation.x, one.rotation.y, one.rotation.z, one.rotation.w = Q
    rec = _via_protobuf(one, topic="/tf_static")
    assert rec.static is True
    assert (rec.transforms[0].frame_id, rec.transforms[0].child_frame_id) == ("world", "robot")
    _assert_pose(rec.transforms[0].parent_from_child)
    unrotated = FrameTransform(parent_frame_id="robot", child_frame_id="camera")
    many = FrameTransforms(transforms=[one, unrotated])
    rec = _via_protobuf(many, topic="/tf")
    assert rec.static is False
    assert [t.child_frame_id for t in rec.transforms] == ["robot", "camera"]
    assert rec.transforms[0].stamp_ns == 4 * 10**9
    assert rec.transforms[1].stamp_ns == LOG_NS
    # An unset protobuf quaternion is all zeros: it stands for no rotation.
    np.testing.assert_array_equal(rec.transforms[1].parent_from_child, np.eye(4))


def test_foxglove_json_messages() -> None:
    stamp = {"sec": 5, "nsec": 6}
    raw = _via_json(
        "foxglove.RawImage",
        {
            "timestamp": stamp,
            "frame_id": "cam",
            "width": 7,
            "height": 5,
            "encoding": "rgb8",
            "step": 21,
            "data": base64.b64encode(RGB.tobytes()).decode(),
        },
    )
    assert raw.stamp_ns == 5 * 10**9 + 6
    np.testing.assert_array_equal(raw.array, RGB)
    comp = _via_json(
        "foxglove.CompressedImage",
        {
            "timestamp": stamp,
            "frame_id": "cam",
            "format": "png",
            "data": base64.b64encode(_encode(".png", SCENE[..., ::-1])).decode(),
        },
    )
    np.testing.assert_array_equal(comp.array, SCENE)
    cal = _via_json(
        "foxglove.CameraCalibration",
        {
            "timestamp": stamp,
            "frame_id": "cam",
            "width": 640,
            "height": 480,
            "distortion_model": "plumb_bob",
            "D": [0.1, -0.2, 0.001, 0.002, 0.05],
            "K": [525.0, 0, 319.5, 0, 526.0, 239.5, 0, 0, 1],
            "R": [1, 0, 0, 0, 1, 0, 0, 0, 1],
            "P": [0] * 12,
        },
    )
    _assert_tum_camera(cal)
    xyz = {"x": 1.0, "y": -2.0, "z": 0.5}
    quat = dict(zip("xyzw", Q, strict=True))
    pose = _via_json(
        "foxglove.PoseInFrame",
        {"timestamp": stamp, "frame_id": "world", "pose": {"position": xyz, "orientation": quat}},
    )
    _assert_pose(pose.parent_from_child)
    tf = _via_json(
        "foxglove.FrameTransform",
        {
            "timestamp": {"sec": 0, "nsec": 0},
            "parent_frame_id": "world",
            "child_frame_id": "robot",
            "translation": xyz,
            "rotation": quat,
        },
    )
    assert tf.transforms[0].stamp_ns == LOG_NS
    _assert_pose(tf.transforms[0].parent_from_child)


def test_schema_names_normalise() -> None:
    assert adapter_for("sensor_msgs/Image") is ADAPTERS["sensor_msgs/msg/Image"]
    assert adapter_for("tf2_msgs/TFMessage") is ADAPTERS["tf2_msgs/msg/TFMessage"]
    assert adapter_for("foxglove.RawImage") is ADAPTERS["foxglove.RawImage"]
    assert adapter_for("visualization_msgs/msg/Marker") is None
    assert normalize_schema_name("nav_msgs/Odometry") == "nav_msgs/msg/Odometry"
