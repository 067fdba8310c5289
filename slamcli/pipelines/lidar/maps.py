"""The run's map: submap grids laid at their optimised poses into one grid."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from slamcli.pipelines.lidar.submaps import Submap
from slamcli.types import OccupancyGrid

F64 = NDArray[np.float64]


def submap_mosaic(submaps: Sequence[Submap], world_from_local: Sequence[F64]) -> OccupancyGrid:
    """One occupancy grid of the submaps, each moved by its ``world_from_local`` (x, y, yaw).

    Every other submap is used (0, 2, 4, ...): with two submaps active at a time those hold each
    node once, so no scan is counted twice. Their log-odds are added cell by cell.
    """
    import cv2

    chosen = [(s, np.asarray(t)) for s, t in zip(submaps, world_from_local, strict=True)]
    chosen = [(s, t) for s, t in chosen if s.index % 2 == 0 and s.grid.log_odds.size]
    if not chosen:
        return OccupancyGrid(np.full((1, 1), np.nan, dtype=np.float32), 0.05)
    res = chosen[0][0].grid.resolution
    corners = []
    for sub, t in chosen:
        h, w = sub.grid.shape
        box = sub.grid.origin + np.array([[0, 0], [w, 0], [0, h], [w, h]]) * res
        c, s = math.cos(t[2]), math.sin(t[2])
        corners.append(box @ np.array([[c, s], [-s, c]]) + t[:2])
    pts = np.vstack(corners)
    origin = np.floor(pts.min(axis=0) / res) * res - res
    size = np.ceil((pts.max(axis=0) - origin) / res).astype(int) + 2
    total = np.zeros((size[1], size[0]), dtype=np.float32)
    seen = np.zeros((size[1], size[0]), dtype=np.uint8)
    for sub, t in chosen:
        c, s = math.cos(t[2]), math.sin(t[2])
        # Map cell centres of the submap (u = col, v = row) to cells of the mosaic.
        o = sub.grid.origin
        # world = R (o + (u + 0.5) res) + t ; mosaic col = (world - origin) / res - 0.5
        rot = np.array([[c, -s], [s, c]])
        lin = rot  # d(mosaic)/d(u, v) in cells
        off = (rot @ (o + 0.5 * res) + t[:2] - origin) / res - 0.5
        m = np.hstack([lin, off[:, None]]).astype(np.float64)
        total += cv2.warpAffine(
            sub.grid.log_odds,
            m,
            (size[0], size[1]),
            flags=cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
        seen |= cv2.warpAffine(
            sub.grid.seen.astype(np.uint8),
            m,
            (size[0], size[1]),
            flags=cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
    prob = 1.0 / (1.0 + np.exp(-total))
    cells = np.where(seen > 0, prob, np.nan).astype(np.float32)
    return OccupancyGrid(cells, float(res), (float(origin[0]), float(origin[1]), 0.0))
