"""KITTI odometry sequences: rectified stereo pairs, ``calib.txt``, ``times.txt`` and poses.

The layout of one sequence of KITTI's odometry benchmark::

    SEQUENCE/                  dataset/sequences/NN/ in KITTI's download
      image_0/ image_1/        grey left and right images, 000000.png, 000001.png, ...
      image_2/ image_3/        colour left and right images (the colour download)
      calib.txt                'P0: ' .. 'P3: ' 3x4 projection matrices (and 'Tr: ')
      times.txt                optional: one time in seconds per frame
      poses.txt                optional: ground truth, one 3x4 row per frame

Excerpts name the folders ``image_l/`` and ``image_r/`` and may give ``calib.txt`` as two bare
rows of 12 numbers (P of the left and of the right camera). The first pair of folders of
:data:`~slamcli.formats.sniff.KITTI_PAIR_FOLDERS` present is read: grey before colour.

Image ``NNNNNN.png`` is frame ``NNNNNN``: it is stamped with line ``NNNNNN + 1`` of
``times.txt``, or ``NNNNNN / 10`` s without one (KITTI records at 10 Hz).

Calibration: the images are rectified, so both cameras share ``K = P[:, :3]``, and with
``P = K [I | t]`` a point ``X`` of the reference camera (camera 0) is at ``X + t`` in the
camera of ``P``. The baseline is ``(P_left[0,3] - P_right[0,3]) / fx``: for the grey pair
``P0[0,3] = 0``, for the colour pair ``P2[0,3]`` is not, since camera 2 sits about 6 cm from
camera 0.

Ground truth is ``poses.txt`` in the folder, else KITTI's ``dataset/poses/NN.txt`` beside
``dataset/sequences/NN/``: the pose of camera 0 in the world of the first frame, one row per
frame. The rig's ``body_from_left`` places the left camera in camera 0's frame (identity for the
grey pair and the excerpts, a translation of ``-K^-1 P2[:, 3]`` for the colour pair), so the
ground truth is the body's.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import FormatError, InputError
from slamcli.formats import sniff
from slamcli.formats.base import (
    Frame,
    ReadStats,
    SourceBase,
    SourceInfo,
    StreamInfo,
    known_kinds,
    provided_kinds,
)
from slamcli.formats.images import decode_image, read_image_file
from slamcli.formats.text import format_stamp, iter_data_lines, parse_floats, parse_stamp_ns
from slamcli.formats.trajectory import read_poses
from slamcli.types import ImageFrame, PinholeCamera, ProgressFn, StereoFrame, StereoRig, Trajectory

log = logging.getLogger(__name__)

DEFAULT_RATE_HZ = 10.0
"""The frame rate stamps assume without ``times.txt``: KITTI's cameras ran at 10 Hz."""

FRAME_KINDS = ("stereo", "image")
"""The frame kinds a KITTI folder provides: the pairs, and the left images alone."""

TIMES_NAME = "times.txt"
POSES_NAME = "poses.txt"

PROJECTION_LABELS = {
    ("image_0", "image_1"): ("P0", "P1"),
    ("image_2", "image_3"): ("P2", "P3"),
    ("image_l", "image_r"): ("P0", "P1"),
}
"""The ``calib.txt`` lines of each pair of image folders (left, right)."""

NAMED = 3
"""Files named in one problem line; ``info --json`` lists them all."""

_IMAGE_NAME = re.compile(r"(\d{6})\.png", re.ASCII)
_MATRIX_LABEL = re.compile(r"P\d|Tr(_\w+)?", re.ASCII)
_NS_PER_S = 1_000_000_000
_INTRINSICS_TOL = 1e-6
"""Largest difference, relative to fx, between a rectified pair's two intrinsic matrices."""

_CALIB_HINT = (
    "KITTI's calib.txt has lines 'P0: ' to 'P3: ' of 12 numbers each (a 3x4 projection matrix, "
    "row-major); an excerpt's may be two bare rows of 12 numbers: P of the left camera, then P "
    "of the right one"
)
_SKIP_HINT = "without --strict, unreadable pairs are skipped and counted"


@dataclass(frozen=True)
class StereoCalibration:
    """The projection matrices of a rectified pair, as ``calib.txt`` gives them.

    Attributes:
        left, right: (3, 4) float64 projection matrices ``K [I | t]`` of the two cameras.
        source: where they came from, for messages ("calib.txt P0/P1").
    """

    left: NDArray[np.float64]
    right: NDArray[np.float64]
    source: str

    @property
    def baseline_m(self) -> float:
        """Distance from the left to the right camera centre along x, in metres."""
        return float((self.left[0, 3] - self.right[0, 3]) / self.left[0, 0])

    @property
    def body_from_left(self) -> NDArray[np.float64]:
        """(4, 4) pose of the left camera in the reference camera's (camera 0's) frame."""
        t = np.linalg.solve(self.left[:, :3], self.left[:, 3])
        pose = np.eye(4)
        pose[:3, 3] = -t
        return pose

    def camera(self, width: int, height: int) -> PinholeCamera:
        """The rectified camera of both images, for images of ``width`` x ``height`` pixels."""
        p = self.left
        return PinholeCamera(
            width, height, float(p[0, 0]), float(p[1, 1]), float(p[0, 2]), float(p[1, 2])
        )


def read_calib(path: str | Path, labels: tuple[str, str] = ("P0", "P1")) -> StereoCalibration:
    """Read the left and right projection matrices of a KITTI ``calib.txt``.

    Args:
        path: the file: ``P0:`` .. ``P3:`` lines (others such as ``Tr:`` are checked but not
            used), or two bare rows of 12 numbers (left, then right).
        labels: the lines of the left and right camera in the labelled form.

    Raises:
        FormatError: naming file:line for a row that is not 12 numbers, a missing or repeated
            line, bare rows other than two, or matrices that are not a rectified pair with the
            right camera to the right of the left one.
    """
    p = Path(path)
    labelled: dict[str, tuple[int, NDArray[np.float64]]] = {}
    bare: list[tuple[int, NDArray[np.float64]]] = []
    for number, fields in iter_data_lines(p):
        label = fields[0][:-1] if fields[0].endswith(":") else None
        if (label is None and labelled) or (label is not None and bare):
            raise FormatError(
                p, "mixes labelled lines ('P0: ...') with bare rows", number, _CALIB_HINT
            )
        if label is None:
            bare.append((number, _matrix_row(fields, p, number, "projection row", 1)))
        elif _MATRIX_LABEL.fullmatch(label):
            if label in labelled:
                first = labelled[label][0]
                raise FormatError(p, f"{label}: given twice (first at line {first})", number)
            labelled[label] = (number, _matrix_row(fields[1:], p, number, f"{label}:", 2))
    if labelled:
        missing = [name for name in labels if name not in labelled]
        if missing:
            found = ", ".join(sorted(labelled)) or "none"
            raise FormatError(
                p,
                f"has no {' and no '.join(m + ':' for m in missing)} line (found {found}); "
                f"the pair needs {labels[0]} (left) and {labels[1]} (right)",
                hint=_CALIB_HINT,
            )
        rows = [labelled[name] for name in labels]
        source = f"{p.name} {labels[0]}/{labels[1]}"
    elif len(bare) == 2:
        rows = bare
        source = f"{p.name} rows 1/2 (left/right)"
    elif bare:
        where = bare[0][0] if len(bare) == 1 else bare[2][0]
        raise FormatError(
            p,
            f"has {len(bare)} projection row(s), expected two (the left and the right camera)",
            where,
            _CALIB_HINT,
        )
    else:
        raise FormatError(p, "holds no projection matrices", hint=_CALIB_HINT)
    calib = StereoCalibration(rows[0][1], rows[1][1], source)
    _check_rectified(calib, p, rows[0][0], rows[1][0])
    return calib


def _matrix_row(
    fields: list[str], path: Path, line: int, what: str, first_column: int
) -> NDArray[np.float64]:
    """A (3, 4) matrix from 12 numbers, row-major."""
    if len(fields) != 12:
        raise FormatError(
            path,
            f"{what} expected 12 numbers (a 3x4 matrix, row-major), found {len(fields)}",
            line,
            _CALIB_HINT,
        )
    try:
        values = parse_floats(fields, path, line, "matrix entry", first_column)
    except FormatError as exc:
        exc.hint = exc.hint or _CALIB_HINT
        raise
    return np.asarray(values, dtype=np.float64).reshape(3, 4)


def _check_rectified(calib: StereoCalibration, path: Path, left_line: int, right_line: int) -> None:
    """The two matrices share one pinhole K and put the right camera to the left camera's
    right; else a FormatError at the offending line."""
    k_left = calib.left[:, :3]
    fx, fy, cx, cy = k_left[0, 0], k_left[1, 1], k_left[0, 2], k_left[1, 2]
    pinhole = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    if not (fx > 0 and fy > 0) or np.abs(k_left - pinhole).max() > _INTRINSICS_TOL * abs(fx):
        raise FormatError(
            path,
            "the left camera's P[:, :3] is not a pinhole K (fx > 0, fy > 0, no skew, last row "
            f"0 0 1): found {np.array2string(k_left, separator=', ').replace(chr(10), '')}",
            left_line,
            _CALIB_HINT,
        )
    k_right = calib.right[:, :3]
    if np.abs(k_right - k_left).max() > _INTRINSICS_TOL * fx:
        raise FormatError(
            path,
            f"the right camera's intrinsics (fx {k_right[0, 0]:g}, fy {k_right[1, 1]:g}, "
            f"cx {k_right[0, 2]:g}, cy {k_right[1, 2]:g}) differ from the left's (fx {fx:g}, "
            f"fy {fy:g}, cx {cx:g}, cy {cy:g}); a rectified pair shares them",
            right_line,
            hint="give the projection matrices of the rectified images",
        )
    if not calib.baseline_m > 0:
        raise FormatError(
            path,
            f"the baseline (P_left[0,3] - P_right[0,3]) / fx is {calib.baseline_m:g} m; the "
            "right camera must sit to the right of the left one (P_right[0,3] = -fx * baseline)",
            right_line,
            hint="are the left and right rows swapped?",
        )


def read_times(path: str | Path) -> NDArray[np.int64]:
    """Read a KITTI ``times.txt``: one time in seconds per line, as (N,) int64 ns.

    Raises:
        FormatError: a line without exactly one number, or a time not after the previous one.
    """
    p = Path(path)
    stamps: list[int] = []
    for number, fields in iter_data_lines(p):
        if len(fields) != 1:
            raise FormatError(
                p, f"expected 1 column (time in seconds), found {len(fields)}", number
            )
        stamp = parse_stamp_ns(fields[0], p, number)
        if stamps and stamp <= stamps[-1]:
            raise FormatError(
                p,
                f"time {format_stamp(stamp)} s is not after the previous line's "
                f"{format_stamp(stamps[-1])} s",
                number,
                hint="times.txt has one increasing time per frame",
            )
        stamps.append(stamp)
    return np.asarray(stamps, dtype=np.int64)


def list_frames(folder: str | Path) -> tuple[NDArray[np.int64], tuple[str, ...]]:
    """The frame numbers and file names of the ``NNNNNN.png`` images in ``folder``, by number."""
    found: list[tuple[int, str]] = []
    for entry in Path(folder).iterdir():
        m = _IMAGE_NAME.fullmatch(entry.name)
        if m:
            found.append((int(m.group(1)), entry.name))
    found.sort()
    return np.asarray([n for n, _ in found], dtype=np.int64), tuple(name for _, name in found)


@dataclass(frozen=True)
class _FirstImage:
    """What the first readable left image says about all of them."""

    width: int
    height: int
    colour: bool


class KittiSource(SourceBase):
    """A KITTI odometry sequence as a :class:`~slamcli.formats.base.Source` of stereo pairs.

    Args:
        path: the sequence folder (``calib.txt`` beside ``image_0/`` and ``image_1/``, or the
            colour or excerpt folders; see the module docstring).
        strict: an unreadable or missing image raises :class:`FormatError` instead of its pair
            being skipped.

    Raises:
        InputError: not a folder, no pair of image folders, or no images.
        FormatError: a malformed ``calib.txt`` or ``times.txt``, or too few times.
    """

    format_name = "kitti"
    frame_kinds = FRAME_KINDS
    OPTIONS = ("strict",)

    def __init__(self, path: str | Path, *, strict: bool = False) -> None:
        self.path = Path(path)
        self.strict = bool(strict)
        self.stats = ReadStats()
        if not self.path.is_dir():
            raise InputError(
                f"{self.path}: a KITTI odometry input is a folder",
                hint="give the sequence folder, e.g. dataset/sequences/00",
            )
        self.left_folder, self.right_folder = self._pick_folders()
        labels = PROJECTION_LABELS[(self.left_folder, self.right_folder)]
        self.calibration = read_calib(self.path / sniff.KITTI_CALIB, labels)
        self.numbers, self.names = list_frames(self.path / self.left_folder)
        if not self.names:
            raise InputError(
                f"{self.path / self.left_folder}: holds no images named like 000000.png",
                hint="KITTI names each image by its 6-digit frame number",
            )
        times_path = self.path / TIMES_NAME
        self.times_ns: NDArray[np.int64] | None = None
        if times_path.is_file():
            self.times_ns = read_times(times_path)
            last = int(self.numbers[-1])
            if self.times_ns.size <= last:
                raise FormatError(
                    times_path,
                    f"has {self.times_ns.size} times, but {self.left_folder}/ holds "
                    f"{self.names[-1]} (frame {last} needs line {last + 1})",
                    hint="times.txt has one line per frame, starting at frame 000000",
                )
            self.stamps_ns = self.times_ns[self.numbers]
        else:
            self.stamps_ns = self.numbers * round(_NS_PER_S / DEFAULT_RATE_HZ)

    def _pick_folders(self) -> tuple[str, str]:
        for left, right in sniff.KITTI_PAIR_FOLDERS:
            if (self.path / left).is_dir():
                if not (self.path / right).is_dir():
                    raise InputError(
                        f"{self.path}: has {left}/ but no {right}/ beside it",
                        hint=f"a stereo sequence needs the right images in {right}/",
                    )
                return left, right
        folders = ", ".join(f"{a}/ + {b}/" for a, b in sniff.KITTI_PAIR_FOLDERS)
        raise InputError(
            f"{self.path}: no pair of image folders ({folders})",
            hint="give a KITTI odometry sequence folder",
        )

    @classmethod
    def sniff(cls, path: str | Path) -> bool:
        """A folder with ``calib.txt`` beside ``image_0/``, ``image_2/`` or ``image_l/``."""
        return sniff.kitti(path)

    def __len__(self) -> int:
        """Number of stereo pairs (left images)."""
        return len(self.names)

    @cached_property
    def _first_image(self) -> _FirstImage:
        """Size and colour of the first left image that decodes."""
        for name in self.names:
            img, _ = self._decode(f"{self.left_folder}/{name}", None)
            if img is not None:
                return _FirstImage(int(img.shape[1]), int(img.shape[0]), img.ndim == 3)
        raise InputError(
            f"{self.path / self.left_folder}: none of its {len(self.names)} images can be read, "
            "so the image size is unknown",
            hint="check the images with 'slamcli info --deep'",
        )

    @cached_property
    def rig(self) -> StereoRig:
        """The rectified pair: camera, baseline and the left camera on the body (camera 0)."""
        first = self._first_image
        return StereoRig(
            self.calibration.camera(first.width, first.height),
            self.calibration.baseline_m,
            self.calibration.body_from_left,
        )

    @property
    def groundtruth_path(self) -> Path | None:
        """``poses.txt`` in the folder, else KITTI's ``poses/NN.txt`` beside
        ``sequences/NN/``, or None."""
        own = self.path / POSES_NAME
        if own.is_file():
            return own
        folder = self.path.resolve()
        if folder.parent.name == "sequences":
            official = folder.parent.parent / "poses" / f"{folder.name}.txt"
            if official.is_file():
                return official
        return None

    @cached_property
    def _groundtruth(self) -> Trajectory | None:
        path = self.groundtruth_path
        if path is None:
            return None
        table = read_poses(path, "kitti")
        n = len(table)
        if self.times_ns is None:
            stamps = np.arange(n, dtype=np.int64) * round(_NS_PER_S / DEFAULT_RATE_HZ)
        elif n > self.times_ns.size:
            raise FormatError(
                path,
                f"has {n} poses but {TIMES_NAME} has {self.times_ns.size} times",
                hint="KITTI's poses file has one row per frame, as times.txt has one line",
            )
        else:
            stamps = self.times_ns[:n]
        return Trajectory(stamps, table.world_from_body)

    def groundtruth(self) -> Trajectory | None:
        """Poses of camera 0 (world_from_body, the body of :attr:`rig`), or None."""
        return self._groundtruth

    def _check_kinds(self, kinds: Collection[str]) -> set[str]:
        return provided_kinds(known_kinds(kinds), FRAME_KINDS, self.path, "a KITTI odometry folder")

    def frames(self, kinds: Collection[str] = ("stereo",)) -> Iterator[Frame]:
        """Yield frames in frame order, reading each image when its frame comes.

        ``stereo`` gives a :class:`StereoFrame` per pair, ``image`` an :class:`ImageFrame` of
        each left image (before the pair of the same frame, sharing its array). Grey images are
        (H, W) uint8, colour ones (H, W, 3) RGB. A pair whose image is missing or unreadable,
        or whose images differ in size, is skipped and counted in :attr:`stats` with a warning
        naming the file (with ``strict``, a :class:`FormatError`).

        Raises:
            ConfigError: an unknown kind.
            InputError: a kind a KITTI folder does not have, or no left image is readable.
        """
        wanted = self._check_kinds(kinds)
        if not wanted:
            return
        rig = self.rig
        for k, name in enumerate(self.names):
            stamp = int(self.stamps_ns[k])
            left_rel = f"{self.left_folder}/{name}"
            left = self._read(left_rel, None)
            if left is None:
                self._skip(left_rel, len(wanted))
                continue
            if "image" in wanted:
                self.stats.read += 1
                yield ImageFrame(stamp, left, rig.camera, left_rel)
            if "stereo" in wanted:
                right = self._read(f"{self.right_folder}/{name}", left)
                if right is None:
                    self._skip(left_rel)
                    continue
                self.stats.read += 1
                pair = f"{left_rel} + {self.right_folder}/{name}"
                yield StereoFrame(stamp, left, right, rig, stamp, pair)

    def _skip(self, name: str, frames: int = 1) -> None:
        self.stats.skipped += frames
        self.stats.skipped_names.extend([name] * frames)

    def _decode(self, rel: str, like: NDArray[np.uint8] | None) -> tuple[NDArray[Any] | None, str]:
        """Image ``rel`` as (H, W) uint8 grey or (H, W, 3) uint8 RGB: ``(image, "")``, or
        ``(None, reason)``. ``like`` is the left image a right one must match."""
        import cv2

        data, reason = read_image_file(self.path / rel)
        if data is None:
            return None, reason
        expect = None if like is None else (like.shape[1], like.shape[0])
        img, reason = decode_image(data, cv2.IMREAD_UNCHANGED, expect=expect)
        if img is None:
            return None, reason.replace("the camera is", "its left image is")
        if img.dtype != np.uint8:
            return None, f"is {img.dtype}, expected 8-bit grey or colour"
        if img.ndim == 3 and img.shape[2] == 1:
            img = img[:, :, 0]
        elif img.ndim == 3:
            code = cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB
            img = cv2.cvtColor(img, code)
        if like is not None and img.ndim != like.ndim:
            kinds = ("grey", "colour")
            return None, f"is {kinds[img.ndim == 3]}, its left image is {kinds[like.ndim == 3]}"
        return img, ""

    def _load(self, rel: str, like: NDArray[np.uint8] | None) -> tuple[NDArray[Any] | None, str]:
        """:meth:`_decode`, and the image must be of the sequence's size."""
        img, reason = self._decode(rel, like)
        camera = self.rig.camera
        if img is not None and (img.shape[1], img.shape[0]) != (camera.width, camera.height):
            h, w = img.shape[:2]
            return None, f"is {w}x{h}, the sequence's images are {camera.width}x{camera.height}"
        return img, reason

    def _read(self, rel: str, like: NDArray[np.uint8] | None) -> NDArray[np.uint8] | None:
        """Image ``rel`` (see :meth:`_load`), or None after a warning (strict: raise)."""
        img, reason = self._load(rel, like)
        if img is None:
            if self.strict:
                raise FormatError(self.path / rel, reason, hint=_SKIP_HINT)
            log.warning("skipping %s: %s", rel, reason)
        return img

    def info(self, deep: bool = False, progress: ProgressFn | None = None) -> SourceInfo:
        """Pairs, camera, baseline, times, ground truth and problems.

        Without ``deep`` only the images' existence is checked; ``deep`` decodes every image,
        reporting ``progress(done, total)``. ``details["unreadable"]`` names every missing or
        undecodable image found.
        """
        problems: list[str] = []
        first = self._first_image
        rig = self.rig
        gt = self.groundtruth()
        pairs = f"{self.left_folder}/ + {self.right_folder}/"
        streams = [StreamInfo.from_stamps("pairs", "stereo", self.stamps_ns, pairs)]
        if gt is not None:
            streams.append(
                StreamInfo.from_stamps("groundtruth", "pose", gt.stamps_ns, self._gt_name())
            )
        frames_in_sequence = int(self.numbers[-1]) + 1
        details: dict[str, Any] = {
            "pair_folders": [self.left_folder, self.right_folder],
            "image_size": [first.width, first.height],
            "colour": first.colour,
            "baseline_m": rig.baseline_m,
            "body_from_left": rig.body_from_left.tolist(),
            "times_source": (
                TIMES_NAME
                if self.times_ns is not None
                else f"none: no {TIMES_NAME}, frames stamped at KITTI's {DEFAULT_RATE_HZ:g} Hz"
            ),
            "deep": deep,
        }
        if self.times_ns is not None and self.times_ns.size != frames_in_sequence:
            problems.append(
                f"{TIMES_NAME} has {self.times_ns.size} times, the images run to frame "
                f"{frames_in_sequence - 1}"
            )
        gaps = frames_in_sequence - int(self.numbers[0]) - len(self)
        if gaps:
            problems.append(
                f"{gaps} frame number(s) missing between {self.names[0]} and {self.names[-1]}"
            )
        if gt is not None:
            details["groundtruth_from"] = self._gt_name()
            details["groundtruth_path_m"] = gt.path_length()
            if len(gt) < frames_in_sequence:
                problems.append(
                    f"{self._gt_name()} has {len(gt)} poses, the images run to frame "
                    f"{frames_in_sequence - 1}"
                )
        unpaired = sorted(set(list_frames(self.path / self.right_folder)[1]) - set(self.names))
        details["unpaired_right"] = unpaired
        if unpaired:
            problems.append(
                f"{len(unpaired)} image(s) in {self.right_folder}/ have no left image: "
                + _named(unpaired)
            )
        unreadable = self._check_files(deep, progress)
        details["unreadable"] = unreadable
        if unreadable:
            problems.append(
                f"{len(unreadable)} image(s) missing or unreadable: " + _named(unreadable)
            )
        return SourceInfo(
            format=self.format_name,
            path=str(self.path),
            streams=streams,
            frames=len(self),
            groundtruth=len(gt) if gt is not None else 0,
            camera=rig.camera,
            camera_source=self.calibration.source,
            problems=problems,
            details=details,
        )

    def _gt_name(self) -> str:
        path = self.groundtruth_path
        if path is None:
            return ""
        return POSES_NAME if path.parent == self.path else f"{path.parent.name}/{path.name}"

    def _check_files(self, deep: bool, progress: ProgressFn | None) -> list[str]:
        """Images of the pairs that are missing (or, with ``deep``, unreadable), as messages."""
        bad: list[str] = []
        total = 2 * len(self)
        done = 0
        for name in self.names:
            left: NDArray[np.uint8] | None = None
            for folder in (self.left_folder, self.right_folder):
                rel = f"{folder}/{name}"
                if deep:
                    img, reason = self._load(rel, left)
                    left = img if folder == self.left_folder else left
                else:
                    reason = "" if (self.path / rel).is_file() else "does not exist"
                if reason:
                    bad.append(f"{rel} {reason}")
                done += 1
                if progress is not None and (deep or done == total):
                    progress(done, total)
        return bad


def _named(names: list[str]) -> str:
    more = f", and {len(names) - NAMED} more" if len(names) > NAMED else ""
    return "; ".join(names[:NAMED]) + more
