"""Compiled kernels of :mod:`slamcli.vision.matching`: grouped ratio matching and search by
projection.

Descriptors arrive as (N, W) uint64 words (a (N, 32) uint8 ORB descriptor is four words); the
Hamming distance is the popcount of their XOR. Candidates are ranked by (distance, index), so
ties go to the lower index whatever order the candidates are visited in, and every result is
the one a sort of all candidate pairs would give.

Pixel coordinates keep their dtype (float32 or float64), and the scalars they are combined with
are cast to it first, as numpy does with Python floats: every cell index and squared distance is
rounded as the equivalent numpy expression rounds it.

This module imports numba: import it only where a match runs.
"""

from __future__ import annotations

import numpy as np

from slamcli.kernels import load_numba

numba = load_numba()

_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)
_S1 = np.uint64(1)
_S2 = np.uint64(2)
_S4 = np.uint64(4)
_S56 = np.uint64(56)

_INT64_MIN = np.iinfo(np.int64).min
_INT64_MAX = np.iinfo(np.int64).max
# Ranks after every real distance (at most 64 bits per word).
_FAR = np.int64(1) << np.int64(62)

#: Status codes of :func:`by_projection`.
OK, BAD_RADIUS, BAD_KEYPOINTS, BAD_SPAN = 0, 1, 2, 3
# Most grid cells :func:`by_projection` allocates (8 bytes each).
_MAX_CELLS = 2.0**31


@numba.njit(cache=True, nogil=True, inline="always")
def _popcount(x: np.uint64) -> np.int64:
    """Set bits of a 64-bit word (SWAR count; LLVM turns it into ``popcnt`` where the CPU has
    it)."""
    x = x - ((x >> _S1) & _M1)
    x = (x & _M2) + ((x >> _S2) & _M2)
    x = (x + (x >> _S4)) & _M4
    return np.int64((x * _H01) >> _S56)


@numba.njit(cache=True, nogil=True, inline="always")
def hamming_rows(a: np.ndarray, i: int, b: np.ndarray, j: int) -> np.int64:
    """Hamming distance (bits) between row ``i`` of words ``a`` and row ``j`` of words ``b``."""
    d = np.int64(0)
    for w in range(a.shape[1]):
        d += _popcount(a[i, w] ^ b[j, w])
    return d


@numba.njit(cache=True, nogil=True, inline="always")
def _to_int64(v: float) -> np.int64:
    """A floored float as int64, as numpy's cast gives it on x86: NaN and values out of range
    become the smallest int64."""
    if v >= -9.223372036854775808e18 and v < 9.223372036854775808e18:
        return np.int64(v)
    return np.int64(_INT64_MIN)


@numba.njit(cache=True, nogil=True)
def _bucket(keys: np.ndarray, n_keys: int) -> tuple[np.ndarray, np.ndarray]:
    """Stable counting sort of ``keys`` (M,) int64 in ``[0, n_keys)``, negative keys left out:
    ``order`` (indices, by key then index) and ``starts`` (n_keys + 1,), key ``c`` holding
    ``order[starts[c]:starts[c + 1]]``."""
    starts = np.zeros(n_keys + 1, np.int64)
    for i in range(keys.shape[0]):
        if keys[i] >= 0:
            starts[keys[i] + 1] += 1
    for c in range(n_keys):
        starts[c + 1] += starts[c]
    fill = starts[:-1].copy()
    order = np.empty(starts[n_keys], np.int64)
    for i in range(keys.shape[0]):
        c = keys[i]
        if c >= 0:
            order[fill[c]] = i
            fill[c] += 1
    return order, starts


@numba.njit(cache=True, nogil=True)
def _group_keys(group_a: np.ndarray, group_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Groups as small keys: ``(key_a, key_b, n_keys)``, equal groups getting equal keys in
    ``[0, n_keys)`` and a b whose group has no a getting -1. Group ids spanning a short range
    are shifted, others ranked through a sort."""
    na = group_a.shape[0]
    nb = group_b.shape[0]
    gmin = group_a.min()
    gmax = group_a.max()
    key_b = np.full(nb, -1, np.int64)
    if np.float64(gmax) - np.float64(gmin) <= 4.0 * (na + nb) + 4096.0:
        for b in range(nb):
            if gmin <= group_b[b] <= gmax:
                key_b[b] = group_b[b] - gmin
        return group_a - gmin, key_b, gmax - gmin + 1
    order = np.argsort(group_a)
    key_a = np.empty(na, np.int64)
    uniq = np.empty(na, np.int64)
    n_keys = 0
    for s in range(na):
        g = group_a[order[s]]
        if n_keys == 0 or g != uniq[n_keys - 1]:
            uniq[n_keys] = g
            n_keys += 1
        key_a[order[s]] = n_keys - 1
    for b in range(nb):
        g = group_b[b]
        lo, hi = 0, n_keys
        while lo < hi:
            mid = (lo + hi) >> 1
            if uniq[mid] < g:
                lo = mid + 1
            else:
                hi = mid
        if lo < n_keys and uniq[lo] == g:
            key_b[b] = lo
    return key_a, key_b, n_keys


@numba.njit(cache=True, nogil=True)
def _one_per_target(best: np.ndarray, best_d: np.ndarray, n_targets: int) -> np.ndarray:
    """Sources (rows of ``best``, upwards) keeping their target: each target ``best[i] >= 0``
    goes to its closest source by ``best_d``, the lower source on a tie."""
    winner = np.full(n_targets, -1, np.int64)
    for i in range(best.shape[0]):
        t = best[i]
        if t >= 0 and (winner[t] < 0 or best_d[i] < best_d[winner[t]]):
            winner[t] = i
    keep = np.empty(best.shape[0], np.int64)
    count = 0
    for i in range(best.shape[0]):
        if best[i] >= 0 and winner[best[i]] == i:
            keep[count] = i
            count += 1
    return keep[:count]


@numba.njit(cache=True, nogil=True)
def ratio_grouped(
    words_a: np.ndarray,
    group_a: np.ndarray,
    words_b: np.ndarray,
    group_b: np.ndarray,
    ratio: float,
    max_distance: float,
) -> np.ndarray:
    """(K, 2) int64 pairs (a, b) sorted by b: each b's nearest a of its own group (ties: lower
    a), kept when ``best < ratio * second`` (second = inf for a lone candidate; compared as
    float64) and ``best <= max_distance``; then each a keeps only its closest b (ties: lower
    b).

    Args:
        words_a, words_b: (Na, W), (Nb, W) uint64 descriptor words, Na and Nb >= 1.
        group_a, group_b: (Na,), (Nb,) int64 group of each descriptor.
    """
    na = group_a.shape[0]
    nb = group_b.shape[0]
    key_a, key_b, n_keys = _group_keys(group_a, group_b)
    order, starts = _bucket(key_a, n_keys)
    best_a = np.full(nb, -1, np.int64)
    best_d = np.zeros(nb, np.int64)
    for b in range(nb):
        c = key_b[b]
        if c < 0 or starts[c] == starts[c + 1]:
            continue
        bd = _FAR
        ba = np.int64(na)
        sd = _FAR
        for s in range(starts[c], starts[c + 1]):
            a = order[s]
            d = hamming_rows(words_a, a, words_b, b)
            if d < bd or (d == bd and a < ba):
                sd = bd
                bd = d
                ba = a
            elif d < sd:
                sd = d
        second = np.inf if starts[c + 1] - starts[c] == 1 else np.float64(sd)
        if np.float64(bd) < ratio * second and np.float64(bd) <= max_distance:
            best_a[b] = ba
            best_d[b] = bd
    keep = _one_per_target(best_a, best_d, na)
    out = np.empty((keep.shape[0], 2), np.int64)
    for row in range(keep.shape[0]):
        out[row, 0] = best_a[keep[row]]
        out[row, 1] = keep[row]
    return out


@numba.njit(cache=True, nogil=True)
def _column_min(xy: np.ndarray, col: int) -> float:
    """Smallest value of a column, NaN when it holds one (as ``np.min``)."""
    m = xy[0, col]
    for i in range(1, xy.shape[0]):
        v = xy[i, col]
        if v < m or np.isnan(v):
            m = v
    return m


@numba.njit(cache=True, nogil=True, inline="always")
def _scan(
    s0: int,
    s1: int,
    p: int,
    best: tuple[np.int64, np.int64, np.int64, np.int64],
    projected: np.ndarray,
    r2: float,
    kp_sorted: np.ndarray,
    words_sorted: np.ndarray,
    oct_sorted: np.ndarray,
    order: np.ndarray,
    point_words: np.ndarray,
    predicted_octaves: np.ndarray,
    use_predicted: bool,
) -> tuple[np.int64, np.int64, np.int64, np.int64]:
    """Ranks the keypoints ``s0:s1`` (in cell order) as candidates of point ``p``: returns the
    updated (best distance, best keypoint, second distance, second keypoint), by (distance,
    keypoint index)."""
    bd, bk, sd, sk = best
    for s in range(s0, s1):
        if use_predicted and abs(oct_sorted[s] - predicted_octaves[p]) > 1:
            continue
        dx = kp_sorted[s, 0] - projected[p, 0]
        dy = kp_sorted[s, 1] - projected[p, 1]
        if not dx * dx + dy * dy <= r2:
            continue
        kk = order[s]
        d = hamming_rows(point_words, p, words_sorted, s)
        if d < bd or (d == bd and kk < bk):
            sd, sk = bd, bk
            bd, bk = d, kk
        elif d < sd or (d == sd and kk < sk):
            sd, sk = d, kk
    return bd, bk, sd, sk


@numba.njit(cache=True, nogil=True)
def _radius_range(radius: np.ndarray) -> tuple[float, float]:
    """Smallest and largest search radius (float64); (NaN, NaN) when one is negative,
    infinite or NaN."""
    r_min = np.float64(radius[0])
    r_max = np.float64(radius[0])
    for p in range(radius.shape[0]):
        r = np.float64(radius[p])
        if not (r >= 0.0 and r < np.inf):
            return np.nan, np.nan
        r_min = min(r_min, r)
        r_max = max(r_max, r)
    return r_min, r_max


@numba.njit(cache=True, nogil=True, inline="always")
def _cell_xy(keypoints: np.ndarray, i: int, scalars: np.ndarray) -> tuple[np.int64, np.int64]:
    """Grid column and row of keypoint ``i`` (``scalars``: corner x, corner y, cell side, in the
    keypoints' dtype)."""
    kx = _to_int64(np.floor((keypoints[i, 0] - scalars[0]) / scalars[2]))
    ky = _to_int64(np.floor((keypoints[i, 1] - scalars[1]) / scalars[2]))
    return kx, ky


@numba.njit(cache=True, nogil=True)
def _grid_size(keypoints: np.ndarray, scalars: np.ndarray) -> tuple[np.int64, np.int64]:
    """Columns and rows of the grid that holds every keypoint (see :func:`_cell_xy`)."""
    nx = np.int64(_INT64_MIN)
    ny = np.int64(_INT64_MIN)
    for i in range(keypoints.shape[0]):
        kx, ky = _cell_xy(keypoints, i, scalars)
        nx = max(nx, kx + 1)
        ny = max(ny, ky + 1)
    return nx, ny


@numba.njit(cache=True, nogil=True)
def _keypoint_grid(
    keypoints: np.ndarray,
    kp_words: np.ndarray,
    kp_octaves: np.ndarray,
    scalars: np.ndarray,
    nx: np.int64,
    ny: np.int64,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(order, starts, keypoints, words, octaves)``: the keypoints bucketed by grid cell
    (:func:`_bucket`; a keypoint outside the grid is in none), and their pixels, descriptor
    words and octaves in that order, so a window row reads consecutive memory."""
    n = keypoints.shape[0]
    cell_of = np.empty(n, np.int64)
    for i in range(n):
        kx, ky = _cell_xy(keypoints, i, scalars)
        inside = 0 <= kx < nx and 0 <= ky < ny
        cell_of[i] = ky * nx + kx if inside else -1
    order, starts = _bucket(cell_of, nx * ny)
    m = order.shape[0]
    kp_sorted = np.empty((m, 2), keypoints.dtype)
    words_sorted = np.empty((m, kp_words.shape[1]), np.uint64)
    oct_sorted = np.empty(m, np.int64)
    for s in range(m):
        i = order[s]
        kp_sorted[s, 0] = keypoints[i, 0]
        kp_sorted[s, 1] = keypoints[i, 1]
        for w in range(kp_words.shape[1]):
            words_sorted[s, w] = kp_words[i, w]
        oct_sorted[s] = kp_octaves[i]
    return order, starts, kp_sorted, words_sorted, oct_sorted


@numba.njit(cache=True, nogil=True)
def by_projection(
    projected: np.ndarray,
    keypoints: np.ndarray,
    radius: np.ndarray,
    point_words: np.ndarray,
    kp_words: np.ndarray,
    kp_octaves: np.ndarray,
    predicted_octaves: np.ndarray,
    use_predicted: bool,
    use_levels: bool,
    max_distance: float,
    ratio: float,
    int_ratio: bool,
    ratio_int: int,
) -> tuple[np.ndarray, int]:
    """``(pairs, status)``: (K, 2) int64 pairs (point, keypoint) sorted by point, as
    :func:`slamcli.vision.matching.match_by_projection` defines them, and :data:`OK`; or no
    pairs and :data:`BAD_RADIUS` (a radius negative, infinite or NaN), :data:`BAD_KEYPOINTS`
    (a keypoint coordinate NaN or -inf) or :data:`BAD_SPAN` (keypoints spread over more than
    2^31 cells).

    Keypoints are bucketed in square cells from their smallest (u, v), of side
    ``max(min radius, max radius / 4, 1)`` pixels; a point visits the ``(2k + 1)^2`` cells
    around its own, ``k = ceil(radius / cell)`` (at most 4). A keypoint there is a candidate
    when within the radius (squared distance in the coordinates' dtype, squared radius in the
    radius' dtype) and, with ``use_predicted``, within one level of the point's predicted
    octave. A keypoint or point with a pixel that is infinite (or, for a point, NaN) has no
    cell and takes part in no pair.

    The best candidate by (distance, keypoint) is kept when within ``max_distance`` and,
    unless ``use_levels`` and the second best is at another level, closer than ``ratio`` times
    the second best (``ratio_int`` times it in wrapping int64 when ``int_ratio``; the largest
    int64 stands for a missing second). Each keypoint then keeps its closest point (ties:
    lower point).

    Args:
        projected: (P, 2) pixels of the points, P >= 1; keypoints: (N, 2) pixels, N >= 1.
        radius: (P,) search radius of each point (pixels).
        point_words, kp_words: (P, W), (N, W) uint64 descriptor words.
        kp_octaves, predicted_octaves: (N,) and (P,) pyramid levels (read only with
            ``use_levels`` / ``use_predicted``).
    """
    n = keypoints.shape[0]
    p_count = projected.shape[0]
    none = np.zeros((0, 2), np.int64)
    r_min, r_max = _radius_range(radius)
    if np.isnan(r_min):
        return none, BAD_RADIUS
    x0 = np.float64(_column_min(keypoints, 0))
    y0 = np.float64(_column_min(keypoints, 1))
    if np.isnan(x0) or np.isnan(y0) or x0 == -np.inf or y0 == -np.inf:
        return none, BAD_KEYPOINTS
    if x0 == np.inf or y0 == np.inf:
        # Every keypoint has an infinite coordinate: none is within a finite radius.
        return none, OK
    cell = max(r_min, r_max / 4.0, 1.0)
    # The corner and the cell side in each array's dtype (what numpy casts Python floats to).
    kp_scalars = np.empty(3, keypoints.dtype)
    kp_scalars[0], kp_scalars[1], kp_scalars[2] = x0, y0, cell
    pt_scalars = np.empty(3, projected.dtype)
    pt_scalars[0], pt_scalars[1], pt_scalars[2] = x0, y0, cell

    nx, ny = _grid_size(keypoints, kp_scalars)
    if np.float64(nx) * np.float64(ny) > _MAX_CELLS:
        return none, BAD_SPAN
    order, starts, kp_sorted, words_sorted, oct_sorted = _keypoint_grid(
        keypoints, kp_words, kp_octaves, kp_scalars, nx, ny
    )

    best_k = np.full(p_count, -1, np.int64)
    best_d = np.zeros(p_count, np.int64)
    for p in range(p_count):
        k = _to_int64(np.ceil(np.float64(radius[p]) / cell))
        px = _to_int64(np.floor((projected[p, 0] - pt_scalars[0]) / pt_scalars[2]))
        py = _to_int64(np.floor((projected[p, 1] - pt_scalars[1]) / pt_scalars[2]))
        r2 = radius[p] * radius[p]
        best = (_FAR, np.int64(n), _FAR, np.int64(n))
        # A pixel too far out for int64 (or NaN) got the smallest int64: no cell near it.
        if px == _INT64_MIN or py == _INT64_MIN:
            continue
        cx0, cx1 = max(px - k, 0), min(px + k + 1, nx)
        cy0, cy1 = max(py - k, 0), min(py + k + 1, ny)
        if cx0 >= cx1:
            continue
        for cy in range(cy0, cy1):
            # The cells of one window row are consecutive, and so are their keypoints.
            best = _scan(
                starts[cy * nx + cx0], starts[cy * nx + cx1], p, best, projected, r2,
                kp_sorted, words_sorted, oct_sorted, order, point_words, predicted_octaves,
                use_predicted,
            )  # fmt: skip
        bd, bk, sd, sk = best
        if bk == n or not np.float64(bd) <= max_distance:
            continue
        has_second = sk < n
        second = sd if has_second else np.int64(_INT64_MAX)
        if int_ratio:
            close = bd < ratio_int * second
        else:
            close = np.float64(bd) < ratio * np.float64(second)
        if close or (use_levels and has_second and kp_octaves[bk] != kp_octaves[sk]):
            best_k[p] = bk
            best_d[p] = bd
    keep = _one_per_target(best_k, best_d, n)
    out = np.empty((keep.shape[0], 2), np.int64)
    for row in range(keep.shape[0]):
        out[row, 0] = keep[row]
        out[row, 1] = best_k[keep[row]]
    return out, OK


@numba.njit(cache=True, nogil=True)
def descend(
    words: np.ndarray,
    centroids: np.ndarray,
    children: np.ndarray,
    node_word: np.ndarray,
    stop_level: int,
) -> np.ndarray:
    """Vocabulary tree descent: the node each descriptor reaches at depth ``stop_level``
    (or the leaf above it), taking at every level the child whose centroid is nearest in
    Hamming distance (ties: the first child). ``words`` (N, W) and ``centroids``
    (n_nodes, W) uint64 words, ``children`` (n_nodes, k) int (-1 for none), ``node_word``
    (n_nodes,) int (>= 0 at a leaf); returns (N,) int32 node ids."""
    n = words.shape[0]
    out = np.zeros(n, np.int32)
    for i in range(n):
        node = 0
        for _ in range(stop_level):
            if node_word[node] >= 0:
                break
            best = node
            best_d = _FAR
            for c in range(children.shape[1]):
                child = children[node, c]
                if child >= 0:
                    d = hamming_rows(words, i, centroids, child)
                    if d < best_d:
                        best_d = d
                        best = child
            node = best
        out[i] = node
    return out
