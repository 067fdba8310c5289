"""ORB features spread over the image, and keypoints lifted to 3-D with depth.

OpenCV's ORB keeps the ``nfeatures`` strongest corners of each pyramid level, which cluster on
the most textured patch of a scene and leave the rest of the image empty; PnP and bundle
adjustment are better conditioned by corners everywhere. :func:`extract_orb` therefore asks
OpenCV for several times more corners than wanted (with a low FAST threshold, so weak texture
still gives some) and keeps them level by level and cell by cell: each pyramid level gets a
share of the features proportional to its area (as ORB-SLAM does), and within a level the
image is cut into square cells and the best corner of every cell is taken before the second
best of any, round after round, until the level's share is full. OpenCV describes every
detected corner in the same call (each from its own pyramid level, so a kept corner's
descriptor is what describing it alone gives), and the kept ones are taken.

Everything is deterministic: OpenCV's ORB has no randomness, and ties are broken by position.
"""

from __future__ import annotations

import operator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry.camera import undistort_points, unproject
from slamcli.types import PinholeCamera

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

_OCTAVE = operator.attrgetter("octave")
_RESPONSE = operator.attrgetter("response")


@dataclass(frozen=True)
class Features:
    """ORB features of one image.

    Attributes:
        keypoints: (N, 2) float32 pixel positions (u, v) in the image as given.
        octaves: (N,) int16 pyramid level each was found at (0 = full resolution).
        descriptors: (N, 32) uint8 ORB descriptors.
        responses: (N,) float32 corner scores (Harris), higher is stronger.
    """

    keypoints: F32
    octaves: NDArray[np.int16]
    descriptors: NDArray[np.uint8]
    responses: F32

    def __len__(self) -> int:
        return int(self.keypoints.shape[0])

    @staticmethod
    def empty() -> Features:
        return Features(
            np.zeros((0, 2), np.float32),
            np.zeros(0, np.int16),
            np.zeros((0, 32), np.uint8),
            np.zeros(0, np.float32),
        )

    def select(self, index: NDArray[Any]) -> Features:
        """The features at ``index`` (an integer or boolean array)."""
        return Features(
            self.keypoints[index],
            self.octaves[index],
            self.descriptors[index],
            self.responses[index],
        )


@dataclass(frozen=True)
class OrbSettings:
    """How :func:`extract_orb` finds features.

    Attributes:
        n_features: features kept per image.
        levels: pyramid levels.
        scale: pyramid scale factor between levels.
        fast_threshold: FAST corner threshold (intensity levels); low, since corners are
            ranked afterwards.
        cell_px: side of the spreading grid's cells, in pixels of each level.
        oversample: how many more corners than wanted are detected before spreading.
    """

    n_features: int = 1000
    levels: int = 8
    scale: float = 1.2
    fast_threshold: int = 12
    cell_px: int = 30
    oversample: float = 2.0


def level_quota(n_features: int, levels: int, scale: float) -> NDArray[np.int64]:
    """Features per pyramid level, proportional to each level's area, summing to n_features."""
    factor = 1.0 / scale
    share = factor ** np.arange(levels)
    share = share / share.sum()
    quota = np.floor(share * n_features).astype(np.int64)
    quota[0] += n_features - int(quota.sum())
    return quota


def extract_orb(gray: NDArray[np.uint8], settings: OrbSettings = OrbSettings()) -> Features:
    """ORB features of a grayscale (H, W) uint8 image, spread over the image and the pyramid."""
    import cv2

    orb = _orb(settings)
    # One call detects and describes every corner (OpenCV lets go of the interpreter lock
    # for all of it; its ``detect`` alone holds it for a good part); the spread then picks
    # the kept ones. The descriptors are those ``compute`` gives the kept corners alone.
    detected, desc = orb.detectAndCompute(gray, None)
    if not detected or desc is None:
        return Features.empty()
    n = len(detected)
    xy = np.asarray(cv2.KeyPoint.convert(detected), np.float64).reshape(-1, 2)
    octave = np.fromiter(map(_OCTAVE, detected), np.int64, n)
    response = np.fromiter(map(_RESPONSE, detected), np.float64, n)
    keep = _spread(xy, octave, response, settings)
    return Features(
        xy[keep].astype(np.float32),
        octave[keep].astype(np.int16),
        np.ascontiguousarray(desc[keep], dtype=np.uint8),
        response[keep].astype(np.float32),
    )


def _orb(settings: OrbSettings) -> Any:
    import cv2

    return cv2.ORB.create(
        nfeatures=max(1, int(settings.n_features * settings.oversample)),
        scaleFactor=settings.scale,
        nlevels=settings.levels,
        fastThreshold=settings.fast_threshold,
    )


def _spread(
    xy: F64, octave: NDArray[np.int64], response: F64, settings: OrbSettings
) -> NDArray[np.int64]:
    """Indices of the corners kept: per level its quota, round-robin over grid cells."""
    quota = level_quota(settings.n_features, settings.levels, settings.scale)
    in_range = (octave >= 0) & (octave < settings.levels)
    idx = np.flatnonzero(in_range)
    lvl = octave[idx]
    x, y, neg = xy[idx, 0], xy[idx, 1], -response[idx]
    # Cells are cell_px wide in each level's own pixels.
    size = settings.cell_px * settings.scale ** lvl.astype(np.float64)
    cell = np.floor(y / size).astype(np.int64) * 100_000 + np.floor(x / size).astype(np.int64)
    # Rank within each (level, cell) by response (ties by position), then, per level, rank 0
    # of every cell before rank 1 of any.
    order = np.lexsort((x, y, neg, cell, lvl))
    group = lvl[order] * 10**12 + cell[order]
    starts = np.r_[0, np.flatnonzero(np.diff(group)) + 1]
    rank = np.empty(order.size, dtype=np.int64)
    rank[order] = np.arange(order.size) - np.repeat(starts, np.diff(np.r_[starts, order.size]))
    ranked = np.lexsort((x, y, neg, rank, lvl))
    bounds = np.searchsorted(lvl[ranked], np.arange(settings.levels + 1))
    chosen: list[NDArray[np.int64]] = []
    leftover: list[NDArray[np.int64]] = []
    spare = 0
    for level in range(settings.levels):
        pick = ranked[bounds[level] : bounds[level + 1]]
        want = int(quota[level]) + spare
        if pick.size == 0:
            spare = want
            continue
        chosen.append(idx[pick[:want]])
        leftover.append(idx[pick[want:]])
        spare = max(0, want - pick.size)
    kept = np.concatenate(chosen) if chosen else np.zeros(0, np.int64)
    if spare and leftover:
        rest = np.concatenate(leftover)
        rest = rest[np.argsort(-response[rest], kind="stable")][:spare]
        kept = np.concatenate([kept, rest])
    return np.sort(kept)


def undistort_keypoints(camera: PinholeCamera, keypoints: NDArray[Any]) -> F64:
    """Raw keypoint pixels -> pixels of ``camera.undistorted()`` (keypoints, not images, are
    undistorted: cheaper, and no resampling blurs the corners)."""
    return undistort_points(camera, np.asarray(keypoints, dtype=np.float64).reshape(-1, 2))


def depth_at(keypoints: NDArray[Any], depth: NDArray[np.float32]) -> F64:
    """Depth (m) under each (N, 2) keypoint, nearest pixel; NaN where it is 0 or outside."""
    h, w = depth.shape
    kp = np.asarray(keypoints, dtype=np.float64).reshape(-1, 2)
    u = np.rint(kp[:, 0]).astype(np.int64)
    v = np.rint(kp[:, 1]).astype(np.int64)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    z = np.full(kp.shape[0], np.nan)
    z[inside] = depth[v[inside], u[inside]]
    z[~(z > 0)] = np.nan
    return z


def lift(keypoints: NDArray[Any], depth: NDArray[np.float32], camera: PinholeCamera) -> F64:
    """(N, 3) camera-frame points under the (N, 2) keypoints, by the depth image; NaN rows
    where there is no depth. Keypoints and depth follow ``camera`` (pinhole)."""
    kp = np.asarray(keypoints, dtype=np.float64).reshape(-1, 2)
    h, w = depth.shape
    clipped = np.stack([np.clip(kp[:, 0], 0, w - 1), np.clip(kp[:, 1], 0, h - 1)], axis=1)
    return unproject(camera, kp, depth_at(clipped, depth))
