"""What the RGB-D folder formats share: colour images and 16-bit depth PNGs in a folder.

:mod:`~slamcli.formats.tum_rgbd` finds its images through list files and
:mod:`~slamcli.formats.redwood` in its ``image/`` (or ``color/``) and ``depth/`` folders; once
an image is named, both read it the same way (:class:`RgbdFolderSource`): the header's size is
checked before decoding, the first colour image must be of the camera's size, depth must be
16-bit single-channel, and raw depth / depth factor = metres (0 = no reading). Both end
``info`` with the same checks: every image present (decodable, with ``deep``), the camera's
size, and the depth scale (:func:`depth_scale_problem`) of a few sampled depth images.
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, cast

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import FormatError, InputError
from slamcli.formats.base import (
    ReadStats,
    SourceBase,
    SourceInfo,
    StreamInfo,
    known_kinds,
    provided_kinds,
)
from slamcli.formats.images import decode_image, read_image_file
from slamcli.types import PinholeCamera, ProgressFn, Trajectory

log = logging.getLogger(__name__)

NAMED = 3
"""Images named in one problem line; ``info --json`` lists them all."""

DEPTH_PLAUSIBLE_M = (0.3, 10.0)
"""Indoor RGB-D sensors report depths in this range (m); the depth-scale check relies on it."""

_DEPTH_SAMPLES = 5
_KNOWN_DEPTH_FACTORS = {1000.0: "millimetres", 5000.0: "TUM units (5000 per metre)"}


@dataclass(frozen=True)
class FolderImage:
    """One image file of an RGB-D folder.

    Attributes:
        rel: the file, relative to the folder.
        depth: a depth image (16-bit single-channel), not a colour one.
        listed_in: the list file naming it, for a folder that lists its images.
        line: its line in ``listed_in`` (1-based).
    """

    rel: str
    depth: bool = False
    listed_in: Path | None = None
    line: int = 0

    @property
    def listed_at(self) -> str:
        """``" (listed at rgb.txt:12)"``, or ``""`` for an image no list names."""
        return f" (listed at {self.listed_in.name}:{self.line})" if self.listed_in else ""


class RgbdFolderSource(SourceBase):
    """A folder of colour and depth images as a :class:`~slamcli.formats.base.Source`: the
    reading, checks and ``info`` ending its formats share.

    A subclass sets the attributes below in ``__init__`` (the depth factor's with
    :meth:`_use_depth_factor`), says which images it has (:meth:`_all_images`,
    :meth:`_colour_images`, :meth:`_paired_depth_image`) and may change them once decoded
    (:meth:`_undistort`).

    Attributes:
        path: the folder.
        strict: an unreadable or missing image raises :class:`FormatError` instead of being
            skipped.
        stats: frames read and skipped.
        camera: the camera of the frames produced.
        camera_source: where ``camera`` came from, for messages.
        depth_factor: raw depth units per metre, and ``depth_factor_source`` where it came from.
    """

    format_name: ClassVar[str]
    frame_kinds: ClassVar[tuple[str, ...]]
    """The frame kinds the folder provides."""
    folder_label: ClassVar[str]
    """What messages call such a folder ("a TUM RGB-D folder")."""
    CAMERA_HINT: ClassVar[str] = (
        "give the right camera with --camera or a camera file next to the data"
    )
    """What to do when the images are not of the camera's size."""
    MISSING: ClassVar[str] = "does not exist"
    """Why an image is unusable when, without ``deep``, it is not a regular file."""
    UNREADABLE: ClassVar[str] = "image(s)"
    """What info's problem line calls the unusable images."""

    path: Path
    strict: bool
    stats: ReadStats
    camera: PinholeCamera
    camera_source: str
    depth_factor: float
    depth_factor_source: str
    _dfactor: np.float32
    _camera_size_confirmed = False

    def __len__(self) -> int:
        """Number of RGB-D frames (colour/depth pairs)."""
        raise NotImplementedError

    def _check_kinds(self, kinds: Collection[str]) -> set[str]:
        """The frame kinds asked for, checked against the known ones and the folder's."""
        wanted = known_kinds(kinds)
        self._check_depth_wanted(wanted)
        return provided_kinds(wanted, self.frame_kinds, self.path, self.folder_label)

    def _check_depth_wanted(self, wanted: set[str]) -> None:
        """Raise when RGB-D frames are wanted and the folder cannot give them."""

    def _all_images(self) -> list[FolderImage]:
        """Every image of the folder, for the file check of ``info``."""
        raise NotImplementedError

    def _colour_images(self) -> Iterable[FolderImage]:
        """The colour images whose first decodable one ``info`` compares with the camera."""
        raise NotImplementedError

    def _paired_depth_image(self, k: int) -> FolderImage:
        """The depth image of frame ``k`` (``0 <= k < len(self)``)."""
        raise NotImplementedError

    def _undistort(self, image: NDArray[Any], nearest: bool = False) -> NDArray[Any]:
        """A decoded colour (or, with ``nearest``, raw depth) image as frames carry it."""
        return image

    def _use_depth_factor(
        self, given: float | None, from_file: float | None, default: float, default_source: str
    ) -> None:
        """Set :attr:`depth_factor`: ``given``, else the camera file's, else ``default``."""
        if given is not None:
            self.depth_factor, self.depth_factor_source = float(given), "given"
        elif from_file is not None:
            self.depth_factor, self.depth_factor_source = from_file, "camera file"
        else:
            self.depth_factor, self.depth_factor_source = default, default_source
        self._dfactor = np.float32(self.depth_factor)

    def _skip(self, name: str, frames: int = 1) -> None:
        self.stats.skipped += frames
        self.stats.skipped_names.extend([name] * frames)

    def _imread(
        self, image: FolderImage, flags: int, expect: tuple[int, int] | None = None
    ) -> tuple[NDArray[Any] | None, str]:
        """Decode ``image``; returns ``(image, "")`` or ``(None, reason)``.

        The size in the file's header is checked against ``expect`` (width, height) and
        :data:`~slamcli.formats.images.MAX_IMAGE_PIXELS` before anything is decoded.
        """
        data, reason = read_image_file(self.path / image.rel)
        if data is None:
            return None, reason
        img, reason = decode_image(data, flags, expect=expect)
        if img is None:
            return None, reason
        if image.depth and (img.dtype != np.uint16 or img.ndim != 2):
            channels = 1 if img.ndim == 2 else img.shape[2]
            return None, (
                f"is {img.dtype} with {channels} channel(s), expected 16-bit single-channel depth"
            )
        return img, ""

    def _unreadable(self, image: FolderImage, reason: str, warn: bool = True) -> None:
        """``image`` is unusable: a FormatError when strict, else maybe a warning.

        A listed image that does not exist is the list's error, named at its line.
        """
        if self.strict:
            hint = "without strict, unreadable images are skipped and counted"
            if image.listed_in is not None and reason == "does not exist":
                raise FormatError(
                    image.listed_in, f"lists {image.rel}, which does not exist", image.line, hint
                )
            raise FormatError(self.path / image.rel, reason + image.listed_at, hint=hint)
        if warn:
            log.warning("skipping %s: %s%s", image.rel, reason, image.listed_at)

    def _read_colour(self, image: FolderImage) -> NDArray[np.uint8] | None:
        """A colour image as (H, W, 3) uint8 RGB (see :meth:`_undistort`), or None if unusable.

        The first colour image of another size than the camera is an InputError: the camera is
        wrong. Once one image has matched, an odd-sized one is an unreadable frame, refused from
        its header.
        """
        import cv2

        size = (self.camera.width, self.camera.height) if self._camera_size_confirmed else None
        bgr, reason = self._imread(image, cv2.IMREAD_COLOR, expect=size)
        if bgr is None:
            self._unreadable(image, reason)
            return None
        if bgr.shape[:2] != (self.camera.height, self.camera.width):
            raise InputError(
                f"{self.path / image.rel}: image is {bgr.shape[1]}x{bgr.shape[0]}, "
                f"the camera ({self.camera_source}) is {self.camera.width}x{self.camera.height}",
                hint=self.CAMERA_HINT,
            )
        self._camera_size_confirmed = True
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB, dst=bgr)
        return cast("NDArray[np.uint8]", self._undistort(rgb))

    def _read_depth(self, image: FolderImage) -> NDArray[np.float32] | None:
        """A depth image as (H, W) float32 metres (0 = no reading), or None if unusable."""
        import cv2

        size = (self.camera.width, self.camera.height)
        raw, reason = self._imread(image, cv2.IMREAD_UNCHANGED, expect=size)
        if raw is None:
            self._unreadable(image, reason)
            return None
        # One pass from uint16 to float32 metres: no float64 intermediate, no extra copy.
        return np.divide(self._undistort(raw, nearest=True), self._dfactor, dtype=np.float32)

    def _same_size(
        self, rgb: NDArray[Any], depth: NDArray[Any], colour: str, image: FolderImage
    ) -> bool:
        """Whether ``depth`` (from ``image``) is as large as ``rgb`` (from ``colour``); a depth
        image that is not is unreadable."""
        if depth.shape == rgb.shape[:2]:
            return True
        self._unreadable(
            image,
            f"is {depth.shape[1]}x{depth.shape[0]}, its colour image {colour} "
            f"is {rgb.shape[1]}x{rgb.shape[0]}",
        )
        return False

    def _finish_info(
        self,
        streams: list[StreamInfo],
        gt: Trajectory | None,
        problems: list[str],
        details: dict[str, Any],
        deep: bool,
        progress: ProgressFn | None,
    ) -> SourceInfo:
        """Check the images, the camera's size and the depth scale, and make ``info``'s answer.

        ``details["unreadable"]`` names every missing or undecodable image found.
        """
        unreadable = self._check_files(deep, progress)
        details["unreadable"] = unreadable
        if unreadable:
            # details["unreadable"] (info --json) names every one; the problem line, a few.
            more = f", and {len(unreadable) - NAMED} more" if len(unreadable) > NAMED else ""
            problems.append(
                f"{len(unreadable)} {self.UNREADABLE} missing or unreadable: "
                + "; ".join(unreadable[:NAMED])
                + more
            )
        self._check_camera_size(problems)
        depth_problem = self._check_depth_scale(details)
        if depth_problem:
            problems.append(depth_problem)
        return SourceInfo(
            format=self.format_name,
            path=str(self.path),
            streams=streams,
            frames=len(self),
            groundtruth=len(gt) if gt is not None else 0,
            camera=self.camera,
            camera_source=self.camera_source,
            problems=problems,
            details=details,
        )

    def _check_files(self, deep: bool, progress: ProgressFn | None) -> list[str]:
        """Images that are not regular files (or, with ``deep``, undecodable), as messages."""
        import cv2

        jobs = self._all_images()
        bad: list[str] = []
        total = len(jobs)
        for done, image in enumerate(jobs, start=1):
            if deep:
                flags = cv2.IMREAD_UNCHANGED if image.depth else cv2.IMREAD_COLOR
                reason = self._imread(image, flags)[1]
            else:
                reason = "" if (self.path / image.rel).is_file() else self.MISSING
            if reason:
                self._unreadable(image, reason, warn=False)
                bad.append(f"{image.rel} {reason}{image.listed_at}")
            if progress is not None and (deep or done == total):
                progress(done, total)
        return bad

    def _check_camera_size(self, problems: list[str]) -> None:
        """Compare the first decodable colour image's size with the camera's."""
        import cv2

        for image in self._colour_images():
            img = self._imread(image, cv2.IMREAD_UNCHANGED)[0]
            if img is None:
                continue
            h, w = img.shape[:2]
            if (w, h) != (self.camera.width, self.camera.height):
                problems.append(
                    f"images are {w}x{h} but the camera ({self.camera_source}) is "
                    f"{self.camera.width}x{self.camera.height}"
                )
            return

    def _check_depth_scale(self, details: dict[str, Any]) -> str | None:
        """Sample a few paired depth images and judge the depth factor (see DEPTH_PLAUSIBLE_M)."""
        import cv2

        if len(self) == 0:
            return None
        n = min(_DEPTH_SAMPLES, len(self))
        picks = np.unique(np.linspace(0, len(self) - 1, n).round().astype(np.intp))
        values: list[NDArray[Any]] = []
        pixels = 0
        for k in picks.tolist():
            raw = self._imread(self._paired_depth_image(k), cv2.IMREAD_UNCHANGED)[0]
            if raw is not None:
                pixels += raw.size
                values.append(raw[raw > 0])
        return depth_sample_check(values, pixels, self.depth_factor, details)


def depth_sample_check(
    values: list[NDArray[Any]], pixels: int, factor: float, details: dict[str, Any]
) -> str | None:
    """Record sampled depth statistics in ``details["depth_check"]`` and judge the depth
    factor. ``values`` are each sampled image's non-zero raw readings, ``pixels`` the pixels
    sampled in all."""
    if not values:
        return None
    valid = np.concatenate(values)
    check: dict[str, Any] = {"samples": len(values), "valid_fraction": valid.size / pixels}
    details["depth_check"] = check
    if valid.size == 0:
        return "the sampled depth images hold no readings (all zero)"
    p5, median, p95 = (float(v) for v in np.percentile(valid, [5, 50, 95]) / factor)
    check.update(
        median_m=median,
        p5_m=p5,
        p95_m=p95,
        plausible_fraction=_plausible_fraction(valid, factor),
    )
    return depth_scale_problem(valid, factor)


def depth_scale_problem(raw: NDArray[Any], factor: float) -> str | None:
    """Judge a depth factor from raw non-zero depth readings, or None if it looks right.

    Indoor RGB-D sensors read between about 0.3 and 10 m (:data:`DEPTH_PLAUSIBLE_M`); a
    Kinect-class sensor reports nothing nearer than ~0.4 m. If fewer than 80 % of readings land
    in that range with ``factor`` but at least 80 % (and 20 points more) do with another common
    factor (1000 = millimetres, 5000 = TUM), the data was most likely written with that one.
    A scale error only shows when the scene reaches the range limits: millimetre data of a
    scene 2-8 m away read with factor 5000 still looks plausible (0.4-1.6 m).

    Args:
        raw: (K,) raw readings, zeros already removed.
        factor: raw units per metre being used.
    """
    if raw.size == 0:
        return None
    here = _plausible_fraction(raw, factor)
    if here >= 0.8:
        return None
    median = float(np.median(raw)) / factor
    lo, hi = DEPTH_PLAUSIBLE_M
    what = f"median {median:.2f} m, only {here:.0%} of readings within {lo:g}-{hi:g} m"
    best = max(
        ((_plausible_fraction(raw, f), f) for f in _KNOWN_DEPTH_FACTORS if f != factor),
        default=(0.0, factor),
    )
    if best[0] >= 0.8 and best[0] >= here + 0.2:
        return (
            f"depth looks like {_KNOWN_DEPTH_FACTORS[best[1]]} read with depth factor {factor:g} "
            f"({what}); with depth factor {best[1]:g}, {best[0]:.0%} would be"
        )
    return f"depth readings look implausible for an indoor scene ({what}); check the depth factor"


def _plausible_fraction(raw: NDArray[Any], factor: float) -> float:
    lo, hi = DEPTH_PLAUSIBLE_M
    m = raw / factor
    return float(np.count_nonzero((m >= lo) & (m <= hi))) / raw.size
