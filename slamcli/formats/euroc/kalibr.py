"""Kalibr calibration files (``--calib``): the camera chain with its IMU, and the IMU's noise.

Kalibr (ETH's ASL, which also recorded EuRoC) writes the calibration most camera-IMU users
have. Two kinds of file are read, told apart by their keys:

* **the camera chain** (``camchain.yaml``, or ``camchain-imucam.yaml`` from a camera-IMU
  calibration): one mapping per camera, ``cam0``, ``cam1``, ..., each with ``camera_model``
  (``pinhole`` is read), ``intrinsics`` [fu, fv, pu, pv], ``distortion_model`` (``radtan``,
  ``equidistant`` or ``none``), ``distortion_coeffs``, ``resolution`` [w, h] and ``rostopic``;
  ``T_cam_imu`` (imu -> camera: ``x_cam = T x_imu``) after a camera-IMU calibration,
  ``T_cn_cnm1`` (the previous camera -> this one) for every camera after the first, and
  ``timeshift_cam_imu`` (seconds: ``t_imu = t_cam + shift``). 4x4 matrices are lists of four
  rows.
* **the IMU** (``imu.yaml``, the input of ``kalibr_calibrate_imu_camera``, or an ``imu0``
  mapping of its results): ``accelerometer_noise_density``, ``accelerometer_random_walk``,
  ``gyroscope_noise_density``, ``gyroscope_random_walk`` (continuous-time, the units of an ASL
  ``sensor.yaml``), ``update_rate`` (Hz) and ``rostopic``.

The result is what an ASL folder's ``sensor.yaml`` files give (:class:`CameraSensor`,
:class:`ImuSensor`), on one body: **the IMU**, as in EuRoC, when the chain has ``T_cam_imu``
(``body_from_cam = inv(T_cam_imu)``, ``body_from_imu`` the identity); else the first camera
(a chain from a camera-only calibration, which cannot place an IMU).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import FormatError, InputError
from slamcli.formats.euroc.calibration import (
    DISTORTION_MODELS,
    IMU_NOISE_KEYS,
    RADTAN,
    CameraSensor,
    ImuSensor,
    StereoRectification,
    _floats,
    _number,
    _require,
    check_pinhole,
    check_rigid,
    read_sensor_yaml,
    rectify_stereo,
)
from slamcli.geometry.se3 import inverse
from slamcli.types import PinholeCamera

F64 = NDArray[np.float64]

_CHAIN_HINT = (
    "a Kalibr camchain.yaml holds cam0, cam1, ... each with camera_model, intrinsics "
    "[fu, fv, pu, pv], distortion_model, distortion_coeffs, resolution [w, h], and T_cam_imu "
    "(camchain-imucam.yaml) or T_cn_cnm1 as four rows of four numbers"
)
_IMU_HINT = (
    "a Kalibr imu.yaml holds accelerometer_noise_density, accelerometer_random_walk, "
    "gyroscope_noise_density, gyroscope_random_walk and update_rate (at the top, or under imu0)"
)


@dataclass(frozen=True)
class KalibrCalibration:
    """What ``--calib`` files give (see the module docstring).

    Attributes:
        paths: the files read.
        cameras: the chain's cameras in order, placed on the body (empty without a chain).
        camera_topics: each camera's ``rostopic`` ("" when not given).
        time_shift_ns: ``timeshift_cam_imu`` of ``cam0`` in ns: add it to an image stamp to
            get the IMU's time.
        imu: the IMU's noise model and rate, ``body_from_sensor`` on the body (None without
            an IMU file).
        imu_topic: the IMU's ``rostopic`` ("" when not given).
        imu_placed: whether the chain places the IMU (``T_cam_imu``): the body is the IMU.
    """

    paths: tuple[Path, ...]
    cameras: tuple[CameraSensor, ...] = ()
    camera_topics: tuple[str, ...] = ()
    time_shift_ns: int = 0
    imu: ImuSensor | None = None
    imu_topic: str = ""
    imu_placed: bool = False

    @property
    def where(self) -> str:
        """The files, for messages."""
        return ", ".join(str(p) for p in self.paths)

    @property
    def chain_path(self) -> Path | None:
        """The camera chain's file, None without one."""
        return self.cameras[0].path if self.cameras else None

    def stereo(self, body_from_cam0: F64 | None = None) -> StereoRectification:
        """The rectification of ``cam0`` and ``cam1``, on the body as
        :meth:`cameras_on_body` places them.

        Raises:
            InputError: the chain has fewer than two cameras, or they cannot form a pair.
        """
        if len(self.cameras) < 2:
            raise InputError(
                f"{self.chain_path or self.where}: the camera chain has "
                f"{len(self.cameras)} camera(s); a stereo pair needs cam0 and cam1",
                hint="run it monocular (--set mode=mono), or give the chain of both cameras",
            )
        left, right = self.cameras_on_body(body_from_cam0)[:2]
        return rectify_stereo(left, right)

    def cameras_on_body(self, body_from_cam0: F64 | None) -> tuple[CameraSensor, ...]:
        """The chain's cameras on the body: as read when the chain places the IMU (the body is
        the IMU), else moved so that ``cam0`` sits at ``body_from_cam0`` (the input's own
        mounting of its first camera; None: ``cam0`` is the body)."""
        if self.imu_placed or body_from_cam0 is None:
            return self.cameras
        base = np.asarray(body_from_cam0, np.float64)
        return tuple(replace(c, body_from_sensor=base @ c.body_from_sensor) for c in self.cameras)

    def imu_on_body(self, fallback: F64 | None) -> ImuSensor | None:
        """The IMU placed on the body: by the chain (the body is the IMU), else at
        ``fallback`` (the input's own ``body_from_imu``); None without an IMU file.

        Raises:
            InputError: neither the chain nor the input places the IMU.
        """
        if self.imu is None:
            return None
        if self.imu_placed:
            return self.imu
        if fallback is None:
            raise InputError(
                f"{self.where}: the IMU's noise is given but nothing places it on the cameras",
                hint="give the camchain-imucam.yaml of a Kalibr camera-IMU calibration "
                "(it has T_cam_imu) with --calib",
            )
        return replace(self.imu, body_from_sensor=np.asarray(fallback, np.float64))


def read_kalibr(paths: list[str | Path] | tuple[str | Path, ...]) -> KalibrCalibration:
    """Read ``--calib`` files: at most one camera chain and one IMU file.

    Raises:
        InputError: a file is missing or unreadable, or two files of one kind are given.
        FormatError: a file is neither kind, or a key is missing or bad (names file and key).
    """
    out = KalibrCalibration(tuple(Path(p) for p in paths))
    chain_seen = imu_seen = None
    for given in paths:
        p = Path(given)
        data = read_sensor_yaml(p)
        if _is_chain(data):
            if chain_seen is not None:
                raise InputError(f"{chain_seen} and {p}: two camera chains given with --calib")
            chain_seen = p
            cameras, topics, shift, placed = _read_chain(p, data)
            out = replace(
                out,
                cameras=cameras,
                camera_topics=topics,
                time_shift_ns=round(shift * 1e9),
                imu_placed=placed,
            )
        elif _imu_mapping(data) is not None:
            if imu_seen is not None:
                raise InputError(f"{imu_seen} and {p}: two IMU files given with --calib")
            imu_seen = p
            imu, topic = _read_imu(p, _imu_mapping(data) or {})
            out = replace(out, imu=imu, imu_topic=topic)
        else:
            raise FormatError(
                p,
                "neither a Kalibr camera chain (cam0: ...) nor an IMU file "
                "(accelerometer_noise_density, ...)",
                hint=f"{_CHAIN_HINT}; {_IMU_HINT}",
            )
    if out.imu is not None and out.imu_placed:
        out = replace(out, imu=replace(out.imu, body_from_sensor=np.eye(4)))
    return out


def _is_chain(data: dict[str, Any]) -> bool:
    return isinstance(data.get("cam0"), dict)


def _imu_mapping(data: dict[str, Any]) -> dict[str, Any] | None:
    """The IMU's keys: the file's top level, or its ``imu0`` mapping (Kalibr's results)."""
    for candidate in (data, data.get("imu0")):
        if isinstance(candidate, dict) and any(k in candidate for k in IMU_NOISE_KEYS):
            return candidate
    return None


def _numbers(p: Path, name: str, value: Any, sizes: tuple[int, ...]) -> F64:
    """A list of numbers of one of ``sizes``, ``name`` (``cam0.intrinsics``) in messages."""
    return _floats(p, {name: value}, name, sizes, _CHAIN_HINT)


def _matrix(p: Path, cam: str, data: dict[str, Any], key: str) -> F64:
    rows = _require(p, data, key, _CHAIN_HINT)
    if not isinstance(rows, list) or len(rows) != 4:
        raise FormatError(p, f"{cam}.{key}: expected four rows of four numbers, found {rows!r}")
    flat = [v for row in rows for v in (row if isinstance(row, list) else [row])]
    m = _numbers(p, f"{cam}.{key}", flat, (16,)).reshape(4, 4)
    return check_rigid(p, f"{cam}.{key}", m, f"{key} is [R t; 0 0 0 1], as four rows")


def _read_camera(p: Path, cam: str, data: dict[str, Any]) -> tuple[PinholeCamera, str, tuple]:
    def key(name: str) -> str:
        return f"{cam}.{name}"

    model_name = str(data.get("camera_model", "pinhole"))
    if model_name != "pinhole":
        raise FormatError(
            p,
            f"{key('camera_model')}: expected 'pinhole', found {model_name!r}",
            hint="only pinhole cameras (radtan or equidistant distortion) are read; "
            "calibrate with Kalibr's pinhole-radtan or pinhole-equi model",
        )
    width, height, fu, fv, cu, cv = check_pinhole(
        p,
        _numbers(p, key("resolution"), _require(p, data, "resolution", _CHAIN_HINT), (2,)),
        _numbers(p, key("intrinsics"), _require(p, data, "intrinsics", _CHAIN_HINT), (4,)),
        key,
    )
    given = str(data.get("distortion_model", "none")).lower()
    if given == "none":
        model, coefficients = RADTAN, (0.0, 0.0, 0.0, 0.0)
    else:
        found = DISTORTION_MODELS.get(given)
        if found is None:
            raise FormatError(
                p,
                f"{key('distortion_model')}: expected radtan, equidistant or none, found {given!r}",
                hint=_CHAIN_HINT,
            )
        model = found
        sizes = (4, 5) if model == RADTAN else (4,)
        given_coefficients = _require(p, data, "distortion_coeffs", _CHAIN_HINT)
        coefficients = tuple(
            _numbers(p, key("distortion_coeffs"), given_coefficients, sizes).tolist()
        )
    distortion = coefficients if model == RADTAN and any(coefficients) else ()
    return PinholeCamera(width, height, fu, fv, cu, cv, distortion), model, coefficients


def _read_chain(
    p: Path, data: dict[str, Any]
) -> tuple[tuple[CameraSensor, ...], tuple[str, ...], float, bool]:
    names = []
    while isinstance(data.get(f"cam{len(names)}"), dict):
        names.append(f"cam{len(names)}")
    placed = all("T_cam_imu" in data[n] for n in names)
    cameras: list[CameraSensor] = []
    topics: list[str] = []
    previous = np.eye(4)  # the previous camera on the body
    for i, cam in enumerate(names):
        entry = data[cam]
        camera, model, coefficients = _read_camera(p, cam, entry)
        if placed:
            body_from_cam = inverse(_matrix(p, cam, entry, "T_cam_imu"))
        elif i == 0:
            body_from_cam = np.eye(4)
        else:
            # T_cn_cnm1 takes the previous camera's coordinates into this one's.
            body_from_cam = previous @ inverse(_matrix(p, cam, entry, "T_cn_cnm1"))
        previous = body_from_cam
        cameras.append(CameraSensor(p, camera, model, coefficients, body_from_cam))
        topics.append(str(entry.get("rostopic") or ""))
    shift = data["cam0"].get("timeshift_cam_imu", 0.0)
    shift = float(_numbers(p, "cam0.timeshift_cam_imu", [shift], (1,))[0])
    if abs(shift) > 1.0:
        raise FormatError(
            p,
            f"cam0.timeshift_cam_imu: {shift} s; Kalibr's shifts are fractions of a frame",
            hint="timeshift_cam_imu is in seconds (t_imu = t_cam + shift)",
        )
    return tuple(cameras), tuple(topics), shift, placed


def _read_imu(p: Path, data: dict[str, Any]) -> tuple[ImuSensor, str]:
    noise = {k: _number(p, data, k, _IMU_HINT) for k in IMU_NOISE_KEYS}
    rate = _number(p, data, "update_rate", _IMU_HINT)
    imu = ImuSensor(p, rate, **noise, body_from_sensor=np.eye(4))
    return imu, str(data.get("rostopic") or "")


__all__ = ["KalibrCalibration", "read_kalibr"]
