"""Stereo matching of ORB keypoints along the rows of a rectified pair, as ORB-SLAM does.

For each left keypoint the right keypoints it may pair with are those on nearly the same row
(within ``band_px`` times the right keypoint's pyramid scale), left of it by a disparity in
``[0, fx * baseline / min_depth]``, and found within one pyramid level of it. The candidate
closest in Hamming distance is taken when that distance is small enough; a right keypoint
claimed by several left ones goes to the closest of them.

The match is then refined to a fraction of a pixel at the left keypoint's pyramid level: an
11x11 patch of the left image around the keypoint (each patch minus its centre pixel, so a
brightness offset between the cameras does not matter) is slid along the right image's row,
+/-5 pixels around the matched keypoint, and a parabola through the smallest sum of absolute
differences (SAD) and its two neighbours gives the sub-pixel offset. A match whose best SAD is
at the window's edge, whose parabola is flat, or whose offset is more than a pixel is dropped;
so are matches whose SAD is above ``1.5 * 1.4`` times the median SAD of the pair (ORB-SLAM's
robust outlier rule).

The pairing and the refinement are compiled with numba (:mod:`slamcli.vision._stereo_kernels`,
imported on the first call, so importing this module stays cheap; the kernels release the GIL,
so matching can run on a thread beside tracking). The pyramid levels are OpenCV resizes of the
full images. Everything is deterministic: ties go to the lower index.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, InputError
from slamcli.types import StereoRig
from slamcli.vision.features import Features
from slamcli.vision.matching import TH_HIGH, TH_LOW, descriptor_words

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]
I64 = NDArray[np.int64]


@dataclass(frozen=True)
class StereoSettings:
    """How :func:`match_stereo` pairs keypoints.

    Attributes:
        band_px: half-height of the row band at pyramid level 0; a right keypoint at level
            ``o`` is a candidate when its row is within ``band_px * scale**o`` of the left one.
        min_depth_m: nearest depth accepted, which bounds the disparity searched
            (``fx * baseline / min_depth_m``); None means one baseline.
        max_hamming: a match's Hamming distance must be below this (ORB-SLAM uses the mean
            of its TH_HIGH and TH_LOW).
        patch_radius_px: half-side of the square SAD patch, in pixels of the keypoint's level.
        search_radius_px: the patch slides this many pixels either side of the matched
            right keypoint, in pixels of the keypoint's level.
        max_offset_px: largest sub-pixel offset the parabola may give (level pixels).
        outlier_factor: matches whose SAD is above this times the median SAD are dropped.
        scale: the pyramid scale factor the features were found with (``OrbSettings.scale``).
    """

    band_px: float = 2.0
    min_depth_m: float | None = None
    max_hamming: int = (TH_HIGH + TH_LOW) // 2
    patch_radius_px: int = 5
    search_radius_px: int = 5
    max_offset_px: float = 1.0
    outlier_factor: float = 1.5 * 1.4
    scale: float = 1.2


@dataclass(frozen=True)
class StereoMatches:
    """The right-image position and depth of each left keypoint.

    Attributes:
        u_right: (N,) float64 sub-pixel column in the right image; NaN when unmatched.
        depth_m: (N,) float64 depth along the left camera's optical axis; NaN when unmatched.
        right_index: (N,) int64 index of the right keypoint each was paired with; -1 when
            unmatched. No right keypoint appears twice.
        n_descriptor: left keypoints whose best candidate passed the Hamming threshold (and
            kept its right keypoint).
        n_refined: of those, the ones the sub-pixel refinement kept.
        n_matched: of those, the ones the SAD outlier rule kept (the finite entries).
    """

    u_right: F64
    depth_m: F64
    right_index: I64
    n_descriptor: int
    n_refined: int
    n_matched: int

    @property
    def matched(self) -> NDArray[np.bool_]:
        """(N,) True where a left keypoint has a match."""
        return self.right_index >= 0

    @staticmethod
    def unmatched(n: int) -> StereoMatches:
        """No match for any of ``n`` left keypoints."""
        return StereoMatches(
            np.full(n, np.nan), np.full(n, np.nan), np.full(n, -1, np.int64), 0, 0, 0
        )


def match_stereo(
    left: Features,
    right: Features,
    left_image: NDArray[np.uint8],
    right_image: NDArray[np.uint8],
    rig: StereoRig,
    settings: StereoSettings = StereoSettings(),
) -> StereoMatches:
    """Right-image column and depth of each left keypoint of a rectified pair.

    Args:
        left, right: ORB features of the left and right images (level-0 pixel positions).
        left_image, right_image: the rectified images, (H, W) grey or (H, W, 3) RGB uint8.
        rig: the pair's geometry (``fx`` and the baseline give depth from disparity).
        settings: search band, thresholds and refinement window.

    Returns:
        One entry per left keypoint; depth is ``fx * baseline / (u_left - u_right)``.

    Raises:
        InputError: the images differ in size or are not uint8 grey or RGB; a feature set's
            arrays disagree in length, or the two sets' descriptors differ in length.
        ConfigError: a setting is out of range.
    """
    _check_settings(settings)
    grey_l, grey_r = _grey(left_image, "left"), _grey(right_image, "right")
    if grey_l.shape != grey_r.shape:
        raise InputError(
            f"stereo images differ in size: left {grey_l.shape}, right {grey_r.shape}",
            hint="pass the two rectified images of one pair",
        )
    _check_features(left, "left")
    _check_features(right, "right")
    n = len(left)
    if n == 0 or len(right) == 0:
        return StereoMatches.unmatched(n)
    if left.descriptors.shape[1] != right.descriptors.shape[1]:
        raise InputError(
            f"stereo descriptors differ in length: left {left.descriptors.shape[1]} bytes, "
            f"right {right.descriptors.shape[1]}",
            hint="extract the features of both images with the same settings",
        )
    fx_b = rig.camera.fx * rig.baseline_m
    min_depth = rig.baseline_m if settings.min_depth_m is None else settings.min_depth_m
    max_disp = fx_b / min_depth
    il, ir = _descriptor_pairs(left, right, max_disp, settings)
    n_descriptor = int(il.size)
    u_r, sad, ok = _refine(left, right, il, ir, grey_l, grey_r, settings)
    disparity = left.keypoints[il, 0].astype(np.float64) - u_r
    ok &= (disparity > 0.0) & (disparity < max_disp)
    il, ir, u_r, sad, disparity = il[ok], ir[ok], u_r[ok], sad[ok], disparity[ok]
    n_refined = int(il.size)
    if il.size:
        median = float(np.sort(sad)[il.size // 2])
        keep = sad <= settings.outlier_factor * median
        il, ir, u_r, disparity = il[keep], ir[keep], u_r[keep], disparity[keep]
    out = StereoMatches.unmatched(n)
    out.u_right[il] = u_r
    out.depth_m[il] = fx_b / disparity
    out.right_index[il] = ir
    return StereoMatches(
        out.u_right, out.depth_m, out.right_index, n_descriptor, n_refined, il.size
    )


def _check_settings(s: StereoSettings) -> None:
    checks: list[tuple[str, bool, str]] = [
        ("band_px", s.band_px > 0, "> 0"),
        ("min_depth_m", s.min_depth_m is None or s.min_depth_m > 0, "> 0 or unset"),
        ("max_hamming", 0 < s.max_hamming <= 256, "in (0, 256]"),
        ("patch_radius_px", s.patch_radius_px >= 1, ">= 1"),
        ("search_radius_px", s.search_radius_px >= 2, ">= 2"),
        ("max_offset_px", s.max_offset_px > 0, "> 0"),
        ("outlier_factor", s.outlier_factor > 0, "> 0"),
        ("scale", s.scale > 1.0, "> 1"),
    ]
    for key, good, allowed in checks:
        if not good:
            raise ConfigError(
                f"stereo.{key} = {getattr(s, key)!r} is out of range: expected {allowed}",
                hint=f"set stereo.{key} {allowed}",
            )


def _check_features(f: Features, which: str) -> None:
    """Raise InputError unless ``f``'s arrays hold one row per keypoint (the compiled
    kernels index them without bounds checks)."""
    n = f.keypoints.shape[0] if f.keypoints.ndim == 2 else -1
    shapes = (f.keypoints.shape, f.octaves.shape, f.descriptors.shape[:1], f.descriptors.ndim)
    if shapes != ((n, 2), (n,), (n,), 2):
        raise InputError(
            f"{which} stereo features: expected keypoints (N, 2), octaves (N,) and "
            f"descriptors (N, B), found {f.keypoints.shape}, {f.octaves.shape} and "
            f"{f.descriptors.shape}",
            hint="pass the Features that extract_orb returns, or a select() of them",
        )


def _grey(image: NDArray[Any], which: str) -> NDArray[np.uint8]:
    img = np.asarray(image)
    if img.dtype != np.uint8 or not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 3)):
        raise InputError(
            f"{which} stereo image: expected (H, W) or (H, W, 3) uint8, "
            f"found {img.shape} {img.dtype}",
            hint="convert the image to 8-bit grey or RGB first",
        )
    if img.ndim == 3:
        import cv2

        return np.asarray(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), dtype=np.uint8)
    return img


def _descriptor_pairs(
    left: Features, right: Features, max_disp: float, s: StereoSettings
) -> tuple[I64, I64]:
    """(left, right) index pairs, in increasing left index: each left keypoint's closest
    candidate (same row band, disparity in [0, max_disp], octaves within one level) below
    ``s.max_hamming``; each right keypoint kept by the closest left one claiming it (ties: lower
    index)."""
    from slamcli.vision import _stereo_kernels as kernels

    oct_r = right.octaves.astype(np.int64)
    lowest, highest = int(oct_r.min()), int(oct_r.max())
    # Python's float power, level by level: the band edges must not move by a bit.
    bands = np.array(
        [s.band_px * s.scale ** float(level) for level in range(lowest, highest + 1)], np.float64
    )
    return kernels.descriptor_pairs(
        left.keypoints[:, 0].astype(np.float64),
        left.keypoints[:, 1].astype(np.float64),
        left.octaves.astype(np.int64),
        descriptor_words(left.descriptors, "left stereo descriptors"),
        right.keypoints[:, 0].astype(np.float64),
        right.keypoints[:, 1].astype(np.float64),
        oct_r,
        descriptor_words(right.descriptors, "right stereo descriptors"),
        lowest,
        bands,
        max_disp,
        float(s.max_hamming),
    )


def _pyramid(image: NDArray[np.uint8], levels: int, scale: float) -> list[NDArray[np.uint8]]:
    """The image at levels 0..levels-1, each ``scale`` times smaller than the one before."""
    import cv2

    h, w = image.shape
    out = [image]
    for level in range(1, levels):
        f = scale**level
        size = (max(1, round(w / f)), max(1, round(h / f)))
        out.append(np.asarray(cv2.resize(image, size, interpolation=cv2.INTER_LINEAR)))
    return out


def _refine(
    left: Features,
    right: Features,
    il: I64,
    ir: I64,
    grey_l: NDArray[np.uint8],
    grey_r: NDArray[np.uint8],
    s: StereoSettings,
) -> tuple[F64, F64, NDArray[np.bool_]]:
    """Sub-pixel right column (level-0 pixels), best SAD and validity of each pair, by SAD
    block matching along the row at the left keypoint's pyramid level."""
    from slamcli.vision import _stereo_kernels as kernels

    m = il.size
    ok = np.zeros(m, dtype=bool)
    if m == 0:
        return np.full(m, np.nan), np.full(m, np.inf), ok
    octave = left.octaves[il].astype(np.int64)
    # numpy's power of the whole array, whose last bit can differ from a scalar power's: the
    # sub-pixel columns (and so the depths) are products with it.
    factor = s.scale ** octave.astype(np.float64)
    levels = int(octave.max()) + 1
    pyr_l = _pyramid(np.ascontiguousarray(grey_l), levels, s.scale)
    pyr_r = _pyramid(np.ascontiguousarray(grey_r), levels, s.scale)
    u_l = left.keypoints[il, 0].astype(np.float64)
    v_l = left.keypoints[il, 1].astype(np.float64)
    u_r0 = right.keypoints[ir, 0].astype(np.float64)
    u_r = np.empty(m, np.float64)
    sad = np.empty(m, np.float64)
    for level in np.unique(octave):
        kernels.refine_level(
            pyr_l[level],
            pyr_r[level],
            int(level),
            octave,
            factor,
            u_l,
            v_l,
            u_r0,
            int(s.patch_radius_px),
            int(s.search_radius_px),
            float(s.max_offset_px),
            u_r,
            sad,
            ok,
        )
    return u_r, sad, ok
