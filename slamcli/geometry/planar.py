"""Planar (SE(2)) poses as (x, y, yaw) rows, and their embedding in SE(3) about +z."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]


def wrap_angle(a: ArrayLike) -> F64:
    """Angles wrapped to [-pi, pi)."""
    return np.asarray((np.asarray(a, dtype=np.float64) + np.pi) % (2.0 * np.pi) - np.pi)


def planar_to_se3(xy_yaw: ArrayLike) -> F64:
    """(N, 3) rows of x, y, yaw -> (N, 4, 4) poses in the z = 0 plane, yaw about +z."""
    p = np.atleast_2d(np.asarray(xy_yaw, dtype=np.float64))
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    out = np.zeros((p.shape[0], 4, 4))
    out[:, 0, 0], out[:, 0, 1], out[:, 1, 0], out[:, 1, 1] = c, -s, s, c
    out[:, 2, 2] = out[:, 3, 3] = 1.0
    out[:, 0, 3], out[:, 1, 3] = p[:, 0], p[:, 1]
    return out


def se3_to_planar(poses: ArrayLike) -> F64:
    """(N, 4, 4) poses -> (N, 3) rows of x, y, yaw (the heading of the body x axis in x-y)."""
    t = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    return np.stack([t[:, 0, 3], t[:, 1, 3], np.arctan2(t[:, 1, 0], t[:, 0, 0])], axis=1)


def compose_planar(a: ArrayLike, b: ArrayLike) -> F64:
    """a ⊕ b for (..., 3) poses: b expressed in a's frame, mapped to the world."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            a[..., 0] + c * b[..., 0] - s * b[..., 1],
            a[..., 1] + s * b[..., 0] + c * b[..., 1],
            wrap_angle(a[..., 2] + b[..., 2]),
        ],
        axis=-1,
    )


def interpolate_planar(stamps_ns: ArrayLike, xy_yaw: ArrayLike, at_ns: ArrayLike) -> F64:
    """Poses at ``at_ns`` by linear interpolation of x, y and of the unwrapped yaw.

    ``stamps_ns`` must be strictly increasing; stamps outside their range take NaN.
    """
    t = np.asarray(stamps_ns, dtype=np.int64)
    p = np.asarray(xy_yaw, dtype=np.float64)
    q = np.asarray(at_ns, dtype=np.int64)
    base = t[0]
    tf, qf = (t - base).astype(np.float64), (q - base).astype(np.float64)
    yaw = np.unwrap(p[:, 2])
    out = np.stack(
        [np.interp(qf, tf, p[:, 0]), np.interp(qf, tf, p[:, 1]), np.interp(qf, tf, yaw)], axis=1
    )
    out[:, 2] = wrap_angle(out[:, 2])
    out[(q < t[0]) | (q > t[-1])] = np.nan
    return out
