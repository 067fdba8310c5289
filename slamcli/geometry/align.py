"""Least-squares alignment of point sets: Umeyama (1991) in 2-D or 3-D, and a weighted planar
rigid fit (Kabsch in 2-D, closed form)."""

from __future__ import annotations

import math

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


def rigid_fit_2d(
    src: ArrayLike, dst: ArrayLike, weights: ArrayLike | None = None
) -> tuple[NDArray[np.float64], float]:
    """The planar rigid transform minimising ``sum w_i ||dst_i - (R(yaw) src_i + t)||²``.

    Closed form (no SVD): with centred points ``a = src - c_src`` and ``b = dst - c_dst`` (``c``
    the weighted centroids), ``yaw = atan2(sum w (a_x b_y - a_y b_x), sum w (a_x b_x + a_y b_y))``.

    Args:
        src: (N, 2) points to move, N >= 1 (one point fixes only the translation: yaw 0).
        dst: (N, 2) the points they pair with.
        weights: (N,) non-negative weights with a positive sum, or None for equal weights.

    Returns:
        (3,) float64 x, y (m) and yaw (rad) of ``dst_from_src``, and the unweighted RMS of the
        residuals ``||R src_i + t - dst_i||`` in metres.
    """
    x = np.asarray(src, dtype=np.float64)
    y = np.asarray(dst, dtype=np.float64)
    if weights is None:
        cx, cy = x.mean(axis=0), y.mean(axis=0)
        a, b = x - cx, y - cy
        h = a.T @ b
    else:
        w = np.asarray(weights, dtype=np.float64)
        w = w / w.sum()
        cx, cy = w @ x, w @ y
        a, b = x - cx, y - cy
        h = (a * w[:, None]).T @ b
    yaw = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = math.cos(yaw), math.sin(yaw)
    rot = np.array([[c, -s], [s, c]])
    t = cy - rot @ cx
    res = (x @ rot.T + t) - y
    return np.array([t[0], t[1], yaw]), float(np.sqrt(np.mean(np.sum(res * res, axis=1))))
