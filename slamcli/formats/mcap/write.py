"""Writing MCAP logs: RGB-D sources and landmark runs as ROS 2 or Foxglove messages, run results.

Three writers share one small MCAP layer (zstd chunks, one schema per type, one channel per topic,
``log_time`` = ``publish_time`` = the data's own stamp, messages in log-time order so chunks
never overlap in time):

* :func:`write_source_mcap` turns a source (a TUM RGB-D folder) into a log a robot could have
  recorded. ``flavor="ros2"`` writes CDR messages with ``ros2msg`` schemas (the full definition
  text with its dependencies, as ``ros2 bag record`` stores it); ``flavor="foxglove"`` writes
  JSON messages with the official Foxglove JSON schemas (``schema_encoding="jsonschema"``,
  ``message_encoding="json"``, binary fields base64 as Foxglove's JSON convention has it).
* :func:`write_landmark_log` turns a landmark run (a ``slamcli synth landmarks`` folder, or the
  same data in memory as a :class:`~slamcli.formats.landmarks.LandmarkLog`) into a log for
  ``slamcli run ekf``: odometry on ``/odom`` (``nav_msgs/msg/Odometry``, CDR, in both flavours:
  Foxglove has no message for velocities), observations on ``/landmarks``
  (``slamcli.LandmarkObservations``, JSON, see :mod:`slamcli.formats.mcap.observations`) and ground
  truth on ``/ground_truth`` (``geometry_msgs/msg/PoseStamped``; foxglove: ``foxglove.PoseInFrame``
  plus world -> ``base_link`` on ``/tf``). Each odometry message's twist is the control applied
  from its stamp to the next (``linear.x`` = v, ``angular.z`` = omega); its pose is the dead
  reckoning of the controls before it (exact arc integration from x = y = yaw = 0 in ``odom``), as
  a wheel-odometry node would publish.
* :func:`write_result_log` / :func:`write_result_mcap` turn a SLAM result or a run folder into a
  ``result.mcap`` a user drags into Foxglove: the trajectory, the occupancy map, the point
  cloud and the mesh (a GLB model inside a ``foxglove.SceneUpdate``).

Topics of a converted source (named as a RealSense or OpenNI driver names them), ros2 type /
foxglove type:

- ``/camera/color/image_raw``: ``sensor_msgs/msg/Image`` rgb8 / ``foxglove.RawImage`` rgb8
- ``/camera/color/image_raw/compressed`` (when compressing): ``sensor_msgs/msg/CompressedImage``
  / ``foxglove.CompressedImage``, format ``jpeg`` or ``png``
- ``/camera/depth/image_raw``: ``sensor_msgs/msg/Image`` / ``foxglove.RawImage``, 16UC1 or 32FC1
- ``/camera/depth/image_raw/compressedDepth`` (ros2, compressing 16UC1):
  ``sensor_msgs/msg/CompressedImage``
- ``/camera/color/camera_info``: ``sensor_msgs/msg/CameraInfo`` / ``foxglove.CameraCalibration``
- ``/groundtruth``: ``geometry_msgs/msg/PoseStamped`` / ``foxglove.PoseInFrame``, in ``world``
- ``/tf`` (foxglove): ``foxglove.FrameTransform`` world -> ``camera_color_optical_frame``
- ``/imu`` (ros2; Foxglove has no IMU schema): ``sensor_msgs/msg/Imu``, acceleration only

Depth encodings: ``16UC1`` is millimetres (the ROS convention for 16-bit depth), rounded to the
nearest millimetre, so TUM's 0.2 mm raw steps are lost (at most 0.5 mm off); ``32FC1`` is float32
metres, bit-identical to the source's depth. Compressed depth (ros2 only) is
``"16UC1; compressedDepth png"``: the 12-byte ``compressed_depth_image_transport`` header
(int32 format 0 and two float32 quantisation parameters, 0 and 0, which 16-bit depth does not
use) followed by a lossless 16-bit PNG of the millimetres. Foxglove's ``CompressedImage`` has no
depth convention (browsers decode a 16-bit PNG to 8 bits), so the foxglove flavour keeps depth
raw, and ``32FC1`` depth stays raw in both flavours because it is chosen for exactness.
"""

from __future__ import annotations

import abc
import base64
import contextlib
import heapq
import json
import logging
import math
import struct
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import cache
from importlib import resources
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from slamcli.atomic import atomic_path
from slamcli.errors import ConfigError, ExportError
from slamcli.formats.landmarks import LandmarkLog, read_landmark_log
from slamcli.formats.mcap.observations import (
    MESSAGE_ENCODING as LANDMARK_MESSAGE_ENCODING,
)
from slamcli.formats.mcap.observations import (
    SCHEMA_ENCODING as LANDMARK_SCHEMA_ENCODING,
)
from slamcli.formats.mcap.observations import (
    SCHEMA_NAME as LANDMARK_SCHEMA_NAME,
)
from slamcli.formats.mcap.observations import landmark_message, landmark_schema
from slamcli.formats.mesh import mesh_to_glb
from slamcli.formats.run_folder import RESULT_KINDS, RUN_FILES, read_run
from slamcli.geometry.planar import integrate_unicycle, wrap_angle
from slamcli.types import (
    ImuFrame,
    OccupancyGrid,
    PinholeCamera,
    ProgressFn,
    RgbdFrame,
    SlamResult,
    Trajectory,
    TriangleMesh,
)

if TYPE_CHECKING:
    from slamcli.formats.base import Source

log = logging.getLogger(__name__)

FLAVORS = ("ros2", "foxglove")
IMAGE_COMPRESSIONS = ("none", "jpeg", "png")
DEPTH_ENCODINGS = ("16UC1", "32FC1")

WORLD_FRAME = "world"
CAMERA_FRAME = "camera_color_optical_frame"
IMU_FRAME = "camera_accel_frame"
"""The Kinect's accelerometer frame: TUM records its readings as the sensor gave them."""
RESULT_CAMERA_FRAME = "camera"

TOPIC_COLOR = "/camera/color/image_raw"
TOPIC_COLOR_COMPRESSED = "/camera/color/image_raw/compressed"
TOPIC_DEPTH = "/camera/depth/image_raw"
TOPIC_DEPTH_COMPRESSED = "/camera/depth/image_raw/compressedDepth"
TOPIC_CAMERA_INFO = "/camera/color/camera_info"
TOPIC_GROUNDTRUTH = "/groundtruth"
TOPIC_TF = "/tf"
TOPIC_IMU = "/imu"

TOPIC_ODOM = "/odom"
TOPIC_LANDMARKS = "/landmarks"
TOPIC_GROUND_TRUTH = "/ground_truth"
ODOM_FRAME = "odom"
BODY_FRAME = "base_link"

TOPIC_RESULT_POSE = "/slamcli/pose"
TOPIC_RESULT_MAP = "/slamcli/map"
TOPIC_RESULT_POINTS = "/slamcli/points"
TOPIC_RESULT_MESH = "/slamcli/mesh"

COMPRESSED_DEPTH_FORMAT = "16UC1; compressedDepth png"
_COMPRESSED_DEPTH_HEADER = struct.pack("<iff", 0, 0.0, 0.0)
_MM_MAX = 65535
_REORDER_WINDOW_NS = 500_000_000
"""A source's frames arrive in colour-stamp order; a paired depth image (and the readings
between the two stamps) may be stamped up to this long before its colour image."""

# Foxglove's NumericType enum values (PackedElementField.type).
_UINT8, _INT8, _FLOAT32 = 1, 2, 7

# Foxglove turns glTF's Y-up into its Z-up by rotating every model +90° about x; a model pose
# of -90° about x undoes that, so the GLB keeps the mesh's own coordinates.
_GLTF_TO_WORLD_XYZW = (-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5))


@dataclass
class McapWriteSummary:
    """What a writer put into a log.

    Attributes:
        path: the MCAP file written.
        topics: topic -> (schema name, message count), in the order channels were created.
        frames: RGB-D frames written (0 for result logs).
        skipped: frames the source skipped because an image was missing or unreadable.
    """

    path: Path
    topics: dict[str, tuple[str, int]] = field(default_factory=dict)
    frames: int = 0
    skipped: int = 0


def check_choice(name: str, value: str, allowed: tuple[str, ...]) -> str:
    """Return ``value`` if it is one of ``allowed``; else a :class:`ConfigError` naming them."""
    if value not in allowed:
        raise ConfigError(f"{name} must be one of {', '.join(allowed)}, got {value!r}")
    return value


# --------------------------------------------------------------------------------------------
# The MCAP layer


class _Log:
    """Schemas and channels registered on first use; messages written in log-time order.

    Messages wait in a small heap until :meth:`release` is told that nothing older will come,
    so the chunks' time ranges do not overlap even where a source delivers a depth image
    stamped a few milliseconds before the colour image it was paired with.
    """

    def __init__(self, stream: IO[bytes], profile: str) -> None:
        from mcap.writer import CompressionType, Writer

        from slamcli import __version__

        self._writer = Writer(stream, compression=CompressionType.ZSTD)
        self._writer.start(profile=profile, library=f"slamcli {__version__}")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._schema_of: dict[str, str] = {}
        self._pending: list[tuple[int, int, int, int, bytes]] = []
        self._order = 0
        self.counts: dict[str, int] = {}

    def add(
        self,
        topic: str,
        schema: tuple[str, str, bytes],
        message_encoding: str,
        stamp_ns: int,
        data: bytes,
    ) -> None:
        """Queue one message; ``schema`` is (name, encoding, definition bytes)."""
        if stamp_ns < 0:
            raise ExportError(
                f"{topic}: timestamp {stamp_ns} ns is before 1970; MCAP log times are unsigned",
                hint="shift the input's timestamps to positive values",
            )
        channel = self._channels.get(topic)
        if channel is None:
            name, encoding, definition = schema
            schema_id = self._schemas.get(name)
            if schema_id is None:
                schema_id = self._writer.register_schema(name, encoding, definition)
                self._schemas[name] = schema_id
            channel = self._writer.register_channel(topic, message_encoding, schema_id)
            self._channels[topic] = channel
            self._schema_of[topic] = name
            self.counts[topic] = 0
        heapq.heappush(self._pending, (stamp_ns, self._order, channel, self.counts[topic], data))
        self._order += 1
        self.counts[topic] += 1

    def release(self, before_ns: int | None = None) -> None:
        """Write the queued messages stamped before ``before_ns`` (None: all of them)."""
        pending = self._pending
        while pending and (before_ns is None or pending[0][0] < before_ns):
            stamp, _, channel, sequence, data = heapq.heappop(pending)
            self._writer.add_message(
                channel, log_time=stamp, data=data, publish_time=stamp, sequence=sequence
            )

    def finish(self) -> None:
        self.release()
        self._writer.finish()

    def topics(self) -> dict[str, tuple[str, int]]:
        return {t: (self._schema_of[t], n) for t, n in self.counts.items()}


def _check_out(out: Path, force: bool) -> None:
    if out.is_dir():
        raise ExportError(
            f"{out}: is a folder", hint="give the path of the .mcap file to write, e.g. out.mcap"
        )
    if out.exists() and not force:
        raise ExportError(
            f"{out}: already exists", hint="pass --force to overwrite it, or choose another output"
        )


@contextlib.contextmanager
def _open_log(out: Path, profile: str, force: bool) -> Iterator[_Log]:
    """A log written to a temporary file that replaces ``out`` only once it is complete."""
    _check_out(out, force)
    with atomic_path(out) as tmp, tmp.open("wb") as stream:
        mcap_log = _Log(stream, profile)
        yield mcap_log
        mcap_log.finish()


# --------------------------------------------------------------------------------------------
# Conversions shared by both flavours


def depth_to_millimetres(depth_m: NDArray[np.floating[Any]]) -> NDArray[np.uint16]:
    """(H, W) metres -> (H, W) uint16 millimetres, rounded; NaN, <= 0 or > 65.535 m -> 0."""
    mm = np.rint(np.asarray(depth_m, dtype=np.float64) * 1000.0)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(mm) & (mm > 0) & (mm <= _MM_MAX)
    return np.where(ok, mm, 0.0).astype(np.uint16)


def _imencode(ext: str, image: NDArray[Any], params: list[int]) -> bytes:
    import cv2

    ok, buf = cv2.imencode(ext, image, params)
    if not ok:
        raise ExportError(f"OpenCV could not encode a {image.shape} {image.dtype} image as {ext}")
    return bytes(buf)


def _encode_color(rgb: NDArray[np.uint8], fmt: str, jpeg_quality: int) -> bytes:
    """(H, W, 3) RGB -> JPEG or PNG bytes."""
    import cv2

    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    if fmt == "jpeg":
        return _imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
    return _imencode(".png", bgr, [])


def _compressed_depth(mm: NDArray[np.uint16]) -> bytes:
    """The ``compressedDepth png`` payload: the 12-byte header, then a 16-bit PNG."""
    return _COMPRESSED_DEPTH_HEADER + _imencode(".png", mm, [])


def _depth_bytes(depth_m: NDArray[np.float32], encoding: str) -> tuple[bytes, int]:
    """Raw little-endian depth bytes and bytes per pixel for ``16UC1`` (mm) or ``32FC1`` (m)."""
    if encoding == "16UC1":
        return depth_to_millimetres(depth_m).astype("<u2").tobytes(), 2
    return np.ascontiguousarray(depth_m, dtype="<f4").tobytes(), 4


def _camera_model(camera: PinholeCamera) -> tuple[str, list[float], list[float], list[float]]:
    """(distortion model, D, K row-major, P row-major) as ROS and Foxglove store them."""
    d = [float(c) for c in camera.distortion]
    if len(d) <= 5:
        model, d = "plumb_bob", d + [0.0] * (5 - len(d))
    elif len(d) == 8:
        model = "rational_polynomial"
    else:
        raise ExportError(
            f"camera has {len(d)} distortion coefficients; CameraInfo takes 5 (plumb_bob) or "
            "8 (rational_polynomial)"
        )
    k = camera.K.reshape(-1).tolist()
    p = np.hstack([camera.K, np.zeros((3, 1))]).reshape(-1).tolist()
    return model, d, k, p


def _split_ns(stamp_ns: int) -> tuple[int, int]:
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return sec, nsec


def _pose_parts(world_from_body: NDArray[np.float64]) -> tuple[list[float], list[float]]:
    """(4, 4) pose -> translation [x, y, z] (m) and unit quaternion [x, y, z, w]."""
    from slamcli.geometry import matrix_to_quat_xyzw

    t = world_from_body[:3, 3].tolist()
    q = matrix_to_quat_xyzw(world_from_body[:3, :3]).tolist()
    return t, q


# --------------------------------------------------------------------------------------------
# Foxglove JSON


@cache
def foxglove_schema(name: str) -> bytes:
    """The official Foxglove JSON schema of ``foxglove.<name>`` (package data, MIT licence)."""
    path = resources.files("slamcli.formats.mcap") / "foxglove_schemas" / f"{name}.json"
    try:
        return path.read_bytes()
    except FileNotFoundError as exc:
        raise ExportError(f"no Foxglove JSON schema for foxglove.{name} in slamcli") from exc


def _fox_time(stamp_ns: int) -> dict[str, int]:
    sec, nsec = _split_ns(stamp_ns)
    return {"sec": sec, "nsec": nsec}


def _fox_pose(
    t: list[float] | tuple[float, ...], q: list[float] | tuple[float, ...]
) -> dict[str, Any]:
    return {
        "position": {"x": t[0], "y": t[1], "z": t[2]},
        "orientation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
    }


_IDENTITY_POSE = _fox_pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


def _put_json(mcap_log: _Log, topic: str, name: str, stamp_ns: int, msg: dict[str, Any]) -> None:
    """Write ``msg`` as a ``foxglove.<name>`` JSON message."""
    try:
        data = json.dumps(msg, separators=(",", ":"), allow_nan=False).encode()
    except ValueError as exc:
        raise ExportError(f"{topic}: a foxglove.{name} message holds a non-finite number") from exc
    mcap_log.add(
        topic, (f"foxglove.{name}", "jsonschema", foxglove_schema(name)), "json", stamp_ns, data
    )


# --------------------------------------------------------------------------------------------
# Source conversion: one class per flavour, the same methods


class _FrameWriter(abc.ABC):
    """Writes the messages of RGB-D frames, ground-truth poses and IMU readings."""

    def __init__(
        self, mcap_log: _Log, compress: str, depth_encoding: str, jpeg_quality: int
    ) -> None:
        self.log = mcap_log
        self.compress = compress
        self.depth_encoding = depth_encoding
        self.jpeg_quality = jpeg_quality

    @abc.abstractmethod
    def rgbd(self, frame: RgbdFrame) -> None:
        """Write a frame's camera info, colour and depth."""

    @abc.abstractmethod
    def pose(self, stamp_ns: int, world_from_camera: NDArray[np.float64]) -> None:
        """Write one ground-truth pose of the colour camera in ``world``."""

    @abc.abstractmethod
    def imu(self, frame: ImuFrame) -> bool:
        """Write one IMU reading; False when the flavour has no message for it."""


class _Ros2Writer(_FrameWriter):
    """ROS 2 messages, CDR-encoded, with the ``ros2msg`` definitions ``ros2 bag`` stores."""

    def __init__(
        self, mcap_log: _Log, compress: str, depth_encoding: str, jpeg_quality: int
    ) -> None:
        from rosbags.typesys import Stores, get_typestore

        super().__init__(mcap_log, compress, depth_encoding, jpeg_quality)
        self.store = get_typestore(Stores.ROS2_HUMBLE)
        self.t = self.store.types
        self._schemas: dict[str, tuple[str, str, bytes]] = {}

    def _put(self, topic: str, stamp_ns: int, msg: Any) -> None:
        typename = msg.__msgtype__
        schema = self._schemas.get(typename)
        if schema is None:
            text, _ = self.store.generate_msgdef(typename, ros_version=2)
            schema = self._schemas[typename] = (typename, "ros2msg", text.encode())
        self.log.add(topic, schema, "cdr", stamp_ns, bytes(self.store.serialize_cdr(msg, typename)))

    def _header(self, stamp_ns: int, frame_id: str) -> Any:
        sec, nsec = _split_ns(stamp_ns)
        time = self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        return self.t["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)

    def _image(self, stamp_ns: int, h: int, w: int, encoding: str, data: bytes) -> Any:
        return self.t["sensor_msgs/msg/Image"](
            header=self._header(stamp_ns, CAMERA_FRAME),
            height=h,
            width=w,
            encoding=encoding,
            is_bigendian=0,
            step=len(data) // h,
            data=np.frombuffer(data, dtype=np.uint8),
        )

    def _compressed(self, stamp_ns: int, fmt: str, data: bytes) -> Any:
        return self.t["sensor_msgs/msg/CompressedImage"](
            header=self._header(stamp_ns, CAMERA_FRAME),
            format=fmt,
            data=np.frombuffer(data, dtype=np.uint8),
        )

    def rgbd(self, frame: RgbdFrame) -> None:
        t = frame.stamp_ns
        depth_t = frame.depth_stamp_ns if frame.depth_stamp_ns is not None else t
        h, w = frame.rgb.shape[:2]
        self._put(TOPIC_CAMERA_INFO, t, self._camera_info(t, frame.camera))
        if self.compress == "none":
            rgb = np.ascontiguousarray(frame.rgb).tobytes()
            self._put(TOPIC_COLOR, t, self._image(t, h, w, "rgb8", rgb))
        else:
            data = _encode_color(frame.rgb, self.compress, self.jpeg_quality)
            self._put(TOPIC_COLOR_COMPRESSED, t, self._compressed(t, self.compress, data))
        if self.compress != "none" and self.depth_encoding == "16UC1":
            data = _compressed_depth(depth_to_millimetres(frame.depth_m))
            msg = self._compressed(depth_t, COMPRESSED_DEPTH_FORMAT, data)
            self._put(TOPIC_DEPTH_COMPRESSED, depth_t, msg)
        else:
            raw, _ = _depth_bytes(frame.depth_m, self.depth_encoding)
            self._put(TOPIC_DEPTH, depth_t, self._image(depth_t, h, w, self.depth_encoding, raw))

    def _camera_info(self, stamp_ns: int, camera: PinholeCamera) -> Any:
        model, d, k, p = _camera_model(camera)
        roi = self.t["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        return self.t["sensor_msgs/msg/CameraInfo"](
            header=self._header(stamp_ns, CAMERA_FRAME),
            height=camera.height,
            width=camera.width,
            distortion_model=model,
            d=np.asarray(d, dtype=np.float64),
            k=np.asarray(k, dtype=np.float64),
            r=np.eye(3).reshape(-1),
            p=np.asarray(p, dtype=np.float64),
            binning_x=0,
            binning_y=0,
            roi=roi,
        )

    def _pose(self, t: Sequence[float], q: Sequence[float]) -> Any:
        """A ``geometry_msgs/msg/Pose`` from a translation and an xyzw quaternion."""
        (x, y, z), (qx, qy, qz, qw) = t, q
        return self.t["geometry_msgs/msg/Pose"](
            position=self.t["geometry_msgs/msg/Point"](x=x, y=y, z=z),
            orientation=self.t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
        )

    def pose(self, stamp_ns: int, world_from_camera: NDArray[np.float64]) -> None:
        self.pose_stamped(TOPIC_GROUNDTRUTH, stamp_ns, *_pose_parts(world_from_camera))

    def pose_stamped(
        self, topic: str, stamp_ns: int, t: Sequence[float], q: Sequence[float]
    ) -> None:
        """A ``geometry_msgs/msg/PoseStamped`` in ``world``: translation, xyzw quaternion."""
        msg = self.t["geometry_msgs/msg/PoseStamped"](
            header=self._header(stamp_ns, WORLD_FRAME), pose=self._pose(t, q)
        )
        self._put(topic, stamp_ns, msg)

    def odometry(
        self, stamp_ns: int, x: float, y: float, yaw: float, v: float, omega: float
    ) -> None:
        """A ``nav_msgs/msg/Odometry`` on ``/odom``: planar pose in ``odom``, twist v and omega."""
        pose = self._pose((x, y, 0.0), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)))
        vector3 = self.t["geometry_msgs/msg/Vector3"]
        twist = self.t["geometry_msgs/msg/Twist"](
            linear=vector3(x=float(v), y=0.0, z=0.0), angular=vector3(x=0.0, y=0.0, z=float(omega))
        )
        msg = self.t["nav_msgs/msg/Odometry"](
            header=self._header(stamp_ns, ODOM_FRAME),
            child_frame_id=BODY_FRAME,
            pose=self.t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=self.t["geometry_msgs/msg/TwistWithCovariance"](
                twist=twist, covariance=np.zeros(36)
            ),
        )
        self._put(TOPIC_ODOM, stamp_ns, msg)

    def imu(self, frame: ImuFrame) -> bool:
        vector3 = self.t["geometry_msgs/msg/Vector3"]
        # ROS convention: covariance element 0 = -1 marks a quantity the sensor does not give.
        unknown = np.zeros(9)
        unknown[0] = -1.0
        accel = frame.accel_mps2
        gyro = frame.gyro_radps
        msg = self.t["sensor_msgs/msg/Imu"](
            header=self._header(frame.stamp_ns, IMU_FRAME),
            orientation=self.t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=unknown.copy(),
            angular_velocity=vector3(*(gyro.tolist() if gyro is not None else (0.0,) * 3)),
            angular_velocity_covariance=np.zeros(9) if gyro is not None else unknown.copy(),
            linear_acceleration=vector3(*(accel.tolist() if accel is not None else (0.0,) * 3)),
            linear_acceleration_covariance=np.zeros(9) if accel is not None else unknown.copy(),
        )
        self._put(TOPIC_IMU, frame.stamp_ns, msg)
        return True


class _FoxgloveWriter(_FrameWriter):
    """Foxglove messages as JSON with the official JSON schemas; ground truth also on /tf."""

    def rgbd(self, frame: RgbdFrame) -> None:
        t = frame.stamp_ns
        depth_t = frame.depth_stamp_ns if frame.depth_stamp_ns is not None else t
        h, w = frame.rgb.shape[:2]
        model, d, k, p = _camera_model(frame.camera)
        calibration = {
            "timestamp": _fox_time(t),
            "frame_id": CAMERA_FRAME,
            "width": frame.camera.width,
            "height": frame.camera.height,
            "distortion_model": model,
            "D": d,
            "K": k,
            "R": np.eye(3).reshape(-1).tolist(),
            "P": p,
        }
        _put_json(self.log, TOPIC_CAMERA_INFO, "CameraCalibration", t, calibration)
        if self.compress == "none":
            rgb = np.ascontiguousarray(frame.rgb).tobytes()
            _put_json(self.log, TOPIC_COLOR, "RawImage", t, _raw_image(t, w, h, "rgb8", rgb))
        else:
            data = _encode_color(frame.rgb, self.compress, self.jpeg_quality)
            msg = {
                "timestamp": _fox_time(t),
                "frame_id": CAMERA_FRAME,
                "data": _b64(data),
                "format": self.compress,
            }
            _put_json(self.log, TOPIC_COLOR_COMPRESSED, "CompressedImage", t, msg)
        raw, _ = _depth_bytes(frame.depth_m, self.depth_encoding)
        msg = _raw_image(depth_t, w, h, self.depth_encoding, raw)
        _put_json(self.log, TOPIC_DEPTH, "RawImage", depth_t, msg)

    def pose(self, stamp_ns: int, world_from_camera: NDArray[np.float64]) -> None:
        _write_pose_and_tf(self.log, TOPIC_GROUNDTRUTH, CAMERA_FRAME, stamp_ns, world_from_camera)

    def imu(self, frame: ImuFrame) -> bool:
        return False


def _raw_image(stamp_ns: int, w: int, h: int, encoding: str, data: bytes) -> dict[str, Any]:
    return {
        "timestamp": _fox_time(stamp_ns),
        "frame_id": CAMERA_FRAME,
        "width": w,
        "height": h,
        "encoding": encoding,
        "step": len(data) // h,
        "data": _b64(data),
    }


def _write_pose_and_tf(
    mcap_log: _Log,
    pose_topic: str,
    child_frame: str,
    stamp_ns: int,
    world_from_child: NDArray[np.float64],
) -> None:
    """A ``foxglove.PoseInFrame`` on ``pose_topic`` and the same pose as a world->child tf."""
    t, q = _pose_parts(world_from_child)
    pose = {"timestamp": _fox_time(stamp_ns), "frame_id": WORLD_FRAME, "pose": _fox_pose(t, q)}
    _put_json(mcap_log, pose_topic, "PoseInFrame", stamp_ns, pose)
    tf = {
        "timestamp": _fox_time(stamp_ns),
        "parent_frame_id": WORLD_FRAME,
        "child_frame_id": child_frame,
        "translation": {"x": t[0], "y": t[1], "z": t[2]},
        "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
    }
    _put_json(mcap_log, TOPIC_TF, "FrameTransform", stamp_ns, tf)


class _PoseFeed:
    """Hands out ground-truth poses in time order, interleaved with the frames."""

    def __init__(self, trajectory: Trajectory | None, write: Callable[[int, Any], None]) -> None:
        if trajectory is None:
            self._stamps = np.zeros(0, dtype=np.int64)
            self._poses = np.zeros((0, 4, 4))
        else:
            self._stamps, self._poses = trajectory.stamps_ns, trajectory.world_from_body
        self._write = write
        self._next = 0
        self.written = 0

    def until(self, stamp_ns: int | None) -> None:
        """Write every pose stamped at or before ``stamp_ns`` (None: all that remain)."""
        end = (
            len(self._stamps)
            if stamp_ns is None
            else int(np.searchsorted(self._stamps, stamp_ns, side="right"))
        )
        for i in range(self._next, end):
            self._write(int(self._stamps[i]), self._poses[i])
        self.written += max(0, end - self._next)
        self._next = max(self._next, end)


def write_source_mcap(
    source: Source,
    out: str | Path,
    *,
    flavor: str = "ros2",
    compress_images: str = "none",
    depth_encoding: str = "16UC1",
    jpeg_quality: int = 90,
    max_frames: int | None = None,
    force: bool = False,
    progress: ProgressFn | None = None,
) -> McapWriteSummary:
    """Write a source's RGB-D frames, camera, ground truth and IMU readings as an MCAP log.

    Topics, message types and the depth encodings are listed in the module docstring. Every
    message is stamped with the data's own time (ns): the header stamp, ``log_time`` and
    ``publish_time`` are equal; depth carries the depth image's stamp, the camera info the
    colour image's. Ground-truth poses (the colour camera in ``world``) are interleaved with
    the frames in time order.

    Args:
        source: an open source (e.g. :class:`~slamcli.formats.tum_rgbd.TumRgbdSource`).
        out: the ``.mcap`` file; written to a temporary name and renamed into place when
            complete, so a failure leaves no partial file and an existing one untouched.
        flavor: ``"ros2"`` (CDR, ``ros2msg`` schemas) or ``"foxglove"`` (JSON, Foxglove
            JSON schemas).
        compress_images: ``"none"``, ``"jpeg"`` or ``"png"`` for colour; with ``16UC1`` in the
            ros2 flavour, depth is then written as ``compressedDepth`` PNG (lossless).
        depth_encoding: ``"16UC1"`` (millimetres) or ``"32FC1"`` (metres, exact).
        jpeg_quality: 1-100, for ``compress_images="jpeg"``.
        max_frames: stop after this many RGB-D frames; the log then ends at the last frame's
            stamp (ground truth and IMU after it are left out).
        force: replace an existing ``out``.
        progress: called as ``progress(frames_done, frames_total)``.

    Raises:
        ConfigError: a bad option value.
        ExportError: ``out`` exists without ``force``, or cannot be written.
        InputError: the source cannot be read.
    """
    check_choice("flavor", flavor, FLAVORS)
    check_choice("compress_images", compress_images, IMAGE_COMPRESSIONS)
    check_choice("depth_encoding", depth_encoding, DEPTH_ENCODINGS)
    if not 1 <= jpeg_quality <= 100:
        raise ConfigError(f"jpeg_quality must be 1-100, got {jpeg_quality}")
    if max_frames is not None and max_frames < 1:
        raise ConfigError(f"max_frames must be at least 1, got {max_frames}")
    out = Path(out)
    info = source.info()
    kinds = ["rgbd"]
    if any(s.kind == "imu" for s in info.streams):
        kinds.append("imu")
    total = info.frames if max_frames is None else min(info.frames, max_frames)
    summary = McapWriteSummary(out)
    imu_dropped = 0
    with _open_log(out, "ros2" if flavor == "ros2" else "", force) as mcap_log:
        cls = _Ros2Writer if flavor == "ros2" else _FoxgloveWriter
        writer = cls(mcap_log, compress_images, depth_encoding, jpeg_quality)
        poses = _PoseFeed(source.groundtruth(), writer.pose)
        last_stamp: int | None = None
        stopped_at: int | None = None
        for frame in source.frames(kinds):
            if max_frames is not None and summary.frames >= max_frames:
                stopped_at = last_stamp
                break
            mcap_log.release(frame.stamp_ns - _REORDER_WINDOW_NS)
            if isinstance(frame, RgbdFrame):
                poses.until(frame.stamp_ns)
                writer.rgbd(frame)
                summary.frames += 1
                last_stamp = frame.stamp_ns
                if progress is not None:
                    progress(summary.frames, total)
            elif isinstance(frame, ImuFrame):
                poses.until(frame.stamp_ns)
                if not writer.imu(frame):
                    imu_dropped += 1
        poses.until(stopped_at)
        summary.topics = mcap_log.topics()
    summary.skipped = source.stats.skipped
    if imu_dropped:
        log.info("%d IMU readings left out: Foxglove has no IMU schema", imu_dropped)
    log.info("wrote %s: %d frames, %d ground-truth poses", out, summary.frames, poses.written)
    return summary


# --------------------------------------------------------------------------------------------
# Landmark runs


def dead_reckon(stamps_ns: NDArray[np.int64], odometry: NDArray[np.float64]) -> NDArray[np.float64]:
    """(K, 3) x, y, yaw at each odometry stamp from x = y = yaw = 0 at the first.

    Each control (v, omega) is applied from its stamp to the next by exact arc integration
    (:func:`~slamcli.geometry.planar.integrate_unicycle`); the pose at stamp k is the result of
    controls 0 .. k-1. Yaw is wrapped to [-pi, pi).
    """
    dts = np.diff(np.asarray(stamps_ns, dtype=np.int64)) * 1e-9
    # No stamps, no poses: the slice drops the start pose integration always returns.
    poses = integrate_unicycle(np.zeros(3), odometry[: len(dts)], dts)[: len(stamps_ns)]
    poses[:, 2] = wrap_angle(poses[:, 2])
    return poses


def write_landmark_log(
    out: str | Path,
    data: str | Path | LandmarkLog,
    *,
    flavor: str = "ros2",
    force: bool = False,
) -> McapWriteSummary:
    """Write a landmark run as an MCAP log that ``slamcli run ekf`` reads.

    Topics and messages are listed in the module docstring. Every message is stamped with the
    data's own time: header / ``timestamp``, ``log_time`` and ``publish_time`` are equal; at
    equal stamps odometry is written before observations. Observations are grouped into one
    message per stamp, in the rows' order.

    Args:
        out: the ``.mcap`` file; written to a temporary name and renamed into place when
            complete, so a failure leaves no partial file and an existing one untouched.
        data: a landmark run folder (see :func:`~slamcli.formats.landmarks.read_landmark_log`)
            or a :class:`~slamcli.formats.landmarks.LandmarkLog`.
        flavor: ``"ros2"`` (profile ros2, PoseStamped ground truth) or ``"foxglove"``
            (``foxglove.PoseInFrame`` ground truth and ``/tf``). Odometry is CDR and
            observations JSON in both.
        force: replace an existing ``out``.

    Raises:
        ConfigError: a bad flavour. InputError: the folder cannot be read.
        ExportError: ``out`` exists without ``force``, or cannot be written.
    """
    check_choice("flavor", flavor, FLAVORS)
    out = Path(out)
    _check_out(out, force)
    run = data if isinstance(data, LandmarkLog) else read_landmark_log(data)
    odo_order = np.argsort(run.odometry_stamps_ns, kind="stable")
    odo_t = run.odometry_stamps_ns[odo_order]
    odo = run.odometry[odo_order]
    odom_xy_yaw = dead_reckon(odo_t, odo).tolist()
    meas_order = np.argsort(run.measurement_stamps_ns, kind="stable")
    meas_t = run.measurement_stamps_ns[meas_order]
    schema = (LANDMARK_SCHEMA_NAME, LANDMARK_SCHEMA_ENCODING, landmark_schema())
    with _open_log(out, "ros2" if flavor == "ros2" else "", force) as mcap_log:
        ros2 = _Ros2Writer(mcap_log, "none", "16UC1", 90)
        for k, stamp in enumerate(odo_t.tolist()):
            x, y, yaw = odom_xy_yaw[k]
            ros2.odometry(stamp, x, y, yaw, float(odo[k, 0]), float(odo[k, 1]))
        starts = np.flatnonzero(np.diff(meas_t, prepend=-1) != 0)
        for begin, end in zip(starts.tolist(), [*starts[1:].tolist(), len(meas_t)], strict=True):
            rows = meas_order[begin:end]
            stamp = int(meas_t[begin])
            msg = landmark_message(
                stamp,
                run.measurement_ids[rows].tolist(),
                run.measurement_ranges[rows].tolist(),
                run.measurement_bearings[rows].tolist(),
                BODY_FRAME,
            )
            try:
                payload = json.dumps(msg, separators=(",", ":"), allow_nan=False).encode()
            except ValueError as exc:
                raise ExportError(
                    f"{TOPIC_LANDMARKS}: an observation at {stamp} ns is not a finite number"
                ) from exc
            mcap_log.add(TOPIC_LANDMARKS, schema, LANDMARK_MESSAGE_ENCODING, stamp, payload)
        gt = run.groundtruth
        if gt is not None and flavor == "ros2":
            from slamcli.geometry import matrix_to_quat_xyzw

            quats = matrix_to_quat_xyzw(gt.world_from_body[:, :3, :3]).tolist()
            positions = gt.positions.tolist()
            for stamp, t, q in zip(gt.stamps_ns.tolist(), positions, quats, strict=True):
                ros2.pose_stamped(TOPIC_GROUND_TRUTH, stamp, t, q)
        elif gt is not None:
            for stamp, pose in zip(gt.stamps_ns.tolist(), gt.world_from_body, strict=True):
                _write_pose_and_tf(mcap_log, TOPIC_GROUND_TRUTH, BODY_FRAME, stamp, pose)
        topics = mcap_log.topics()
    log.info(
        "wrote %s: %d odometry, %d observation messages",
        out,
        topics.get(TOPIC_ODOM, ("", 0))[1],
        topics.get(TOPIC_LANDMARKS, ("", 0))[1],
    )
    return McapWriteSummary(out, topics)


# --------------------------------------------------------------------------------------------
# Result logs


def write_result_log(
    out: str | Path, result: SlamResult, *, force: bool = False
) -> McapWriteSummary:
    """Write a SLAM result as an MCAP log that opens in Foxglove (JSON, official schemas).

    Topics: ``/slamcli/pose`` (``foxglove.PoseInFrame`` per pose, in ``world``) and ``/tf``
    (``foxglove.FrameTransform`` world -> ``camera``) from the trajectory; ``/slamcli/map``
    (``foxglove.Grid``), ``/slamcli/points`` (``foxglove.PointCloud``) and ``/slamcli/mesh``
    (``foxglove.SceneUpdate`` with the mesh as a GLB model, vertex colours kept), each once at
    the trajectory's first stamp (0 without a trajectory). The run calls this at its end for
    ``--mcap``; :func:`write_result_mcap` does the same from a run folder's files.

    The grid's cells carry ``occupancy`` (int8: 0-100 percent, -1 unknown, as
    ``nav_msgs/OccupancyGrid``) and ``red``/``green``/``blue``/``alpha`` (uint8: free white,
    occupied black, unknown grey) so Foxglove shows it like a map server would.

    Raises:
        ExportError: nothing to write, ``out`` exists without ``force``, or a write failed.
    """
    out = Path(out)
    traj = result.trajectory
    if traj is None and result.grid is None and result.points is None and result.mesh is None:
        raise ExportError(
            f"{out}: nothing to write; the result has no trajectory, map, points or mesh"
        )
    t0 = int(traj.stamps_ns[0]) if traj is not None and len(traj) else 0
    with _open_log(out, "", force) as mcap_log:
        if result.grid is not None:
            _put_json(mcap_log, TOPIC_RESULT_MAP, "Grid", t0, grid_message(result.grid, t0))
        if result.points is not None:
            msg = point_cloud_message(result.points, result.point_colors, t0)
            _put_json(mcap_log, TOPIC_RESULT_POINTS, "PointCloud", t0, msg)
        if result.mesh is not None:
            _put_json(mcap_log, TOPIC_RESULT_MESH, "SceneUpdate", t0, mesh_message(result.mesh, t0))
        if traj is not None:
            for stamp, pose in zip(traj.stamps_ns.tolist(), traj.world_from_body, strict=True):
                _write_pose_and_tf(mcap_log, TOPIC_RESULT_POSE, RESULT_CAMERA_FRAME, stamp, pose)
        topics = mcap_log.topics()
    return McapWriteSummary(out, topics)


def grid_message(grid: OccupancyGrid, stamp_ns: int) -> dict[str, Any]:
    """A ``foxglove.Grid`` (JSON) of an occupancy grid; row 0 is the lowest y, as in the grid."""
    prob = np.asarray(grid.prob, dtype=np.float32)
    if prob.ndim != 2 or prob.size == 0:
        raise ExportError(f"occupancy grid must be a non-empty (H, W) array, got {prob.shape}")
    h, w = prob.shape
    unknown = np.isnan(prob)
    p = np.clip(np.where(unknown, 0.0, prob), 0.0, 1.0)
    cells = np.empty((h, w, 5), dtype=np.uint8)
    cells[..., 0] = np.where(unknown, -1, np.rint(p * 100.0)).astype(np.int8).view(np.uint8)
    cells[..., 1:4] = np.where(unknown, 205, np.rint((1.0 - p) * 255.0)).astype(np.uint8)[..., None]
    cells[..., 4] = 255
    x, y, yaw = (float(v) for v in grid.origin_xy_yaw)
    res = float(grid.resolution_m)
    fields = [
        {"name": "occupancy", "offset": 0, "type": _INT8},
        {"name": "red", "offset": 1, "type": _UINT8},
        {"name": "green", "offset": 2, "type": _UINT8},
        {"name": "blue", "offset": 3, "type": _UINT8},
        {"name": "alpha", "offset": 4, "type": _UINT8},
    ]
    return {
        "timestamp": _fox_time(stamp_ns),
        "frame_id": WORLD_FRAME,
        "pose": _fox_pose((x, y, 0.0), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))),
        "column_count": w,
        "cell_size": {"x": res, "y": res},
        "row_stride": w * 5,
        "cell_stride": 5,
        "fields": fields,
        "data": _b64(cells.tobytes()),
    }


def point_cloud_message(
    points: NDArray[np.floating[Any]], colors: NDArray[np.uint8] | None, stamp_ns: int
) -> dict[str, Any]:
    """A ``foxglove.PointCloud`` (JSON): float32 x, y, z (m) and, with colours, uint8 RGBA."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    layout = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    fields = [{"name": n, "offset": 4 * i, "type": _FLOAT32} for i, n in enumerate("xyz")]
    if colors is not None:
        rgb = np.asarray(colors, dtype=np.uint8).reshape(len(pts), -1)
        layout += [("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1")]
        fields += [
            {"name": n, "offset": 12 + i, "type": _UINT8}
            for i, n in enumerate(("red", "green", "blue", "alpha"))
        ]
    packed = np.zeros(len(pts), dtype=np.dtype(layout))
    for i, axis in enumerate("xyz"):
        packed[axis] = pts[:, i]
    if colors is not None:
        packed["red"], packed["green"], packed["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
        packed["alpha"] = rgb[:, 3] if rgb.shape[1] > 3 else 255
    return {
        "timestamp": _fox_time(stamp_ns),
        "frame_id": WORLD_FRAME,
        "pose": _IDENTITY_POSE,
        "point_stride": packed.dtype.itemsize,
        "fields": fields,
        "data": _b64(packed.tobytes()),
    }


def mesh_message(mesh: TriangleMesh, stamp_ns: int) -> dict[str, Any]:
    """A ``foxglove.SceneUpdate`` (JSON) with one entity holding the mesh as a GLB model."""
    model = {
        "pose": _fox_pose((0.0, 0.0, 0.0), _GLTF_TO_WORLD_XYZW),
        "scale": {"x": 1.0, "y": 1.0, "z": 1.0},
        "color": {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0},
        "override_color": False,
        "url": "",
        "media_type": "model/gltf-binary",
        "data": _b64(mesh_to_glb(mesh)),
    }
    entity = {
        "timestamp": _fox_time(stamp_ns),
        "frame_id": WORLD_FRAME,
        "id": "mesh",
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [],
        "arrows": [],
        "cubes": [],
        "spheres": [],
        "cylinders": [],
        "lines": [],
        "triangles": [],
        "texts": [],
        "models": [model],
    }
    return {"deletions": [], "entities": [entity]}


def write_result_mcap(
    run_dir: str | Path, out: str | Path | None = None, *, force: bool = False
) -> Path:
    """Write ``result.mcap`` (or ``out``) for a run folder; see :func:`write_result_log`.

    Raises:
        InputError: not a run folder, or an unreadable result file.
        ExportError: the folder holds none of the files of
            :data:`~slamcli.formats.run_folder.RESULT_KINDS`, ``out`` exists without
            ``force``, or the write failed.
    """
    run = read_run(run_dir)
    if not any(run.has(kind) for kind in RESULT_KINDS):
        names = ", ".join(RUN_FILES[kind] for kind in RESULT_KINDS)
        raise ExportError(f"{run.path}: nothing to write; the run folder has none of {names}")
    dest = Path(out) if out is not None else run.path / "result.mcap"
    return write_result_log(dest, run.result(), force=force).path
