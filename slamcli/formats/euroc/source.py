"""EuRoC / ASL folders as a :class:`~slamcli.formats.base.Source` of rectified stereo pairs,
single images and IMU samples.

The layout (a folder holding ``mav0/``, or ``mav0/`` itself)::

    mav0/cam0/data.csv      #timestamp [ns],filename     and cam0/data/<stamp>.png
    mav0/cam0/sensor.yaml   T_BS, resolution, intrinsics, distortion (calibration.py)
    mav0/cam1/...           the right camera, the same way (optional: cam0 alone is monocular)
    mav0/imu0/data.csv      t [ns], w_x w_y w_z [rad/s], a_x a_y a_z [m/s^2]
    mav0/imu0/sensor.yaml   T_BS, rate_hz, noise densities and random walks
    mav0/state_groundtruth_estimate0/data.csv   optional: EuRoC's ground truth of the body

A folder with ``cam0`` alone gives single images (``image``) and IMU samples: a monocular
input. A stereo folder gives ``image`` frames too: ``cam0``'s images alone, for a monocular
run. An ``image`` frame is the recorded image with its camera as calibrated (OpenCV's k1 k2 p1
p2 for the radial-tangential model, undistorted by the pipeline's keypoints; an equidistant
camera's image is remapped to a pinhole one with the same intrinsics) and ``cam0``'s ``T_BS``
as its ``body_from_camera``.

A stereo pair is a left and a right stamp whose images both exist. EuRoC's cameras are
triggered together, so the two ``data.csv`` list equal stamps; they are paired one to one,
nearest first, within ``max_dt`` (default :data:`PAIR_MAX_DT_S`, 1 ms), which takes equal
stamps and tolerates a rounding of the last digits. Listed images that do not exist are left
out of the pairs and reported by :meth:`EurocSource.info`. A pair whose images are not of the
calibrated size (or cannot be decoded) is skipped with a warning naming the file and counted in
:attr:`EurocSource.stats`, so a run reports the loss.

The body frame is EuRoC's: the IMU's (``imu0`` ``T_BS`` is the identity there), which the
ground truth of ``state_groundtruth_estimate0`` also follows; the rig's ``body_from_left``
places the rectified left camera on it.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Collection, Iterator
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats import sniff
from slamcli.formats.base import (
    ReadStats,
    SourceBase,
    SourceInfo,
    StreamInfo,
    known_kinds,
    provided_kinds,
)
from slamcli.formats.euroc.calibration import (
    EQUIDISTANT,
    CameraSensor,
    ImuSensor,
    StereoRectification,
    read_camera_sensor,
    read_imu_sensor,
    rectify_stereo,
)
from slamcli.formats.euroc.kalibr import KalibrCalibration, read_kalibr
from slamcli.formats.images import decode_image, image_size, read_image_file
from slamcli.formats.pairing import associate_stamps
from slamcli.formats.text import iter_data_lines, parse_count, parse_floats
from slamcli.formats.trajectory import read_trajectory
from slamcli.types import (
    Frame,
    ImageFrame,
    ImuFrame,
    PinholeCamera,
    ProgressFn,
    StereoFrame,
    StereoRig,
    Trajectory,
)

log = logging.getLogger(__name__)

FRAME_KINDS = ("stereo", "image", "imu")
"""The frame kinds an ASL folder provides (one with ``cam0`` alone: ``image`` and ``imu``)."""

MONO_FRAME_KINDS = ("image", "imu")
IMU_MARGIN_S = 1.0
"""IMU samples further than this before the first image or after the last are not read with
the images (a visual-inertial run needs none of them)."""
"""The frame kinds of an ASL folder with ``cam0`` alone."""

PAIR_MAX_DT_S = 0.001
"""Default pairing tolerance of left and right stamps, seconds (EuRoC's are equal)."""

GROUNDTRUTH_CSV = Path("state_groundtruth_estimate0") / "data.csv"
"""EuRoC's ground truth of the body, relative to ``mav0/``."""

GROUNDTRUTH_BESIDE = ("groundtruth_body.txt", "groundtruth.txt", "groundtruth.tum")
"""Trajectory files looked for beside ``mav0/`` (not read: named in ``info`` only)."""

NAMED = 3
"""Images named in one problem line."""

_NO_STAMPS = np.zeros(0, dtype=np.int64)

MISSING_KEPT = 20
"""Missing images named per camera in ``info`` (and so in run.json); the others are counted.
A ``data.csv`` may list millions of images that are not there: their names are its rows."""


@dataclass(frozen=True)
class ImageCsv:
    """One camera's ``data.csv``, sorted by time.

    Attributes:
        path: the csv file (its images are in ``data/`` beside it).
        stamps_ns: (N,) int64 nanoseconds.
        files: N file names as listed.
        lines: N 1-based line numbers, for messages.
        listed: rows the file lists, kept or not.
        missing: (``existing_only``) the first :data:`MISSING_KEPT` rows left out because
            their image is not in ``data/``, as ``"cam0/data/x.png (listed at
            cam0/data.csv:97)"``.
        missing_count: how many rows were left out so.
    """

    path: Path
    stamps_ns: NDArray[np.int64]
    files: tuple[str, ...]
    lines: tuple[int, ...]
    listed: int = 0
    missing: tuple[str, ...] = ()
    missing_count: int = 0

    def __len__(self) -> int:
        return len(self.files)

    def image(self, k: int) -> Path:
        """The image file of entry ``k``."""
        return self.path.parent / "data" / self.files[k]

    def where(self, k: int) -> str:
        """``"cam1/data.csv:97"``: where entry ``k`` is listed."""
        return f"{self.path.parent.name}/{self.path.name}:{self.lines[k]}"


def read_image_csv(path: str | Path, existing_only: bool = False) -> ImageCsv:
    """Read an ASL camera ``data.csv`` (``#timestamp [ns],filename`` lines).

    With ``existing_only`` the rows whose image is not in ``data/`` beside the file are left
    out as they are read, counted and the first :data:`MISSING_KEPT` named, so a list of
    millions of absent images costs neither memory nor a file-system lookup per row (``data/``
    is listed once).

    Raises:
        InputError: the file is missing.
        FormatError: a line without two fields or with a bad stamp (names file:line).
    """
    p = Path(path)
    folder, camera = p.parent / "data", p.parent.name
    present = _image_names(folder) if existing_only else None
    stamps: list[int] = []
    files: list[str] = []
    lines: list[int] = []
    missing: list[str] = []
    listed = missing_count = 0
    for number, fields in iter_data_lines(p, delimiter=","):
        if len(fields) != 2 or not fields[1]:
            raise FormatError(
                p,
                f"expected 'timestamp [ns],filename', found {len(fields)} field(s)",
                number,
                hint="an ASL camera data.csv has one 'stamp_ns,stamp_ns.png' line per image",
            )
        stamp = parse_count(fields[0], p, number, "timestamp", "whole nanoseconds")
        listed += 1
        name = fields[1]
        if present is not None and not _exists(folder, name, present):
            missing_count += 1
            if len(missing) < MISSING_KEPT:
                missing.append(f"{camera}/data/{name} (listed at {camera}/{p.name}:{number})")
            continue
        stamps.append(stamp)
        files.append(name)
        lines.append(number)
    t = np.asarray(stamps, dtype=np.int64)
    order = np.argsort(t, kind="stable")
    return ImageCsv(
        p,
        t[order],
        tuple(files[i] for i in order),
        tuple(lines[i] for i in order),
        listed,
        tuple(missing),
        missing_count,
    )


def _image_names(folder: Path) -> frozenset[str]:
    """Names of the regular files (or links to them) in ``folder``; empty when it is none."""
    try:
        with os.scandir(folder) as entries:
            return frozenset(e.name for e in entries if e.is_file())
    except OSError:
        return frozenset()


def _exists(folder: Path, name: str, present: frozenset[str]) -> bool:
    """Whether image ``name`` (a file name, or a path below ``folder``) is a file."""
    if name in present:
        return True
    return ("/" in name or os.sep in name) and (folder / name).is_file()


def read_imu_csv(
    path: str | Path, *, in_file_order: bool = False
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Read an ASL ``imu0/data.csv``: t [ns], w_x w_y w_z [rad/s], a_x a_y a_z [m/s^2].

    Returns:
        (N,) int64 stamps, (N, 3) float64 gyro rad/s and (N, 3) float64 accel m/s², sorted by
        time (stable), or ``in_file_order`` as the file lists them (to check the stamps).

    Raises:
        FormatError: a line without 7 fields, a bad stamp or value (names file:line).
    """
    p = Path(path)
    stamps: list[int] = []
    rows: list[list[str]] = []
    numbers: list[int] = []
    for number, fields in iter_data_lines(p, delimiter=","):
        if len(fields) != 7:
            raise FormatError(
                p,
                f"expected 7 comma-separated columns (t [ns], w_xyz, a_xyz), found {len(fields)}",
                number,
            )
        stamps.append(parse_count(fields[0], p, number, "timestamp", "whole nanoseconds"))
        rows.append(fields[1:])
        numbers.append(number)
    try:
        values = np.array(rows, dtype=np.float64).reshape(-1, 6)
    except ValueError:
        # Slow path only on failure: name the line and column.
        for number, fields in zip(numbers, rows, strict=True):
            parse_floats(fields, p, number, "IMU value", first_column=2)
        raise FormatError(p, "an IMU value is not a number") from None
    bad = ~np.isfinite(values)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise FormatError(
            p, f"column {col + 2}: IMU value {rows[row][col]!r} is not finite", numbers[row]
        )
    t = np.asarray(stamps, dtype=np.int64)
    if in_file_order:
        return t, values[:, :3], values[:, 3:]
    order = np.argsort(t, kind="stable")
    return t[order], values[order, :3], values[order, 3:]


def mav_folder(path: str | Path) -> Path:
    """The ``mav0`` folder of an ASL input: ``path/mav0`` if it exists, else ``path``."""
    p = Path(path)
    return p / "mav0" if (p / "mav0").is_dir() else p


class EurocSource(SourceBase):
    """A EuRoC / ASL folder (see the module docstring) as a
    :class:`~slamcli.formats.base.Source` of :class:`StereoFrame`, :class:`ImageFrame` and
    :class:`ImuFrame`.

    Args:
        path: the folder holding ``mav0/``, or ``mav0/`` itself.
        max_dt: pairing tolerance of left and right stamps in seconds.

    Raises:
        InputError: not a folder, or ``cam0`` missing.
        FormatError: a malformed ``data.csv`` or ``sensor.yaml`` (names file, line or key).
        ConfigError: a bad option value.
    """

    format_name = "euroc"
    frame_kinds = FRAME_KINDS
    OPTIONS = ("max_dt", "calib")

    def __init__(
        self,
        path: str | Path,
        *,
        max_dt: float = PAIR_MAX_DT_S,
        calib: Collection[str | Path] | None = None,
    ) -> None:
        self.path = Path(path)
        if not np.isfinite(max_dt) or max_dt <= 0:
            raise ConfigError(f"max_dt must be a positive number of seconds, got {max_dt}")
        if not self.path.is_dir():
            raise InputError(f"{self.path}: a EuRoC / ASL input is a folder")
        self.mav = mav_folder(self.path)
        if not (self.mav / "cam0" / "data.csv").is_file():
            raise InputError(
                f"{self.mav}: ASL folder has no cam0/data.csv",
                hint="a EuRoC / ASL folder holds mav0/ with cam0/ (data.csv, data/, sensor.yaml), "
                "cam1/ the same way for a stereo pair, and imu0/",
            )
        self.max_dt = float(max_dt)
        self.stats = ReadStats()
        self.stereo = (self.mav / "cam1" / "data.csv").is_file()
        """Whether the folder has a right camera (``cam1``): else it is monocular."""
        self.frame_kinds = FRAME_KINDS if self.stereo else MONO_FRAME_KINDS
        self.left_csv = read_image_csv(self.mav / "cam0" / "data.csv", existing_only=True)
        self.left_sensor: CameraSensor = read_camera_sensor(self.mav / "cam0" / "sensor.yaml")
        self._rectification: StereoRectification | None = None
        if self.stereo:
            self.right_csv = read_image_csv(self.mav / "cam1" / "data.csv", existing_only=True)
            self.right_sensor = read_camera_sensor(self.mav / "cam1" / "sensor.yaml")
            self._rectification = rectify_stereo(self.left_sensor, self.right_sensor)
        else:
            self.right_csv = ImageCsv(self.mav / "cam1" / "data.csv", _NO_STAMPS, (), ())
        self._imu_folder = self.mav / "imu0"
        self.imu_sensor: ImuSensor | None = (
            read_imu_sensor(self._imu_folder / "sensor.yaml")
            if (self._imu_folder / "sensor.yaml").is_file()
            else None
        )
        self.calib = read_kalibr(tuple(calib)) if calib else None
        """The Kalibr files given with ``--calib``, which replace the sensor files they cover."""
        if self.calib is not None:
            self._use_calib(self.calib)
        self.missing = [*self.left_csv.missing, *self.right_csv.missing]
        """The first missing images of each camera (:data:`MISSING_KEPT`), named."""
        self.missing_count = self.left_csv.missing_count + self.right_csv.missing_count
        """How many listed images are missing."""
        li, ri = (
            associate_stamps(
                self.left_csv.stamps_ns, self.right_csv.stamps_ns, round(self.max_dt * 1e9)
            )
            if self.stereo
            else ([], [])
        )
        self.left_index = np.asarray(li, dtype=np.int64)
        self.right_index = np.asarray(ri, dtype=np.int64)

    def _use_calib(self, calib: KalibrCalibration) -> None:
        """Take the cameras, the IMU's noise and the image time shift from Kalibr's files
        (see :mod:`slamcli.formats.euroc.kalibr`); what they leave out stays the folder's."""
        if calib.cameras:
            cameras = calib.cameras_on_body(self.left_sensor.body_from_sensor)
            if self.stereo and len(cameras) < 2:
                raise InputError(
                    f"{calib.chain_path}: the camera chain has one camera; {self.mav} has cam0 "
                    "and cam1",
                    hint="give the chain of both cameras",
                )
            self.left_sensor = cameras[0]
            if self.stereo:
                self.right_sensor = cameras[1]
                self._rectification = rectify_stereo(self.left_sensor, self.right_sensor)
        if calib.imu is not None:
            folder = self.imu_sensor.body_from_sensor if self.imu_sensor is not None else None
            self.imu_sensor = calib.imu_on_body(folder)
        elif calib.imu_placed and self.imu_sensor is not None:
            self.imu_sensor = replace(self.imu_sensor, body_from_sensor=np.eye(4))
        if calib.time_shift_ns:
            # Kalibr: t_imu = t_cam + shift. The images are put on the IMU's clock.
            self.left_csv = replace(
                self.left_csv, stamps_ns=self.left_csv.stamps_ns + calib.time_shift_ns
            )
            self.right_csv = replace(
                self.right_csv, stamps_ns=self.right_csv.stamps_ns + calib.time_shift_ns
            )

    @classmethod
    def sniff(cls, path: str | Path) -> bool:
        """A folder with ``mav0/cam0/data.csv``, or a ``mav0`` folder itself."""
        return sniff.euroc(path)

    def __len__(self) -> int:
        """Number of stereo pairs (left and right images both present); of a monocular folder,
        of ``cam0`` images."""
        return int(self.left_index.size) if self.stereo else len(self.left_csv)

    @property
    def rectification(self) -> StereoRectification:
        """The stereo pair's rectification.

        Raises:
            InputError: the folder has no ``cam1``.
        """
        if self._rectification is None:
            raise InputError(
                f"{self.mav}: ASL folder has no cam1/data.csv: no stereo pairs",
                hint="run it monocular (--set mode=mono), or give the folder's cam1/",
            )
        return self._rectification

    @property
    def rig(self) -> StereoRig:
        """The rectified :class:`~slamcli.types.StereoRig` every frame carries."""
        return self.rectification.rig

    @cached_property
    def camera(self) -> PinholeCamera:
        """``cam0`` as its ``image`` frames carry it: as calibrated (radial-tangential), or
        the pinhole its equidistant images are remapped to."""
        cam = self.left_sensor.camera
        if self.left_sensor.model == EQUIDISTANT:
            return cam.undistorted()
        return cam

    @cached_property
    def _fisheye_maps(self) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        import cv2

        cam = self.left_sensor.camera
        d = np.asarray(self.left_sensor.coefficients, np.float64).reshape(4, 1)
        return cv2.fisheye.initUndistortRectifyMap(
            cam.K, d, np.eye(3), cam.K, (cam.width, cam.height), cv2.CV_32FC1
        )

    @property
    def pair_stamps_ns(self) -> NDArray[np.int64]:
        """(P,) int64 left stamps of the pairs, in time order."""
        return self.left_csv.stamps_ns[self.left_index]

    @property
    def pair_right_stamps_ns(self) -> NDArray[np.int64]:
        """(P,) int64 right stamps of the pairs, in the order of :attr:`pair_stamps_ns`."""
        return self.right_csv.stamps_ns[self.right_index]

    @cached_property
    def _imu_as_listed(
        self,
    ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]] | None:
        """``imu0/data.csv`` in file order (for the stamp checks), read once; None without it."""
        p = self._imu_folder / "data.csv"
        return read_imu_csv(p, in_file_order=True) if p.is_file() else None

    @cached_property
    def _imu(
        self,
    ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]] | None:
        """The IMU samples sorted by time (stable), from the one read."""
        listed = self._imu_as_listed
        if listed is None:
            return None
        t, gyro, accel = listed
        order = np.argsort(t, kind="stable")
        return t[order], gyro[order], accel[order]

    @cached_property
    def _groundtruth(self) -> Trajectory | None:
        p = self.mav / GROUNDTRUTH_CSV
        return read_trajectory(p, "euroc") if p.is_file() else None

    def groundtruth(self) -> Trajectory | None:
        """EuRoC's ground truth: world_from_body (body = IMU frame), or None without it."""
        return self._groundtruth

    def frames(self, kinds: Collection[str] | None = None) -> Iterator[Frame]:
        """Yield the requested kinds in time order (at equal stamps: IMU first); by default
        stereo pairs, or a monocular folder's images.

        ``stereo`` gives a rectified :class:`StereoFrame` (grey (H, W) uint8, or RGB for colour
        images) per pair, ``image`` an :class:`ImageFrame` per ``cam0`` image (see the module's
        text), ``imu`` an :class:`ImuFrame` per ``imu0`` row. Images that cannot be decoded or
        are not of the calibrated size are skipped, logged and counted. ``stereo`` and
        ``image`` are not read together.

        Raises:
            ConfigError: an unknown kind.
            InputError: a kind an ASL folder does not have, or ``imu`` without ``imu0/data.csv``.
        """
        if kinds is None:
            kinds = ("stereo",) if self.stereo else ("image",)
        wanted = self._check_kinds(kinds)
        if {"stereo", "image"} <= wanted:
            raise ConfigError(
                "a EuRoC / ASL folder gives stereo pairs or cam0's images, not both at once"
            )
        imu = self._imu if "imu" in wanted else None
        if "imu" in wanted and imu is None:
            raise InputError(
                f"{self.mav}: has no imu0/data.csv: no IMU frames",
                hint="run without the IMU, or give the folder's imu0/",
            )
        imu_t = imu[0] if imu is not None else np.zeros(0, dtype=np.int64)
        pair_t = (
            self.pair_stamps_ns
            if "stereo" in wanted
            else self.left_csv.stamps_ns
            if "image" in wanted
            else np.zeros(0, dtype=np.int64)
        )
        imu_rows = np.arange(imu_t.size, dtype=np.int64)
        if imu_t.size and pair_t.size:
            # With images, the IMU is read over their span and IMU_MARGIN_S either side (an
            # excerpt's images may cover seconds of a sequence's whole IMU log).
            margin = round(IMU_MARGIN_S * 1e9)
            keep = (imu_t >= pair_t.min() - margin) & (imu_t <= pair_t.max() + margin)
            imu_rows, imu_t = imu_rows[keep], imu_t[keep]
        t = np.concatenate([imu_t, pair_t])
        code = np.concatenate([np.zeros(imu_t.size, np.int64), np.ones(pair_t.size, np.int64)])
        idx = np.concatenate([imu_rows, np.arange(pair_t.size)]).astype(np.int64)
        for c, k in zip(
            *(a[np.lexsort((idx, code, t))].tolist() for a in (code, idx)), strict=True
        ):
            if c == 0 and imu is not None:
                self.stats.read += 1
                yield ImuFrame(int(imu[0][k]), accel_mps2=imu[2][k], gyro_radps=imu[1][k])
                continue
            frame = self._pair(k) if "stereo" in wanted else self._image(k)
            if frame is not None:
                self.stats.read += 1
                yield frame

    def _check_kinds(self, kinds: Collection[str]) -> set[str]:
        what = "a EuRoC / ASL folder" if self.stereo else "an ASL folder with cam0 alone"
        return provided_kinds(known_kinds(kinds), self.frame_kinds, self.path, what)

    def _image(self, k: int) -> ImageFrame | None:
        """``cam0`` image ``k``, or None (logged and counted in :attr:`stats`) when unusable."""
        img = self._load(self.left_csv, k, self.left_sensor.camera, "image")
        name = f"cam0/data/{self.left_csv.files[k]}"
        if img is None:
            self.stats.skipped += 1
            self.stats.skipped_names.append(name)
            return None
        if self.left_sensor.model == EQUIDISTANT:
            import cv2

            img = cv2.remap(img, *self._fisheye_maps, cv2.INTER_LINEAR)
        return ImageFrame(
            int(self.left_csv.stamps_ns[k]),
            img,
            self.camera,
            name,
            self.left_sensor.body_from_sensor,
        )

    def raw_pair(self, k: int) -> tuple[NDArray[np.uint8], NDArray[np.uint8]] | None:
        """Pair ``k``'s left and right images as recorded (not rectified): grey (H, W) or RGB
        (H, W, 3) uint8, or None (logged and counted in :attr:`stats`) when one is unusable."""
        li, ri = int(self.left_index[k]), int(self.right_index[k])
        camera = self.rig.camera
        left = self._load(self.left_csv, li, camera)
        right = self._load(self.right_csv, ri, camera) if left is not None else None
        name = self._pair_name(li, ri)
        if left is not None and right is not None and left.ndim != right.ndim:
            log.warning("skipping the stereo pair %s: one image is grey, the other colour", name)
            left = None
        if left is None or right is None:
            self.stats.skipped += 1
            self.stats.skipped_names.append(name)
            return None
        return left, right

    def _pair(self, k: int) -> StereoFrame | None:
        """Pair ``k`` rectified, or None (logged and counted) when an image is unusable."""
        raw = self.raw_pair(k)
        if raw is None:
            return None
        li, ri = int(self.left_index[k]), int(self.right_index[k])
        left, right = self.rectification.remap(*raw)
        return StereoFrame(
            int(self.left_csv.stamps_ns[li]),
            left,
            right,
            self.rig,
            int(self.right_csv.stamps_ns[ri]),
            self._pair_name(li, ri),
        )

    def _pair_name(self, li: int, ri: int) -> str:
        return f"cam0/data/{self.left_csv.files[li]} + cam1/data/{self.right_csv.files[ri]}"

    def _load(
        self, csv: ImageCsv, k: int, camera: PinholeCamera, what: str = "stereo pair"
    ) -> NDArray[np.uint8] | None:
        """Image ``k`` of ``csv`` as grey (H, W) or RGB (H, W, 3) uint8, or None (logged) when
        it is unreadable or not of ``camera``'s size."""
        import cv2

        path = csv.image(k)
        data, reason = read_image_file(path)
        img: NDArray[Any] | None = None
        if data is not None:
            img, reason = decode_image(
                data, cv2.IMREAD_UNCHANGED, expect=(camera.width, camera.height)
            )
        if img is not None and img.dtype != np.uint8:
            reason = f"is {img.dtype}, expected 8-bit"
            img = None
        if img is None:
            log.warning(
                "skipping the %s of %s: %s (the calibration is %dx%d)",
                what,
                path,
                reason,
                camera.width,
                camera.height,
            )
            return None
        if img.ndim == 3:
            code = cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB
            img = cv2.cvtColor(img, code)
        return np.ascontiguousarray(img)

    def info(self, deep: bool = False, progress: ProgressFn | None = None) -> SourceInfo:
        """Streams (cameras, stereo pairs, IMU, ground truth), the rectified camera, baseline,
        distortion model, IMU noise settings and problems (missing images, unpaired stamps).

        ``deep`` also reads every paired image and checks its size from its header, reporting
        ``progress(done, total)``.
        """
        problems: list[str] = []
        cams = [self.left_sensor, self.right_sensor] if self.stereo else [self.left_sensor]
        csvs = [self.left_csv, self.right_csv] if self.stereo else [self.left_csv]
        streams = [self._camera_stream(csv) for csv in csvs]
        details: dict[str, Any] = {
            "mav0": str(self.mav),
            "distortion_model": self.left_sensor.model,
            "raw_cameras": {
                f"cam{i}": c.camera.to_dict() | {"coefficients": list(c.coefficients)}
                for i, c in enumerate(cams)
            },
            "missing_images": list(self.missing),
            "missing_images_count": self.missing_count,
        }
        if self.stereo:
            rig = self.rig
            streams.append(
                StreamInfo.from_stamps("stereo", "stereo", self.pair_stamps_ns, "rectified pairs")
            )
            details |= {
                "baseline_m": rig.baseline_m,
                "body_from_left": rig.body_from_left.tolist(),
                "pair_max_dt_s": self.max_dt,
                "unpaired_left": len(self.left_csv) - len(self),
                "unpaired_right": len(self.right_csv) - len(self),
            }
            camera = rig.camera
            camera_source = (
                f"rectified from {self._calibrated_by()} "
                f"({self.left_sensor.model}, baseline {rig.baseline_m:.4f} m)"
            )
        else:
            details["body_from_camera"] = self.left_sensor.body_from_sensor.tolist()
            camera = self.camera
            camera_source = (
                f"{self._calibrated_by()} ({self.left_sensor.model}; no cam1: monocular)"
            )
        if self.calib is not None:
            details["calib"] = {
                "files": [str(p) for p in self.calib.paths],
                "body": "imu" if self.calib.imu_placed else "the folder's",
                "time_shift_s": self.calib.time_shift_ns * 1e-9,
            }
        if self.missing_count:
            problems.append(self._missing_problem())
        self._imu_info(streams, details, problems)
        gt = self.groundtruth()
        if gt is not None:
            streams.append(
                StreamInfo.from_stamps("groundtruth", "pose", gt.stamps_ns, str(GROUNDTRUTH_CSV))
            )
        else:
            beside = [n for n in GROUNDTRUTH_BESIDE if (self.mav.parent / n).is_file()]
            note = "ground truth: none in mav0" + (
                f"; {beside[0]} beside it (pass --groundtruth)" if beside else ""
            )
            details["groundtruth"] = note
            if beside:
                problems.append(note)
        if deep:
            wrong = self._check_sizes(progress)
            details["wrong_size"] = wrong
            if wrong:
                problems.append(
                    f"{len(wrong)} image(s) unreadable or not of the calibrated size: "
                    + "; ".join(wrong[:NAMED])
                )
        return SourceInfo(
            format=self.format_name,
            path=str(self.path),
            streams=streams,
            frames=len(self),
            groundtruth=len(gt) if gt is not None else 0,
            camera=camera,
            camera_source=camera_source,
            problems=problems,
            details=details,
        )

    def _calibrated_by(self) -> str:
        """Where the cameras' calibration comes from, for ``info``."""
        if self.calib is not None and self.calib.chain_path is not None:
            return f"{self.calib.chain_path} (--calib)"
        if self.stereo:
            return "mav0/cam0/sensor.yaml and mav0/cam1/sensor.yaml"
        return "mav0/cam0/sensor.yaml"

    def _camera_stream(self, csv: ImageCsv) -> StreamInfo:
        """A camera's images that exist, and how many its ``data.csv`` lists beyond them."""
        where = f"mav0/{csv.path.parent.name}/{csv.path.name}"
        if csv.missing_count:
            where += f" ({csv.listed} listed, {csv.missing_count} missing)"
        return StreamInfo.from_stamps(csv.path.parent.name, "image", csv.stamps_ns, where)

    def _missing_problem(self) -> str:
        """One line: how many listed images are missing, the first few, and where the rest
        are (the rows of each camera's ``data.csv`` whose image is not in its ``data/``)."""
        count = self.missing_count
        named = "; ".join(self.missing[:NAMED])
        if count <= NAMED:
            return f"{count} listed image(s) missing: {named}"
        cameras = " and ".join(
            f"{c.path.parent.name}/{c.path.name} ({c.missing_count})"
            for c in (self.left_csv, self.right_csv)
            if c.missing_count
        )
        return (
            f"{count} listed image(s) missing: {named}, and {count - NAMED} more: the rows of "
            f"{cameras} whose image is not in data/ beside it"
        )

    def _imu_info(
        self, streams: list[StreamInfo], details: dict[str, Any], problems: list[str]
    ) -> None:
        """The IMU's stream, noise settings and checks (:func:`check_imu`: stamps, gaps, rate,
        how its time lines up with ``cam0``'s, units, saturation)."""
        from slamcli.formats.imu_checks import check_imu

        imu = self._imu
        if imu is None:
            problems.append("no imu0/data.csv: no IMU frames")
        else:
            streams.append(StreamInfo.from_stamps("imu0", "imu", imu[0], "mav0/imu0/data.csv"))
        if self.imu_sensor is not None:
            details["imu"] = self.imu_sensor.details()
        elif imu is not None:
            problems.append("no imu0/sensor.yaml: the IMU noise settings are unknown")
        if imu is not None:
            assert self._imu_as_listed is not None
            report = check_imu(
                *self._imu_as_listed,
                camera_stamps_ns=self.left_csv.stamps_ns,
                rate_hz=self.imu_sensor.rate_hz if self.imu_sensor is not None else None,
                where="mav0/imu0/data.csv",
            )
            details["imu_check"] = report.to_dict()
            problems.extend(report.problems)

    def _check_sizes(self, progress: ProgressFn | None) -> list[str]:
        camera = self.rig.camera if self.stereo else self.left_sensor.camera
        left = self.left_index if self.stereo else np.arange(len(self.left_csv))
        jobs = [(self.left_csv, int(k)) for k in left] + [
            (self.right_csv, int(k)) for k in self.right_index
        ]
        wrong: list[str] = []
        for done, (csv, k) in enumerate(jobs, start=1):
            name = f"{csv.path.parent.name}/data/{csv.files[k]}"
            data, reason = read_image_file(csv.image(k))
            try:
                size = image_size(data) if data is not None else None
            except ValueError as exc:
                size, reason = None, str(exc)
            if data is None or reason:
                wrong.append(f"{name} {reason}")
            elif size is not None and size != (camera.width, camera.height):
                wrong.append(f"{name} is {size[0]}x{size[1]}")
            if progress is not None:
                progress(done, len(jobs))
        return wrong


__all__ = [
    "FRAME_KINDS",
    "PAIR_MAX_DT_S",
    "EurocSource",
    "ImageCsv",
    "mav_folder",
    "read_image_csv",
    "read_imu_csv",
]
