"""A KITTI or EuRoC stereo folder written as an MCAP log, as a ROS 2 stereo camera records it.

Topics, all ROS 2 messages as CDR with ``ros2msg`` schemas:

- ``/cam0/image_raw``, ``/cam1/image_raw``: ``sensor_msgs/msg/Image``, ``mono8`` (``rgb8`` for
  colour), the images as recorded: KITTI's rectified ones, EuRoC's raw ones. Header stamp =
  the image's time, frame ``cam0`` / ``cam1``.
- ``/cam0/camera_info``, ``/cam1/camera_info``: ``sensor_msgs/msg/CameraInfo``, one per image
  with its stamp, as ROS's stereo calibration writes them: ``K`` and ``D`` of the raw camera
  (``plumb_bob`` for radial-tangential, ``equidistant`` for fisheye), ``R`` the rectification
  rotation, ``P`` the rectified projection; the right camera's ``P[0,3] = -fx' * baseline``.
  KITTI's images are already rectified: ``D`` zero, ``R`` identity, ``K = P[:3,:3]``.
- ``/imu0`` (EuRoC): ``sensor_msgs/msg/Imu`` in frame ``imu0``: angular velocity and linear
  acceleration, no orientation (``orientation_covariance[0] = -1``). Only the samples from 1 s
  before the first pair to 1 s after the last are written, not the whole ``imu0/data.csv``.
- ``/tf_static``: one ``tf2_msgs/msg/TFMessage`` at the log's first stamp: ``base_link`` ->
  ``cam0`` and -> ``cam1`` (the cameras the images were taken with) and, where ``imu0`` has a
  ``sensor.yaml``, -> ``imu0``. KITTI's body is the left camera (camera 0), so ``cam0`` is
  ``base_link`` itself and ``cam1`` sits one baseline along its x axis; EuRoC's are the
  ``T_BS`` of the sensors' ``sensor.yaml``.
- ``/groundtruth``: ``geometry_msgs/msg/PoseStamped`` in ``world``: the pose of ``base_link``
  (EuRoC: the body, i.e. the IMU; KITTI: camera 0) at every ground-truth time.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, InputError
from slamcli.formats.euroc.calibration import EQUIDISTANT, CameraSensor
from slamcli.formats.euroc.source import EurocSource
from slamcli.formats.kitti import KittiSource
from slamcli.formats.mcap.write.convert import pose_parts
from slamcli.formats.mcap.write.layer import (
    BODY_FRAME,
    TOPIC_TF_STATIC,
    LogWriter,
    McapWriteSummary,
    open_log,
)
from slamcli.formats.mcap.write.messages import Ros2Writer
from slamcli.geometry.se3 import make_pose
from slamcli.types import ImuFrame, ProgressFn, StereoFrame, Trajectory

if TYPE_CHECKING:
    from slamcli.formats.base import Source

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
StereoFolder = KittiSource | EurocSource
"""The stereo sources :func:`write_stereo_mcap` writes."""

LEFT_FRAME = "cam0"
RIGHT_FRAME = "cam1"
STEREO_IMU_FRAME = "imu0"
TOPIC_LEFT_IMAGE = "/cam0/image_raw"
TOPIC_RIGHT_IMAGE = "/cam1/image_raw"
TOPIC_LEFT_INFO = "/cam0/camera_info"
TOPIC_RIGHT_INFO = "/cam1/camera_info"
TOPIC_STEREO_IMU = "/imu0"

IMU_MARGIN_NS = 1_000_000_000
"""IMU samples are written from this long before the first pair to this long after the last."""

_REORDER_WINDOW_NS = 500_000_000
"""Pairs arrive in left-stamp order; a right image may be stamped a little before its left."""

_ROS_DISTORTION = {EQUIDISTANT: "equidistant"}
"""ROS's ``distortion_model`` of an ASL model; radial-tangential is ``plumb_bob``."""


@dataclass(frozen=True)
class StereoCameraInfo:
    """One camera of a stereo log, as its ``sensor_msgs/CameraInfo`` and tf describe it.

    Attributes:
        frame_id: ``cam0`` or ``cam1``.
        width, height: image size in pixels.
        distortion_model: ``plumb_bob`` or ``equidistant``.
        d: the distortion coefficients (5 for plumb_bob: k1 k2 p1 p2 k3; 4 for equidistant).
        k: (3, 3) float64 intrinsics of the images as recorded.
        r: (3, 3) float64 rotation from the recorded camera to the rectified one.
        p: (3, 4) float64 rectified projection (``P[0,3] = -fx' * baseline`` for the right).
        body_from_camera: (4, 4) float64 pose of the recorded camera on ``base_link``.
    """

    frame_id: str
    width: int
    height: int
    distortion_model: str
    d: tuple[float, ...]
    k: F64
    r: F64
    p: F64
    body_from_camera: F64


def stereo_cameras(source: StereoFolder) -> tuple[StereoCameraInfo, StereoCameraInfo]:
    """The left and right camera of a KITTI or EuRoC folder as the log describes them (see the
    module docstring)."""
    if isinstance(source, KittiSource):
        rig = source.rig
        right_from_left = make_pose(np.eye(3), np.array([rig.baseline_m, 0.0, 0.0]))
        tx = -rig.camera.fx * rig.baseline_m
        return (
            _rectified_camera(LEFT_FRAME, source, 0.0, rig.body_from_left),
            _rectified_camera(RIGHT_FRAME, source, tx, rig.body_from_left @ right_from_left),
        )
    rect = source.rectification
    return (
        _raw_camera(LEFT_FRAME, source.left_sensor, rect.left_from_raw, rect.left_projection),
        _raw_camera(RIGHT_FRAME, source.right_sensor, rect.right_from_raw, rect.right_projection),
    )


def _rectified_camera(
    frame_id: str, source: KittiSource, tx: float, body_from_camera: F64
) -> StereoCameraInfo:
    """A camera whose images are rectified already: no distortion, R identity, P = [K | t]."""
    cam = source.rig.camera
    p = np.hstack([cam.K, np.array([[tx], [0.0], [0.0]])])
    return StereoCameraInfo(
        frame_id,
        cam.width,
        cam.height,
        "plumb_bob",
        (0.0,) * 5,
        cam.K,
        np.eye(3),
        p,
        body_from_camera,
    )


def _raw_camera(frame_id: str, sensor: CameraSensor, r: F64, p: F64) -> StereoCameraInfo:
    model = _ROS_DISTORTION.get(sensor.model, "plumb_bob")
    d = tuple(sensor.coefficients)
    if model == "plumb_bob":
        d = d + (0.0,) * (5 - len(d))
    cam = sensor.camera
    return StereoCameraInfo(
        frame_id, cam.width, cam.height, model, d, cam.K, r, p, sensor.body_from_sensor
    )


class _StereoRos2Writer(Ros2Writer):
    """The ROS 2 messages of a stereo log: images and camera infos in the cameras' frames, IMU
    samples in ``imu0``, the static transforms in one message."""

    def __init__(self, mcap_log: LogWriter) -> None:
        super().__init__(mcap_log, "none", "16UC1", 90)

    def image(
        self, topic: str, stamp_ns: int, camera: StereoCameraInfo, image: NDArray[np.uint8]
    ) -> None:
        """A ``sensor_msgs/msg/Image``: mono8 for (H, W), rgb8 for (H, W, 3) uint8."""
        h, w = image.shape[:2]
        data = np.ascontiguousarray(image, dtype=np.uint8).tobytes()
        encoding = "mono8" if image.ndim == 2 else "rgb8"
        self._put(topic, stamp_ns, self._image(stamp_ns, h, w, encoding, data, camera.frame_id))

    def camera_info(self, topic: str, stamp_ns: int, camera: StereoCameraInfo) -> None:
        """A ``sensor_msgs/msg/CameraInfo`` of ``camera`` (K, D, R, P as the class says)."""
        roi = self.t["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        msg = self.t["sensor_msgs/msg/CameraInfo"](
            header=self._header(stamp_ns, camera.frame_id),
            height=camera.height,
            width=camera.width,
            distortion_model=camera.distortion_model,
            d=np.asarray(camera.d, dtype=np.float64),
            k=np.asarray(camera.k, dtype=np.float64).reshape(-1),
            r=np.asarray(camera.r, dtype=np.float64).reshape(-1),
            p=np.asarray(camera.p, dtype=np.float64).reshape(-1),
            binning_x=0,
            binning_y=0,
            roi=roi,
        )
        self._put(topic, stamp_ns, msg)

    def static_transforms(self, stamp_ns: int, body_from_child: dict[str, F64]) -> None:
        """One ``tf2_msgs/msg/TFMessage`` on ``/tf_static``: ``base_link`` -> each child."""
        vector3 = self.t["geometry_msgs/msg/Vector3"]
        transforms = []
        for child, pose in body_from_child.items():
            (x, y, z), (qx, qy, qz, qw) = pose_parts(pose)
            transforms.append(
                self.t["geometry_msgs/msg/TransformStamped"](
                    header=self._header(stamp_ns, BODY_FRAME),
                    child_frame_id=child,
                    transform=self.t["geometry_msgs/msg/Transform"](
                        translation=vector3(x=x, y=y, z=z),
                        rotation=self.t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
                    ),
                )
            )
        msg = self.t["tf2_msgs/msg/TFMessage"](transforms=transforms)
        self._put(TOPIC_TF_STATIC, stamp_ns, msg)


def write_stereo_mcap(
    source: Source,
    out: str | Path,
    *,
    groundtruth: Trajectory | None = None,
    force: bool = False,
    progress: ProgressFn | None = None,
) -> McapWriteSummary:
    """Write a KITTI or EuRoC stereo folder as an MCAP log (topics in the module docstring).

    Images are written as recorded (KITTI's rectified, EuRoC's raw, with the calibration that
    rectifies them), every pair whose two images exist and decode; a pair that does not is
    skipped, logged and counted. The IMU samples (EuRoC) are those from 1 s before the first
    pair to 1 s after the last. Every message carries its data's own stamp (header,
    ``log_time`` and ``publish_time``), and the log holds them in time order.

    Args:
        source: an open :class:`~slamcli.formats.kitti.KittiSource` or
            :class:`~slamcli.formats.euroc.EurocSource`.
        out: the ``.mcap`` file; written to a temporary name and renamed into place when
            complete, so a failure leaves no partial file and an existing one untouched.
        groundtruth: world_from_body poses of ``base_link`` to write instead of the source's
            own ground truth (e.g. EuRoC's body trajectory from a file beside ``mav0``).
        force: replace an existing ``out``.
        progress: called as ``progress(pairs_done, pairs_total)``.

    Returns:
        The topics written, ``frames`` = pairs written, ``skipped`` = pairs skipped.

    Raises:
        InputError: the folder has no stereo pair, or cannot be read.
        ConfigError: ``source`` is not a KITTI or EuRoC folder.
        ExportError: ``out`` exists without ``force``, or cannot be written.
    """
    if not isinstance(source, KittiSource | EurocSource):
        raise ConfigError(
            f"{source.path}: a {source.format_name} source is not a stereo folder",
            hint="stereo logs are written from KITTI and EuRoC folders; write_source_mcap "
            "writes other sources",
        )
    out = Path(out)
    info = source.info()
    stamps = (
        source.stamps_ns if isinstance(source, KittiSource) else source.pair_stamps_ns
    ).astype(np.int64)
    if stamps.size == 0:
        raise InputError(
            f"{source.path}: no stereo pair has both of its images",
            hint=f"'slamcli info {source.path}' lists the missing images",
        )
    cameras = stereo_cameras(source)
    truth = groundtruth if groundtruth is not None else source.groundtruth()
    imu = _imu_window(source, stamps) if any(s.kind == "imu" for s in info.streams) else []
    mounts = {camera.frame_id: camera.body_from_camera for camera in cameras}
    if isinstance(source, EurocSource) and source.imu_sensor is not None:
        mounts[STEREO_IMU_FRAME] = source.imu_sensor.body_from_sensor
    starts = [int(stamps[0])]
    if imu:
        starts.append(imu[0].stamp_ns)
    if truth is not None and len(truth):
        starts.append(int(truth.stamps_ns[0]))
    pairs = 0
    with open_log(out, "ros2", force) as mcap_log:
        writer = _StereoRos2Writer(mcap_log)
        if isinstance(source, EurocSource) and source.imu_sensor is not None:
            mcap_log.channel_metadata[TOPIC_STEREO_IMU] = imu_metadata(
                source.imu_sensor.rate_hz, source.imu_sensor.noise(), STEREO_IMU_FRAME
            )
        writer.static_transforms(min(starts), mounts)
        if truth is not None:
            for stamp, pose in zip(truth.stamps_ns.tolist(), truth.world_from_body, strict=True):
                writer.pose(stamp, pose)
        for sample in imu:
            writer.imu(sample, TOPIC_STEREO_IMU, STEREO_IMU_FRAME)
        for left_ns, right_ns, left, right in _pairs(source):
            mcap_log.release(min(left_ns, right_ns) - _REORDER_WINDOW_NS)
            for topic, info_topic, stamp, camera, image in (
                (TOPIC_LEFT_IMAGE, TOPIC_LEFT_INFO, left_ns, cameras[0], left),
                (TOPIC_RIGHT_IMAGE, TOPIC_RIGHT_INFO, right_ns, cameras[1], right),
            ):
                writer.image(topic, stamp, camera, image)
                writer.camera_info(info_topic, stamp, camera)
            pairs += 1
            if progress is not None:
                progress(pairs, int(stamps.size))
        topics = mcap_log.topics()
    poses = len(truth) if truth is not None else 0
    log.info(
        "wrote %s: %d stereo pairs, %d IMU samples, %d ground-truth poses",
        out,
        pairs,
        len(imu),
        poses,
    )
    return McapWriteSummary(out, topics, frames=pairs, skipped=source.stats.skipped)


def _pairs(source: StereoFolder) -> Iterator[tuple[int, int, NDArray[np.uint8], NDArray[np.uint8]]]:
    """(left stamp, right stamp, left image, right image) of each readable pair, as recorded."""
    if isinstance(source, KittiSource):
        for frame in source.frames(("stereo",)):
            if not isinstance(frame, StereoFrame):
                continue
            right_ns = frame.right_stamp_ns if frame.right_stamp_ns is not None else frame.stamp_ns
            yield frame.stamp_ns, right_ns, frame.left, frame.right
        return
    left_ns, right_ns = source.pair_stamps_ns.tolist(), source.pair_right_stamps_ns.tolist()
    for k in range(len(source)):
        raw = source.raw_pair(k)
        if raw is not None:
            yield left_ns[k], right_ns[k], raw[0], raw[1]


def imu_metadata(rate_hz: float, noise: dict[str, float], frame_id: str) -> dict[str, str]:
    """The IMU channel's metadata: its noise model
    (:data:`~slamcli.formats.euroc.calibration.IMU_NOISE_KEYS`; ``sensor_msgs/Imu`` has no
    field for it), nominal rate and frame (whose pose on the body ``/tf_static`` gives), as
    strings (MCAP's metadata type)."""
    from slamcli.formats.euroc.calibration import IMU_NOISE_KEYS

    out = {key: repr(float(noise[key])) for key in IMU_NOISE_KEYS}
    return out | {"rate_hz": repr(float(rate_hz)), "frame_id": frame_id}


def _imu_window(source: StereoFolder, stamps: NDArray[np.int64]) -> list[ImuFrame]:
    """The source's IMU samples within the pairs' span widened by :data:`IMU_MARGIN_NS`."""
    first, last = int(stamps[0]) - IMU_MARGIN_NS, int(stamps[-1]) + IMU_MARGIN_NS
    return [
        frame
        for frame in source.frames(("imu",))
        if isinstance(frame, ImuFrame) and first <= frame.stamp_ns <= last
    ]


__all__ = [
    "IMU_MARGIN_NS",
    "LEFT_FRAME",
    "RIGHT_FRAME",
    "STEREO_IMU_FRAME",
    "TOPIC_LEFT_IMAGE",
    "TOPIC_LEFT_INFO",
    "TOPIC_RIGHT_IMAGE",
    "TOPIC_RIGHT_INFO",
    "TOPIC_STEREO_IMU",
    "StereoCameraInfo",
    "StereoFolder",
    "stereo_cameras",
    "write_stereo_mcap",
]
