"""Scans as points: beams to 2-D points in the body frame, and voxel filtering."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry.planar import transform_points_planar
from slamcli.types import ScanFrame

F64 = NDArray[np.float64]


def scan_points(scan: ScanFrame, max_range_m: float | None = None) -> F64:
    """(N, 2) float64 end points of the scan's readings in the body frame.

    Only beams whose range is a reading (:meth:`ScanFrame.readings`) give points; ``max_range_m``
    drops readings beyond it as well.
    """
    keep = scan.readings()
    if max_range_m is not None:
        with np.errstate(invalid="ignore"):
            keep &= scan.ranges_m <= max_range_m
    r = scan.ranges_m[keep].astype(np.float64)
    a = scan.angles()[keep]
    local = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    return transform_points_planar(scan.body_from_sensor, local)


def voxel_filter(points: F64, size_m: float) -> F64:
    """The mean of the points in each ``size_m`` square cell, in the order cells are first met.

    Evens out the density of a scan (many points on near walls, few on far ones), so that no
    stretch of wall outweighs the others in matching.
    """
    if len(points) == 0 or size_m <= 0:
        return points
    cells = np.floor(points / size_m).astype(np.int64)
    _, first, inverse = np.unique(cells, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(first), 2))
    np.add.at(sums, inverse, points)
    counts = np.bincount(inverse, minlength=len(first)).astype(np.float64)
    means = sums / counts[:, None]
    return means[np.argsort(first, kind="stable")]
