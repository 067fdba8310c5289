"""Probability grids: scans inserted by ray casting, the likelihood field matching reads.

A grid is a window of square cells over the plane holding log-odds of occupancy. Inserting a
scan from a sensor position marks every cell a beam crosses as a miss and the cell of its end
point as a hit (Cartographer's and GMapping's inverse sensor model), each at most once per scan;
cells no beam reached stay unknown. The window grows as scans reach past it.

Cell ``(row, col)`` covers ``x`` in ``origin[0] + col * resolution`` plus one cell, ``y``
likewise by row: rows grow with ``y``, unlike an image's.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

_SHIFT = 4
"""Sub-cell bits of the line end points handed to OpenCV (1/16 of a cell)."""
_GROW = 64
"""Cells added on a side when the window grows, so that it grows seldom."""


def log_odds(p: float) -> float:
    return math.log(p / (1.0 - p))


class ProbabilityGrid:
    """Log-odds occupancy over a growing window of cells.

    Args:
        resolution_m: cell side.
        hit, miss: probability an end point's cell, and a crossed cell, is occupied.
        clamp: largest log-odds magnitude a cell takes (keeps a map able to change).
    """

    def __init__(
        self, resolution_m: float, hit: float = 0.7, miss: float = 0.4, clamp: float = 3.5
    ) -> None:
        self.resolution = float(resolution_m)
        self.hit = log_odds(hit)
        self.miss = log_odds(miss)
        self.clamp = float(clamp)
        self.origin = np.zeros(2)
        self.log_odds = np.zeros((0, 0), dtype=np.float32)
        self.seen = np.zeros((0, 0), dtype=bool)
        self.insertions = 0

    @property
    def shape(self) -> tuple[int, int]:
        h, w = self.log_odds.shape
        return h, w

    def cell_of(self, xy: F64) -> NDArray[np.int64]:
        """(N, 2) (row, col) of the cells holding ``xy`` (may lie outside the window)."""
        ij = np.floor((xy - self.origin) / self.resolution).astype(np.int64)
        return ij[:, ::-1]

    def _ensure(self, lo: F64, hi: F64) -> None:
        """Grow the window to hold the box from ``lo`` to ``hi`` (world x, y)."""
        r = self.resolution
        if self.log_odds.size == 0:
            self.origin = np.floor(lo / r) * r - _GROW * r
            cols = math.ceil((hi[0] - self.origin[0]) / r) + _GROW
            rows = math.ceil((hi[1] - self.origin[1]) / r) + _GROW
            self.log_odds = np.zeros((rows, cols), dtype=np.float32)
            self.seen = np.zeros((rows, cols), dtype=bool)
            return
        rows, cols = self.shape
        c0, r0 = np.floor((lo - self.origin) / r).astype(int)
        c1, r1 = np.ceil((hi - self.origin) / r).astype(int)
        left = _GROW if c0 < 0 else 0
        left += -c0 if c0 < 0 else 0
        bottom = (_GROW - r0) if r0 < 0 else 0
        right = (c1 - cols + _GROW) if c1 >= cols else 0
        top = (r1 - rows + _GROW) if r1 >= rows else 0
        if left or bottom or right or top:
            pad = ((bottom, top), (left, right))
            self.log_odds = np.pad(self.log_odds, pad)
            self.seen = np.pad(self.seen, pad)
            self.origin = self.origin - np.array([left, bottom]) * r

    def insert(self, points: F64, sensor_xy: F64, misses: F64 | None = None) -> None:
        """Ray cast one scan: ``points`` (N, 2) world end points seen from ``sensor_xy`` (2,).

        ``misses`` (M, 2) are the far ends of beams that saw nothing (no return): free along
        their length, no hit at their end.
        """
        if not len(points) and (misses is None or not len(misses)):
            return
        ends = points if misses is None or not len(misses) else np.vstack([points, misses])
        lo = np.minimum(ends.min(axis=0), sensor_xy) - self.resolution
        hi = np.maximum(ends.max(axis=0), sensor_xy) + self.resolution
        self._ensure(lo, hi)
        import cv2

        r = self.resolution
        c0, r0 = np.floor((lo - self.origin) / r).astype(int)
        c1, r1 = np.ceil((hi - self.origin) / r).astype(int) + 1
        mask = np.zeros((r1 - r0, c1 - c0), dtype=np.uint8)
        scale = float(1 << _SHIFT)
        win = self.origin + np.array([c0, r0]) * r
        start = np.rint(((sensor_xy - win) / r - 0.5) * scale).astype(np.int32)
        stop = np.rint(((ends - win) / r - 0.5) * scale).astype(np.int32)
        lines = np.empty((len(stop), 2, 2), dtype=np.int32)
        lines[:, 0] = start
        lines[:, 1] = stop
        cv2.polylines(
            mask, list(lines[:, None, :, :].reshape(-1, 2, 1, 2)), False, 1, 1, cv2.LINE_8, _SHIFT
        )
        hit = np.zeros_like(mask, dtype=bool)
        if len(points):
            ij = np.floor((points - win) / r).astype(np.int64)
            ok = (ij[:, 0] >= 0) & (ij[:, 0] < mask.shape[1]) & (ij[:, 1] >= 0)
            ok &= ij[:, 1] < mask.shape[0]
            hit[ij[ok, 1], ij[ok, 0]] = True
        crossed = mask.astype(bool)
        free = crossed & ~hit
        lo_win = self.log_odds[r0:r1, c0:c1]
        lo_win[free] += self.miss
        lo_win[hit] += self.hit
        np.clip(lo_win, -self.clamp, self.clamp, out=lo_win)
        self.seen[r0:r1, c0:c1] |= crossed | hit
        self.insertions += 1

    def shrink(self) -> None:
        """Cut the window to the cells beams reached (a finished grid grows no more)."""
        rows = np.flatnonzero(self.seen.any(axis=1))
        cols = np.flatnonzero(self.seen.any(axis=0))
        if not len(rows):
            return
        r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        self.log_odds = np.ascontiguousarray(self.log_odds[r0:r1, c0:c1])
        self.seen = np.ascontiguousarray(self.seen[r0:r1, c0:c1])
        self.origin = self.origin + np.array([c0, r0]) * self.resolution

    def probabilities(self) -> F32:
        """(H, W) float32 occupancy probability, NaN where no beam reached."""
        p = 1.0 / (1.0 + np.exp(-self.log_odds))
        return np.where(self.seen, p, np.nan).astype(np.float32)

    def occupied(self) -> NDArray[np.bool_]:
        """(H, W) cells more likely occupied than not."""
        return self.seen & (self.log_odds > 0)

    def likelihood_field(self, sigma_m: float, box: F64 | None = None) -> Field:
        """How well a point fits the grid: ``exp(-d^2 / 2 sigma^2)`` of its distance ``d`` to
        the nearest occupied cell, as a :class:`Field`; over the cells of ``box`` (xmin, ymin,
        xmax, ymax, world) only when given (the field outside it reads 0)."""
        import cv2

        r0, c0 = 0, 0
        occ = self.occupied()
        if box is not None and occ.size:
            margin = math.ceil(3.0 * sigma_m / self.resolution) + 1
            lo = np.floor((box[:2] - self.origin) / self.resolution).astype(int) - margin
            hi = np.ceil((box[2:] - self.origin) / self.resolution).astype(int) + margin
            c0, r0 = max(0, lo[0]), max(0, lo[1])
            c1, r1 = min(occ.shape[1], hi[0]), min(occ.shape[0], hi[1])
            occ = occ[r0 : max(r0, r1), c0 : max(c0, c1)]
        if not occ.any():
            values = np.zeros((max(1, occ.shape[0]), max(1, occ.shape[1])), dtype=np.float32)
        else:
            dist = cv2.distanceTransform((~occ).astype(np.uint8), cv2.DIST_L2, 5)
            d = dist * np.float32(self.resolution / sigma_m)
            values = np.exp(np.float32(-0.5) * d * d)
        origin = self.origin + np.array([c0, r0]) * self.resolution
        return Field(values, self.resolution, origin)


class Field:
    """Values on cells (a likelihood field), sampled at points.

    Attributes:
        values: (H, W) float32, rows growing with y.
        resolution: cell side, m.
        origin: (2,) world x, y of cell (0, 0)'s corner.
    """

    def __init__(self, values: F32, resolution: float, origin: F64) -> None:
        self.values = values
        self.resolution = resolution
        self.origin = origin

    def sample(self, xy: F64) -> tuple[F64, F64]:
        """Bilinear values (N,) at world points ``xy`` (N, 2) and their gradients (N, 2) in
        x, y (per metre); 0 outside the window."""
        h, w = self.values.shape
        u = (xy[:, 0] - self.origin[0]) / self.resolution - 0.5
        v = (xy[:, 1] - self.origin[1]) / self.resolution - 0.5
        j0 = np.floor(u).astype(np.int64)
        i0 = np.floor(v).astype(np.int64)
        fu = u - j0
        fv = v - i0
        inside = (j0 >= 0) & (j0 < w - 1) & (i0 >= 0) & (i0 < h - 1)
        j0 = np.where(inside, j0, 0)
        i0 = np.where(inside, i0, 0)
        f = self.values
        a = f[i0, j0].astype(np.float64)
        b = f[i0, j0 + 1].astype(np.float64)
        c = f[i0 + 1, j0].astype(np.float64)
        d = f[i0 + 1, j0 + 1].astype(np.float64)
        value = (a * (1 - fu) + b * fu) * (1 - fv) + (c * (1 - fu) + d * fu) * fv
        du = ((b - a) * (1 - fv) + (d - c) * fv) / self.resolution
        dv = ((c - a) * (1 - fu) + (d - b) * fu) / self.resolution
        value = np.where(inside, value, 0.0)
        grad = np.stack([np.where(inside, du, 0.0), np.where(inside, dv, 0.0)], axis=1)
        return value, grad
