"""A landmark run written as an MCAP log for ``slamcli run ekf``.

Odometry on ``/odom`` (``nav_msgs/msg/Odometry``, CDR, in both flavours: Foxglove has no
message for velocities), observations on ``/landmarks`` (``slamcli.LandmarkObservations``,
JSON, see :mod:`slamcli.formats.mcap.observations`) and ground truth on ``/ground_truth``
(``geometry_msgs/msg/PoseStamped``; foxglove: ``foxglove.PoseInFrame`` plus world ->
``base_link`` on ``/tf``). Each odometry message's twist is the control applied from its stamp
to the next (``linear.x`` = v, ``angular.z`` = omega); its pose is the dead reckoning of the
controls before it (exact arc integration from x = y = yaw = 0 in ``odom``), as a wheel-odometry
node would publish.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ExportError
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
from slamcli.formats.mcap.write.foxglove import write_pose_and_tf
from slamcli.formats.mcap.write.layer import (
    BODY_FRAME,
    FLAVORS,
    TOPIC_GROUND_TRUTH,
    TOPIC_LANDMARKS,
    TOPIC_ODOM,
    McapWriteSummary,
    check_choice,
    check_out,
    open_log,
)
from slamcli.formats.mcap.write.messages import Ros2Writer
from slamcli.geometry.planar import integrate_unicycle, wrap_angle

log = logging.getLogger(__name__)


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
    check_out(out, force)
    run = data if isinstance(data, LandmarkLog) else read_landmark_log(data)
    odo_order = np.argsort(run.odometry_stamps_ns, kind="stable")
    odo_t = run.odometry_stamps_ns[odo_order]
    odo = run.odometry[odo_order]
    odom_xy_yaw = dead_reckon(odo_t, odo).tolist()
    meas_order = np.argsort(run.measurement_stamps_ns, kind="stable")
    meas_t = run.measurement_stamps_ns[meas_order]
    schema = (LANDMARK_SCHEMA_NAME, LANDMARK_SCHEMA_ENCODING, landmark_schema())
    with open_log(out, "ros2" if flavor == "ros2" else "", force) as mcap_log:
        ros2 = Ros2Writer(mcap_log, "none", "16UC1", 90)
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
                write_pose_and_tf(mcap_log, TOPIC_GROUND_TRUTH, BODY_FRAME, stamp, pose)
        topics = mcap_log.topics()
    log.info(
        "wrote %s: %d odometry, %d observation messages",
        out,
        topics.get(TOPIC_ODOM, ("", 0))[1],
        topics.get(TOPIC_LANDMARKS, ("", 0))[1],
    )
    return McapWriteSummary(out, topics)
