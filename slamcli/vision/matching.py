"""Matching ORB descriptors: by appearance alone (ratio test) and guided by a pose (search by
projection, as ORB-SLAM tracks its local map).

Distances are Hamming distances between 256-bit descriptors. Every function returns index
pairs into its inputs and is deterministic (ties go to the lower index).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

I64 = NDArray[np.int64]
F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint16)

#: Hamming distances ORB-SLAM treats as a sure (TH_LOW) and an acceptable (TH_HIGH) match.
TH_LOW = 50
TH_HIGH = 100


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
    pairs (a, b), at most one per a and per b. The nearest and second nearest are taken within
    the group; a lone candidate passes the ratio test.

    Every pair of one group is compared at once, so the cost follows the sum over groups of
    ``len(a in group) * len(b in group)`` instead of ``len(a) * len(b)``.
    """
    ga = np.asarray(group_a, np.int64)
    gb = np.asarray(group_b, np.int64)
    if len(desc_a) == 0 or len(desc_b) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    order = np.argsort(ga, kind="stable")
    sorted_groups = ga[order]
    lo = np.searchsorted(sorted_groups, gb, side="left")
    count = np.searchsorted(sorted_groups, gb, side="right") - lo
    b_idx = np.repeat(np.arange(len(gb)), count)
    if b_idx.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    # Position of each candidate within its b's run: 0, 1, ... count-1.
    starts = np.cumsum(count) - count
    within = np.arange(b_idx.size) - np.repeat(starts, count)
    a_idx = order[np.repeat(lo, count) + within]
    dist = hamming(desc_a[a_idx], desc_b[b_idx])
    rank = np.lexsort((a_idx, dist, b_idx))
    b_s, a_s, d_s = b_idx[rank], a_idx[rank], dist[rank]
    first = np.r_[True, b_s[1:] != b_s[:-1]]
    best = np.flatnonzero(first)
    has_second = best + 1 < b_s.size
    has_second[has_second] = ~first[best[has_second] + 1]
    second = np.where(has_second, d_s[np.minimum(best + 1, b_s.size - 1)], np.inf)
    ok = (d_s[best] < ratio * second) & (d_s[best] <= max_distance)
    best = best[ok]
    if best.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    return _one_to_one(a_s[best], b_s[best], d_s[best].astype(np.float64))


def _one_to_one(a: I64, b: I64, dist: NDArray[np.float64]) -> I64:
    """Keep, for each ``a`` index, only its closest pair (ties: lower b)."""
    order = np.lexsort((b, dist, a))
    a, b = a[order], b[order]
    first = np.r_[True, a[1:] != a[:-1]]
    out = np.stack([a[first], b[first]], axis=1)
    return out[np.argsort(out[:, 1], kind="stable")]


def _near(projected: F64, radius_px: F64, keypoints: F64) -> tuple[I64, I64]:
    """Candidate (point, keypoint) index pairs: every keypoint in the grid cells that a point's
    search circle touches (a superset of those within its radius, each pair once).

    Keypoints are bucketed in square cells (one sort, then cell -> keypoints as offsets), and
    each point visits the ``(2k + 1)^2`` cells around its own, ``k = ceil(radius / cell)``; the
    cell is at least a quarter of the largest radius, so no point visits more than 81."""
    radius = np.asarray(radius_px, dtype=np.float64)
    cell = max(float(np.min(radius)), float(np.max(radius)) / 4.0, 1.0)
    x0 = float(np.min(keypoints[:, 0]))
    y0 = float(np.min(keypoints[:, 1]))
    kx = np.floor((keypoints[:, 0] - x0) / cell).astype(np.int64)
    ky = np.floor((keypoints[:, 1] - y0) / cell).astype(np.int64)
    nx, ny = int(kx.max()) + 1, int(ky.max()) + 1
    cell_of = ky * nx + kx
    order = np.argsort(cell_of, kind="stable")
    starts = np.searchsorted(cell_of[order], np.arange(nx * ny + 1))
    # Each point's window of cells.
    k = np.ceil(radius / cell).astype(np.int64)
    side = 2 * k + 1
    n_win = side * side
    pt = np.repeat(np.arange(len(projected)), n_win)
    local = np.arange(int(n_win.sum())) - np.repeat(np.cumsum(n_win) - n_win, n_win)
    px = np.floor((projected[:, 0] - x0) / cell).astype(np.int64)
    py = np.floor((projected[:, 1] - y0) / cell).astype(np.int64)
    cx = px[pt] + local % side[pt] - k[pt]
    cy = py[pt] + local // side[pt] - k[pt]
    inside = (cx >= 0) & (cx < nx) & (cy >= 0) & (cy < ny)
    pt, cid = pt[inside], cy[inside] * nx + cx[inside]
    lo = starts[cid]
    counts = starts[cid + 1] - lo
    pt, lo, counts = pt[counts > 0], lo[counts > 0], counts[counts > 0]
    total = int(counts.sum())
    offs = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    return np.repeat(pt, counts), order[np.repeat(lo, counts) + offs]


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

    Each keypoint goes to at most one point (the closest in descriptor space).
    """
    p, n = len(projected), len(keypoints)
    if p == 0 or n == 0:
        return np.zeros((0, 2), dtype=np.int64)
    cp, ck = _near(projected, radius_px, keypoints)
    if cp.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    d2 = np.sum((keypoints[ck] - projected[cp]) ** 2, axis=1)
    ok = d2 <= radius_px[cp] ** 2
    if kp_octaves is not None and predicted_octaves is not None:
        ok &= np.abs(kp_octaves[ck].astype(np.int64) - predicted_octaves[cp]) <= 1
    cp, ck = cp[ok], ck[ok]
    if cp.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    dist = hamming(point_desc[cp], kp_desc[ck])
    # Best and second best per point: ordered by point, distance, keypoint (one unique key).
    order = np.argsort((cp * 257 + dist) * n + ck)
    cp, ck, dist = cp[order], ck[order], dist[order]
    first = np.r_[True, cp[1:] != cp[:-1]]
    best = np.flatnonzero(first)
    nxt = best + 1
    has_second = (nxt < cp.size) & np.r_[~first[1:], False][best]
    second = np.full(best.size, np.iinfo(np.int64).max)
    second[has_second] = dist[nxt[has_second]]
    keep = dist[best] <= max_distance
    if kp_octaves is not None:
        same_level = np.ones(best.size, dtype=bool)
        same_level[has_second] = kp_octaves[ck[best[has_second]]] == kp_octaves[ck[nxt[has_second]]]
        keep &= ~same_level | (dist[best] < ratio * second)
    else:
        keep &= dist[best] < ratio * second
    bp, bk, bd = cp[best[keep]], ck[best[keep]], dist[best[keep]]
    if bp.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    # One point per keypoint: the closest descriptor wins.
    out = _one_to_one(bk, bp, bd.astype(np.float64))
    return out[:, ::-1][np.argsort(out[:, 1], kind="stable")]
