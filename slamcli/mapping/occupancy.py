"""A log-odds occupancy grid and vectorised 2-D ray carving.

The rules, exactly:

- Every cell holds a log-odds value ``l``, 0 at the start. Per **scan** (one depth frame, or
  one batch of range-bearing rays) a cell containing at least one ray end marked as a hit gets
  ``+`` :data:`L_OCC` (0.85) once; every other cell that a ray of the scan crosses (and the end
  cell of a ray that is not a hit) gets ``+`` :data:`L_FREE` (-0.4) once. After each scan the
  values are clamped to [:data:`L_MIN`, :data:`L_MAX`] = [-2, 3.5] (OctoMap's defaults), so a
  cell can change its mind after a few scans.
- A cell no scan ever touched stays **unknown** (NaN probability); otherwise its probability
  is ``1 - 1 / (1 + exp(l))``. With map_server's thresholds (occupied >= 0.65, free <= 0.196)
  one hit makes a cell occupied (p = 0.70), four free passes without a hit make it free
  (p = 0.17); cells in between are written as unknown in a trinary map.
- A ray's cells are found by sampling the segment from its start cell's centre to its end
  cell's centre every half cell, so a cell the segment only clips at a corner may be missed; the
  start cell is always included.

Cell ``(row, col)`` covers ``[x0 + col * res, x0 + (col + 1) * res) x [y0 + row * res, ...)``,
row 0 the lowest y, as in :class:`~slamcli.types.OccupancyGrid` (yaw 0).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.errors import ConfigError
from slamcli.types import OccupancyGrid

L_FREE = -0.4
"""Log-odds added to a cell a ray passes through (or ends in without a hit)."""
L_OCC = 0.85
"""Log-odds added to a cell holding a hit."""
L_MIN = -2.0
"""Lower clamp of the log-odds (p = 0.12)."""
L_MAX = 3.5
"""Upper clamp of the log-odds (p = 0.97)."""

_SAMPLES_PER_CELL = 2


class LogOddsGrid:
    """A fixed-extent log-odds grid (see the module docstring for the update rules).

    Attributes:
        logodds: (H, W) float32.
        touched: (H, W) bool, cells any update reached.
        resolution_m: cell edge in metres.
        origin_xy: world (x, y) of cell (0, 0)'s lower-left corner, metres.
    """

    def __init__(self, shape: tuple[int, int], resolution_m: float, origin_xy: ArrayLike) -> None:
        h, w = (int(v) for v in shape)
        if h < 1 or w < 1:
            raise ConfigError(f"grid shape must be positive, got {shape}")
        if not (math.isfinite(resolution_m) and resolution_m > 0):
            raise ConfigError(f"--resolution: must be a number > 0 m, got {resolution_m!r}")
        self.logodds = np.zeros((h, w), dtype=np.float32)
        self.touched = np.zeros((h, w), dtype=bool)
        self.resolution_m = float(resolution_m)
        origin = np.asarray(origin_xy, dtype=np.float64).reshape(2)
        self.origin_xy = origin

    @classmethod
    def covering(
        cls, xy_min: ArrayLike, xy_max: ArrayLike, resolution_m: float, margin_m: float
    ) -> LogOddsGrid:
        """A grid covering the box ``[xy_min, xy_max]`` plus ``margin_m`` on every side, its
        origin snapped to a multiple of the resolution."""
        res = float(resolution_m)
        lo = np.floor((np.asarray(xy_min, dtype=np.float64) - margin_m) / res) * res
        hi = np.asarray(xy_max, dtype=np.float64) + margin_m
        cols, rows = (np.ceil((hi - lo) / res).astype(np.int64) + 1).tolist()
        return cls((rows, cols), res, lo)

    @property
    def shape(self) -> tuple[int, int]:
        h, w = self.logodds.shape
        return int(h), int(w)

    def cells(self, xy: ArrayLike) -> NDArray[np.int64]:
        """World points (..., 2) -> (..., 2) int64 (row, col); may lie outside the grid."""
        p = np.asarray(xy, dtype=np.float64)
        rc = np.floor((p - self.origin_xy) / self.resolution_m).astype(np.int64)
        return rc[..., ::-1]

    def _linear(self, rc: NDArray[np.int64]) -> NDArray[np.int64]:
        """Flat indices of the (N, 2) cells that lie inside the grid."""
        h, w = self.shape
        inside = (rc[:, 0] >= 0) & (rc[:, 0] < h) & (rc[:, 1] >= 0) & (rc[:, 1] < w)
        rc = rc[inside]
        return rc[:, 0] * w + rc[:, 1]

    def integrate(
        self,
        starts_xy: ArrayLike,
        ends_xy: ArrayLike,
        hit: ArrayLike,
    ) -> None:
        """One scan: carve the rays from ``starts_xy`` to ``ends_xy`` free and mark hits.

        Args:
            starts_xy: (N, 2) or (2,) float metres, where each ray starts.
            ends_xy: (N, 2) float metres, where each ray ends.
            hit: (N,) bool, whether the end is an obstacle (its cell gets ``L_OCC``) or free
                space (its cell is carved like the rest of the ray).
        """
        ends = np.asarray(ends_xy, dtype=np.float64).reshape(-1, 2)
        starts = np.broadcast_to(np.asarray(starts_xy, dtype=np.float64), ends.shape)
        is_hit = np.asarray(hit, dtype=bool).reshape(-1)
        if ends.shape[0] == 0:
            return
        # Rays with the same start cell, end cell and verdict carve the same cells (up to half a
        # cell): each is traced once, from cell centre to cell centre. A camera's thousands of
        # rays shrink to one per cell they end in.
        start_rc, end_rc = self.cells(starts), self.cells(ends)
        keys = np.unique(_pack(start_rc, end_rc, is_hit))
        start_rc, end_rc, is_hit = _unpack(keys)
        hit_lin = np.unique(self._linear(end_rc[is_hit]))
        free_lin = self._trace(start_rc + np.float64(0.5), end_rc + np.float64(0.5))
        size = self.logodds.size
        free = np.zeros(size, dtype=bool)
        free[free_lin] = True
        free[hit_lin] = False
        flat = self.logodds.reshape(-1)
        flat[free] += L_FREE
        flat[hit_lin] += L_OCC
        np.clip(flat, L_MIN, L_MAX, out=flat)
        touched = self.touched.reshape(-1)
        touched[free] = True
        touched[hit_lin] = True

    def _trace(self, a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.int64]:
        """Flat indices (with repeats) of the grid cells the segments from ``a`` to ``b``
        ((N, 2) (row, col) in cell units) pass through, sampled every half cell, ends
        included."""
        if a.shape[0] == 0:
            return np.zeros(0, dtype=np.int64)
        d = b - a
        steps = np.ceil(np.hypot(d[:, 0], d[:, 1]) * _SAMPLES_PER_CELL).astype(np.int64) + 1
        owner = np.repeat(np.arange(a.shape[0]), steps)
        first = np.repeat(np.cumsum(steps) - steps, steps)
        t = (np.arange(owner.size) - first) / np.repeat(np.maximum(steps - 1, 1), steps)
        h, w = self.shape
        row = np.floor(a[owner, 0] + t * d[owner, 0]).astype(np.int64)
        col = np.floor(a[owner, 1] + t * d[owner, 1]).astype(np.int64)
        inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        return (row * w + col)[inside]

    def set_cells(self, rc: NDArray[np.int64], value: float) -> None:
        """Set the log-odds of the (N, 2) cells (those inside the grid) to ``value``."""
        lin = self._linear(np.asarray(rc, dtype=np.int64).reshape(-1, 2))
        self.logodds.reshape(-1)[lin] = value
        self.touched.reshape(-1)[lin] = True

    def disc_cells(self, centres_xy: ArrayLike, radius_m: float) -> NDArray[np.int64]:
        """(K, 2) cells whose centres lie within ``radius_m`` of any of the (N, 2) centres
        (and always the cell holding each centre)."""
        centres = np.asarray(centres_xy, dtype=np.float64).reshape(-1, 2)
        res = self.resolution_m
        reach = math.ceil(radius_m / res) + 1
        offs = np.arange(-reach, reach + 1)
        dr, dc = np.meshgrid(offs, offs, indexing="ij")
        off = np.stack([dr.ravel(), dc.ravel()], axis=1)
        base = self.cells(centres)
        rc = base[:, None, :] + off[None, :, :]
        centre_xy = self.origin_xy + (rc[..., ::-1] + 0.5) * res
        near = np.linalg.norm(centre_xy - centres[:, None, :], axis=-1) <= radius_m
        near |= np.all(off == 0, axis=1)[None, :]
        return rc[near]

    def probability(self) -> NDArray[np.float32]:
        """(H, W) float32 occupancy probability, NaN where no update ever reached."""
        prob = (1.0 - 1.0 / (1.0 + np.exp(self.logodds.astype(np.float64)))).astype(np.float32)
        prob[~self.touched] = np.nan
        return prob

    def to_grid(self) -> OccupancyGrid:
        """The grid as an :class:`OccupancyGrid` (yaw 0)."""
        x0, y0 = (float(v) for v in self.origin_xy)
        return OccupancyGrid(self.probability(), self.resolution_m, (x0, y0, 0.0))


_PACK_BITS = 15
_PACK_OFFSET = 1 << (_PACK_BITS - 1)


def _pack(
    start_rc: NDArray[np.int64], end_rc: NDArray[np.int64], hit: NDArray[np.bool_]
) -> NDArray[np.int64]:
    """One int64 per ray: start and end cells (each coordinate clipped to +-16383 cells) and
    the verdict, for a fast ``np.unique``."""
    key = np.zeros(hit.shape[0], dtype=np.int64)
    for part in (start_rc[:, 0], start_rc[:, 1], end_rc[:, 0], end_rc[:, 1]):
        clipped = np.clip(part, -_PACK_OFFSET, _PACK_OFFSET - 1) + _PACK_OFFSET
        key = (key << _PACK_BITS) | clipped
    return (key << 1) | hit.astype(np.int64)


def _unpack(
    key: NDArray[np.int64],
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
    hit = (key & 1).astype(bool)
    key = key >> 1
    parts = []
    mask = (1 << _PACK_BITS) - 1
    for _ in range(4):
        parts.append((key & mask) - _PACK_OFFSET)
        key = key >> _PACK_BITS
    er, ec, sr, sc = parts[1], parts[0], parts[3], parts[2]
    return np.stack([sr, sc], axis=1), np.stack([er, ec], axis=1), hit
