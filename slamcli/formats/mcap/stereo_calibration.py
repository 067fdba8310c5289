"""The calibration of a stereo pair recorded in a log: each camera's ``CameraInfo``, the
transforms between the cameras and the body, and the rectification they call for.

A ``sensor_msgs/CameraInfo`` (ROS 1 spells its fields ``K D R P``, ROS 2 ``k d r p``; a
``foxglove.CameraCalibration`` has the same fields) holds the raw camera ``K`` and its
distortion ``D`` (``plumb_bob``/``rational_polynomial`` for OpenCV's radial-tangential model,
``equidistant`` for its fisheye one), the rotation ``R`` onto the rectified frame and the
rectified projection ``P``; in a stereo calibration the right camera's ``P[0,3]`` is
``-fx' * baseline``. The pair is read one of three ways:

* **already rectified** (``D`` all zero and ``R`` the identity or absent; or both image topics
  named ``image_rect...``, which ROS's ``image_proc`` rectifies with ``R`` and ``P``): the
  camera is the left ``P`` (``K`` without one), the baseline ``(P_l[0,3] - P_r[0,3]) /
  P_r[0,0]``; the images are used as they are.
* **raw, with R and P** (ROS's stereo calibration): the remap tables come from
  ``initUndistortRectifyMap(K, D, R, P)`` of each camera (the fisheye variant for
  ``equidistant``), built once.
* **raw, without them** (``R``/``P`` absent, or a right ``P`` without a baseline term): the
  pose of the left camera in the right one comes from tf (``/tf_static``) between the two
  ``CameraInfo`` frame ids, and OpenCV's ``stereoRectify`` rectifies the pair as the EuRoC
  source does (:mod:`slamcli.formats.euroc.calibration`).

Where a right ``P`` has no baseline term, tf gives the baseline of already rectified images
too. The rig's ``body_from_left`` is the left camera's frame on the body frame found in tf
(see :func:`slamcli.formats.mcap.stereo.body_frame`), times the rectification rotation;
without a body in tf it is the identity (the ground truth is then taken to be the left
camera's).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import InputError
from slamcli.formats.euroc.calibration import (
    EQUIDISTANT,
    RADTAN,
    RawStereoPair,
    StereoRectification,
    rectify_raw_pair,
    rectify_with_projections,
)
from slamcli.formats.mcap.decode import DecodeError
from slamcli.formats.mcap.tf import TfBuffer
from slamcli.geometry import make_pose
from slamcli.types import PinholeCamera, StereoRig

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]

CAMERA_INFO_MODELS = {
    "": RADTAN,
    "plumb_bob": RADTAN,
    "rational_polynomial": RADTAN,
    "radtan": RADTAN,
    "equidistant": EQUIDISTANT,
    "fisheye": EQUIDISTANT,
}
"""``distortion_model`` names of a CameraInfo, by the OpenCV model they mean."""

IDENTITY_TOL = 1e-9
"""Largest deviation from the identity of an ``R`` taken for "no rectification rotation"."""

_RIGHT_HINT = (
    "a stereo pair has the left camera on --left-topic and the right one on --right-topic; "
    "check the CameraInfo P matrices and the tf between the camera frames"
)


@dataclass(frozen=True)
class CameraInfo:
    """The calibration fields of one ``CameraInfo`` (or ``foxglove.CameraCalibration``).

    Attributes:
        topic: the calibration topic.
        frame_id: the camera's frame (its header's).
        width, height: the image size in pixels.
        model: ``distortion_model`` as given.
        d: the distortion coefficients.
        k: (3, 3) float64 raw camera matrix.
        r: (3, 3) float64 rectification rotation, None when absent (all zero).
        p: (3, 4) float64 rectified projection, None when absent (all zero).
    """

    topic: str
    frame_id: str
    width: int
    height: int
    model: str
    d: tuple[float, ...]
    k: F64
    r: F64 | None
    p: F64 | None

    @property
    def undistorted(self) -> bool:
        """``D`` all zero and ``R`` the identity or absent: the images need no remapping."""
        no_rotation = self.r is None or bool(np.abs(self.r - np.eye(3)).max() <= IDENTITY_TOL)
        return not any(self.d) and no_rotation

    @property
    def projection(self) -> F64:
        """``P``, or ``[K | 0]`` without one."""
        if self.p is not None:
            return self.p
        return np.hstack([self.k, np.zeros((3, 1))])

    @property
    def has_baseline(self) -> bool:
        """Whether ``P`` has a baseline term (``P[0,3]`` non-zero)."""
        return self.p is not None and self.p[0, 3] != 0.0

    def raw_camera(self) -> PinholeCamera:
        """The raw camera (``K``, no distortion terms: they are :attr:`d`)."""
        k = self.k
        return PinholeCamera(
            self.width, self.height, float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])
        )


def _field(msg: Any, *names: str) -> Any:
    for name in names:
        value = msg.get(name) if isinstance(msg, dict) else getattr(msg, name, None)
        if value is not None:
            return value
    return None


def _matrix(topic: str, value: Any, shape: tuple[int, int], name: str) -> F64 | None:
    """A row-major matrix field, None when absent or all zero."""
    if value is None:
        return None
    m = np.asarray(list(value) if not isinstance(value, np.ndarray) else value, dtype=np.float64)
    m = m.reshape(-1)
    if m.size == 0 or not m.any():
        return None
    if m.size != shape[0] * shape[1] or not np.isfinite(m).all():
        raise DecodeError(
            f"channel {topic}: CameraInfo {name} has {m.size} values, expected "
            f"{shape[0] * shape[1]} finite numbers"
        )
    return m.reshape(shape)


def read_camera_info(msg: Any, topic: str) -> CameraInfo:
    """The calibration fields of a decoded CameraInfo or CameraCalibration message.

    Raises:
        DecodeError: no image size, no camera matrix, or a matrix of the wrong size (names
            the topic).
    """
    header = _field(msg, "header")
    frame_id = _field(header, "frame_id") if header is not None else _field(msg, "frame_id")
    width, height = int(_field(msg, "width") or 0), int(_field(msg, "height") or 0)
    if width <= 0 or height <= 0:
        raise DecodeError(
            f"channel {topic}: CameraInfo has image size {width}x{height}",
            hint="the stereo calibration needs the calibrated image size",
        )
    k = _matrix(topic, _field(msg, "k", "K"), (3, 3), "K")
    if k is None or not (k[0, 0] > 0 and k[1, 1] > 0):
        raise DecodeError(
            f"channel {topic}: camera is not calibrated (K is "
            f"{k.tolist() if k is not None else 'all zero'})",
            hint="the stereo pair needs calibrated CameraInfo topics",
        )
    d = _field(msg, "d", "D")
    return CameraInfo(
        topic,
        str(frame_id or "").lstrip("/"),
        width,
        height,
        str(_field(msg, "distortion_model") or ""),
        tuple(float(x) for x in (d if d is not None else ())),
        k,
        _matrix(topic, _field(msg, "r", "R"), (3, 3), "R"),
        _matrix(topic, _field(msg, "p", "P"), (3, 4), "P"),
    )


@dataclass(frozen=True)
class StereoCalibration:
    """How the pairs of a log are rectified, and the rig they then follow.

    Attributes:
        rig: the rectified geometry every frame carries.
        rectification: the remap tables; None when the images are already rectified.
        method: how the calibration was found, for ``info``.
        size: (width, height) of the calibrated images.
        body_frame: the tf frame ``rig.body_from_left`` refers to ("" when none was found).
    """

    rig: StereoRig
    rectification: StereoRectification | None
    method: str
    size: tuple[int, int]
    body_frame: str

    def rectify(
        self, left: NDArray[np.uint8], right: NDArray[np.uint8]
    ) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        """A recorded pair -> the rectified pair (unchanged when already rectified)."""
        if self.rectification is None:
            return left, right
        return self.rectification.remap(left, right)


def calibrate_stereo(
    path: Path,
    infos: tuple[CameraInfo, CameraInfo],
    tf: TfBuffer,
    body: str | None,
    rectified_topics: bool = False,
) -> StereoCalibration:
    """The calibration of a pair from its two CameraInfos and tf (see the module docstring).

    Args:
        path: the log, for messages.
        infos: the left and the right camera's calibration.
        tf: the log's static transforms (and the first sample of moving ones).
        body: the body frame for ``body_from_left``; None: the left camera is the body.
        rectified_topics: the image topics are named ``image_rect...``.

    Raises:
        InputError: cameras of different sizes or distortion models, a right ``P`` without a
            baseline term and no tf between the cameras, or a right camera that is not to the
            right of the left one.
    """
    left, right = infos
    where = f"{path}: {left.topic} and {right.topic}"
    if (left.width, left.height) != (right.width, right.height):
        raise InputError(
            f"{where}: the cameras are calibrated for {left.width}x{left.height} and "
            f"{right.width}x{right.height} images; a stereo pair needs one size",
            hint="check --left-topic and --right-topic name the two cameras of one pair",
        )
    size = (left.width, left.height)
    body_from_cam, body_frame = body_from_camera(tf, body, left.frame_id)
    given_p = left.p is not None and right.p is not None
    if (left.undistorted and right.undistorted) or (rectified_topics and given_p):
        r1 = left.r if left.r is not None and not left.undistorted else np.eye(3)
        p1, p2 = left.projection, right.projection
        if right.has_baseline:
            baseline = float((p1[0, 3] - p2[0, 3]) / p2[0, 0])
            how = f"already rectified: P of {left.topic} and {right.topic}"
        else:
            baseline = _tf_baseline(where, tf, infos)
            how = f"already rectified: P of {left.topic}, baseline from tf"
        if not baseline > 0:
            raise InputError(
                f"{where}: the right camera is not to the right of the left one "
                f"(baseline {baseline:.4g} m)",
                hint=_RIGHT_HINT,
            )
        camera = PinholeCamera(
            size[0], size[1], float(p1[0, 0]), float(p1[1, 1]), float(p1[0, 2]), float(p1[1, 2])
        )
        rig = StereoRig(camera, baseline, body_from_cam @ make_pose(r1.T, np.zeros(3)))
        return StereoCalibration(rig, None, how, size, body_frame)
    pair = _raw_pair(where, infos, body_from_cam)
    if left.r is not None and right.r is not None and given_p and right.has_baseline:
        rect = rectify_with_projections(pair, (left.r, right.r), (left.p, right.p))
        how = f"rectified with the R and P of {left.topic} and {right.topic} ({pair.model})"
    else:
        rect = rectify_raw_pair(pair, _right_from_left(where, tf, infos))
        how = (
            f"rectified by stereoRectify from tf {left.frame_id} -> {right.frame_id} ({pair.model})"
        )
    return StereoCalibration(rect.rig, rect, how, size, body_frame)


def _raw_pair(
    where: str, infos: tuple[CameraInfo, CameraInfo], body_from_cam: F64
) -> RawStereoPair:
    left, right = infos
    models = [CAMERA_INFO_MODELS.get(i.model.strip().lower()) for i in infos]
    for info, model in zip(infos, models, strict=True):
        if model is None:
            raise InputError(
                f"{where}: {info.topic} has distortion model {info.model!r}",
                hint="stereo pairs are rectified from plumb_bob, rational_polynomial or "
                "equidistant calibrations",
            )
        if model == EQUIDISTANT and len(info.d) != 4:
            raise InputError(
                f"{where}: {info.topic} has {len(info.d)} equidistant coefficients, expected 4"
            )
    if models[0] != models[1]:
        raise InputError(
            f"{where}: the cameras have distortion models {left.model!r} and {right.model!r}; "
            "a stereo pair needs one"
        )
    return RawStereoPair(
        (left.raw_camera(), right.raw_camera()),
        (left.d, right.d),
        str(models[0]),
        body_from_cam,
        where,
        _RIGHT_HINT,
    )


def body_from_camera(tf: TfBuffer, body: str | None, frame: str) -> tuple[F64, str]:
    """(4, 4) body_from_camera and the body's name; the identity and "" when tf has none."""
    if body is None or not frame:
        return np.eye(4), ""
    try:
        return tf.lookup(body, frame, 0), body
    except InputError as exc:
        log.warning(
            "no transform %s <- %s in tf (%s); the left camera is the body", body, frame, exc
        )
        return np.eye(4), ""


def _right_from_left(where: str, tf: TfBuffer, infos: tuple[CameraInfo, CameraInfo]) -> F64:
    left, right = infos
    try:
        return tf.lookup(right.frame_id, left.frame_id, 0)
    except InputError as exc:
        raise InputError(
            f"{where}: {right.topic} has no P with a baseline term (P[0,3] = -fx * baseline) "
            f"and tf has no transform between {left.frame_id or '(no frame id)'} and "
            f"{right.frame_id or '(no frame id)'} ({exc.msg})",
            hint="record the stereo calibration's P in the CameraInfo, or the camera frames "
            "on /tf_static",
        ) from None


def _tf_baseline(where: str, tf: TfBuffer, infos: tuple[CameraInfo, CameraInfo]) -> float:
    """The baseline of rectified cameras from tf: the left camera's x in the right one."""
    t = _right_from_left(where, tf, infos)[:3, 3]
    return float(np.linalg.norm(t)) if t[0] < 0 else -float(t[0])


__all__ = [
    "CAMERA_INFO_MODELS",
    "CameraInfo",
    "StereoCalibration",
    "body_from_camera",
    "calibrate_stereo",
    "read_camera_info",
]
