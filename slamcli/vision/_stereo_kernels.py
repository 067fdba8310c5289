"""Compiled kernels of :mod:`slamcli.vision.stereo`: pairing keypoints along rows by descriptor,
and the SAD refinement of a pair at its pyramid level.

Descriptor pairing (:func:`descriptor_pairs`): the right keypoints are sorted by octave, then
row, and the rows are compared in numpy's sort order (NaN after every number), so a left
keypoint's row band in the run of an octave holds exactly the keypoints that two
``np.searchsorted`` calls would give. The band is found through a table of where each whole
row starts in each run, the keypoints of the band's first and last whole rows being tested one
by one (binary searches where the table does not reach: rows far apart, or not finite).
Hamming distances count the bits of the XOR of 64-bit words. Each left keypoint takes its
closest candidate (ties: lower right index); a right keypoint claimed by several goes to the
closest of them (ties: lower left index).

Refinement (:func:`refine_level`): integer sums of absolute differences of the centre-subtracted
patches (the same whole numbers as float32 sums, which are exact below 2**24), then a parabola
through the smallest one and its neighbours in float64.

This module imports numba: import it only where stereo matching runs.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from slamcli.kernels import load_numba
from slamcli.vision._matching_kernels import hamming_rows

numba = load_numba()

I64 = NDArray[np.int64]
F64 = NDArray[np.float64]

#: Rounded positions beyond this magnitude are outside any image (and their int64 arithmetic
#: would overflow).
_FAR = 2.0**62
#: Rows within this magnitude have exact whole-row neighbours in float64.
_EXACT = 2.0**52


@numba.njit(cache=True, nogil=True)
def _lt(a: float, b: float) -> bool:
    """``a < b`` in numpy's sort order, where NaN comes after every number."""
    return (a < b) | ((b != b) & (a == a))


@numba.njit(cache=True, nogil=True)
def _first_not_below(rows: np.ndarray, lo: int, hi: int, q: float) -> int:
    """First index in [lo, hi) of sorted ``rows`` whose row is not below ``q`` (hi if none):
    ``np.searchsorted(side="left")``. The halving step is a select, not a branch."""
    if hi <= lo:
        return lo
    base = lo
    n = hi - lo
    while n > 1:
        half = n >> 1
        base = base + half if _lt(rows[base + half - 1], q) else base
        n -= half
    return base + 1 if _lt(rows[base], q) else base


@numba.njit(cache=True, nogil=True)
def _first_above(rows: np.ndarray, lo: int, hi: int, q: float) -> int:
    """First index in [lo, hi) of sorted ``rows`` whose row is above ``q`` (hi if none):
    ``np.searchsorted(side="right")``."""
    if hi <= lo:
        return lo
    base = lo
    n = hi - lo
    while n > 1:
        half = n >> 1
        base = base if _lt(q, rows[base + half - 1]) else base + half
        n -= half
    return base if _lt(q, rows[base]) else base + 1


@numba.njit(cache=True, nogil=True)
def _by_octave_and_row(v_r: np.ndarray, oct_r: np.ndarray, oct_min: int, n_oct: int) -> tuple:
    """Order of the right keypoints by octave, then row (NaN last), and the start of each
    octave's run in it (``n_oct + 1`` offsets)."""
    by_row = np.argsort(v_r)
    run_lo = np.zeros(n_oct + 1, np.int64)
    for j in range(v_r.size):
        run_lo[oct_r[j] - oct_min + 1] += 1
    for k in range(n_oct):
        run_lo[k + 1] += run_lo[k]
    fill = run_lo[:-1].copy()
    order = np.empty(v_r.size, np.int64)
    for j in by_row:
        k = oct_r[j] - oct_min
        order[fill[k]] = j
        fill[k] += 1
    return order, run_lo


@numba.njit(cache=True, nogil=True)
def _row_table(rows: np.ndarray, run_lo: np.ndarray) -> tuple:
    """``(first, y0)``: ``first[k, b]`` is the first index of run ``k`` of ``rows`` whose row is
    not below ``y0 + b``, for every whole row ``y0 + b`` from the lowest finite row (rounded
    down) to one past the highest. Empty (0 columns) when the rows span too many whole rows
    for a table, or are too large for whole rows to be exact in float64."""
    n_oct = run_lo.size - 1
    lowest = np.inf
    highest = -np.inf
    for r in rows:
        if np.isfinite(r):
            lowest = min(lowest, r)
            highest = max(highest, r)
    y0 = 0.0
    n_y = 0
    if lowest <= highest and lowest > -_EXACT and highest < _EXACT:
        y0 = np.floor(lowest)
        span = np.floor(highest) - y0 + 2.0
        if span * n_oct <= 4.0 * rows.size + 4096.0:
            n_y = int(span)
    first = np.empty((n_oct, n_y), np.int64)
    for k in range(n_oct):
        t = run_lo[k]
        for b in range(n_y):
            while t < run_lo[k + 1] and _lt(rows[t], y0 + b):
                t += 1
            first[k, b] = t
    return first, y0


@numba.njit(cache=True, nogil=True)
def _descriptor_pairs(
    u_l: np.ndarray,
    v_l: np.ndarray,
    oct_l: np.ndarray,
    words_l: np.ndarray,
    u_r: np.ndarray,
    v_r: np.ndarray,
    oct_r: np.ndarray,
    words_r: np.ndarray,
    oct_min: int,
    bands: np.ndarray,
    max_disp: float,
    max_hamming: float,
) -> tuple:
    """The pairs of :func:`descriptor_pairs` (same arguments)."""
    n_l = u_l.size
    n_r = u_r.size
    n_oct = bands.size
    n_words = words_r.shape[1]
    order, run_lo = _by_octave_and_row(v_r, oct_r, oct_min, n_oct)
    rows = np.empty(n_r, np.float64)
    cols = np.empty(n_r, np.float64)
    words = np.empty((n_r, n_words), np.uint64)
    for t in range(n_r):
        rows[t] = v_r[order[t]]
        cols[t] = u_r[order[t]]
        words[t] = words_r[order[t]]
    first, y0 = _row_table(rows, run_lo)
    y_end = y0 + (first.shape[1] - 1)

    # Each left keypoint's closest candidate, as the smallest key distance * n_r + index.
    none = np.int64(1) << 62
    best = np.full(n_l, none, np.int64)
    for i in range(n_l):
        key_min = none
        for level in range(oct_l[i] - 1, oct_l[i] + 2):
            k = level - oct_min
            if k < 0 or k >= n_oct:
                continue
            bottom = v_l[i] - bands[k]
            top = v_l[i] + bands[k]
            # The whole rows around the band from the table (a few extra keypoints, tested
            # below), or the band itself by binary search.
            exact = not (bottom >= y0 and top < y_end)
            if exact:
                lo = _first_not_below(rows, run_lo[k], run_lo[k + 1], bottom)
                hi = _first_above(rows, run_lo[k], run_lo[k + 1], top)
            else:
                lo = first[k, int(np.floor(bottom) - y0)]
                hi = first[k, int(np.floor(top) - y0) + 1]
            for t in range(lo, hi):
                disp = u_l[i] - cols[t]
                d = hamming_rows(words_l, i, words, t)
                key = d * n_r + order[t]
                good = (
                    (disp >= 0.0)
                    & (disp <= max_disp)
                    & (exact | ((rows[t] >= bottom) & (rows[t] <= top)))
                )
                # A select rather than a branch: the test fails unpredictably often.
                key_min = min(key_min, key if good else none)
        if key_min < none and key_min // n_r < max_hamming:
            best[i] = key_min

    # Each right keypoint to the closest left one claiming it; left ones in increasing order,
    # so a tie keeps the lower index.
    owner = np.full(n_r, -1, np.int64)
    for i in range(n_l):
        if best[i] < none:
            j = best[i] % n_r
            if owner[j] < 0 or best[i] < best[owner[j]]:
                owner[j] = i
    count = 0
    for j in range(n_r):
        count += owner[j] >= 0
    il = np.empty(count, np.int64)
    ir = np.empty(count, np.int64)
    count = 0
    for i in range(n_l):
        if best[i] < none and owner[best[i] % n_r] == i:
            il[count] = i
            ir[count] = best[i] % n_r
            count += 1
    return il, ir


def descriptor_pairs(
    u_l: F64,
    v_l: F64,
    oct_l: I64,
    words_l: NDArray[np.uint64],
    u_r: F64,
    v_r: F64,
    oct_r: I64,
    words_r: NDArray[np.uint64],
    oct_min: int,
    bands: F64,
    max_disp: float,
    max_hamming: float,
) -> tuple[I64, I64]:
    """(left, right) index pairs of the descriptor matches, in increasing left index.

    ``u_*``, ``v_*``: (N,) float64 level-0 pixel columns and rows; ``oct_*``: (N,) int64
    octaves; ``words_*``: (N, K) uint64 descriptors (zero-padded to whole words). ``bands[k]``
    is the half-height (pixels) of the row band of right octave ``oct_min + k``, for every
    octave from the lowest right one to the highest. A pair needs octaves within one level,
    ``v_l - band <= v_r <= v_l + band`` (in numpy's sort order, NaN after every number), a
    disparity ``u_l - u_r`` in ``[0, max_disp]`` and a Hamming distance below ``max_hamming``.
    """
    il, ir = _descriptor_pairs(
        u_l, v_l, oct_l, words_l, u_r, v_r, oct_r, words_r, oct_min, bands, max_disp, max_hamming
    )
    return il, ir


@numba.njit(cache=True, nogil=True)
def _refine_level(
    img_l: np.ndarray,
    img_r: np.ndarray,
    level: int,
    octave: np.ndarray,
    factor: np.ndarray,
    u_l: np.ndarray,
    v_l: np.ndarray,
    u_r0: np.ndarray,
    w: int,
    reach: int,
    max_offset: float,
    u_r: np.ndarray,
    sad: np.ndarray,
    ok: np.ndarray,
) -> None:
    """The refinement of :func:`refine_level` (same arguments)."""
    height, width = img_l.shape
    side = 2 * w + 1
    span = 2 * reach + 1
    # Column-major copies (element [x * side + y]), so that the window of each shift is one
    # contiguous run of the strip.
    patch = np.empty(side * side, np.int64)
    strip = np.empty((side + 2 * reach) * side, np.int64)
    cost = np.zeros(span, np.int64)
    for k in range(octave.size):
        if octave[k] != level:
            continue
        f = factor[k]
        xl = np.rint(u_l[k] / f)
        yl = np.rint(v_l[k] / f)
        xr = np.rint(u_r0[k] / f)
        inside = abs(xl) < _FAR and abs(yl) < _FAR and abs(xr) < _FAR
        ul = int(xl) if inside else 0
        vl = int(yl) if inside else 0
        ur = int(xr) if inside else 0
        inside = (
            inside
            and vl - w >= 0
            and vl + w < height
            and ul - w >= 0
            and ul + w < width
            and ur - w - reach >= 0
            and ur + w + reach < width
        )
        if inside:
            centre = np.int64(img_l[vl, ul])
            for x in range(side):
                column = img_l[vl - w :, ul - w + x]
                out = patch[x * side :]
                for y in range(side):
                    out[y] = np.int64(column[y]) - centre
            for x in range(side + 2 * reach):
                column = img_r[vl - w :, ur - w - reach + x]
                out = strip[x * side :]
                for y in range(side):
                    out[y] = np.int64(column[y])
            for i in range(span):
                window = strip[i * side :]
                c = window[w * side + w]
                total = 0
                for j in range(side * side):
                    total += abs(patch[j] + c - window[j])
                cost[i] = total
        else:
            ur = 0
            cost[:] = 0
        best = 0
        for i in range(1, span):
            if cost[i] < cost[best]:
                best = i
        b = min(max(best, 1), span - 2)
        d1 = float(cost[b - 1])
        d2 = float(cost[b])
        d3 = float(cost[b + 1])
        denom = 2.0 * (d1 + d3 - 2.0 * d2)
        flat = denom <= 0.0
        delta = 0.0 if flat else (d1 - d3) / denom
        ok[k] = inside and best > 0 and best < span - 1 and not flat and abs(delta) <= max_offset
        u_r[k] = f * ((ur + (best - reach)) + delta)
        sad[k] = float(cost[best])


def refine_level(
    img_l: NDArray[np.uint8],
    img_r: NDArray[np.uint8],
    level: int,
    octave: I64,
    factor: F64,
    u_l: F64,
    v_l: F64,
    u_r0: F64,
    patch_radius: int,
    search_radius: int,
    max_offset: float,
    u_r: F64,
    sad: F64,
    ok: NDArray[np.bool_],
) -> None:
    """Refine, in place, the pairs ``k`` with ``octave[k] == level`` on that level's images.

    ``img_l``, ``img_r``: (H, W) uint8 images of the level; ``factor[k]``: the level's scale
    (level-0 pixels per level pixel); ``u_l``, ``v_l``: (M,) float64 level-0 position of the left
    keypoint; ``u_r0``: (M,) float64 level-0 column of the right one. Positions are rounded at the
    level; a pair whose patch (``patch_radius`` half-side) or search strip (``search_radius``
    either side) leaves the image gets zero costs and ``ok`` False. Writes ``u_r[k]`` (level-0
    sub-pixel column), ``sad[k]`` (best sum of absolute differences) and ``ok[k]`` (minimum
    inside the window, parabola curved and offset within ``max_offset`` level pixels).
    """
    _refine_level(
        img_l,
        img_r,
        level,
        octave,
        factor,
        u_l,
        v_l,
        u_r0,
        patch_radius,
        search_radius,
        max_offset,
        u_r,
        sad,
        ok,
    )
