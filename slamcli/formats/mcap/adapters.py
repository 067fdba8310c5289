"""Adapters from decoded messages to slamcli records, keyed by normalised schema name.

An adapter is called as ``adapter(message, log_time_ns, topic)`` with a message from
:func:`slamcli.formats.mcap.decode.decoder_for`: a ``rosbags`` dataclass (ROS 1 and ROS 2), a
protobuf message or a JSON ``dict`` (Foxglove schemas). It returns one record:
:class:`ImageRecord`, :class:`CameraInfoRecord`, :class:`PoseRecord`, :class:`TransformRecord`,
:class:`TwistRecord`, :class:`ScanRecord`, :class:`~slamcli.types.ImuFrame` or
:class:`~slamcli.types.LandmarkFrame` (``slamcli.LandmarkObservations``, see
:mod:`slamcli.formats.mcap.observations`).

Stamps come from the message header (``sec`` + ``nanosec``) or Foxglove ``timestamp``; where that
is absent or zero the log time is used. Images come out as owned, C-contiguous arrays: RGB
(H, W, 3) uint8, mono (H, W) uint8, depth (H, W) float32 metres with 0 = no reading.

Laser scans (``sensor_msgs/msg/LaserScan``, ROS 1 ``sensor_msgs/LaserScan``,
``foxglove.LaserScan``) are checked before they become records: a scan without ranges, with an
angle increment that is zero or not finite, with ranges that do not span ``angle_min`` to
``angle_max`` (within one increment) or with a bad range interval raises :class:`DecodeError`,
which a source counts as a skipped message. Foxglove scans carry no range limits and JSON no
infinities: a range of 0 (how slamcli writes a beam without a reading) or ``null`` is no reading
there, every positive finite range is one.
"""

from __future__ import annotations

import base64
import logging
import math
import struct
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.formats.images import decode_image, size_problem
from slamcli.formats.mcap.decode import DecodeError, normalize_ros_type
from slamcli.formats.mcap.observations import SCHEMA_NAME as LANDMARK_SCHEMA_NAME
from slamcli.formats.mcap.observations import landmark_frame
from slamcli.formats.mcap.records import (
    CameraInfoRecord,
    ImageRecord,
    PoseRecord,
    ScanRecord,
    TransformRecord,
    TwistRecord,
)
from slamcli.geometry import make_pose, quat_xyzw_to_matrix
from slamcli.types import ImuFrame, LandmarkFrame, PinholeCamera, ScanFrame

log = logging.getLogger(__name__)

AdapterRecord = (
    ImageRecord
    | CameraInfoRecord
    | PoseRecord
    | TransformRecord
    | TwistRecord
    | ScanRecord
    | ImuFrame
    | LandmarkFrame
)
Adapter = Callable[[Any, int, str], AdapterRecord]
"""``adapter(message, log_time_ns, topic) -> record``."""

_NS = 1_000_000_000
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_COMPRESSED_DEPTH_HEADER = struct.Struct("<iff")
"""compressed_depth_image_transport's ConfigHeader: format enum, depthQuantA, depthQuantB."""

# encoding -> (kind, element dtype, channels in the buffer, OpenCV conversion to RGB or None)
_RAW_ENCODINGS: dict[str, tuple[str, str, int, str | None]] = {
    "rgb8": ("rgb", "u1", 3, None),
    "bgr8": ("rgb", "u1", 3, "COLOR_BGR2RGB"),
    "rgba8": ("rgb", "u1", 4, "COLOR_RGBA2RGB"),
    "bgra8": ("rgb", "u1", 4, "COLOR_BGRA2RGB"),
    # Raw Bayer mosaics (ROS names the 2x2 pattern from the top-left pixel; OpenCV from the
    # second row's second and third, hence the shifted names), demosaiced by OpenCV.
    "bayer_rggb8": ("rgb", "u1", 1, "COLOR_BayerBG2RGB"),
    "bayer_bggr8": ("rgb", "u1", 1, "COLOR_BayerRG2RGB"),
    "bayer_gbrg8": ("rgb", "u1", 1, "COLOR_BayerGR2RGB"),
    "bayer_grbg8": ("rgb", "u1", 1, "COLOR_BayerGB2RGB"),
    # 4:2:2 YUV, two bytes per pixel: ROS's yuv422 is UYVY, yuv422_yuy2 is YUYV.
    "yuv422": ("rgb", "u1", 2, "COLOR_YUV2RGB_UYVY"),
    "uyvy": ("rgb", "u1", 2, "COLOR_YUV2RGB_UYVY"),
    "yuv422_yuy2": ("rgb", "u1", 2, "COLOR_YUV2RGB_YUY2"),
    "yuyv": ("rgb", "u1", 2, "COLOR_YUV2RGB_YUY2"),
    "mono8": ("mono", "u1", 1, None),
    "8uc1": ("mono", "u1", 1, None),
    "16uc1": ("depth", "u2", 1, None),
    "32fc1": ("depth", "f4", 1, None),
}
_OPENCV_DISTORTION_MODELS = frozenset({"", "plumb_bob", "rational_polynomial"})
_ANGLE_SLACK = 1.001
"""How many increments the last beam's angle may be off ``angle_max`` (drivers round the beam
count either way)."""
_FOXGLOVE_RANGE_MIN = float(np.finfo(np.float32).smallest_normal)
"""The range limit of a Foxglove scan: every positive range is a reading, 0 is none."""


def normalize_schema_name(name: str) -> str:
    """``sensor_msgs/Image`` (ROS 1) -> ``sensor_msgs/msg/Image``; ROS 2 and Foxglove names kept."""
    return normalize_ros_type(name)


# -- field access shared by attribute-style messages and JSON dicts ---------------------------


def _get(obj: Any, name: str, default: Any = None) -> Any:
    if isinstance(obj, dict):
        return obj.get(name, default)
    return getattr(obj, name, default)


def _bytes(value: Any) -> Any:
    """A buffer for an image payload; Foxglove JSON carries bytes fields as base64 strings."""
    if isinstance(value, str):
        try:
            return base64.b64decode(value)
        except ValueError as exc:
            # binascii.Error (bad padding or length) and non-ASCII text are both ValueErrors.
            raise DecodeError(
                f"the image data is not the base64 text Foxglove JSON carries ({exc})"
            ) from None
    return value if value is not None else b""


def _stamp_or(sec: int, nsec: int, log_time_ns: int) -> int:
    ns = int(sec) * _NS + int(nsec)
    return ns if ns > 0 else log_time_ns


def _header_stamp(header: Any, log_time_ns: int) -> int:
    stamp = _get(header, "stamp")
    if stamp is None:
        return log_time_ns
    return _stamp_or(_get(stamp, "sec", 0), _get(stamp, "nanosec", 0), log_time_ns)


def _foxglove_stamp(msg: Any, log_time_ns: int) -> int:
    ts = _get(msg, "timestamp")
    if ts is None:
        return log_time_ns
    if isinstance(ts, dict):
        nsec = ts.get("nsec") or ts.get("nanosec") or 0
        return _stamp_or(int(ts.get("sec") or 0), int(nsec), log_time_ns)
    # google.protobuf.Timestamp
    return _stamp_or(_get(ts, "seconds", 0), _get(ts, "nanos", 0), log_time_ns)


def _pose(position: Any, orientation: Any) -> NDArray[np.float64]:
    """(4, 4) parent_from_child from a point/vector and an xyzw quaternion message."""
    t = (_get(position, "x", 0.0), _get(position, "y", 0.0), _get(position, "z", 0.0))
    q = np.array(
        [
            _get(orientation, "x", 0.0),
            _get(orientation, "y", 0.0),
            _get(orientation, "z", 0.0),
            _get(orientation, "w", 0.0),
        ],
        dtype=np.float64,
    )
    # An all-zero quaternion is what an unset protobuf/JSON field holds: treat it as no rotation.
    rotation = quat_xyzw_to_matrix(q) if q.any() else np.eye(3)
    return make_pose(rotation, t)


# -- images -----------------------------------------------------------------------------------


def decode_raw_image(
    topic: str,
    encoding: str,
    width: int,
    height: int,
    step: int,
    data: Any,
    big_endian: bool = False,
) -> tuple[str, NDArray[Any]]:
    """Decode an uncompressed image buffer.

    Args:
        topic: for error messages.
        encoding: ROS/Foxglove encoding (rgb8, bgr8, rgba8, bgra8, bayer_rggb8 and the other
            three Bayer patterns, yuv422 / uyvy, yuv422_yuy2 / yuyv, mono8, 8UC1, 16UC1, 32FC1).
        width, height: pixels.
        step: bytes per row (>= width * bytes per pixel; 0 means unpadded rows).
        data: the pixel buffer (bytes or uint8 array).
        big_endian: byte order of 16UC1 / 32FC1 samples.

    Returns:
        ``(kind, array)``: ``"rgb"`` (H, W, 3) uint8, ``"mono"`` (H, W) uint8 or ``"depth"``
        (H, W) float32 metres (16UC1 millimetres are scaled; NaN, inf and negative -> 0).
    """
    spec = _RAW_ENCODINGS.get(encoding.lower())
    if spec is None:
        raise DecodeError(
            f"channel {topic}: image encoding {encoding!r} is not supported",
            hint="supported encodings: rgb8, bgr8, rgba8, bgra8, bayer_rggb8, bayer_bggr8, "
            "bayer_gbrg8, bayer_grbg8, yuv422 (uyvy), yuv422_yuy2 (yuyv), mono8, 8UC1, 16UC1, "
            "32FC1",
        )
    kind, elem, channels, conversion = spec
    dtype = np.dtype(elem).newbyteorder(">" if big_endian else "<")
    pixel = dtype.itemsize * channels
    row = width * pixel
    step = int(step) or row
    problem = size_problem(width, height)
    if problem:
        raise DecodeError(f"channel {topic}: {encoding} image {problem}")
    if step < row:
        raise DecodeError(
            f"channel {topic}: {encoding} image row step {step} is smaller than width {width} x "
            f"{pixel} bytes"
        )
    buf = np.frombuffer(data, dtype=np.uint8)
    needed = step * (height - 1) + row
    if buf.size < needed:
        raise DecodeError(
            f"channel {topic}: {encoding} image {width}x{height} (step {step}) needs "
            f"{needed} bytes, the message has {buf.size}"
        )
    view = np.ndarray(
        (height, width, channels),
        dtype=dtype,
        buffer=buf,
        strides=(step, pixel, dtype.itemsize),
    )
    if conversion is not None:
        import cv2

        # cvtColor reads the padded rows in place and is several times faster than a numpy
        # channel shuffle; it returns a new contiguous array.
        return kind, cv2.cvtColor(view, getattr(cv2, conversion))
    if kind == "rgb":
        return kind, view.copy(order="C")
    if kind == "mono":
        return kind, view[..., 0].copy(order="C")
    depth = view[..., 0].astype(np.float32, order="C")
    if elem == "u2":
        depth /= 1000.0
    else:
        _zero_invalid(depth)
    return kind, depth


def _zero_invalid(depth: NDArray[np.float32]) -> None:
    """In place: NaN, ±inf and negative depths (ROS's "no reading" markers) -> 0."""
    depth[~(np.isfinite(depth) & (depth > 0))] = 0.0


def decode_compressed_image(topic: str, fmt: str, data: Any) -> tuple[str, NDArray[Any]]:
    """Decode a compressed image payload with OpenCV.

    ``fmt`` is a ROS ``CompressedImage.format`` (``"jpeg"``, ``"png"``,
    ``"rgb8; jpeg compressed bgr8"``, ``"16UC1; compressedDepth png"``, ...) or a Foxglove
    format (``"jpeg"``, ``"png"``, ``"webp"``). Colour images come out RGB; single-channel 16-bit
    PNGs are depth in millimetres (as ROS's compressed transport writes 16UC1).

    Returns:
        ``(kind, array)`` as for :func:`decode_raw_image`.
    """
    import cv2

    text = fmt.strip().lower()
    if "compresseddepth" in text:
        return "depth", _decode_compressed_depth(topic, fmt, data)
    original = text.split(";", 1)[0].strip() if ";" in text else ""
    # "rgb8; jpeg compressed bgr8": the channel order the encoder was given is the last word.
    packed = text.rsplit("compressed", 1)[1].strip() if "compressed" in text else ""
    image, reason = decode_image(_bytes(data))
    if image is None:
        raise DecodeError(f"channel {topic}: the {fmt!r} compressed image {reason}")
    if image.ndim == 2:
        if image.dtype == np.uint8:
            return "mono", np.ascontiguousarray(image)
        if image.dtype == np.uint16 and original in ("", "16uc1"):
            depth = image.astype(np.float32)
            depth /= 1000.0
            return "depth", depth
    elif image.ndim == 3 and image.dtype == np.uint8 and image.shape[2] in (3, 4):
        # OpenCV hands back the channels in the order they were encoded, which it calls BGR.
        four = image.shape[2] == 4
        if packed.startswith("rgb"):
            return "rgb", cv2.cvtColor(image, cv2.COLOR_RGBA2RGB) if four else image
        return "rgb", cv2.cvtColor(image, cv2.COLOR_BGRA2RGB if four else cv2.COLOR_BGR2RGB)
    shape = "x".join(str(s) for s in image.shape)
    raise DecodeError(
        f"channel {topic}: compressed image {fmt!r} decoded to an unsupported {image.dtype} array "
        f"of shape {shape}"
    )


def _decode_compressed_depth(topic: str, fmt: str, data: Any) -> NDArray[np.float32]:
    """compressed_depth_image_transport payload -> (H, W) float32 metres, 0 = no reading."""

    raw = bytes(_bytes(data))
    original = fmt.split(";", 1)[0].strip().lower()
    if "rvl" in fmt.lower():
        raise DecodeError(
            f"channel {topic}: compressedDepth format {fmt!r} (RVL) is not supported",
            hint="record depth with the png compressedDepth format or as raw 16UC1",
        )
    if raw.startswith(_PNG_MAGIC):
        quant_a = quant_b = 0.0
        png = raw
    else:
        if len(raw) < _COMPRESSED_DEPTH_HEADER.size:
            raise DecodeError(f"channel {topic}: compressedDepth payload is only {len(raw)} bytes")
        _, quant_a, quant_b = _COMPRESSED_DEPTH_HEADER.unpack_from(raw)
        png = raw[_COMPRESSED_DEPTH_HEADER.size :]
    image, reason = decode_image(png)
    if image is None:
        raise DecodeError(f"channel {topic}: compressedDepth payload of {fmt!r} {reason}")
    if image.ndim != 2 or image.dtype != np.uint16:
        raise DecodeError(
            f"channel {topic}: compressedDepth payload of {fmt!r} is not a single-channel "
            "16-bit PNG"
        )
    if original == "16uc1":
        depth = image.astype(np.float32)
        depth /= 1000.0
        return depth
    if original == "32fc1":
        # ROS stores inverse depth: value = depthQuantA / depth + depthQuantB, 0 = no reading.
        a, b = np.float32(quant_a), np.float32(quant_b)
        depth = np.zeros(image.shape, dtype=np.float32)
        valid = image != 0
        depth[valid] = a / (image[valid].astype(np.float32) - b)
        _zero_invalid(depth)
        return depth
    raise DecodeError(
        f"channel {topic}: compressedDepth image of encoding {original!r} is not supported",
        hint="supported: 16UC1 and 32FC1",
    )


def _image_record(
    stamp_ns: int, frame_id: str, encoding: str, decoded: tuple[str, NDArray[Any]]
) -> ImageRecord:
    kind, array = decoded
    return ImageRecord(stamp_ns, frame_id, kind, array, encoding)


def _ros_image(msg: Any, log_time_ns: int, topic: str) -> ImageRecord:
    decoded = decode_raw_image(
        topic,
        msg.encoding,
        int(msg.width),
        int(msg.height),
        int(msg.step),
        msg.data,
        big_endian=bool(msg.is_bigendian),
    )
    header = msg.header
    return _image_record(_header_stamp(header, log_time_ns), header.frame_id, msg.encoding, decoded)


def _ros_compressed_image(msg: Any, log_time_ns: int, topic: str) -> ImageRecord:
    decoded = decode_compressed_image(topic, msg.format, msg.data)
    header = msg.header
    return _image_record(_header_stamp(header, log_time_ns), header.frame_id, msg.format, decoded)


def _foxglove_raw_image(msg: Any, log_time_ns: int, topic: str) -> ImageRecord:
    encoding = str(_get(msg, "encoding", ""))
    decoded = decode_raw_image(
        topic,
        encoding,
        int(_get(msg, "width", 0)),
        int(_get(msg, "height", 0)),
        int(_get(msg, "step", 0)),
        _bytes(_get(msg, "data")),
    )
    stamp = _foxglove_stamp(msg, log_time_ns)
    return _image_record(stamp, str(_get(msg, "frame_id", "")), encoding, decoded)


def _foxglove_compressed_image(msg: Any, log_time_ns: int, topic: str) -> ImageRecord:
    fmt = str(_get(msg, "format", ""))
    decoded = decode_compressed_image(topic, fmt, _get(msg, "data"))
    stamp = _foxglove_stamp(msg, log_time_ns)
    return _image_record(stamp, str(_get(msg, "frame_id", "")), fmt, decoded)


# -- calibration ------------------------------------------------------------------------------


def camera_from_calibration(
    topic: str, width: int, height: int, k: Any, d: Any, model: str
) -> PinholeCamera:
    """A :class:`PinholeCamera` from a row-major 3x3 ``K`` (9 values) and coefficients ``d``.

    plumb_bob (k1, k2, p1, p2, k3) and rational_polynomial (k1, k2, p1, p2, k3, k4, k5, k6) are
    OpenCV's order already and are kept as given. Other models are refused unless all their
    coefficients are zero.
    """
    kk = np.asarray(k, dtype=np.float64).reshape(-1)
    if kk.size != 9:
        raise DecodeError(f"channel {topic}: camera matrix K has {kk.size} values, expected 9")
    fx, cx, fy, cy = float(kk[0]), float(kk[2]), float(kk[4]), float(kk[5])
    if not (fx > 0 and fy > 0):
        raise DecodeError(
            f"channel {topic}: camera is not calibrated (fx={fx:g}, fy={fy:g})",
            hint="use a calibrated camera_info topic or give the camera explicitly",
        )
    distortion = tuple(float(x) for x in np.asarray(d, dtype=np.float64).reshape(-1))
    if model.strip().lower() not in _OPENCV_DISTORTION_MODELS and any(distortion):
        raise DecodeError(
            f"channel {topic}: distortion model {model!r} is not supported",
            hint="supported: plumb_bob, rational_polynomial (or undistorted images)",
        )
    return PinholeCamera(int(width), int(height), fx, fy, cx, cy, distortion)


def _ros_camera_info(msg: Any, log_time_ns: int, topic: str) -> CameraInfoRecord:
    # ROS 1 spells the calibration fields in upper case.
    k = msg.k if hasattr(msg, "k") else msg.K
    d = msg.d if hasattr(msg, "d") else msg.D
    camera = camera_from_calibration(topic, msg.width, msg.height, k, d, msg.distortion_model)
    header = msg.header
    return CameraInfoRecord(_header_stamp(header, log_time_ns), header.frame_id, camera)


def _foxglove_camera_calibration(msg: Any, log_time_ns: int, topic: str) -> CameraInfoRecord:
    camera = camera_from_calibration(
        topic,
        int(_get(msg, "width", 0)),
        int(_get(msg, "height", 0)),
        list(_get(msg, "K", ())),
        list(_get(msg, "D", ())),
        str(_get(msg, "distortion_model", "")),
    )
    stamp = _foxglove_stamp(msg, log_time_ns)
    return CameraInfoRecord(stamp, str(_get(msg, "frame_id", "")), camera)


# -- poses, transforms, motion ----------------------------------------------------------------


def _ros_odometry(msg: Any, log_time_ns: int, topic: str) -> PoseRecord:
    pose = msg.pose.pose
    twist = msg.twist.twist
    header = msg.header
    return PoseRecord(
        _header_stamp(header, log_time_ns),
        header.frame_id,
        msg.child_frame_id,
        _pose(pose.position, pose.orientation),
        (float(twist.linear.x), float(twist.angular.z)),
    )


def _ros_pose_stamped(msg: Any, log_time_ns: int, topic: str) -> PoseRecord:
    header = msg.header
    pose = msg.pose
    return PoseRecord(
        _header_stamp(header, log_time_ns),
        header.frame_id,
        "",
        _pose(pose.position, pose.orientation),
    )


def _ros_pose_with_covariance_stamped(msg: Any, log_time_ns: int, topic: str) -> PoseRecord:
    header = msg.header
    pose = msg.pose.pose
    return PoseRecord(
        _header_stamp(header, log_time_ns),
        header.frame_id,
        "",
        _pose(pose.position, pose.orientation),
    )


def is_static_tf_topic(topic: str) -> bool:
    """Whether a transform topic carries static transforms (``/tf_static``, ``/ns/tf_static``)."""
    return topic.rstrip("/").rsplit("/", 1)[-1] == "tf_static"


def _ros_tf(msg: Any, log_time_ns: int, topic: str) -> TransformRecord:
    poses = tuple(
        PoseRecord(
            _header_stamp(t.header, log_time_ns),
            t.header.frame_id,
            t.child_frame_id,
            _pose(t.transform.translation, t.transform.rotation),
        )
        for t in msg.transforms
    )
    return TransformRecord(poses, is_static_tf_topic(topic))


def _ros_imu(msg: Any, log_time_ns: int, topic: str) -> ImuFrame:
    # REP 145: element 0 of a covariance set to -1 means the sensor does not provide that part.
    accel = gyro = None
    if msg.linear_acceleration_covariance[0] != -1.0:
        a = msg.linear_acceleration
        accel = np.array([a.x, a.y, a.z], dtype=np.float64)
    if msg.angular_velocity_covariance[0] != -1.0:
        w = msg.angular_velocity
        gyro = np.array([w.x, w.y, w.z], dtype=np.float64)
    return ImuFrame(_header_stamp(msg.header, log_time_ns), accel, gyro)


def _ros_twist(msg: Any, log_time_ns: int, topic: str) -> TwistRecord:
    return TwistRecord(log_time_ns, float(msg.linear.x), float(msg.angular.z))


def _ros_twist_stamped(msg: Any, log_time_ns: int, topic: str) -> TwistRecord:
    twist = msg.twist
    return TwistRecord(
        _header_stamp(msg.header, log_time_ns), float(twist.linear.x), float(twist.angular.z)
    )


def _foxglove_pose_in_frame(msg: Any, log_time_ns: int, topic: str) -> PoseRecord:
    pose = _get(msg, "pose", {})
    return PoseRecord(
        _foxglove_stamp(msg, log_time_ns),
        str(_get(msg, "frame_id", "")),
        "",
        _pose(_get(pose, "position", {}), _get(pose, "orientation", {})),
    )


def _foxglove_transform_pose(msg: Any, log_time_ns: int) -> PoseRecord:
    return PoseRecord(
        _foxglove_stamp(msg, log_time_ns),
        str(_get(msg, "parent_frame_id", "")),
        str(_get(msg, "child_frame_id", "")),
        _pose(_get(msg, "translation", {}), _get(msg, "rotation", {})),
    )


def _foxglove_frame_transform(msg: Any, log_time_ns: int, topic: str) -> TransformRecord:
    return TransformRecord((_foxglove_transform_pose(msg, log_time_ns),), is_static_tf_topic(topic))


def _foxglove_frame_transforms(msg: Any, log_time_ns: int, topic: str) -> TransformRecord:
    poses = tuple(
        _foxglove_transform_pose(t, log_time_ns) for t in _get(msg, "transforms", ()) or ()
    )
    return TransformRecord(poses, is_static_tf_topic(topic))


# -- laser scans ------------------------------------------------------------------------------


def scan_record(
    topic: str,
    stamp_ns: int,
    frame_id: str,
    ranges: Any,
    angle_min: float,
    angle_max: float,
    angle_increment: float,
    range_limits: tuple[float, float],
    frame_from_scan: NDArray[np.float64] | None = None,
) -> ScanRecord:
    """A checked :class:`ScanRecord` of one sweep (mounting zero until tf gives it).

    Args:
        topic: for error messages.
        stamp_ns: the sweep's stamp.
        frame_id: the frame the sweep was taken in.
        ranges: (N,) metres, anything numpy turns into float32 (kept as recorded).
        angle_min, angle_max: angles of the first and last beam, radians.
        angle_increment: angle between beams, radians (negative for a clockwise scanner).
        range_limits: (range_min, range_max) metres.
        frame_from_scan: (4, 4) pose of the scan's origin in ``frame_id``, where the message
            has one.

    Raises:
        DecodeError: no ranges, a zero or non-finite increment or angle, ranges that do not
            span ``angle_min`` to ``angle_max`` within one increment, or a range interval that
            is not one.
    """
    try:
        r = np.array(ranges, dtype=np.float32).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise DecodeError(f"channel {topic}: a scan's ranges are not numbers ({exc})") from None
    n = r.size
    inc, first, last = float(angle_increment), float(angle_min), float(angle_max)
    where = f"channel {topic}: a scan"
    if n == 0:
        raise DecodeError(f"{where} has no ranges")
    if not (math.isfinite(inc) and inc != 0.0):
        raise DecodeError(
            f"{where} has angle_increment {inc:g}; it must be a non-zero finite number",
            hint="the driver wrote a broken message; it is skipped",
        )
    if not (math.isfinite(first) and math.isfinite(last)):
        raise DecodeError(f"{where} has angles {first:g} to {last:g}; they must be finite")
    end = first + (n - 1) * inc
    if abs(end - last) > abs(inc) * _ANGLE_SLACK:
        expected = round((last - first) / inc) + 1
        raise DecodeError(
            f"{where} has {n} ranges, which from angle_min {first:.6g} by {inc:.6g} rad end at "
            f"{end:.6g} rad, not at angle_max {last:.6g} rad (that would take {expected} ranges)",
            hint="the ranges do not match the angles; the scan is skipped",
        )
    low, high = (float(v) for v in range_limits)
    if math.isnan(low) or math.isnan(high) or low > high:
        raise DecodeError(f"{where} has range_min {low:g} and range_max {high:g}")
    scan = ScanFrame(stamp_ns, r, first, inc, low, high, name=f"{topic}@{stamp_ns}")
    return ScanRecord(frame_id, scan, frame_from_scan)


def _ros_laser_scan(msg: Any, log_time_ns: int, topic: str) -> ScanRecord:
    header = msg.header
    return scan_record(
        topic,
        _header_stamp(header, log_time_ns),
        header.frame_id,
        msg.ranges,
        msg.angle_min,
        msg.angle_max,
        msg.angle_increment,
        (msg.range_min, msg.range_max),
    )


def _foxglove_laser_scan(msg: Any, log_time_ns: int, topic: str) -> ScanRecord:
    # JSON has no NaN: a beam without a value is null there.
    ranges = [math.nan if v is None else v for v in _get(msg, "ranges", ()) or ()]
    start, end = float(_get(msg, "start_angle", 0.0)), float(_get(msg, "end_angle", 0.0))
    # Foxglove gives the first and last bearing; one beam has no increment to give.
    inc = (end - start) / (len(ranges) - 1) if len(ranges) > 1 else math.nan
    pose = _get(msg, "pose")
    origin = None
    if pose:
        origin = _pose(_get(pose, "position", {}), _get(pose, "orientation", {}))
    return scan_record(
        topic,
        _foxglove_stamp(msg, log_time_ns),
        str(_get(msg, "frame_id", "")),
        ranges,
        start,
        end,
        inc,
        (_FOXGLOVE_RANGE_MIN, math.inf),
        origin,
    )


ADAPTERS: dict[str, Adapter] = {
    "sensor_msgs/msg/Image": _ros_image,
    "sensor_msgs/msg/CompressedImage": _ros_compressed_image,
    "sensor_msgs/msg/CameraInfo": _ros_camera_info,
    "sensor_msgs/msg/Imu": _ros_imu,
    "sensor_msgs/msg/LaserScan": _ros_laser_scan,
    "nav_msgs/msg/Odometry": _ros_odometry,
    "geometry_msgs/msg/PoseStamped": _ros_pose_stamped,
    "geometry_msgs/msg/PoseWithCovarianceStamped": _ros_pose_with_covariance_stamped,
    "geometry_msgs/msg/Twist": _ros_twist,
    "geometry_msgs/msg/TwistStamped": _ros_twist_stamped,
    "tf2_msgs/msg/TFMessage": _ros_tf,
    "tf/msg/tfMessage": _ros_tf,
    "foxglove.RawImage": _foxglove_raw_image,
    "foxglove.CompressedImage": _foxglove_compressed_image,
    "foxglove.CameraCalibration": _foxglove_camera_calibration,
    "foxglove.PoseInFrame": _foxglove_pose_in_frame,
    "foxglove.FrameTransform": _foxglove_frame_transform,
    "foxglove.FrameTransforms": _foxglove_frame_transforms,
    "foxglove.LaserScan": _foxglove_laser_scan,
    LANDMARK_SCHEMA_NAME: landmark_frame,
}
"""Adapters keyed by normalised schema name (see :func:`normalize_schema_name`)."""


def adapter_for(schema_name: str) -> Adapter | None:
    """The adapter for a schema (ROS 1, ROS 2 or Foxglove name), or None if there is none."""
    return ADAPTERS.get(normalize_schema_name(schema_name))
