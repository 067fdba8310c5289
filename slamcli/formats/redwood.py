"""Open3D / Redwood reconstruction-system RGB-D folders.

The layout Open3D's reconstruction system and the Redwood / augmented ICL-NUIM datasets use::

    FOLDER/
      image/ or color/       colour images (PNG or JPEG)
      depth/                 16-bit depth PNGs registered to the colour camera
      trajectory.log         optional: ground truth, Redwood .log format
      camera_intrinsic.json  optional: Open3D PinholeCameraIntrinsic JSON

Colour and depth are paired by sorted file name (natural order: ``2.png`` before ``10.png``)
when the two folders hold as many images; otherwise by the number in the file name, and the
images left without a partner are reported by ``info``. Frame ``k`` (its position, or its
number counted from the smallest one) is stamped ``k / fps`` seconds (30 fps: nothing in the
layout records the rate).

Depth PNG values are millimetres (depth factor 1000) unless ``depth_factor`` or a camera file
says otherwise; 0 = no reading.

A Redwood ``.log`` is a sequence of five-line blocks: a header ``id id frame`` whose first
number is the frame index, then the 4x4 camera-to-world matrix, row by row. The ground truth is
the first of :data:`GROUNDTRUTH_LOG_NAMES` present, else the one ``.log`` whose name says it is
a trajectory (``livingroom1-traj.log``), else the folder's only ``.log`` not named as odometry.
Its poses are stamped like the frames, so frame ``k`` and pose ``k`` pair exactly.

The camera comes from, first match wins: ``fx/fy/cx/cy``; ``camera`` (a preset name or a camera
file); a ``camera.yaml``/``camera.yml``/``camera.json`` in the folder; an Open3D intrinsic JSON
in the folder (:data:`OPEN3D_CAMERA_NAMES`); else the PrimeSense defaults Open3D assumes
(640x480, fx = fy = 525, cx = 319.5, cy = 239.5).
"""

from __future__ import annotations

import re
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
from slamcli.formats.camera import CameraChoice, find_camera_file, load_camera_file, resolve_camera
from slamcli.formats.rgbd_folder import NAMED, FolderImage, RgbdFolderSource
from slamcli.formats.text import iter_data_lines, parse_count, parse_floats
from slamcli.types import ImageFrame, PinholeCamera, ProgressFn, RgbdFrame, Trajectory

if TYPE_CHECKING:
    from typing_extensions import Unpack

COLOUR_FOLDERS = sniff.REDWOOD_COLOUR_FOLDERS
"""Colour image folders, in the order they are looked for."""

COLOUR_SUFFIXES = (".png", ".jpg", ".jpeg")
DEPTH_SUFFIXES = (".png",)

DEFAULT_FPS = 30.0
"""Frame rate used for stamps: the layout does not record one, and the sensors ran at 30 Hz."""

DEFAULT_DEPTH_FACTOR = 1000.0
"""Raw depth units per metre: Redwood and Open3D depth PNGs hold millimetres."""

PRIMESENSE = PinholeCamera(640, 480, 525.0, 525.0, 319.5, 239.5, ())
"""Open3D's ``PrimeSenseDefault`` intrinsics, the camera of Redwood and ICL-NUIM data."""

OPEN3D_CAMERA_NAMES = ("camera_intrinsic.json", "intrinsic.json", "camera_primesense.json")
"""Open3D intrinsic JSON files looked for in the folder, in this order."""

GROUNDTRUTH_LOG_NAMES = ("groundtruth.log", "gt.log", "trajectory.log", "traj.log")
"""Ground-truth trajectory files looked for first, in this order."""

FRAME_KINDS = ("rgbd", "image")
"""The frame kinds a Redwood folder provides."""

_NUMBER = re.compile(r"(\d+)")
_LOG_HINT = (
    "a Redwood .log has blocks of 5 lines: 'id id frame', then the 4x4 camera-to-world "
    "matrix, one row of 4 numbers per line"
)


@dataclass(frozen=True)
class Pair:
    """One RGB-D frame: its index (for its stamp) and its two files, relative to the folder."""

    index: int
    colour: str
    depth: str


def natural_key(name: str) -> tuple[Any, ...]:
    """Sort key ordering the digit runs of ``name`` by value: ``2.png`` before ``10.png``."""
    return tuple(
        (0, int(part), part) if part.isdigit() else (1, 0, part)
        for part in _NUMBER.split(name)
        if part
    )


def file_number(name: str) -> int | None:
    """The last run of digits in a file name's stem (``frame-000012.png`` -> 12), or None."""
    found = _NUMBER.findall(Path(name).stem)
    return int(found[-1]) if found else None


def read_redwood_log(path: str | Path, fps: float = DEFAULT_FPS) -> Trajectory:
    """Read a Redwood ``.log`` trajectory; pose of frame ``k`` stamped ``k / fps`` seconds.

    Raises:
        FormatError: a bad header or matrix line, a block cut short, a matrix that is not a
            rigid transform, or a frame index given twice (names the file and line).
    """
    p = Path(path)
    lines = list(iter_data_lines(p))
    if not lines:
        raise FormatError(p, "holds no poses", hint=_LOG_HINT)
    try:
        indices, poses = _read_log_blocks(p, lines)
    except FormatError as exc:
        exc.hint = exc.hint or _LOG_HINT
        raise
    order = np.argsort(np.asarray(indices, dtype=np.int64), kind="stable")
    frame = np.asarray(indices, dtype=np.int64)[order]
    return Trajectory(frame_stamps_ns(frame, fps), np.stack(poses)[order])


def _read_log_blocks(
    p: Path, lines: list[tuple[int, list[str]]]
) -> tuple[list[int], list[NDArray[np.float64]]]:
    """Frame indices and matrices of a ``.log``'s blocks, in file order."""
    indices: list[int] = []
    poses: list[NDArray[np.float64]] = []
    seen: dict[int, int] = {}
    for start in range(0, len(lines), 5):
        number, header = lines[start]
        if len(header) != 3:
            raise FormatError(
                p,
                f"expected a block header 'id id frame' (3 whole numbers), found "
                f"{len(header)} field(s)",
                number,
                _LOG_HINT,
            )
        ids = [parse_count(f, p, number, "block header field") for f in header]
        block = lines[start + 1 : start + 5]
        if len(block) < 4:
            raise FormatError(
                p,
                f"block for frame {ids[0]} has {len(block)} matrix row(s), expected 4",
                block[-1][0] if block else number,
                _LOG_HINT,
            )
        rows = []
        for row_number, fields in block:
            if len(fields) != 4:
                raise FormatError(
                    p,
                    f"expected a matrix row of 4 numbers, found {len(fields)} field(s)",
                    row_number,
                    _LOG_HINT,
                )
            rows.append(parse_floats(fields, p, row_number, "matrix entry"))
        m = np.asarray(rows, dtype=np.float64)
        if not np.allclose(m[3], (0.0, 0.0, 0.0, 1.0), atol=1e-6):
            raise FormatError(
                p,
                f"last matrix row is {' '.join(block[3][1])}, expected 0 0 0 1",
                block[3][0],
                _LOG_HINT,
            )
        r = m[:3, :3]
        error = float(np.abs(r.T @ r - np.eye(3)).max())
        if error > 1e-3 or np.linalg.det(r) < 0:
            raise FormatError(
                p,
                f"the matrix of frame {ids[0]} is not a rotation and translation "
                f"(|R^T R - I| = {error:.2g}, det {np.linalg.det(r):.3g})",
                number,
                _LOG_HINT,
            )
        if ids[0] in seen:
            raise FormatError(
                p,
                f"frame {ids[0]} is given twice (first at line {seen[ids[0]]})",
                number,
                _LOG_HINT,
            )
        seen[ids[0]] = number
        indices.append(ids[0])
        poses.append(m)
    return indices, poses


def frame_stamps_ns(index: NDArray[np.int64], fps: float = DEFAULT_FPS) -> NDArray[np.int64]:
    """Stamps (int64 ns) of frame indices at ``fps`` frames per second."""
    return np.rint(np.asarray(index, dtype=np.float64) * (1e9 / fps)).astype(np.int64)


def find_groundtruth_log(folder: str | Path) -> tuple[Path | None, list[Path]]:
    """The ground-truth ``.log`` of a folder (see the module docstring) and the other ones."""
    logs = sorted(
        (p for p in Path(folder).glob("*") if p.suffix.lower() == ".log" and p.is_file()),
        key=lambda p: natural_key(p.name),
    )
    by_name = {p.name.lower(): p for p in logs}
    chosen: Path | None = next((by_name[n] for n in GROUNDTRUTH_LOG_NAMES if n in by_name), None)
    if chosen is None:
        named = [p for p in logs if re.search(r"traj|groundtruth|(?:^|[-_])gt(?:$|[-_])", p.stem)]
        if len(named) == 1:
            chosen = named[0]
        elif not named:
            rest = [p for p in logs if "odom" not in p.stem.lower()]
            chosen = rest[0] if len(rest) == 1 else None
    return chosen, [p for p in logs if p != chosen]


class RedwoodSource(RgbdFolderSource):
    """An Open3D / Redwood RGB-D folder as a :class:`~slamcli.formats.base.Source`.

    Args:
        path: the folder (holds ``image/`` or ``color/``, and ``depth/``).
        depth_factor: raw depth units per metre; default: the camera file's, else 1000.
        camera, fx, fy, cx, cy: camera choice, see the module docstring.
        strict: an unreadable image raises :class:`FormatError` instead of being skipped.
        fps: frame rate for the stamps of frames and ground truth.

    Raises:
        InputError: not a folder, no colour or depth folder, no images, or file names that
            cannot be paired.
        FormatError: a malformed camera file (the ``.log`` is read by :meth:`groundtruth`).
        ConfigError: a bad option value.
    """

    format_name = "redwood"
    frame_kinds = FRAME_KINDS
    folder_label = "an Open3D/Redwood RGB-D folder"
    CAMERA_HINT = "give the right camera with --camera or a camera_intrinsic.json in the folder"
    MISSING = "is not a regular file"
    OPTIONS = ("depth_factor", "camera", "fx", "fy", "cx", "cy", "strict")

    def __init__(
        self,
        path: str | Path,
        *,
        depth_factor: float | None = None,
        strict: bool = False,
        fps: float = DEFAULT_FPS,
        **choice: Unpack[CameraChoice],
    ) -> None:
        self.path = Path(path)
        if depth_factor is not None and not (np.isfinite(depth_factor) and depth_factor > 0):
            raise ConfigError(f"depth_factor must be > 0 (units per metre), got {depth_factor}")
        if not (np.isfinite(fps) and fps > 0):
            raise ConfigError(f"fps must be a positive number of frames per second, got {fps}")
        if not self.path.is_dir():
            raise InputError(f"{self.path}: an Open3D/Redwood RGB-D input is a folder")
        colour_dir = next((self.path / n for n in COLOUR_FOLDERS if (self.path / n).is_dir()), None)
        depth_dir = self.path / "depth"
        if colour_dir is None or not depth_dir.is_dir():
            missing = (
                [] if colour_dir is not None else [" or ".join(f"{n}/" for n in COLOUR_FOLDERS)]
            )
            if not depth_dir.is_dir():
                missing.append("depth/")
            raise InputError(
                f"{self.path}: Open3D/Redwood RGB-D folder has no {' and no '.join(missing)}",
                hint="an Open3D/Redwood folder has colour images in image/ (or color/) and "
                "16-bit depth PNGs in depth/",
            )
        self.colour_dir = colour_dir
        self.depth_dir = depth_dir
        self.fps = float(fps)
        self.strict = bool(strict)
        self.stats = ReadStats()
        self.colour_files = _list_images(colour_dir, COLOUR_SUFFIXES)
        self.depth_files = _list_images(depth_dir, DEPTH_SUFFIXES)
        if not self.colour_files or not self.depth_files:
            empty = colour_dir if not self.colour_files else depth_dir
            kinds = "PNG or JPEG" if empty is colour_dir else "PNG"
            raise InputError(
                f"{empty}: holds no {kinds} images",
                hint="colour images go in image/ (or color/), 16-bit depth PNGs in depth/",
            )
        self.pairs, self.unpaired_colour, self.unpaired_depth, self.pairing = self._pair()
        resolved = self._resolve_camera(choice)
        self.camera, self.camera_source, file_factor = resolved
        self._use_depth_factor(depth_factor, file_factor, DEFAULT_DEPTH_FACTOR, "Redwood default")
        self.groundtruth_path, self.other_logs = find_groundtruth_log(self.path)

    @classmethod
    def sniff(cls, path: str | Path) -> bool:
        """A folder with ``depth/`` and ``image/`` or ``color/`` subfolders."""
        return sniff.redwood(path)

    def __len__(self) -> int:
        """Number of paired RGB-D frames."""
        return len(self.pairs)

    def _pair(self) -> tuple[list[Pair], list[str], list[str], str]:
        colour = [f"{self.colour_dir.name}/{n}" for n in self.colour_files]
        depth = [f"depth/{n}" for n in self.depth_files]
        if len(colour) == len(depth):
            pairs = [Pair(k, c, d) for k, (c, d) in enumerate(zip(colour, depth, strict=True))]
            return pairs, [], [], "sorted order"
        numbers: list[dict[int, str]] = []
        for names in (colour, depth):
            table: dict[int, str] = {}
            for name in names:
                n = file_number(name)
                if n is None or n in table:
                    why = "has no number" if n is None else f"has the number of {table[n]}"
                    raise InputError(
                        f"{self.path}: {len(colour)} colour and {len(depth)} depth images, and "
                        f"{name} {why}: they cannot be paired",
                        hint="pair them by sorted order (the same count in both folders) or "
                        "by a distinct frame number in every file name",
                    )
                table[n] = name
            numbers.append(table)
        by_colour, by_depth = numbers
        first = min(min(by_colour), min(by_depth))
        common = sorted(set(by_colour) & set(by_depth))
        pairs = [Pair(n - first, by_colour[n], by_depth[n]) for n in common]
        lone_c = [by_colour[n] for n in sorted(set(by_colour) - set(by_depth))]
        lone_d = [by_depth[n] for n in sorted(set(by_depth) - set(by_colour))]
        return pairs, lone_c, lone_d, "file-name number"

    def _resolve_camera(self, choice: CameraChoice) -> tuple[PinholeCamera, str, float | None]:
        camera = choice.get("camera")
        if camera is not None:
            base = resolve_camera(self.path, camera)
            cam, source, factor = base.camera, base.source, base.depth_factor
        elif find_camera_file(self.path) is not None:
            base = resolve_camera(self.path)
            cam, source, factor = base.camera, base.source, base.depth_factor
        else:
            found = next(
                (self.path / n for n in OPEN3D_CAMERA_NAMES if (self.path / n).is_file()), None
            )
            if found is not None:
                f = load_camera_file(found)
                cam, factor = f.camera, f.depth_factor
                source = f"Open3D camera file {found.name} next to the data"
            else:
                cam, factor = PRIMESENSE, None
                source = "PrimeSense default (no camera file in the folder)"
        fx, fy, cx, cy = choice.get("fx"), choice.get("fy"), choice.get("cx"), choice.get("cy")
        if any(v is not None for v in (fx, fy, cx, cy)):
            explicit = resolve_camera(self.path, cam, fx, fy, cx, cy)
            return explicit.camera, f"explicit fx/fy/cx/cy (image size from {source})", factor
        return cam, source, factor

    @cached_property
    def _groundtruth(self) -> Trajectory | None:
        if self.groundtruth_path is None:
            return None
        return read_redwood_log(self.groundtruth_path, self.fps)

    def groundtruth(self) -> Trajectory | None:
        """Camera-to-world poses from the folder's trajectory ``.log``, or None."""
        return self._groundtruth

    def frame_stamps_ns(self) -> NDArray[np.int64]:
        """(N,) stamps of the paired frames, in order."""
        return frame_stamps_ns(np.asarray([p.index for p in self.pairs], dtype=np.int64), self.fps)

    def frames(self, kinds: Collection[str] = ("rgbd",)) -> Iterator[Frame]:
        """Yield frames of the requested kinds in frame order, decoding images lazily.

        ``rgbd`` gives an :class:`RgbdFrame` per pair, ``image`` an :class:`ImageFrame` per
        paired colour image (sharing the decoded array with the RGB-D frame when both are
        asked for). Frames whose images are missing or unreadable are skipped and counted in
        :attr:`stats` (with ``strict``, a :class:`FormatError`).

        Raises:
            ConfigError: an unknown kind.
            InputError: a kind this folder never has, or images not of the camera's size.
        """
        wanted = self._check_kinds(kinds)
        stamps = self.frame_stamps_ns().tolist()
        for pair, stamp in zip(self.pairs, stamps, strict=True):
            rgb = self._read_colour(FolderImage(pair.colour))
            if rgb is None:
                self._skip(pair.colour, 2 if "image" in wanted and "rgbd" in wanted else 1)
                continue
            if "image" in wanted:
                self.stats.read += 1
                yield ImageFrame(stamp, rgb, self.camera, pair.colour)
            if "rgbd" not in wanted:
                continue
            depth_image = FolderImage(pair.depth, depth=True)
            depth = self._read_depth(depth_image)
            if depth is None or not self._same_size(rgb, depth, pair.colour, depth_image):
                self._skip(pair.colour)
                continue
            self.stats.read += 1
            yield RgbdFrame(stamp, rgb, depth, self.camera, stamp, pair.colour)

    def info(self, deep: bool = False, progress: ProgressFn | None = None) -> SourceInfo:
        """Streams, pairing, camera, ground truth, a depth-scale check and problems.

        Without ``deep`` only the images' existence is checked and a few depth images are
        decoded; ``deep`` decodes every image, reporting ``progress(done, total)``.

        Raises:
            FormatError: a malformed ground-truth ``.log``.
        """
        problems: list[str] = []
        gt = self.groundtruth()
        n = len(self)
        colour_index = [p.index for p in self.pairs]
        streams = [
            _stream(
                self.colour_dir.name,
                "image",
                len(self.colour_files),
                self.fps,
                f"{self.colour_dir.name}/",
            ),
            _stream("depth", "depth", len(self.depth_files), self.fps, "depth/"),
        ]
        details: dict[str, Any] = {
            "colour_folder": self.colour_dir.name,
            "pairing": self.pairing,
            "fps": self.fps,
            "unpaired_colour": self.unpaired_colour,
            "unpaired_depth": self.unpaired_depth,
            "depth_factor": self.depth_factor,
            "depth_factor_source": self.depth_factor_source,
            "deep": deep,
        }
        for what, lone in (("colour", self.unpaired_colour), ("depth", self.unpaired_depth)):
            if lone:
                more = f", and {len(lone) - NAMED} more" if len(lone) > NAMED else ""
                problems.append(
                    f"{len(lone)} {what} image(s) have no partner with the same number: "
                    + ", ".join(lone[:NAMED])
                    + more
                )
        if gt is not None and self.groundtruth_path is not None:
            streams.append(
                StreamInfo(
                    "groundtruth",
                    "pose",
                    len(gt),
                    self.fps if len(gt) > 1 else None,
                    float(gt.stamps_ns[0]) * 1e-9,
                    float(gt.stamps_ns[-1]) * 1e-9,
                    self.groundtruth_path.name,
                )
            )
            details["groundtruth_from"] = self.groundtruth_path.name
            stamps = set(gt.stamps_ns.tolist())
            covered = sum(1 for s in self.frame_stamps_ns().tolist() if s in stamps)
            details["groundtruth_covered"] = covered
            details["groundtruth_coverage"] = covered / n if n else None
            if n and covered < 0.9 * n:
                problems.append(f"only {covered} of {n} frames have a pose in the ground truth")
        else:
            details["groundtruth_coverage"] = None
        if self.other_logs:
            details["other_logs"] = [p.name for p in self.other_logs]
            if gt is None:
                problems.append(
                    "no ground truth: cannot tell which .log is the trajectory among "
                    + ", ".join(p.name for p in self.other_logs)
                    + f" (name it {GROUNDTRUTH_LOG_NAMES[2]})"
                )
        details["frame_indices"] = [min(colour_index), max(colour_index)] if colour_index else None
        return self._finish_info(streams, gt, problems, details, deep, progress)

    def _all_images(self) -> list[FolderImage]:
        return [FolderImage(f"{self.colour_dir.name}/{n}") for n in self.colour_files] + [
            FolderImage(f"depth/{n}", depth=True) for n in self.depth_files
        ]

    def _colour_images(self) -> Iterator[FolderImage]:
        return (FolderImage(pair.colour) for pair in self.pairs)

    def _paired_depth_image(self, k: int) -> FolderImage:
        return FolderImage(self.pairs[k].depth, depth=True)


def _list_images(folder: Path, suffixes: tuple[str, ...]) -> list[str]:
    """Names of the image files in ``folder`` with one of ``suffixes``, in natural order."""
    names = [p.name for p in folder.iterdir() if p.suffix.lower() in suffixes]
    return sorted(names, key=natural_key)


def _stream(name: str, kind: str, count: int, fps: float, detail: str) -> StreamInfo:
    if count == 0:
        return StreamInfo(name, kind, 0, detail=detail)
    return StreamInfo(name, kind, count, fps if count > 1 else None, 0.0, (count - 1) / fps, detail)
