"""Writing MCAP logs: RGB-D and scan sources and landmark runs as ROS 2 or Foxglove messages, run
results.

Four writers share one small MCAP layer (:mod:`~slamcli.formats.mcap.write.layer`):

* :func:`write_source_mcap` (:mod:`~slamcli.formats.mcap.write.source`) turns a source (a TUM
  RGB-D folder, a log of laser scans and odometry) into a log a robot could have recorded.
  ``flavor="ros2"`` writes CDR messages with ``ros2msg`` schemas (the full definition text with
  its dependencies, as ``ros2 bag record`` stores it); ``flavor="foxglove"`` writes JSON
  messages with the official Foxglove JSON schemas (``schema_encoding="jsonschema"``,
  ``message_encoding="json"``, binary fields base64 as Foxglove's JSON convention has it). The
  topics are listed in :mod:`~slamcli.formats.mcap.write.messages`, the depth encodings in
  :mod:`~slamcli.formats.mcap.write.convert`.
* :func:`write_scan_mcap` (:mod:`~slamcli.formats.mcap.write.scans`) writes laser scans and
  odometry given in memory (``sensor_msgs/msg/LaserScan`` or ``foxglove.LaserScan``,
  ``nav_msgs/msg/Odometry``, the mounting on ``/tf_static``); a source's scans are converted
  with the same messages.
* :func:`write_landmark_log` (:mod:`~slamcli.formats.mcap.write.landmarks`) turns a landmark run
  (a ``slamcli synth landmarks`` folder, or the same data in memory as a
  :class:`~slamcli.formats.landmarks.LandmarkLog`) into a log for ``slamcli run ekf``.
* :func:`write_result_log` / :func:`write_result_mcap` (:mod:`~slamcli.formats.mcap.write.result`)
  turn a SLAM result or a run folder into a ``result.mcap`` a user drags into Foxglove.
"""

from __future__ import annotations

from slamcli.formats.mcap.write.convert import COMPRESSED_DEPTH_FORMAT, depth_to_millimetres
from slamcli.formats.mcap.write.foxglove import foxglove_schema
from slamcli.formats.mcap.write.landmarks import dead_reckon, write_landmark_log
from slamcli.formats.mcap.write.layer import (
    BODY_FRAME,
    CAMERA_FRAME,
    FLAVORS,
    IMU_FRAME,
    LASER_FRAME,
    ODOM_FRAME,
    RESULT_CAMERA_FRAME,
    TOPIC_CAMERA_INFO,
    TOPIC_COLOR,
    TOPIC_COLOR_COMPRESSED,
    TOPIC_DEPTH,
    TOPIC_DEPTH_COMPRESSED,
    TOPIC_GROUND_TRUTH,
    TOPIC_GROUNDTRUTH,
    TOPIC_IMU,
    TOPIC_LANDMARKS,
    TOPIC_ODOM,
    TOPIC_RESULT_MAP,
    TOPIC_RESULT_MESH,
    TOPIC_RESULT_POINTS,
    TOPIC_RESULT_POSE,
    TOPIC_SCAN,
    TOPIC_TF,
    TOPIC_TF_STATIC,
    WORLD_FRAME,
    McapWriteSummary,
    check_choice,
)
from slamcli.formats.mcap.write.result import (
    grid_message,
    mesh_message,
    point_cloud_message,
    write_result_log,
    write_result_mcap,
)
from slamcli.formats.mcap.write.scans import laser_scan_message, write_scan_mcap
from slamcli.formats.mcap.write.source import (
    DEPTH_ENCODINGS,
    IMAGE_COMPRESSIONS,
    write_source_mcap,
)

__all__ = [
    "BODY_FRAME",
    "CAMERA_FRAME",
    "COMPRESSED_DEPTH_FORMAT",
    "DEPTH_ENCODINGS",
    "FLAVORS",
    "IMAGE_COMPRESSIONS",
    "IMU_FRAME",
    "LASER_FRAME",
    "ODOM_FRAME",
    "RESULT_CAMERA_FRAME",
    "TOPIC_CAMERA_INFO",
    "TOPIC_COLOR",
    "TOPIC_COLOR_COMPRESSED",
    "TOPIC_DEPTH",
    "TOPIC_DEPTH_COMPRESSED",
    "TOPIC_GROUNDTRUTH",
    "TOPIC_GROUND_TRUTH",
    "TOPIC_IMU",
    "TOPIC_LANDMARKS",
    "TOPIC_ODOM",
    "TOPIC_RESULT_MAP",
    "TOPIC_RESULT_MESH",
    "TOPIC_RESULT_POINTS",
    "TOPIC_RESULT_POSE",
    "TOPIC_SCAN",
    "TOPIC_TF",
    "TOPIC_TF_STATIC",
    "WORLD_FRAME",
    "McapWriteSummary",
    "check_choice",
    "dead_reckon",
    "depth_to_millimetres",
    "foxglove_schema",
    "grid_message",
    "laser_scan_message",
    "mesh_message",
    "point_cloud_message",
    "write_landmark_log",
    "write_result_log",
    "write_result_mcap",
    "write_scan_mcap",
    "write_source_mcap",
]
