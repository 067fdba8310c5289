"""EuRoC / ASL ``sensor.yaml`` files and the rectification of a stereo pair.

An ASL sensor file is YAML written the way OpenCV's ``FileStorage`` writes it: its first line
is the directive ``%YAML:1.0``, which PyYAML refuses, so :func:`read_sensor_yaml` blanks it
(keeping the line numbers) before parsing. A camera's file holds ``T_BS`` (body_from_sensor,
a 4x4 row-major ``data`` list), ``resolution`` [width, height], ``intrinsics`` [fu, fv, cu, cv],
``distortion_model`` (``radial-tangential``: OpenCV's plumb_bob k1 k2 p1 p2; ``equidistant``:
OpenCV's fisheye k1 k2 k3 k4) and ``distortion_coefficients``; the IMU's file holds ``T_BS``,
``rate_hz`` and the noise densities and random walks.

:func:`rectify_stereo` rectifies two such cameras with OpenCV's ``stereoRectify`` (``alpha``
0: every rectified pixel sees the scene; ``fisheye.stereoRectify`` with ``balance`` 0 for the
equidistant model) and builds the remap tables once. OpenCV takes the pose of the second camera
relative to the first as ``x_1 = R x_0 + T``, i.e. ``cam1_from_cam0 = inv(T_BS1) @ T_BS0``;
its ``R1`` rotates the raw left camera onto the rectified one (``rect_from_cam0``), so the
rectified left camera sits on the body at ``T_BS0 @ inv(R1)``.

The same rectification serves cameras described otherwise (a log's ``CameraInfo`` messages):
:func:`rectify_raw_pair` takes a :class:`RawStereoPair` and the pose between the two cameras;
:func:`rectify_with_projections` builds the tables of a rectification already computed (ROS's
stereo calibration stores each camera's ``R`` and ``P``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from slamcli.errors import FormatError, InputError
from slamcli.formats.images import size_problem
from slamcli.formats.text import (
    MAX_YAML_BYTES,
    check_yaml_expansion,
    read_limited_text,
    yaml_problem,
)
from slamcli.geometry.se3 import inverse, make_pose
from slamcli.types import PinholeCamera, StereoRig

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

RADTAN = "radial-tangential"
EQUIDISTANT = "equidistant"
DISTORTION_MODELS = {
    "radial-tangential": RADTAN,
    "radtan": RADTAN,
    "plumb_bob": RADTAN,
    "equidistant": EQUIDISTANT,
    "equi": EQUIDISTANT,
    "fisheye": EQUIDISTANT,
}
"""Distortion model names an ASL or Kalibr file may use, by the model they mean."""

ROTATION_TOL = 1e-3
"""Largest deviation of ``R^T R`` from identity accepted in a ``T_BS`` (its rows are printed to
about 12 digits, so real files are far below it)."""

_DIRECTIVE = re.compile(r"^%YAML[: ]\d+\.\d+\s*$")
_YAML11_EXPONENT = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)[eE][+-]?\d+", re.ASCII)
_CAMERA_HINT = (
    "an ASL camera sensor.yaml has T_BS (rows, cols, data: 16 numbers), resolution [w, h], "
    "intrinsics [fu, fv, cu, cv], distortion_model and distortion_coefficients"
)
_IMU_HINT = (
    "an ASL IMU sensor.yaml has T_BS, rate_hz, gyroscope_noise_density, gyroscope_random_walk, "
    "accelerometer_noise_density and accelerometer_random_walk"
)


@dataclass(frozen=True)
class CameraSensor:
    """One camera of an ASL folder, as its ``sensor.yaml`` describes it.

    Attributes:
        path: the sensor file.
        camera: the raw intrinsics; ``distortion`` holds OpenCV's k1 k2 p1 p2 for the
            radial-tangential model and is empty for the equidistant one (see ``coefficients``).
        model: :data:`RADTAN` or :data:`EQUIDISTANT`.
        coefficients: the distortion coefficients as the file lists them.
        body_from_sensor: (4, 4) float64 ``T_BS``.
    """

    path: Path
    camera: PinholeCamera
    model: str
    coefficients: tuple[float, ...]
    body_from_sensor: F64


IMU_NOISE_KEYS = (
    "gyroscope_noise_density",
    "gyroscope_random_walk",
    "accelerometer_noise_density",
    "accelerometer_random_walk",
)
"""An IMU's noise model by ASL's names and units (``sensor.yaml``): what a visual-inertial run
needs besides the samples, wherever the IMU comes from (an ASL folder, an MCAP channel's
metadata)."""


@dataclass(frozen=True)
class ImuSensor:
    """The IMU of an ASL folder: ``T_BS``, the nominal rate and the noise model.

    Attributes:
        path: the sensor file.
        rate_hz: the nominal sample rate.
        gyroscope_noise_density: rad / s / sqrt(Hz).
        gyroscope_random_walk: rad / s^2 / sqrt(Hz).
        accelerometer_noise_density: m / s^2 / sqrt(Hz).
        accelerometer_random_walk: m / s^3 / sqrt(Hz).
        body_from_sensor: (4, 4) float64 ``T_BS``.
    """

    path: Path
    rate_hz: float
    gyroscope_noise_density: float
    gyroscope_random_walk: float
    accelerometer_noise_density: float
    accelerometer_random_walk: float
    body_from_sensor: F64

    def noise(self) -> dict[str, float]:
        """The noise settings by their ASL names (for ``info``)."""
        return {key: float(getattr(self, key)) for key in IMU_NOISE_KEYS}

    def details(self) -> dict[str, Any]:
        """What a source's ``info`` gives as ``details["imu"]``: ``rate_hz``, the noise
        settings and ``body_from_imu``."""
        return {
            "rate_hz": self.rate_hz,
            **self.noise(),
            "body_from_imu": self.body_from_sensor.tolist(),
        }


@dataclass(frozen=True)
class StereoRectification:
    """A rectified stereo pair's geometry and the remap tables that produce it.

    Attributes:
        rig: the rectified geometry (camera from ``P1``, baseline from ``P2``,
            ``body_from_left`` from ``T_BS0`` and ``R1``).
        left_map, right_map: two (H, W) float32 tables each, the raw-image x and y of every
            rectified pixel of the left and the right image.
        left_from_raw: (3, 3) float64 rotation ``R1`` from the raw left camera to the rectified
            one; ``right_from_raw`` is ``R2`` for the right camera.
        left_projection, right_projection: (3, 4) float64 rectified projections ``P1`` and
            ``P2`` as OpenCV gives them (``P2[0, 3] = -fx * baseline``), for a ``CameraInfo``.
    """

    rig: StereoRig
    left_map: tuple[F32, F32]
    right_map: tuple[F32, F32]
    left_from_raw: F64
    right_from_raw: F64
    left_projection: F64
    right_projection: F64

    def remap(
        self, left: NDArray[np.uint8], right: NDArray[np.uint8]
    ) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        """Raw left and right images (of the calibrated size) -> the rectified pair (bilinear;
        pixels seeing outside the raw image are 0)."""
        import cv2

        out: list[NDArray[np.uint8]] = []
        for image, (mx, my) in ((left, self.left_map), (right, self.right_map)):
            rectified = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            out.append(np.asarray(rectified, dtype=np.uint8))
        return out[0], out[1]


def read_sensor_yaml(path: str | Path) -> dict[str, Any]:
    """An ASL ``sensor.yaml`` as a mapping (the ``%YAML:1.0`` directive OpenCV writes is blanked).

    Raises:
        InputError: the file does not exist or cannot be read.
        FormatError: not valid YAML, or not a mapping of keys; larger than
            :data:`~slamcli.formats.text.MAX_YAML_BYTES` or, its aliases expanded, than
            :data:`~slamcli.formats.text.MAX_YAML_VALUES` values.
    """
    p = Path(path)
    try:
        text = read_limited_text(p, MAX_YAML_BYTES, "a sensor.yaml", _CAMERA_HINT)
    except FileNotFoundError:
        raise InputError(f"{p}: no such file", hint=_CAMERA_HINT) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot be read ({exc})") from None
    lines = text.splitlines()
    if lines and _DIRECTIVE.match(lines[0]):
        lines[0] = "#"
    text = "\n".join(lines)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        problem, line = yaml_problem(exc, text)
        raise FormatError(p, f"not valid YAML ({problem})", line) from None
    check_yaml_expansion(p, data)
    if not isinstance(data, dict):
        found = "an empty file" if data is None else f"a {type(data).__name__}"
        raise FormatError(p, f"expected a mapping of keys, found {found}")
    return data


def _require(p: Path, data: dict[str, Any], key: str, hint: str) -> Any:
    if key not in data or data[key] is None:
        raise FormatError(p, f"missing key {key!r}", hint=hint)
    return data[key]


def _to_float(p: Path, key: str, value: Any, hint: str) -> float:
    if isinstance(value, str) and _YAML11_EXPONENT.fullmatch(value.strip()):
        # YAML 1.1 (PyYAML) reads 1e-05, an exponent without a decimal point, as a string;
        # OpenCV, which wrote the file, means the number.
        value = float(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise FormatError(p, f"key {key!r}: expected a number, found {value!r}", hint=hint)
    return float(value)


def _floats(p: Path, data: dict[str, Any], key: str, sizes: tuple[int, ...], hint: str) -> F64:
    value = _require(p, data, key, hint)
    if not isinstance(value, list) or len(value) not in sizes:
        want = " or ".join(str(n) for n in sizes)
        raise FormatError(p, f"key {key!r}: expected a list of {want} numbers, found {value!r}")
    return np.array([_to_float(p, f"{key}[{i}]", v, hint) for i, v in enumerate(value)])


def _number(p: Path, data: dict[str, Any], key: str, hint: str, positive: bool = True) -> float:
    value = _to_float(p, key, _require(p, data, key, hint), hint)
    if positive and value <= 0:
        raise FormatError(p, f"key {key!r}: must be > 0, found {value!r}", hint=hint)
    return value


def _body_from_sensor(p: Path, data: dict[str, Any], hint: str) -> F64:
    """``T_BS`` as a (4, 4) rigid transform: a mapping with a 16-number ``data`` list (OpenCV's
    matrix layout), or the 16 numbers themselves."""
    value = _require(p, data, "T_BS", hint)
    if isinstance(value, dict):
        rows, cols = value.get("rows", 4), value.get("cols", 4)
        if (rows, cols) != (4, 4):
            raise FormatError(p, f"key 'T_BS': expected a 4x4 matrix, found {rows}x{cols}")
        m = _floats(p, value, "data", (16,), hint)
    else:
        m = _floats(p, data, "T_BS", (16,), hint)
    return check_rigid(
        p, "T_BS", m.reshape(4, 4), "T_BS is body_from_sensor, row-major: [R t; 0 0 0 1]"
    )


def check_rigid(p: Path, key: str, t: F64, hint: str) -> F64:
    """``t`` when it is a (4, 4) rigid transform (a rotation within :data:`ROTATION_TOL`, last
    row 0 0 0 1).

    Raises:
        FormatError: it is not (names the file and ``key``).
    """
    r = t[:3, :3]
    error = float(np.abs(r.T @ r - np.eye(3)).max())
    if error > ROTATION_TOL or not np.allclose(t[3], (0.0, 0.0, 0.0, 1.0)) or np.linalg.det(r) < 0:
        raise FormatError(
            p,
            f"key {key!r}: not a rigid transform (rotation off by {error:.2g}, last row "
            f"{t[3].tolist()})",
            hint=hint,
        )
    return t


def check_pinhole(
    p: Path, size: F64, intrinsics: F64, name: Callable[[str], str]
) -> tuple[int, int, float, float, float, float]:
    """A pinhole camera's ``resolution`` [w, h] and ``intrinsics`` [fu, fv, cu, cv], checked:
    whole pixel counts of a size images may have, and positive focal lengths.

    Raises:
        FormatError: they are not (names the file, and the key as ``name(key)`` writes it).
    """
    if np.any(size <= 0) or np.any(size != np.round(size)):
        raise FormatError(
            p, f"{name('resolution')}: expected two pixel counts, found {size.tolist()}"
        )
    width, height = int(size[0]), int(size[1])
    problem = size_problem(width, height)
    if problem:
        raise FormatError(p, f"{name('resolution')}: the camera {problem}")
    fu, fv, cu, cv = (float(v) for v in intrinsics)
    if fu <= 0 or fv <= 0:
        raise FormatError(p, f"{name('intrinsics')}: focal lengths must be > 0, found {fu}, {fv}")
    return width, height, fu, fv, cu, cv


def read_camera_sensor(path: str | Path) -> CameraSensor:
    """A camera's ``sensor.yaml`` (see the module docstring).

    Raises:
        FormatError: a missing key, a bad value or an unsupported model (names file and key).
    """
    p = Path(path)
    data = read_sensor_yaml(p)
    body_from_sensor = _body_from_sensor(p, data, _CAMERA_HINT)
    model_name = str(data.get("camera_model", "pinhole"))
    if model_name != "pinhole":
        raise FormatError(
            p,
            f"key 'camera_model': expected 'pinhole', found {model_name!r}",
            hint="only pinhole cameras (radial-tangential or equidistant distortion) are read",
        )
    width, height, fu, fv, cu, cv = check_pinhole(
        p,
        _floats(p, data, "resolution", (2,), _CAMERA_HINT),
        _floats(p, data, "intrinsics", (4,), _CAMERA_HINT),
        lambda key: f"key {key!r}",
    )
    given = str(_require(p, data, "distortion_model", _CAMERA_HINT))
    model = DISTORTION_MODELS.get(given.lower())
    if model is None:
        raise FormatError(
            p,
            f"key 'distortion_model': expected radial-tangential or equidistant, found {given!r}",
        )
    sizes = (4, 5) if model == RADTAN else (4,)
    coefficients = tuple(_floats(p, data, "distortion_coefficients", sizes, _CAMERA_HINT).tolist())
    distortion = coefficients if model == RADTAN and any(coefficients) else ()
    camera = PinholeCamera(width, height, fu, fv, cu, cv, distortion)
    return CameraSensor(p, camera, model, coefficients, body_from_sensor)


def read_imu_sensor(path: str | Path) -> ImuSensor:
    """The IMU's ``sensor.yaml``: ``T_BS``, ``rate_hz`` and the four noise settings.

    Raises:
        FormatError: a missing key or a bad value (names file and key).
    """
    p = Path(path)
    data = read_sensor_yaml(p)
    return ImuSensor(
        p,
        _number(p, data, "rate_hz", _IMU_HINT),
        _number(p, data, "gyroscope_noise_density", _IMU_HINT),
        _number(p, data, "gyroscope_random_walk", _IMU_HINT),
        _number(p, data, "accelerometer_noise_density", _IMU_HINT),
        _number(p, data, "accelerometer_random_walk", _IMU_HINT),
        _body_from_sensor(p, data, _IMU_HINT),
    )


@dataclass(frozen=True)
class RawStereoPair:
    """Two raw cameras to be rectified into one :class:`StereoRectification`.

    Attributes:
        cameras: the left and the right raw camera (size and ``K``; both of one size).
        coefficients: each camera's distortion coefficients as OpenCV takes them for ``model``
            (k1 k2 p1 p2 [k3 ...] for :data:`RADTAN`, k1 k2 k3 k4 for :data:`EQUIDISTANT`).
        model: :data:`RADTAN` or :data:`EQUIDISTANT`.
        body_from_left: (4, 4) float64 pose of the raw left camera on the body.
        where: names the pair in messages (files, topics).
        hint: what to check when the right camera is not to the right of the left one.
    """

    cameras: tuple[PinholeCamera, PinholeCamera]
    coefficients: tuple[tuple[float, ...], tuple[float, ...]]
    model: str
    body_from_left: F64
    where: str
    hint: str = "a stereo pair has cam0 on the left and cam1 on its right"


def rectify_stereo(left: CameraSensor, right: CameraSensor) -> StereoRectification:
    """Rectify a horizontal stereo pair (see the module docstring) and build its remap tables.

    Raises:
        InputError: the cameras differ in size or distortion model, the right camera is not
            to the right of the left one, or the pair is vertical.
    """
    a, b = left.camera, right.camera
    if (a.width, a.height) != (b.width, b.height) or left.model != right.model:
        raise InputError(
            f"{left.path} and {right.path}: a stereo pair needs two cameras of one size and "
            f"distortion model, found {a.width}x{a.height} {left.model} and "
            f"{b.width}x{b.height} {right.model}"
        )
    pair = RawStereoPair(
        (a, b),
        (left.coefficients, right.coefficients),
        left.model,
        left.body_from_sensor,
        f"{left.path} and {right.path}",
        "a stereo pair has cam0 on the left and cam1 on its right; check the T_BS",
    )
    return rectify_raw_pair(pair, inverse(right.body_from_sensor) @ left.body_from_sensor)


def rectify_raw_pair(pair: RawStereoPair, right_from_left: F64) -> StereoRectification:
    """Rectify two raw cameras with OpenCV's ``stereoRectify`` (``fisheye.stereoRectify`` for
    the equidistant model) given the (4, 4) pose of the left camera in the right one
    (``x_right = R x_left + T``), and build the remap tables.

    Raises:
        InputError: the right camera is not to the right of the left one, or the pair is
            vertical.
    """
    import cv2

    a, b = pair.cameras
    # OpenCV's fisheye module reshapes its inputs and needs them contiguous.
    rotation = np.ascontiguousarray(right_from_left[:3, :3], dtype=np.float64)
    translation = np.ascontiguousarray(right_from_left[:3, 3].reshape(3, 1), dtype=np.float64)
    size = (a.width, a.height)
    d0, d1 = (np.asarray(c, dtype=np.float64) for c in pair.coefficients)
    if pair.model == RADTAN:
        r1, r2, p1, p2 = cv2.stereoRectify(
            a.K, d0, b.K, d1, size, rotation, translation, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
        )[:4]
    else:
        r1, r2, p1, p2 = cv2.fisheye.stereoRectify(
            a.K,
            d0,
            b.K,
            d1,
            size,
            rotation,
            translation,
            flags=cv2.CALIB_ZERO_DISPARITY,
            newImageSize=size,
            balance=0.0,
            fov_scale=1.0,
        )[:4]
    return rectify_with_projections(pair, (r1, r2), (p1, p2))


def rectify_with_projections(
    pair: RawStereoPair, rotations: tuple[Any, Any], projections: tuple[Any, Any]
) -> StereoRectification:
    """The remap tables of a rectification already computed, as ROS's stereo calibration
    stores it: each camera's rotation ``R`` onto the rectified frame (3x3) and rectified
    projection ``P`` (3x4; the right one's ``P[0,3] = -fx * baseline``).

    Raises:
        InputError: the right camera is not to the right of the left one, or the pair is
            vertical.
    """
    import cv2

    a, b = pair.cameras
    size = (a.width, a.height)
    r1, r2 = (np.asarray(r, dtype=np.float64).reshape(3, 3) for r in rotations)
    p1, p2 = (np.asarray(p, dtype=np.float64).reshape(3, 4) for p in projections)
    d0, d1 = (np.asarray(c, dtype=np.float64) for c in pair.coefficients)
    init = (
        cv2.initUndistortRectifyMap if pair.model == RADTAN else cv2.fisheye.initUndistortRectifyMap
    )
    maps = [
        init(k, d, r, np.ascontiguousarray(p[:, :3]), size, cv2.CV_32FC1)
        for k, d, r, p in ((a.K, d0, r1, p1), (b.K, d1, r2, p2))
    ]
    baseline = (p1[0, 3] - p2[0, 3]) / p2[0, 0]
    if abs(p2[1, 3] - p1[1, 3]) > 1e-9 * abs(p2[0, 0]) or baseline <= 0:
        raise InputError(
            f"{pair.where}: the second camera is not to the right of the first "
            f"(rectified offset x {-p2[0, 3]:.4g}, y {-p2[1, 3]:.4g} pixel metres)",
            hint=pair.hint,
        )
    fx, fy, cx, cy = (float(v) for v in (p1[0, 0], p1[1, 1], p1[0, 2], p1[1, 2]))
    camera = PinholeCamera(a.width, a.height, fx, fy, cx, cy)
    body_from_left = pair.body_from_left @ make_pose(r1.T, np.zeros(3))
    return StereoRectification(
        StereoRig(camera, float(baseline), body_from_left),
        _tables(maps[0]),
        _tables(maps[1]),
        r1,
        r2,
        p1,
        p2,
    )


def _tables(maps: Any) -> tuple[F32, F32]:
    return np.asarray(maps[0], dtype=np.float32), np.asarray(maps[1], dtype=np.float32)


__all__ = [
    "DISTORTION_MODELS",
    "EQUIDISTANT",
    "RADTAN",
    "CameraSensor",
    "ImuSensor",
    "RawStereoPair",
    "StereoRectification",
    "read_camera_sensor",
    "read_imu_sensor",
    "read_sensor_yaml",
    "rectify_raw_pair",
    "rectify_stereo",
    "rectify_with_projections",
]
