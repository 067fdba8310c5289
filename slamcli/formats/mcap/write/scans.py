"""Laser scans and odometry written as an MCAP log, as a robot with a 2-D lidar records them.

Topics (ros2 type / foxglove type), named as :func:`write_scan_mcap` is told:

- the scan topic (``/scan``): ``sensor_msgs/msg/LaserScan`` / ``foxglove.LaserScan``, in the
  laser frame. ROS stores angles and range limits as float32. Foxglove's message has no range
  limits, and JSON no infinities: a beam without a reading (beyond the limits, infinite or NaN)
  is written as range 0, which the reader takes for no reading.
- the odometry topic (``/odom``): ``nav_msgs/msg/Odometry`` in both flavours (CDR; Foxglove has
  no message for velocities), the pose of the base frame in the odometry frame; a velocity the
  frame does not have is written as 0.
- ``/tf_static``: ``tf2_msgs/msg/TFMessage`` / ``foxglove.FrameTransform``, base -> laser: the
  scans' planar mounting, once, at the first scan's stamp.

Read back by :class:`~slamcli.formats.mcap.source.McapSource`, a ros2 log gives the frames it
was written from: stamps, ranges and the mounting's and odometry's translations exactly,
rotations to rounding, angles and range limits as float32 holds them.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, ExportError
from slamcli.formats.mcap.write.convert import pose_parts
from slamcli.formats.mcap.write.foxglove import IDENTITY_POSE, fox_time, frame_transform, put_json
from slamcli.formats.mcap.write.layer import (
    BODY_FRAME,
    FLAVORS,
    LASER_FRAME,
    ODOM_FRAME,
    TOPIC_ODOM,
    TOPIC_SCAN,
    TOPIC_TF_STATIC,
    LogWriter,
    McapWriteSummary,
    check_choice,
    open_log,
)
from slamcli.formats.mcap.write.messages import Ros2Writer
from slamcli.geometry import planar_to_se3
from slamcli.types import OdometryFrame, ScanFrame

log = logging.getLogger(__name__)


def laser_scan_message(scan: ScanFrame, frame_id: str) -> dict[str, Any]:
    """A ``foxglove.LaserScan`` (JSON) of a sweep in ``frame_id``; beams without a reading
    are 0."""
    n = len(scan.ranges_m)
    ranges = np.where(scan.readings(), scan.ranges_m, np.float32(0.0)).astype(np.float32)
    return {
        "timestamp": fox_time(scan.stamp_ns),
        "frame_id": frame_id,
        "pose": IDENTITY_POSE,
        "start_angle": float(scan.angle_min_rad),
        "end_angle": float(scan.angle_min_rad + (n - 1) * scan.angle_increment_rad),
        "ranges": ranges.astype(np.float64).tolist(),
        "intensities": [],
    }


class ScanWriter:
    """Writes scan and odometry frames in one flavour, and the scans' mounting once.

    Args:
        mcap_log: the log being written.
        flavor: ``"ros2"`` or ``"foxglove"``.
        scan_topic, odom_topic: where scans and odometry go.
        laser_frame, base_frame, odom_frame: the frames of the scans, of the body and of the
            odometry's origin.

    Raises:
        ConfigError: two of the topics (scans, odometry, ``/tf_static``) are the same.
    """

    def __init__(
        self,
        mcap_log: LogWriter,
        flavor: str,
        *,
        scan_topic: str = TOPIC_SCAN,
        odom_topic: str = TOPIC_ODOM,
        laser_frame: str = LASER_FRAME,
        base_frame: str = BODY_FRAME,
        odom_frame: str = ODOM_FRAME,
    ) -> None:
        if len({scan_topic, odom_topic, TOPIC_TF_STATIC}) < 3:
            raise ConfigError(
                f"the scan topic ({scan_topic}), the odometry topic ({odom_topic}) and "
                f"{TOPIC_TF_STATIC} must differ"
            )
        self.log = mcap_log
        self.flavor = flavor
        self.ros2 = Ros2Writer(mcap_log, "none", "16UC1", 90)
        self.scan_topic, self.odom_topic = scan_topic, odom_topic
        self.laser_frame, self.base_frame, self.odom_frame = laser_frame, base_frame, odom_frame
        self.mounting: NDArray[np.float64] | None = None
        self.scans = 0
        self.odometry_frames = 0

    def write(self, frame: Any) -> None:
        """Write a :class:`ScanFrame` or an :class:`OdometryFrame`."""
        if isinstance(frame, ScanFrame):
            self.scan(frame)
        elif isinstance(frame, OdometryFrame):
            self.odometry(frame)
        else:
            raise ExportError(
                f"a scan log holds scans and odometry, not {type(frame).__name__} frames"
            )

    def scan(self, frame: ScanFrame) -> None:
        """Write one sweep (and, with the first, the mounting on ``/tf_static``)."""
        self._mount(frame)
        if self.flavor == "ros2":
            self.ros2.laser_scan(self.scan_topic, self.laser_frame, frame)
        else:
            msg = laser_scan_message(frame, self.laser_frame)
            put_json(self.log, self.scan_topic, "LaserScan", frame.stamp_ns, msg)
        self.scans += 1

    def _mount(self, frame: ScanFrame) -> None:
        mounting = np.asarray(frame.body_from_sensor, dtype=np.float64).reshape(3)
        if self.mounting is None:
            self.mounting = mounting
            pose = planar_to_se3(mounting)[0]
            frames = (self.base_frame, self.laser_frame)
            if self.flavor == "ros2":
                self.ros2.transform(TOPIC_TF_STATIC, frame.stamp_ns, frames, pose)
            else:
                tf = frame_transform(frame.stamp_ns, *frames, pose)
                put_json(self.log, TOPIC_TF_STATIC, "FrameTransform", frame.stamp_ns, tf)
        elif not np.array_equal(mounting, self.mounting):
            raise ExportError(
                f"{self.scan_topic}: scan {frame.name or frame.stamp_ns} is mounted at "
                f"{mounting.tolist()} (x, y, yaw), the first at {self.mounting.tolist()}; "
                f"frame {self.laser_frame} has one mounting",
                hint="write scans of differently mounted scanners to separate logs",
            )

    def odometry(self, frame: OdometryFrame) -> None:
        """Write one odometry pose (``nav_msgs/msg/Odometry``)."""
        if frame.world_from_body is None:
            raise ExportError(
                f"{self.odom_topic}: the odometry at {frame.stamp_ns} ns has no pose; "
                "nav_msgs/Odometry needs one",
                hint="integrate the velocities into poses first",
            )
        t, q = pose_parts(np.asarray(frame.world_from_body, dtype=np.float64))
        v = 0.0 if frame.v is None else float(frame.v)
        omega = 0.0 if frame.omega is None else float(frame.omega)
        frames = (self.odom_frame, self.base_frame)
        self.ros2.odometry_pose(self.odom_topic, frame.stamp_ns, t, q, v, omega, frames)
        self.odometry_frames += 1


def write_scan_mcap(
    path: str | Path,
    frames: Iterable[ScanFrame | OdometryFrame],
    *,
    flavor: str = "ros2",
    scan_topic: str = TOPIC_SCAN,
    odom_topic: str = TOPIC_ODOM,
    laser_frame: str = LASER_FRAME,
    base_frame: str = BODY_FRAME,
    odom_frame: str = ODOM_FRAME,
    force: bool = False,
) -> McapWriteSummary:
    """Write scans and odometry as an MCAP log that ``slamcli run lidar`` reads.

    Topics and messages are listed in the module docstring. Every message is stamped with its
    frame's stamp (header / ``timestamp``, ``log_time`` and ``publish_time``); frames may come
    in any order, the log holds them in time order. All scans share the mounting of the first
    (``body_from_sensor``).

    Args:
        path: the ``.mcap`` file; written to a temporary name and renamed into place when
            complete, so a failure leaves no partial file and an existing one untouched.
        frames: scans and odometry (each odometry frame with a pose).
        flavor: ``"ros2"`` (profile ros2) or ``"foxglove"`` (Foxglove JSON scans and tf;
            odometry CDR).
        scan_topic, odom_topic: the topics.
        laser_frame, base_frame, odom_frame: frame ids of the scans, the body and the
            odometry's origin.
        force: replace an existing file.

    Returns:
        The topics written and, as ``frames``, the number of scans.

    Raises:
        ConfigError: a bad flavour, or topics that are not distinct.
        ExportError: no frames, a frame of another kind, odometry without a pose, scans of
            different mountings, ``path`` exists without ``force``, or a failed write.
    """
    check_choice("flavor", flavor, FLAVORS)
    out = Path(path)
    with open_log(out, "ros2" if flavor == "ros2" else "", force) as mcap_log:
        writer = ScanWriter(
            mcap_log,
            flavor,
            scan_topic=scan_topic,
            odom_topic=odom_topic,
            laser_frame=laser_frame,
            base_frame=base_frame,
            odom_frame=odom_frame,
        )
        for frame in frames:
            writer.write(frame)
        if writer.scans + writer.odometry_frames == 0:
            raise ExportError(f"{out}: nothing to write; no scan or odometry frames were given")
        topics = mcap_log.topics()
    log.info("wrote %s: %d scans, %d odometry", out, writer.scans, writer.odometry_frames)
    return McapWriteSummary(out, topics, frames=writer.scans)
