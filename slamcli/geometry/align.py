"""Least-squares alignment of point sets (Umeyama 1991)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.errors import InputError


def umeyama(
    src: ArrayLike, dst: ArrayLike, with_scale: bool = False
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Find R, t, s minimising ``sum ||dst_i - (s R src_i + t)||²``.

    Args:
        src: (N, D) points to move (D = 2 or 3).
        dst: (N, D) target points.
        with_scale: estimate s (Sim(D)); otherwise s = 1 (SE(D)).

    Returns:
        rotation (D, D), translation (D,), scale.
    """
    x = np.asarray(src, dtype=np.float64)
    y = np.asarray(dst, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2:
        raise InputError(
            f"alignment needs two (N, D) arrays of one shape, got {x.shape}, {y.shape}"
        )
    n, d = x.shape
    if n < 2:
        raise InputError(f"alignment needs at least 2 point pairs, got {n}")
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    sigma_x = float(np.mean(np.sum(xc * xc, axis=1)))
    cov = yc.T @ xc / n
    u, sv, vt = np.linalg.svd(cov)
    if np.linalg.matrix_rank(cov) < d - 1:
        raise InputError(
            "alignment is degenerate: the matched positions are (nearly) collinear or identical",
            hint="use --align none, or evaluate a longer stretch of the trajectory",
        )
    sign = np.eye(d)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        sign[-1, -1] = -1.0
    rotation = u @ sign @ vt
    scale = float(np.trace(np.diag(sv) @ sign) / sigma_x) if with_scale else 1.0
    translation = my - scale * rotation @ mx
    return rotation, translation, scale
