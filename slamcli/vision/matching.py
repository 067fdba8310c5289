"""Matching ORB descriptors: by appearance alone (ratio test) and guided by a pose (search by
projection, as ORB-SLAM tracks its local map).

Distances are Hamming distances between 256-bit descriptors. Every function returns index
pairs into its inputs and is deterministic (ties go to the lower index).

:func:`match_ratio_grouped` and :func:`match_by_projection` run compiled loops
(:mod:`slamcli.vision._matching_kernels`, imported on their first call, so importing this module
does not import numba; the kernels are cached on disk, so only the first run after an install
compiles them).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, InputError

I64 = NDArray[np.int64]
F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint16)

#: Hamming distances ORB-SLAM treats as a sure (TH_LOW) and an acceptable (TH_HIGH) match.
TH_LOW = 50
TH_HIGH = 100

_INT64 = np.iinfo(np.int64)


def hamming(a: U8, b: U8, dtype: type[np.integer[Any]] = np.int64) -> NDArray[Any]:
    """Hamming distances between broadcastable (..., 32) uint8 descriptor arrays -> (...).

    The XOR of the bytes is counted eight bytes at a time (``np.bitwise_count`` of uint64
    words), or byte by byte through a table when the descriptor length is not a multiple of 8.
    """
    x = np.bitwise_xor(a, b)  # a new C-contiguous array: its last axis can be re-viewed
    if x.shape[-1] % 8 == 0 and x.dtype == np.uint8:
        return np.bitwise_count(x.view(np.uint64)).sum(axis=-1, dtype=dtype)
    return _POPCOUNT[x].sum(axis=-1, dtype=dtype)


def match_ratio(desc_a: U8, desc_b: U8, ratio: float, max_distance: int = 256) -> I64:
    """(K, 2) index pairs (a, b) of matches passing Lowe's ratio test, at most one per b.

    Each descriptor of ``b`` takes its nearest neighbour in ``a`` when that is closer than
    ``ratio`` times the second nearest (and within ``max_distance``); when several ``b`` pick
    the same ``a``, only the closest keeps it.
    """
    import cv2

    if len(desc_a) < 2 or len(desc_b) < 1:
        return np.zeros((0, 2), dtype=np.int64)
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(desc_b, desc_a, k=2)
    good = [
        (m[0].trainIdx, m[0].queryIdx, m[0].distance)
        for m in pairs
        if len(m) == 2 and m[0].distance < ratio * m[1].distance and m[0].distance <= max_distance
    ]
    if not good:
        return np.zeros((0, 2), dtype=np.int64)
    arr = np.array(good, dtype=np.float64)
    return _one_to_one(arr[:, 0].astype(np.int64), arr[:, 1].astype(np.int64), arr[:, 2])


def match_ratio_grouped(
    desc_a: U8,
    group_a: NDArray[np.integer[Any]],
    desc_b: U8,
    group_b: NDArray[np.integer[Any]],
    ratio: float,
    max_distance: int = 256,
) -> I64:
    """:func:`match_ratio` with each descriptor of ``b`` compared only with those of ``a`` in
    its own group (a vocabulary node, as ORB-SLAM's search for triangulation does): (K, 2)
    pairs (a, b), at most one per a and per b, sorted by b. The nearest and second nearest are
    taken within the group (ties: lower a); a lone candidate passes the ratio test. When
    several b keep the same a, the closest b keeps it (ties: lower b).

    The cost follows the sum over groups of ``len(a in group) * len(b in group)`` instead of
    ``len(a) * len(b)``. The ratio test is evaluated in float64.

    Raises:
        InputError: descriptors that are not 2-D uint8 arrays of one width, or groups whose
            length differs from their descriptors'.
        ConfigError: ``ratio`` or ``max_distance`` that is not a real number.
    """
    ga = np.asarray(group_a, np.int64)
    gb = np.asarray(group_b, np.int64)
    if len(desc_a) == 0 or len(desc_b) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    wa, wb = _words_pair(desc_a, "desc_a", desc_b, "desc_b")
    _check_length(ga, len(wa), "group_a", "desc_a")
    _check_length(gb, len(wb), "group_b", "desc_b")
    if np.result_type(ratio, np.float64) != np.float64:
        raise _not_real("ratio", ratio)
    from slamcli.vision import _matching_kernels as kernels

    return kernels.ratio_grouped(wa, ga, wb, gb, float(ratio), _max_distance(max_distance))


def _one_to_one(a: I64, b: I64, dist: NDArray[np.float64]) -> I64:
    """Keep, for each ``a`` index, only its closest pair (ties: lower b)."""
    order = np.lexsort((b, dist, a))
    a, b = a[order], b[order]
    first = np.r_[True, a[1:] != a[:-1]]
    out = np.stack([a[first], b[first]], axis=1)
    return out[np.argsort(out[:, 1], kind="stable")]


def match_by_projection(
    projected: F64,
    point_desc: U8,
    radius_px: F64,
    keypoints: F64,
    kp_desc: U8,
    *,
    kp_octaves: NDArray[np.int16] | None = None,
    predicted_octaves: NDArray[np.int64] | None = None,
    max_distance: int = TH_HIGH,
    ratio: float = 0.9,
) -> I64:
    """(K, 2) pairs (point, keypoint): map points projected into an image matched to the
    image's keypoints within a search radius.

    Args:
        projected: (P, 2) predicted pixel of each map point.
        point_desc: (P, 32) the points' representative descriptors.
        radius_px: (P,) search radius of each point (ORB-SLAM scales it with the octave the
            point is expected at).
        keypoints: (N, 2) the image's keypoints, same pixel frame as ``projected``.
        kp_desc: (N, 32) their descriptors.
        kp_octaves, predicted_octaves: when given, a keypoint is a candidate only within one
            pyramid level of the level the point is predicted at.
        max_distance: largest Hamming distance accepted.
        ratio: the best candidate must be closer than ``ratio`` times the second best (when the
            two are at different pyramid levels, as ORB-SLAM, the test is skipped).

    Candidates are found through a grid: keypoints are bucketed in square cells from their
    smallest (u, v), of side ``max(min radius, max radius / 4, 1)`` px, and a point looks in the
    ``(2k + 1)^2`` cells around its own, ``k = ceil(radius / cell)`` (at most 9 x 9); there a
    keypoint is a candidate when its squared distance to the point (in the coordinates' dtype,
    float32 or float64; other dtypes are taken as float64) is at most the squared radius.
    Candidates are ranked by (Hamming distance, keypoint index). Each keypoint goes to at most
    one point (the closest in descriptor space, the lower point on a tie); pairs are sorted by
    point.

    Raises:
        InputError: arrays of the wrong shape or length, descriptors that are not uint8 of one
            width, radii that are negative or not finite, keypoints with NaN or -inf pixels.
        ConfigError: ``ratio`` or ``max_distance`` that is not a real number.
    """
    p, n = len(projected), len(keypoints)
    if p == 0 or n == 0:
        return np.zeros((0, 2), dtype=np.int64)
    pt = _coords(projected, "projected")
    kp = _coords(keypoints, "keypoints")
    pw, kw = _words_pair(point_desc, "point_desc", kp_desc, "kp_desc")
    _check_length(pw, p, "point_desc", "projected", ndim=2)
    _check_length(kw, n, "kp_desc", "keypoints", ndim=2)
    radius = np.asarray(radius_px)
    if radius.dtype != np.float32:
        radius = radius.astype(np.float64)
    _check_length(radius, p, "radius_px", "projected")
    use_levels = kp_octaves is not None
    use_predicted = kp_octaves is not None and predicted_octaves is not None
    kp_oct = _levels(kp_octaves, n, "kp_octaves", np.int16)
    pred_oct = _levels(
        predicted_octaves if use_predicted else None, p, "predicted_octaves", np.int64
    )
    # ``best < ratio * second`` is evaluated as numpy would on int64 distances: in int64 for
    # an integer ratio, in float64 otherwise.
    int_ratio = type(ratio) is not float and np.result_type(ratio, np.int64) == np.int64
    if not (int_ratio or type(ratio) is float or np.result_type(ratio, np.int64) == np.float64):
        raise _not_real("ratio", ratio)
    ratio_int = int(ratio) if int_ratio else 0
    if not _INT64.min <= ratio_int <= _INT64.max:
        raise _not_real("ratio", ratio)
    from slamcli.vision import _matching_kernels as kernels

    pairs, status = kernels.by_projection(
        pt,
        kp,
        radius,
        pw,
        kw,
        kp_oct,
        pred_oct,
        use_predicted,
        use_levels,
        _max_distance(max_distance),
        float(ratio),
        int_ratio,
        ratio_int,
    )
    if status == kernels.BAD_RADIUS:
        r64 = radius.astype(np.float64)
        first = int(np.argmin((r64 >= 0) & (r64 < np.inf)))
        raise InputError(
            f"radius_px: expected finite radii >= 0 px, got {r64[first]} for point {first}",
            hint="give every point a finite, non-negative search radius",
        )
    if status == kernels.BAD_SPAN:
        raise InputError(
            f"keypoints: spread over {np.ptp(kp, axis=0)} px, too wide a grid for search radii "
            f"up to {np.max(radius)} px",
            hint="pass the pixels of one image",
        )
    if status == kernels.BAD_KEYPOINTS:
        raise InputError(
            f"keypoints: expected finite pixels, got a smallest (u, v) of {np.min(kp, axis=0)}",
            hint="drop keypoints with NaN or -inf coordinates before matching",
        )
    return pairs


def descriptor_words(desc: U8, name: str) -> NDArray[np.uint64]:
    """(N, B) uint8 descriptors as (N, ceil(B / 8)) uint64 words, zero-padded (the padding
    adds nothing to any Hamming distance)."""
    d = np.asarray(desc)
    if d.ndim != 2 or d.dtype != np.uint8:
        raise InputError(
            f"{name}: expected (N, 32) uint8 descriptors, got {d.dtype} of shape {d.shape}",
            hint="pass descriptors as extract_orb returns them",
        )
    pad = -d.shape[1] % 8
    if pad:
        d = np.pad(d, ((0, 0), (0, pad)))
    return np.ascontiguousarray(d).view(np.uint64)


def _words_pair(
    a: U8, name_a: str, b: U8, name_b: str
) -> tuple[NDArray[np.uint64], NDArray[np.uint64]]:
    """Two descriptor arrays of one width as uint64 words (:func:`descriptor_words`)."""
    wa, wb = descriptor_words(a, name_a), descriptor_words(b, name_b)
    if np.shape(a)[1] != np.shape(b)[1]:
        raise InputError(
            f"{name_a} and {name_b}: descriptors of {np.shape(a)[1]} and {np.shape(b)[1]} bytes",
            hint="match descriptors of one kind (ORB: 32 bytes)",
        )
    return wa, wb


def _check_length(values: NDArray[Any], expected: int, name: str, of: str, ndim: int = 1) -> None:
    """Raises InputError unless ``values`` is ``ndim``-D with one row per row of ``of``."""
    if values.ndim != ndim or len(values) != expected:
        shape = "(N,)" if ndim == 1 else "(N, ...)"
        raise InputError(
            f"{name}: expected {expected} rows (one per row of {of}) of shape {shape}, "
            f"got shape {values.shape}",
            hint=f"give {name} one value per row of {of}",
        )


def _coords(xy: F64, name: str) -> NDArray[np.floating[Any]]:
    """(M, 2) pixels as a C-contiguous float32 or float64 array (other dtypes: float64)."""
    a = np.asarray(xy)
    if a.dtype != np.float32:
        a = a.astype(np.float64, copy=False)
    if a.ndim != 2 or a.shape[1] != 2:
        raise InputError(
            f"{name}: expected (M, 2) pixels, got shape {a.shape}",
            hint="pass one (u, v) row per point",
        )
    return np.ascontiguousarray(a)


def _levels(
    levels: NDArray[np.integer[Any]] | None, expected: int, name: str, dtype: type[np.integer[Any]]
) -> NDArray[np.integer[Any]]:
    """Pyramid levels as a C-contiguous (expected,) array; zeros of ``dtype`` when not given
    (and then never read)."""
    if levels is None:
        return np.zeros(expected, dtype)
    a = np.ascontiguousarray(levels)
    _check_length(a, expected, name, "keypoints" if name == "kp_octaves" else "projected")
    return a


def _max_distance(value: float) -> float:
    """``max_distance`` as a float64: compared with a Hamming distance (a small integer) it
    decides as the int64 or float64 comparison numpy would make."""
    if np.result_type(value, np.int64) not in (np.int64, np.float64):
        raise _not_real("max_distance", value)
    return float(value)


def _not_real(name: str, value: object) -> ConfigError:
    """The error for a matching parameter that is not a real number."""
    return ConfigError(
        f"{name}: expected a real number (int or float), got {value!r}",
        hint=f"pass {name} as a Python int or float",
    )
