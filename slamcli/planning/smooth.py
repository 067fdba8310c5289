"""From a grid path to a short, smooth polyline that never touches a blocked cell.

Every segment is checked against the blocked cells with an exact supercover traversal: a
segment *touches* a cell when it meets the cell's closed square (edges and corners count), so
a segment that grazes a blocked cell's corner is rejected. Leaving the map counts as touching
a blocked cell. Coordinates are continuous grid coordinates ``(u, v)`` in cells (see
:func:`slamcli.planning.costmap.world_to_uv`), which are metres divided by the resolution.

Steps: :func:`densify` makes the grid path itself valid under that rule (an 8-connected
diagonal step that passes the corner of a blocked cell gets the free side cell inserted),
:func:`shortcut` keeps, from each kept point, the farthest later point in line of sight, and
:func:`round_corners` cuts each corner (Chaikin), keeping a corner whose cut would touch a
blocked cell.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import ArrayLike, NDArray

_EPS = 1e-9
"""Slack (cells) added around each segment, so rounding never lets a grazing contact through."""

_CORNER_OFFSET = 1e-6
"""How far (cells, along each axis) :func:`densify` moves a corner point into a free cell."""

_SAMPLE_STEPS = (16.0, 2.0)
"""Spacings (cells) of the points :meth:`SegmentChecker.maybe_free` looks up along a segment:
a coarse pass rules out most blocked segments cheaply, a fine one most of the rest."""

_SHORTCUT_STEPS = (32.0,)
"""The first, coarse pass of :meth:`SegmentChecker.maybe_free` over all of :func:`shortcut`'s
candidates."""

_BATCH = 1 << 20
"""Most sample points or touched cells held in memory at once."""


class SegmentChecker:
    """Answers "does this segment touch a blocked cell?" for many segments at once.

    ``blocked`` is (H, W) bool, row = v, column = u. Nothing is precomputed: a check costs in
    proportion to the cells the segments touch, and :meth:`maybe_free` rejects most blocked
    segments for a fraction of that.
    """

    def __init__(self, blocked: NDArray[np.bool_]) -> None:
        self.blocked = np.asarray(blocked, dtype=bool)
        self.shape = self.blocked.shape

    def free(self, p: ArrayLike, q: ArrayLike) -> NDArray[np.bool_]:
        """(M,) bool: segment p[i] -> q[i] ((M, 2) arrays of (u, v)) touches no blocked cell."""
        p = np.atleast_2d(np.asarray(p, dtype=np.float64))
        q = np.atleast_2d(np.asarray(q, dtype=np.float64))
        ok = self.maybe_free(p, q)
        todo = np.flatnonzero(ok)
        for part in _batches(_strip_counts(p[todo], q[todo]), _BATCH):
            idx = todo[part]
            ok[idx] = self._exact_free(p[idx], q[idx])
        return ok

    def maybe_free(
        self, p: ArrayLike, q: ArrayLike, steps: tuple[float, ...] = _SAMPLE_STEPS
    ) -> NDArray[np.bool_]:
        """(M,) bool, False for segments certainly not free: a point on them lies in a blocked
        cell or off the map (points every ``steps[k]`` cells or less in pass k, both ends
        included). True means "check exactly" (:meth:`free`)."""
        p = np.atleast_2d(np.asarray(p, dtype=np.float64))
        q = np.atleast_2d(np.asarray(q, dtype=np.float64))
        ok = np.ones(len(p), dtype=bool)
        for step in steps:
            todo = np.flatnonzero(ok)
            ok[todo] = self._samples_free(p[todo], q[todo], step)
        return ok

    def _samples_free(
        self, p: NDArray[np.float64], q: NDArray[np.float64], step: float
    ) -> NDArray[np.bool_]:
        d = q - p
        n = np.ceil(np.sqrt((d**2).sum(axis=1)) / step).astype(np.int64) + 1
        ok = np.ones(len(p), dtype=bool)
        h, w = self.shape
        for part in _batches(n, _BATCH):
            counts = n[part]
            seg = np.repeat(part, counts)
            k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
            t = k / np.maximum(counts - 1, 1).repeat(counts)
            col = np.floor(p[seg, 0] + t * d[seg, 0]).astype(np.int64)
            row = np.floor(p[seg, 1] + t * d[seg, 1]).astype(np.int64)
            inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
            hit = ~inside
            hit[inside] = self.blocked[row[inside], col[inside]]
            ok[seg[hit]] = False
        return ok

    def _exact_free(self, p: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.bool_]:
        seg, col, vlo, vhi = _column_runs(p, q)
        h, w = self.shape
        r0 = np.ceil(vlo - _EPS).astype(np.int64) - 1
        r1 = np.floor(vhi + _EPS).astype(np.int64)
        # A strip that leaves the map touches a blocked cell; the others are read cell by cell.
        outside = (col < 0) | (col >= w) | (r0 < 0) | (r1 >= h)
        hit = np.zeros(len(p), dtype=bool)
        hit[seg[outside]] = True
        keep = ~outside
        seg, col, r0, r1 = seg[keep], col[keep], r0[keep], r1[keep]
        n = r1 - r0 + 1
        rows = np.repeat(r0, n) + (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n))
        blocked = self.blocked[rows, np.repeat(col, n)]
        hit[np.repeat(seg, n)[blocked]] = True
        return ~hit


def _strip_counts(p: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.int64]:
    """(M,) an upper bound of the cells each segment touches (for batching)."""
    d = np.abs(q - p)
    return (np.ceil(d[:, 0]) + np.ceil(d[:, 1])).astype(np.int64) * 2 + 4


def _batches(sizes: NDArray[np.int64], limit: int) -> list[NDArray[np.int64]]:
    """Consecutive index groups of ``sizes`` whose sums stay near ``limit`` (at least one
    index per group)."""
    if len(sizes) == 0:
        return []
    total = np.cumsum(sizes)
    if total[-1] <= limit:
        return [np.arange(len(sizes))]
    cuts = np.searchsorted(total, np.arange(limit, total[-1], limit), side="right")
    bounds = np.unique(np.concatenate(([0], cuts, [len(sizes)])))
    return [np.arange(a, b) for a, b in itertools.pairwise(bounds) if b > a]


def touched_cells(p: ArrayLike, q: ArrayLike) -> NDArray[np.int64]:
    """(K, 2) int64 (row, col) of every cell whose closed square the segment p -> q meets."""
    _, col, vlo, vhi = _column_runs(np.atleast_2d(p), np.atleast_2d(q))
    r0 = np.ceil(vlo - _EPS).astype(np.int64) - 1
    r1 = np.floor(vhi + _EPS).astype(np.int64)
    out = [
        np.stack((np.arange(a, b + 1), np.full(b - a + 1, c)), 1)
        for a, b, c in zip(r0, r1, col, strict=True)
    ]
    return np.concatenate(out).astype(np.int64) if out else np.zeros((0, 2), np.int64)


def _column_runs(
    p: NDArray[np.float64], q: NDArray[np.float64]
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Split segments into column strips: (segment index, column, v range) per strip.

    The part of a segment inside the strip ``col <= u <= col + 1`` is a segment itself, so its
    v values form one interval; the segment meets cell (row, col) exactly when that interval
    meets ``[row, row + 1]``.
    """
    p = np.asarray(p, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    ulo = np.minimum(p[:, 0], q[:, 0]) - _EPS
    uhi = np.maximum(p[:, 0], q[:, 0]) + _EPS
    c_first = np.ceil(ulo).astype(np.int64) - 1
    c_last = np.floor(uhi).astype(np.int64)
    n = c_last - c_first + 1
    seg = np.repeat(np.arange(len(p)), n)
    col = np.repeat(c_first, n) + (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n))
    pu, pv, qu, qv = p[seg, 0], p[seg, 1], q[seg, 0], q[seg, 1]
    du = qu - pu
    steep = np.abs(du) < 1e-12
    # v where the segment crosses the strip's borders, clamped to the segment's own ends.
    a = np.clip(col.astype(np.float64), np.minimum(pu, qu), np.maximum(pu, qu))
    b = np.clip(col + 1.0, np.minimum(pu, qu), np.maximum(pu, qu))
    with np.errstate(divide="ignore", invalid="ignore"):
        va = np.where(steep, pv, pv + (a - pu) / np.where(steep, 1.0, du) * (qv - pv))
        vb = np.where(steep, qv, pv + (b - pu) / np.where(steep, 1.0, du) * (qv - pv))
    return seg, col, np.minimum(va, vb), np.maximum(va, vb)


def densify(cells: NDArray[np.int64], checker: SegmentChecker) -> NDArray[np.float64]:
    """Grid path (K, 2) row/col -> (K', 2) (u, v): the cell centres, every step free.

    A diagonal step is free unless it passes the corner of a blocked cell (the search allows
    that when the other side cell is free). Such a step gets a point inserted just off the
    corner, :data:`_CORNER_OFFSET` cells into the free side cell: both halves are then free
    and the detour is about 3e-12 cells long, so the path keeps the search's length.
    """
    uv = np.asarray(cells, dtype=np.float64)[:, ::-1] + 0.5
    if len(uv) < 2:
        return uv
    ok = checker.free(uv[:-1], uv[1:])
    if ok.all():
        return uv
    out = [uv[0]]
    for i in range(len(uv) - 1):
        a, b = uv[i], uv[i + 1]
        if not ok[i]:
            corner = (a + b) / 2
            for side in ((b[0], a[1]), (a[0], b[1])):
                p = corner + 2 * _CORNER_OFFSET * (np.asarray(side) - corner)
                if checker.free(np.stack((a, p)), np.stack((p, b))).all():
                    out.append(p)
                    break
        out.append(b)
    return np.asarray(out)


def segment_costs(
    p: NDArray[np.float64], q: NDArray[np.float64], extra_cost: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(M,) cost of segments p[i] -> q[i] (cells): length times (1 + mean extra cost).

    The mean is over the cells under points spaced at most half a cell apart along the
    segment, so a segment and the polyline it replaces are priced the same way.
    """
    length = np.linalg.norm(q - p, axis=1)
    n = np.maximum(np.ceil(length / 0.5), 1).astype(np.int64)
    seg = np.repeat(np.arange(len(p)), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    f = ((k + 0.5) / n[seg])[:, None]
    pts = p[seg] + f * (q[seg] - p[seg])
    h, w = extra_cost.shape
    rows = np.clip(np.floor(pts[:, 1]).astype(np.int64), 0, h - 1)
    cols = np.clip(np.floor(pts[:, 0]).astype(np.int64), 0, w - 1)
    mean = np.bincount(seg, weights=extra_cost[rows, cols], minlength=len(p)) / n
    return length * (1.0 + mean)


def shortcut(
    points: NDArray[np.float64],
    checker: SegmentChecker,
    extra_cost: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Greedy line of sight: from each kept point, jump to the farthest later visible point.

    ``points`` (K, 2) is a polyline whose consecutive segments are free; the result (K', 2)
    keeps its ends, every segment is free and it is never longer. With ``extra_cost`` (H, W)
    a jump must also cost no more than the stretch it replaces (:func:`segment_costs`), so
    shortcuts do not undo the clearance the search paid for.

    The later points that a coarse :meth:`SegmentChecker.maybe_free` pass does not rule out
    are checked exactly from the farthest back, a few at a time (more each round), so the
    search stops at the answer.
    """
    if len(points) <= 2:
        return points.copy()
    cum = None
    if extra_cost is not None:
        cum = np.concatenate(([0.0], np.cumsum(segment_costs(points[:-1], points[1:], extra_cost))))
    kept = [0]
    i = 0
    last = len(points) - 1
    while i < last:
        later = np.arange(i + 1, last + 1)
        starts = np.broadcast_to(points[i], (len(later), 2))
        maybe = later[checker.maybe_free(starts, points[later], steps=_SHORTCUT_STEPS)]
        # The next point always qualifies (its segment is free and priced like itself).
        j = i + 1
        hi, size = len(maybe), 8
        while hi > 0:
            cand = maybe[max(hi - size, 0) : hi]
            start = np.broadcast_to(points[i], (len(cand), 2))
            ok = checker.free(start, points[cand])
            if cum is not None and extra_cost is not None:
                good = np.flatnonzero(ok)
                cost = segment_costs(start[good], points[cand[good]], extra_cost)
                ok[good] = cost <= cum[cand[good]] - cum[i] + 1e-9 * (1.0 + cum[-1])
            if ok.any():
                j = int(cand[np.flatnonzero(ok)[-1]])
                break
            hi, size = hi - size, size * 2
        kept.append(j)
        i = j
    return points[kept]


def round_corners(
    points: NDArray[np.float64],
    checker: SegmentChecker,
    iterations: int = 3,
    fraction: float = 0.25,
    max_cut: float = 10.0,
) -> NDArray[np.float64]:
    """Chaikin corner cutting: corner P becomes P + t(prev - P), P + t(next - P).

    ``t`` = ``fraction`` of each side, at most ``max_cut`` (cells). Only the new segment
    between the two cut points needs a check (the other pieces lie on free segments); a cut
    that touches a blocked cell is retried at a half and a quarter of the size, and the corner
    is kept as it is when all fail. Cutting a corner never makes the path longer.
    """
    pts = np.asarray(points, dtype=np.float64)
    for _ in range(iterations):
        if len(pts) < 3:
            break
        prev, mid, nxt = pts[:-2], pts[1:-1], pts[2:]
        d_prev, d_next = prev - mid, nxt - mid
        len_prev = np.linalg.norm(d_prev, axis=1)
        len_next = np.linalg.norm(d_next, axis=1)
        cross = d_prev[:, 0] * d_next[:, 1] - d_prev[:, 1] * d_next[:, 0]
        todo = np.abs(cross) > 1e-12 * len_prev * len_next
        a = mid.copy()
        b = mid.copy()
        cut = np.zeros(len(mid), dtype=bool)
        for scale in (1.0, 0.5, 0.25):
            idx = np.flatnonzero(todo & ~cut)
            if len(idx) == 0:
                break
            t_prev = np.minimum(scale * fraction, max_cut / len_prev[idx])[:, None]
            t_next = np.minimum(scale * fraction, max_cut / len_next[idx])[:, None]
            ca = mid[idx] + t_prev * d_prev[idx]
            cb = mid[idx] + t_next * d_next[idx]
            ok = checker.free(ca, cb)
            a[idx[ok]], b[idx[ok]] = ca[ok], cb[ok]
            cut[idx[ok]] = True
        if not cut.any():
            break
        out = [pts[:1]]
        for k in range(len(mid)):
            out.append(np.stack((a[k], b[k])) if cut[k] else mid[k : k + 1])
        out.append(pts[-1:])
        pts = np.concatenate(out)
    return pts


def polyline_length(points: NDArray[np.float64]) -> float:
    """Total length of a (K, 2) polyline, in the points' units."""
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
