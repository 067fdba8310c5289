"""Planar (SE(2)) poses as (x, y, yaw) rows, their embedding in SE(3) about +z, and the exact
unicycle motion of a planar robot."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]
Real = float | F64
"""A float or a float64 array: the unicycle functions broadcast over arrays and stay cheap on
plain floats."""


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


def invert_planar(a: ArrayLike) -> F64:
    """a⁻¹ for (..., 3) poses: the world's origin and axes seen from ``a``."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [-(c * a[..., 0] + s * a[..., 1]), s * a[..., 0] - c * a[..., 1], wrap_angle(-a[..., 2])],
        axis=-1,
    )


def between_planar(a: ArrayLike, b: ArrayLike) -> F64:
    """a⁻¹ ⊕ b for (..., 3) poses: the pose ``b`` in ``a``'s frame."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[..., 2] - a[..., 2])], -1)


def rotation_2d(yaw: ArrayLike) -> F64:
    """(..., 2, 2) rotation matrices of angles ``yaw`` (...,), radians counter-clockwise."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def transform_points_planar(pose: ArrayLike, xy: ArrayLike) -> F64:
    """(N, 2) points in the frame of ``pose`` (3,) x, y, yaw, mapped to the frame the pose is
    expressed in: ``R(yaw) p + (x, y)``."""
    p = np.asarray(pose, dtype=np.float64)
    return np.asarray(np.asarray(xy, dtype=np.float64) @ rotation_2d(p[2]).T + p[:2])


def sin_ratio(a: Real) -> Real:
    """``sin(a) / a`` elementwise, radians, with its limit 1 at ``a = 0``.

    Exactly ``sin(a) / a`` wherever ``a != 0``: the zero test adds 1 to both numerator and
    denominator only where ``a == 0``, so there is no branch and no tolerance. Cheap on plain
    floats too, where the motion models call it once per odometry record.
    """
    zero = a == 0.0
    return (np.sin(a) + zero) / (a + zero)


def unicycle_step(
    x: Real, y: Real, yaw: Real, v: Real, omega: Real, dt: Real
) -> tuple[Real, Real, Real]:
    """A unicycle's pose after speed ``v`` (m/s) and turn rate ``omega`` (rad/s) held for ``dt``
    seconds from (``x``, ``y``, ``yaw``) (m, m, rad); all arguments broadcast together.

    The exact arc, written in its chord form so the straight line (ω = 0) is the same formula's
    limit rather than a separate branch::

        a = ω dt / 2,  L = v dt sin(a) / a,  φ = yaw + a
        x' = x + L cos φ,  y' = y + L sin φ,  yaw' = yaw + ω dt

    Returns:
        New x, y (m) and yaw (rad). The yaw is not wrapped, so a sequence of steps keeps a
        continuous heading; wrap it with :func:`wrap_angle` where a range matters.
    """
    a = 0.5 * omega * dt
    chord = v * dt * sin_ratio(a)
    phi = yaw + a
    return x + chord * np.cos(phi), y + chord * np.sin(phi), yaw + omega * dt


def integrate_unicycle(start: ArrayLike, controls: ArrayLike, dt: ArrayLike) -> F64:
    """Poses along piecewise-constant unicycle controls, by :func:`unicycle_step`.

    Args:
        start: (3,) x, y (m) and yaw (rad) before the first control.
        controls: (K, 2) float64 v (m/s) and omega (rad/s), control k held for ``dt[k]``.
        dt: seconds each control is held, a scalar or (K,).

    Returns:
        (K + 1, 3) float64 poses: the start, then the pose after each control. Bit for bit the
        same as applying :func:`unicycle_step` K times: headings and positions are running sums
        (``np.cumsum`` adds in order), and every step's displacement depends only on its own
        heading. Yaw is continuous (not wrapped).
    """
    p0 = np.asarray(start, dtype=np.float64)
    u = np.asarray(controls, dtype=np.float64).reshape(-1, 2)
    t = np.broadcast_to(np.asarray(dt, dtype=np.float64), (len(u),))
    v, w = u[:, 0], u[:, 1]
    yaw = np.cumsum(np.concatenate([p0[2:3], w * t]))
    dx, dy, _ = unicycle_step(0.0, 0.0, yaw[:-1], v, w, t)
    x = np.cumsum(np.concatenate([p0[0:1], dx]))
    y = np.cumsum(np.concatenate([p0[1:2], dy]))
    return np.stack([x, y, yaw], axis=1)


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
