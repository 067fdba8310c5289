"""The messages of RGB-D frames, poses, odometry and IMU readings, one writer per flavour.

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

The messages of scan logs (laser scans, odometry poses, tf) are in
:mod:`~slamcli.formats.mcap.write.scans`; their ROS 2 messages are built here.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.formats.mcap.write.convert import (
    COMPRESSED_DEPTH_FORMAT,
    camera_model,
    compressed_depth,
    depth_bytes,
    depth_to_millimetres,
    encode_color,
    pose_parts,
    split_ns,
)
from slamcli.formats.mcap.write.foxglove import b64, fox_time, put_json, write_pose_and_tf
from slamcli.formats.mcap.write.layer import (
    BODY_FRAME,
    CAMERA_FRAME,
    IMU_FRAME,
    ODOM_FRAME,
    TOPIC_CAMERA_INFO,
    TOPIC_COLOR,
    TOPIC_COLOR_COMPRESSED,
    TOPIC_DEPTH,
    TOPIC_DEPTH_COMPRESSED,
    TOPIC_GROUNDTRUTH,
    TOPIC_IMU,
    TOPIC_ODOM,
    WORLD_FRAME,
    LogWriter,
)
from slamcli.types import ImuFrame, PinholeCamera, RgbdFrame, ScanFrame


class FrameWriter(abc.ABC):
    """Writes the messages of RGB-D frames, ground-truth poses and IMU readings."""

    def __init__(
        self, mcap_log: LogWriter, compress: str, depth_encoding: str, jpeg_quality: int
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
    def imu(self, frame: ImuFrame, topic: str = TOPIC_IMU, frame_id: str = IMU_FRAME) -> bool:
        """Write one IMU reading on ``topic`` in ``frame_id``; False when the flavour has no
        message for it."""


class Ros2Writer(FrameWriter):
    """ROS 2 messages, CDR-encoded, with the ``ros2msg`` definitions ``ros2 bag`` stores."""

    def __init__(
        self, mcap_log: LogWriter, compress: str, depth_encoding: str, jpeg_quality: int
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
        sec, nsec = split_ns(stamp_ns)
        time = self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        return self.t["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)

    def _image(
        self,
        stamp_ns: int,
        h: int,
        w: int,
        encoding: str,
        data: bytes,
        frame_id: str = CAMERA_FRAME,
    ) -> Any:
        return self.t["sensor_msgs/msg/Image"](
            header=self._header(stamp_ns, frame_id),
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
            data = encode_color(frame.rgb, self.compress, self.jpeg_quality)
            self._put(TOPIC_COLOR_COMPRESSED, t, self._compressed(t, self.compress, data))
        if self.compress != "none" and self.depth_encoding == "16UC1":
            data = compressed_depth(depth_to_millimetres(frame.depth_m))
            msg = self._compressed(depth_t, COMPRESSED_DEPTH_FORMAT, data)
            self._put(TOPIC_DEPTH_COMPRESSED, depth_t, msg)
        else:
            raw, _ = depth_bytes(frame.depth_m, self.depth_encoding)
            self._put(TOPIC_DEPTH, depth_t, self._image(depth_t, h, w, self.depth_encoding, raw))

    def _camera_info(self, stamp_ns: int, camera: PinholeCamera) -> Any:
        model, d, k, p = camera_model(camera)
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
        self.pose_stamped(TOPIC_GROUNDTRUTH, stamp_ns, *pose_parts(world_from_camera))

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
        q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
        self.odometry_pose(TOPIC_ODOM, stamp_ns, (x, y, 0.0), q, v, omega)

    def odometry_pose(
        self,
        topic: str,
        stamp_ns: int,
        t: Sequence[float],
        q: Sequence[float],
        v: float,
        omega: float,
        frames: tuple[str, str] = (ODOM_FRAME, BODY_FRAME),
    ) -> None:
        """A ``nav_msgs/msg/Odometry``: the pose (translation m, xyzw quaternion) of
        ``frames[1]`` in ``frames[0]``, twist ``linear.x`` = v (m/s), ``angular.z`` = omega
        (rad/s)."""
        vector3 = self.t["geometry_msgs/msg/Vector3"]
        twist = self.t["geometry_msgs/msg/Twist"](
            linear=vector3(x=float(v), y=0.0, z=0.0), angular=vector3(x=0.0, y=0.0, z=float(omega))
        )
        pose = self._pose(t, q)
        msg = self.t["nav_msgs/msg/Odometry"](
            header=self._header(stamp_ns, frames[0]),
            child_frame_id=frames[1],
            pose=self.t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=self.t["geometry_msgs/msg/TwistWithCovariance"](
                twist=twist, covariance=np.zeros(36)
            ),
        )
        self._put(topic, stamp_ns, msg)

    def transform(
        self,
        topic: str,
        stamp_ns: int,
        frames: tuple[str, str],
        parent_from_child: NDArray[np.float64],
    ) -> None:
        """A ``tf2_msgs/msg/TFMessage`` of one transform: ``frames`` are (parent, child)."""
        (x, y, z), (qx, qy, qz, qw) = pose_parts(parent_from_child)
        vector3 = self.t["geometry_msgs/msg/Vector3"]
        transform = self.t["geometry_msgs/msg/TransformStamped"](
            header=self._header(stamp_ns, frames[0]),
            child_frame_id=frames[1],
            transform=self.t["geometry_msgs/msg/Transform"](
                translation=vector3(x=x, y=y, z=z),
                rotation=self.t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
            ),
        )
        self._put(topic, stamp_ns, self.t["tf2_msgs/msg/TFMessage"](transforms=[transform]))

    def laser_scan(self, topic: str, frame_id: str, scan: ScanFrame) -> None:
        """A ``sensor_msgs/msg/LaserScan`` of a sweep in ``frame_id``; its angles and range
        limits are float32 there, its ranges as they are."""
        n = len(scan.ranges_m)
        msg = self.t["sensor_msgs/msg/LaserScan"](
            header=self._header(scan.stamp_ns, frame_id),
            angle_min=float(scan.angle_min_rad),
            angle_max=float(scan.angle_min_rad + (n - 1) * scan.angle_increment_rad),
            angle_increment=float(scan.angle_increment_rad),
            time_increment=0.0,
            scan_time=0.0,
            range_min=float(scan.range_min_m),
            range_max=float(scan.range_max_m),
            ranges=np.asarray(scan.ranges_m, dtype=np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )
        self._put(topic, scan.stamp_ns, msg)

    def imu(self, frame: ImuFrame, topic: str = TOPIC_IMU, frame_id: str = IMU_FRAME) -> bool:
        vector3 = self.t["geometry_msgs/msg/Vector3"]
        # ROS convention: covariance element 0 = -1 marks a quantity the sensor does not give.
        unknown = np.zeros(9)
        unknown[0] = -1.0
        accel = frame.accel_mps2
        gyro = frame.gyro_radps
        msg = self.t["sensor_msgs/msg/Imu"](
            header=self._header(frame.stamp_ns, frame_id),
            orientation=self.t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=unknown.copy(),
            angular_velocity=vector3(*(gyro.tolist() if gyro is not None else (0.0,) * 3)),
            angular_velocity_covariance=np.zeros(9) if gyro is not None else unknown.copy(),
            linear_acceleration=vector3(*(accel.tolist() if accel is not None else (0.0,) * 3)),
            linear_acceleration_covariance=np.zeros(9) if accel is not None else unknown.copy(),
        )
        self._put(topic, frame.stamp_ns, msg)
        return True


class FoxgloveWriter(FrameWriter):
    """Foxglove messages as JSON with the official JSON schemas; ground truth also on /tf."""

    def rgbd(self, frame: RgbdFrame) -> None:
        t = frame.stamp_ns
        depth_t = frame.depth_stamp_ns if frame.depth_stamp_ns is not None else t
        h, w = frame.rgb.shape[:2]
        model, d, k, p = camera_model(frame.camera)
        calibration = {
            "timestamp": fox_time(t),
            "frame_id": CAMERA_FRAME,
            "width": frame.camera.width,
            "height": frame.camera.height,
            "distortion_model": model,
            "D": d,
            "K": k,
            "R": np.eye(3).reshape(-1).tolist(),
            "P": p,
        }
        put_json(self.log, TOPIC_CAMERA_INFO, "CameraCalibration", t, calibration)
        if self.compress == "none":
            rgb = np.ascontiguousarray(frame.rgb).tobytes()
            put_json(self.log, TOPIC_COLOR, "RawImage", t, _raw_image(t, w, h, "rgb8", rgb))
        else:
            data = encode_color(frame.rgb, self.compress, self.jpeg_quality)
            msg = {
                "timestamp": fox_time(t),
                "frame_id": CAMERA_FRAME,
                "data": b64(data),
                "format": self.compress,
            }
            put_json(self.log, TOPIC_COLOR_COMPRESSED, "CompressedImage", t, msg)
        raw, _ = depth_bytes(frame.depth_m, self.depth_encoding)
        msg = _raw_image(depth_t, w, h, self.depth_encoding, raw)
        put_json(self.log, TOPIC_DEPTH, "RawImage", depth_t, msg)

    def pose(self, stamp_ns: int, world_from_camera: NDArray[np.float64]) -> None:
        write_pose_and_tf(self.log, TOPIC_GROUNDTRUTH, CAMERA_FRAME, stamp_ns, world_from_camera)

    def imu(self, frame: ImuFrame, topic: str = TOPIC_IMU, frame_id: str = IMU_FRAME) -> bool:
        return False


def _raw_image(stamp_ns: int, w: int, h: int, encoding: str, data: bytes) -> dict[str, Any]:
    return {
        "timestamp": fox_time(stamp_ns),
        "frame_id": CAMERA_FRAME,
        "width": w,
        "height": h,
        "encoding": encoding,
        "step": len(data) // h,
        "data": b64(data),
    }
