"""TUM RGB-D folders: ``rgb.txt``, ``depth.txt``, ``groundtruth.txt``, ``accelerometer.txt``.

A folder holds list files of ``timestamp filename`` lines and the PNGs they name: 8-bit colour
and 16-bit depth registered to the colour camera (value / depth factor = metres, 0 = no
reading). Colour and depth are paired exactly like TUM's ``associate.py``: every pair with
``|t_rgb - (t_depth + dt_offset)| < max_dt`` is a candidate, candidates are taken in order of
increasing ``|Δt|`` and each image is used at most once.

Ground-truth coverage (``info().details["groundtruth_coverage"]``) is the fraction of
associated frames whose colour stamp has a ground-truth pose within
:data:`GROUNDTRUTH_MAX_DT_S` (the matching tolerance of TUM's ``evaluate_ate.py``);
``groundtruth_span_coverage`` is the fraction inside the ground-truth time span, where a pose
can be interpolated.

Undistortion (``undistort=True``) remaps the colour image with the camera's distortion model
onto the same pinhole (same K, zero distortion); pixels that map outside the raw image become
black. The depth image gets the same remap, with nearest-neighbour sampling, because the
driver registered it pixel for pixel to the colour image: the same warp keeps that 1:1
correspondence, and nearest sampling never invents depths by blending a foreground and a
background reading across an edge. The depth values themselves are z-depths along the optical
axis, which undistortion (no rotation, same centre) leaves unchanged. Caveat: the Kinect's
hardware registration used its factory colour model, so registered depth only approximately
shares the distortion that TUM calibrated later; TUM recommends the ROS default intrinsics
without undistortion for that reason, which is why ``undistort`` is off by default.
"""

from __future__ import annotations

from collections.abc import Collection, Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats import sniff
from slamcli.formats.base import Frame, ReadStats, SourceInfo, StreamInfo
from slamcli.formats.camera import DEFAULT_DEPTH_FACTOR, CameraChoice, resolve_camera
from slamcli.formats.pairing import associate_stamps
from slamcli.formats.rgbd_folder import DEPTH_PLAUSIBLE_M as DEPTH_PLAUSIBLE_M
from slamcli.formats.rgbd_folder import FolderImage, RgbdFolderSource
from slamcli.formats.rgbd_folder import depth_sample_check as depth_sample_check
from slamcli.formats.rgbd_folder import depth_scale_problem as depth_scale_problem
from slamcli.formats.text import iter_data_lines, parse_floats, parse_stamp_ns
from slamcli.formats.trajectory import read_trajectory
from slamcli.geometry.camera import undistort_image
from slamcli.types import ImageFrame, ImuFrame, ProgressFn, RgbdFrame, Trajectory

if TYPE_CHECKING:
    from typing_extensions import Unpack

GROUNDTRUTH_MAX_DT_S = 0.02
"""A frame counts as covered by ground truth when a pose lies within this many seconds."""

FRAME_KINDS = ("rgbd", "image", "imu")
"""The frame kinds a TUM folder provides."""


@dataclass(frozen=True)
class ImageList:
    """One ``timestamp filename`` list file, sorted by time.

    Attributes:
        path: the list file.
        stamps_ns: (N,) int64 nanoseconds, non-decreasing.
        files: N file names as listed (relative to the folder).
        lines: N line numbers in the list file (1-based), for messages.
    """

    path: Path
    stamps_ns: NDArray[np.int64]
    files: tuple[str, ...]
    lines: tuple[int, ...]

    def __len__(self) -> int:
        return len(self.files)

    def where(self, k: int) -> str:
        """``"rgb.txt:12"``: where entry ``k`` was listed."""
        return f"{self.path.name}:{self.lines[k]}"


def read_image_list(path: str | Path) -> ImageList:
    """Read a TUM ``timestamp filename`` list (comments, blank lines and CRLF allowed).

    Raises:
        FormatError: a line without exactly two fields, or a bad timestamp (names file:line).
    """
    p = Path(path)
    stamps: list[int] = []
    files: list[str] = []
    lines: list[int] = []
    for number, fields in iter_data_lines(p):
        if len(fields) != 2:
            raise FormatError(
                p,
                f"expected 'timestamp filename', found {len(fields)} fields",
                number,
                hint="TUM list files have one 'timestamp path/to/image.png' per line",
            )
        stamps.append(parse_stamp_ns(fields[0], p, number))
        files.append(fields[1])
        lines.append(number)
    order = np.argsort(np.asarray(stamps, dtype=np.int64), kind="stable")
    return ImageList(
        p,
        np.asarray(stamps, dtype=np.int64)[order],
        tuple(files[i] for i in order),
        tuple(lines[i] for i in order),
    )


class TumRgbdSource(RgbdFolderSource):
    """A TUM RGB-D folder as a :class:`~slamcli.formats.base.Source`.

    Args:
        path: the folder (holds ``rgb.txt`` and ``depth.txt``).
        max_dt: pairing tolerance in seconds (strict, as in ``associate.py``).
        dt_offset: seconds added to depth stamps before pairing.
        depth_factor: raw depth units per metre; default: the camera file's, else 5000.
        camera, fx, fy, cx, cy: camera choice, see :func:`~slamcli.formats.camera.resolve_camera`.
        undistort: remove lens distortion from colour (and, the same way, depth); see the
            module docstring.
        strict: an unreadable or missing image raises :class:`FormatError` instead of being
            skipped.

    Raises:
        InputError: not a folder, or ``rgb.txt``/``depth.txt`` missing.
        FormatError: a malformed list line.
        ConfigError: a bad option value.
    """

    format_name = "tum"
    frame_kinds = FRAME_KINDS
    folder_label = "a TUM RGB-D folder"
    UNREADABLE = "listed image(s)"
    OPTIONS = (
        "max_dt",
        "dt_offset",
        "depth_factor",
        "camera",
        "fx",
        "fy",
        "cx",
        "cy",
        "undistort",
        "strict",
    )

    def __init__(
        self,
        path: str | Path,
        *,
        max_dt: float = 0.02,
        dt_offset: float = 0.0,
        depth_factor: float | None = None,
        undistort: bool = False,
        strict: bool = False,
        **choice: Unpack[CameraChoice],
    ) -> None:
        self.path = Path(path)
        if not np.isfinite(max_dt) or max_dt <= 0:
            raise ConfigError(f"max_dt must be a positive number of seconds, got {max_dt}")
        if not np.isfinite(dt_offset):
            raise ConfigError(f"dt_offset must be a finite number of seconds, got {dt_offset}")
        if depth_factor is not None and not (np.isfinite(depth_factor) and depth_factor > 0):
            raise ConfigError(f"depth_factor must be > 0 (units per metre), got {depth_factor}")
        if not self.path.is_dir():
            raise InputError(f"{self.path}: a TUM RGB-D input is a folder")
        # rgb.txt alone is a colour-only sequence (monocular input): it has no RGB-D frames.
        self.has_depth = (self.path / "depth.txt").is_file()
        needed = ("rgb.txt", "depth.txt") if not (self.path / "rgb.txt").is_file() else ("rgb.txt",)
        missing = [n for n in needed if not (self.path / n).is_file()]
        if missing:
            present = [
                n for n in ("rgb.txt", "depth.txt", "associations.txt") if (self.path / n).is_file()
            ]
            raise InputError(
                f"{self.path}: TUM RGB-D folder has no {' and no '.join(missing)}"
                + (f" (found {', '.join(present)})" if present else ""),
                hint="a TUM RGB-D folder has rgb.txt and depth.txt listing 'timestamp file' lines",
            )
        self.max_dt = float(max_dt)
        self.dt_offset = float(dt_offset)
        self.undistort = bool(undistort)
        self.strict = bool(strict)
        self.stats = ReadStats()
        self.rgb_list = read_image_list(self.path / "rgb.txt")
        self.depth_list = (
            read_image_list(self.path / "depth.txt")
            if self.has_depth
            else ImageList(self.path / "depth.txt", np.zeros(0, np.int64), (), ())
        )
        resolved = resolve_camera(self.path, **choice)
        self.raw_camera = resolved.camera
        self.camera_source = resolved.source
        self.camera_is_fallback = resolved.fallback
        self._use_depth_factor(
            depth_factor, resolved.depth_factor, DEFAULT_DEPTH_FACTOR, "TUM default"
        )
        self._remove_distortion = self.undistort and self.raw_camera.is_distorted
        self.camera = self.raw_camera.undistorted() if self._remove_distortion else self.raw_camera
        self.rgb_index, self.depth_index = associate_stamps(
            self.rgb_list.stamps_ns,
            self.depth_list.stamps_ns,
            round(self.max_dt * 1e9),
            round(self.dt_offset * 1e9),
        )

    @classmethod
    def sniff(cls, path: str | Path) -> bool:
        """A folder with ``rgb.txt`` or ``depth.txt``; :meth:`open` names whichever is missing."""
        return sniff.tum_rgbd(path)

    def __len__(self) -> int:
        """Number of associated RGB-D frames."""
        return int(self.rgb_index.size)

    def associations(self) -> list[tuple[int, str, int, str]]:
        """The pairs as ``(rgb_stamp_ns, rgb_file, depth_stamp_ns, depth_file)``, by time."""
        r, d = self.rgb_list, self.depth_list
        return [
            (int(r.stamps_ns[i]), r.files[i], int(d.stamps_ns[j]), d.files[j])
            for i, j in zip(self.rgb_index.tolist(), self.depth_index.tolist(), strict=True)
        ]

    @cached_property
    def _groundtruth(self) -> Trajectory | None:
        p = self.path / "groundtruth.txt"
        return read_trajectory(p, "tum") if p.is_file() else None

    def groundtruth(self) -> Trajectory | None:
        """Poses of the colour camera in the mocap world (camera-to-world), or None."""
        return self._groundtruth

    @cached_property
    def _accelerometer(self) -> tuple[NDArray[np.int64], NDArray[np.float64]] | None:
        p = self.path / "accelerometer.txt"
        if not p.is_file():
            return None
        stamps: list[int] = []
        rows: list[list[float]] = []
        for number, fields in iter_data_lines(p):
            if len(fields) != 4:
                raise FormatError(
                    p, f"expected 'timestamp ax ay az', found {len(fields)} fields", number
                )
            stamps.append(parse_stamp_ns(fields[0], p, number))
            rows.append(parse_floats(fields[1:], p, number, "acceleration", first_column=2))
        t = np.asarray(stamps, dtype=np.int64)
        order = np.argsort(t, kind="stable")
        return t[order], np.asarray(rows, dtype=np.float64).reshape(-1, 3)[order]

    def frames(self, kinds: Collection[str] = ("rgbd",)) -> Iterator[Frame]:
        """Yield frames of the requested kinds in time order, decoding images lazily.

        ``rgbd`` gives :class:`RgbdFrame` for each associated pair, ``image`` an
        :class:`ImageFrame` for every listed colour image, ``imu`` an accelerometer-only
        :class:`ImuFrame` (m/s²). When ``rgbd`` and ``image`` are both asked for, a colour
        image is decoded once and the two frames share its array. Frames whose images are
        missing or unreadable are skipped and counted in :attr:`stats` (with ``strict``, a
        :class:`FormatError`).

        Raises:
            ConfigError: an unknown kind.
            InputError: a kind a TUM folder never has, or images not of the camera's size.
        """
        wanted = self._check_kinds(kinds)
        stamps: list[NDArray[np.int64]] = []
        codes: list[NDArray[np.int64]] = []
        index: list[NDArray[np.int64]] = []
        # At equal stamps: accelerometer, then the image, then the RGB-D frame built from it.
        accel = self._accelerometer if "imu" in wanted else None
        if accel is not None:
            stamps.append(accel[0])
            codes.append(np.zeros(accel[0].size, dtype=np.int64))
            index.append(np.arange(accel[0].size, dtype=np.int64))
        if "image" in wanted:
            n = len(self.rgb_list)
            stamps.append(self.rgb_list.stamps_ns)
            codes.append(np.ones(n, dtype=np.int64))
            index.append(np.arange(n, dtype=np.int64))
        if "rgbd" in wanted:
            stamps.append(self.rgb_list.stamps_ns[self.rgb_index])
            codes.append(np.full(self.rgb_index.size, 2, dtype=np.int64))
            index.append(np.arange(self.rgb_index.size, dtype=np.int64))
        if not stamps:
            return
        t, c, k = (np.concatenate(x) for x in (stamps, codes, index))
        order = np.lexsort((k, c, t))
        last_rgb: tuple[int, NDArray[np.uint8] | None] = (-1, None)
        for code, idx in zip(c[order].tolist(), k[order].tolist(), strict=True):
            if code == 0 and accel is not None:
                self.stats.read += 1
                yield ImuFrame(int(accel[0][idx]), accel_mps2=accel[1][idx])
                continue
            ri = idx if code == 1 else int(self.rgb_index[idx])
            name = self.rgb_list.files[ri]
            if last_rgb[0] == ri:
                rgb = last_rgb[1]
            else:
                rgb = self._load_rgb(ri)
                last_rgb = (ri, rgb)
            if code == 1:
                if rgb is None:
                    self._skip(name)
                    continue
                self.stats.read += 1
                yield ImageFrame(int(self.rgb_list.stamps_ns[ri]), rgb, self.camera, name)
                continue
            di = int(self.depth_index[idx])
            depth = self._load_depth(di) if rgb is not None else None
            if rgb is None or depth is None:
                self._skip(name)
                continue
            if not self._same_size(rgb, depth, name, self._image(self.depth_list, di)):
                self._skip(name)
                continue
            self.stats.read += 1
            yield RgbdFrame(
                int(self.rgb_list.stamps_ns[ri]),
                rgb,
                depth,
                self.camera,
                int(self.depth_list.stamps_ns[di]),
                name,
            )

    def info(self, deep: bool = False, progress: ProgressFn | None = None) -> SourceInfo:
        """Streams, pairing, camera, ground-truth coverage, depth-scale check and problems.

        Without ``deep`` only the listed files' existence is checked and a few depth images
        are decoded; ``deep`` decodes every listed image, reporting ``progress(done, total)``.
        ``details["unreadable"]`` names every missing or undecodable image found.
        """
        problems: list[str] = []
        gt = self.groundtruth()
        accel = self._accelerometer
        streams = [StreamInfo.from_stamps("rgb", "image", self.rgb_list.stamps_ns, "rgb.txt")]
        if self.has_depth:
            streams.append(
                StreamInfo.from_stamps("depth", "depth", self.depth_list.stamps_ns, "depth.txt")
            )
        else:
            problems.append("no depth.txt: colour only (monocular pipelines only)")
        if gt is not None:
            streams.append(
                StreamInfo.from_stamps("groundtruth", "pose", gt.stamps_ns, "groundtruth.txt")
            )
        if accel is not None:
            streams.append(
                StreamInfo.from_stamps("accelerometer", "imu", accel[0], "accelerometer.txt")
            )
        n_rgb, n_depth, n_pairs = len(self.rgb_list), len(self.depth_list), len(self)
        details: dict[str, Any] = {
            "max_dt_s": self.max_dt,
            "dt_offset_s": self.dt_offset,
            "unmatched_rgb": n_rgb - n_pairs,
            "unmatched_depth": n_depth - n_pairs,
            "depth_factor": self.depth_factor,
            "depth_factor_source": self.depth_factor_source,
            "undistort": self._remove_distortion,
            "deep": deep,
        }
        if n_pairs:
            dt = np.abs(
                self.rgb_list.stamps_ns[self.rgb_index]
                - self.depth_list.stamps_ns[self.depth_index]
                - round(self.dt_offset * 1e9)
            )
            details["pair_dt_ms"] = {
                "median": float(np.median(dt)) * 1e-6,
                "max": float(dt.max()) * 1e-6,
            }
        elif self.has_depth:
            problems.append(
                f"no colour/depth pairs within max_dt {self.max_dt:g} s; the stamps may be "
                "offset (see dt_offset)"
            )
        for what, unmatched, total in (
            ("colour", n_rgb - n_pairs, n_rgb),
            ("depth", n_depth - n_pairs, n_depth),
        ):
            if n_pairs and unmatched > 0.1 * total:
                problems.append(
                    f"{unmatched} of {total} {what} images have no partner within {self.max_dt:g} s"
                )
        if self.camera_is_fallback:
            problems.append(f"camera unknown: {self.camera_source}")
        self._coverage(gt, details, problems)
        return self._finish_info(streams, gt, problems, details, deep, progress)

    def _check_depth_wanted(self, wanted: set[str]) -> None:
        if "rgbd" in wanted and not self.has_depth:
            raise InputError(
                f"{self.path}: has rgb.txt but no depth.txt: colour only, no RGB-D frames",
                hint="RGB-D pipelines need depth; 'slamcli run visual' runs colour-only input "
                "monocular",
            )

    def _image(self, lst: ImageList, k: int) -> FolderImage:
        """Image ``k`` of ``lst`` (the colour or the depth list)."""
        return FolderImage(lst.files[k], lst is self.depth_list, lst.path, lst.lines[k])

    def _all_images(self) -> list[FolderImage]:
        return [
            self._image(lst, k) for lst in (self.rgb_list, self.depth_list) for k in range(len(lst))
        ]

    def _colour_images(self) -> Iterator[FolderImage]:
        return (self._image(self.rgb_list, k) for k in range(len(self.rgb_list)))

    def _paired_depth_image(self, k: int) -> FolderImage:
        return self._image(self.depth_list, int(self.depth_index[k]))

    def _undistort(self, image: NDArray[Any], nearest: bool = False) -> NDArray[Any]:
        """``image`` remapped onto the undistorted camera when asked (see the module docstring)."""
        if not self._remove_distortion:
            return image
        return undistort_image(self.raw_camera, image, nearest=nearest)

    def _load_rgb(self, k: int) -> NDArray[np.uint8] | None:
        """Colour image ``k`` as (H, W, 3) uint8 RGB (undistorted if asked), or None if unusable."""
        return self._read_colour(self._image(self.rgb_list, k))

    def _load_depth(self, k: int) -> NDArray[np.float32] | None:
        """Depth image ``k`` as (H, W) float32 metres (0 = no reading), or None if unusable."""
        return self._read_depth(self._image(self.depth_list, k))

    def _coverage(
        self, gt: Trajectory | None, details: dict[str, Any], problems: list[str]
    ) -> None:
        if gt is None or len(gt) == 0 or len(self) == 0:
            details["groundtruth_coverage"] = None
            details["groundtruth_span_coverage"] = None
            return
        q = self.rgb_list.stamps_ns[self.rgb_index]
        g = gt.stamps_ns
        after = np.searchsorted(g, q)
        left = g[np.clip(after - 1, 0, g.size - 1)]
        right = g[np.clip(after, 0, g.size - 1)]
        nearest = np.minimum(np.abs(q - left), np.abs(q - right))
        covered = int(np.count_nonzero(nearest <= round(GROUNDTRUTH_MAX_DT_S * 1e9)))
        inside = int(np.count_nonzero((q >= g[0]) & (q <= g[-1])))
        details["groundtruth_covered"] = covered
        details["groundtruth_coverage"] = covered / len(self)
        details["groundtruth_span_coverage"] = inside / len(self)
        if covered < 0.9 * len(self):
            problems.append(
                f"only {covered} of {len(self)} frames have a ground-truth pose within "
                f"{GROUNDTRUTH_MAX_DT_S:g} s"
            )
