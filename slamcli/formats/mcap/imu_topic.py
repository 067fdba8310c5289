"""A log's IMU topic for a visual-inertial run: its noise model and mounting, and its checks.

``sensor_msgs/Imu`` has no field for the noise model, so it comes from a Kalibr ``imu.yaml``
given with ``--calib`` (placed by the Kalibr camera chain, whose body is the IMU, or else by tf
from the messages' frame), or from the channel's metadata, as slamcli's stereo logs write it
(placed by tf from the frame the metadata names). A ROS 1 bag has no channel metadata.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import InputError
from slamcli.formats.euroc.calibration import IMU_NOISE_KEYS
from slamcli.formats.euroc.kalibr import KalibrCalibration
from slamcli.types import ImuFrame

F64 = NDArray[np.float64]


def imu_settings(
    topic: str,
    metadata: Mapping[str, str],
    body_frame: str | None,
    calib: KalibrCalibration | None,
    body_from: Callable[[str, str], F64],
    message_frame: Callable[[], str],
) -> dict[str, Any]:
    """``{"imu": {...}}`` (the keys of :meth:`slamcli.formats.euroc.ImuSensor.details`) when
    the noise model is known and the IMU placed on the rig's body (see the module docstring);
    else nothing (the run is visual).

    Args:
        topic: the IMU topic.
        metadata: its channel's metadata.
        body_frame: the rig's body in tf ("" or None when none was found).
        calib: the ``--calib`` files.
        body_from: ``(body, frame)`` -> (4, 4) pose of ``frame`` on ``body`` from tf.
        message_frame: the ``frame_id`` of the topic's first message.

    Raises:
        InputError: the metadata is not numbers or names a frame tf cannot place on the body;
            a Kalibr IMU that nothing places.
    """
    if calib is not None and calib.imu is not None:
        placed = None
        if not calib.imu_placed and body_frame:
            frame = message_frame()
            if frame:
                try:
                    placed = body_from(body_frame, frame)
                except InputError:
                    placed = None
        imu = calib.imu_on_body(placed)
        assert imu is not None
        return {"imu": imu.details()}
    if not body_frame or not all(key in metadata for key in IMU_NOISE_KEYS):
        return {}
    try:
        settings: dict[str, Any] = {key: float(metadata[key]) for key in IMU_NOISE_KEYS}
        settings["rate_hz"] = float(metadata.get("rate_hz", "200"))
    except ValueError as exc:
        raise InputError(f"{topic}: the channel's noise metadata is not a number ({exc})") from None
    frame = metadata.get("frame_id", "")
    if frame and frame != body_frame:
        settings["body_from_imu"] = body_from(body_frame, frame).tolist()
    return {"imu": settings}


def check_imu_topic(
    topic: str, records: Iterable[Any], image_stamps_ns: list[int]
) -> tuple[dict[str, Any], list[str]]:
    """The IMU topic's checks (:func:`~slamcli.formats.imu_checks.check_imu`: header stamps in
    log order, gaps, rate, units, saturation, and how its time lines up with the images'
    header stamps when some were read), over its ``records``. Samples without both a gyroscope
    and an accelerometer reading are left out of the checks and counted."""
    from slamcli.formats.imu_checks import check_imu

    stamps: list[int] = []
    gyro: list[F64] = []
    accel: list[F64] = []
    partial = 0
    for rec in records:
        if not isinstance(rec, ImuFrame):
            continue
        if rec.gyro_radps is None or rec.accel_mps2 is None:
            partial += 1
            continue
        stamps.append(rec.stamp_ns)
        gyro.append(rec.gyro_radps)
        accel.append(rec.accel_mps2)
    if partial and not stamps:
        return {"imu_topic": topic, "imu_partial_samples": partial}, [
            f"{topic}: {partial} sample(s), none with both a gyroscope and an "
            "accelerometer reading: a visual-inertial run needs both"
        ]
    report = check_imu(
        np.asarray(stamps, dtype=np.int64),
        np.asarray(gyro, dtype=np.float64).reshape(-1, 3),
        np.asarray(accel, dtype=np.float64).reshape(-1, 3),
        camera_stamps_ns=np.asarray(image_stamps_ns, dtype=np.int64) if image_stamps_ns else None,
        where=topic,
    )
    details: dict[str, Any] = {"imu_topic": topic, "imu_check": report.to_dict()}
    if partial:
        details["imu_partial_samples"] = partial
    return details, list(report.problems)


__all__ = ["check_imu_topic", "imu_settings"]
