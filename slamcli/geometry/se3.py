"""SO(3)/SE(3) maths on stacks. Every function broadcasts over leading dimensions.

Quaternions are Hamilton unit quaternions; ``xyzw`` order is used only at TUM file edges.
Tangent vectors are ``[rho (3), phi (3)]``: translation part first, rotation second.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]
_EPS = 1e-10


def make_pose(rotation: ArrayLike, translation: ArrayLike) -> F64:
    """(…,3,3) rotations and (…,3) translations -> (…,4,4) homogeneous transforms."""
    r = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    shape = np.broadcast_shapes(r.shape[:-2], t.shape[:-1])
    out = np.zeros((*shape, 4, 4))
    out[..., :3, :3] = r
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def compose(a_from_b: ArrayLike, b_from_c: ArrayLike) -> F64:
    """(…,4,4) @ (…,4,4) -> a_from_c."""
    return np.matmul(np.asarray(a_from_b, np.float64), np.asarray(b_from_c, np.float64))


def inverse(a_from_b: ArrayLike) -> F64:
    """Inverse of rigid transforms, (…,4,4) -> b_from_a, using R^T rather than a general inverse."""
    t = np.asarray(a_from_b, dtype=np.float64)
    rt = np.swapaxes(t[..., :3, :3], -1, -2)
    return make_pose(rt, -np.einsum("...ij,...j->...i", rt, t[..., :3, 3]))


def _hat(v: F64) -> F64:
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def so3_exp(rotvec: ArrayLike) -> F64:
    """Rotation vectors (…,3) in radians -> rotation matrices (…,3,3) (Rodrigues)."""
    phi = np.asarray(rotvec, dtype=np.float64)
    theta = np.linalg.norm(phi, axis=-1)[..., None, None]
    k = _hat(phi)
    small = theta < 1e-6
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * k + b * (k @ k)


def rotation_angle(rotation: ArrayLike) -> F64:
    """Angle in radians, in [0, π], of (…,3,3) rotations (or of the rotation part of (…,4,4))."""
    r = np.asarray(rotation, dtype=np.float64)[..., :3, :3]
    cos = (np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))


def so3_log(rotation: ArrayLike) -> F64:
    """Rotation matrices (…,3,3) -> rotation vectors (…,3), exact up to and including π."""
    r = np.asarray(rotation, dtype=np.float64)[..., :3, :3]
    return quat_wxyz_to_rotvec(matrix_to_quat_wxyz(r))


def quat_wxyz_to_rotvec(quat: ArrayLike) -> F64:
    """Unit quaternions (…,4) wxyz -> rotation vectors (…,3)."""
    q = np.asarray(quat, dtype=np.float64)
    q = np.where(q[..., :1] < 0.0, -q, q)
    w = np.clip(q[..., 0], -1.0, 1.0)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    small = s < 1e-8
    scale = np.where(small, 2.0 / np.maximum(w, _EPS), angle / np.where(small, 1.0, s))
    return v * scale[..., None]


def _left_jacobian(phi: F64) -> F64:
    theta = np.linalg.norm(phi, axis=-1)[..., None, None]
    k = _hat(phi)
    small = theta < 1e-6
    safe = np.where(small, 1.0, theta)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    c = np.where(small, 1.0 / 6.0 - theta**2 / 120.0, (safe - np.sin(safe)) / safe**3)
    return np.eye(3) + b * k + c * (k @ k)


def se3_exp(twist: ArrayLike) -> F64:
    """Twists (…,6) ``[rho, phi]`` -> transforms (…,4,4)."""
    xi = np.asarray(twist, dtype=np.float64)
    rho, phi = xi[..., :3], xi[..., 3:]
    t = np.einsum("...ij,...j->...i", _left_jacobian(phi), rho)
    return make_pose(so3_exp(phi), t)


def se3_log(pose: ArrayLike) -> F64:
    """Transforms (…,4,4) -> twists (…,6) ``[rho, phi]``."""
    p = np.asarray(pose, dtype=np.float64)
    phi = so3_log(p[..., :3, :3])
    rho = np.linalg.solve(_left_jacobian(phi), p[..., :3, 3:4])[..., 0]
    return np.concatenate([rho, phi], axis=-1)


def quat_wxyz_to_matrix(quat: ArrayLike) -> F64:
    """Quaternions (…,4) wxyz (normalised here) -> rotation matrices (…,3,3)."""
    q = np.asarray(quat, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty((*q.shape[:-1], 3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - z * w)
    out[..., 0, 2] = 2 * (x * z + y * w)
    out[..., 1, 0] = 2 * (x * y + z * w)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - x * w)
    out[..., 2, 0] = 2 * (x * z - y * w)
    out[..., 2, 1] = 2 * (y * z + x * w)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def quat_xyzw_to_matrix(quat: ArrayLike) -> F64:
    """Quaternions (…,4) xyzw (TUM order) -> rotation matrices (…,3,3)."""
    q = np.asarray(quat, dtype=np.float64)
    return quat_wxyz_to_matrix(np.concatenate([q[..., 3:], q[..., :3]], axis=-1))


def matrix_to_quat_wxyz(rotation: ArrayLike) -> F64:
    """Rotation matrices (…,3,3) -> unit quaternions (…,4) wxyz with w >= 0.

    Uses the largest-diagonal branch (Shepperd) so it is accurate near 180°.
    """
    r = np.asarray(rotation, dtype=np.float64)[..., :3, :3]
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    # Four candidate 4*q_i^2 values; pick the largest per rotation.
    cand = np.stack(
        [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22],
        axis=-1,
    )
    best = np.argmax(cand, axis=-1)
    s = np.sqrt(np.maximum(np.take_along_axis(cand, best[..., None], -1)[..., 0], _EPS)) * 2.0
    d21, d02, d10 = (
        r[..., 2, 1] - r[..., 1, 2],
        r[..., 0, 2] - r[..., 2, 0],
        r[..., 1, 0] - r[..., 0, 1],
    )
    s21, s02, s10 = (
        r[..., 2, 1] + r[..., 1, 2],
        r[..., 0, 2] + r[..., 2, 0],
        r[..., 1, 0] + r[..., 0, 1],
    )
    q = np.stack(
        [
            np.select([best == 0, best == 1, best == 2], [s / 4, d21 / s, d02 / s], d10 / s),
            np.select([best == 0, best == 1, best == 2], [d21 / s, s / 4, s10 / s], s02 / s),
            np.select([best == 0, best == 1, best == 2], [d02 / s, s10 / s, s / 4], s21 / s),
            np.select([best == 0, best == 1, best == 2], [d10 / s, s02 / s, s21 / s], s / 4),
        ],
        axis=-1,
    )
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def matrix_to_quat_xyzw(rotation: ArrayLike) -> F64:
    """Rotation matrices (…,3,3) -> unit quaternions (…,4) xyzw (TUM order), w >= 0."""
    q = matrix_to_quat_wxyz(rotation)
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def slerp(q0: ArrayLike, q1: ArrayLike, fraction: ArrayLike) -> F64:
    """Spherical interpolation of wxyz quaternions (…,4) at fractions t (…) in [0, 1].

    Takes the shorter arc; falls back to normalised linear interpolation for nearly equal inputs.
    """
    a = np.asarray(q0, dtype=np.float64)
    b = np.asarray(q1, dtype=np.float64)
    t = np.asarray(fraction, dtype=np.float64)[..., None]
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0.0, -b, b)
    dot = np.abs(dot)
    close = dot > 1.0 - 1e-9
    omega = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_omega = np.where(close, 1.0, np.sin(omega))
    wa = np.where(close, 1.0 - t, np.sin((1.0 - t) * omega) / sin_omega)
    wb = np.where(close, t, np.sin(t * omega) / sin_omega)
    q = wa * a + wb * b
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def blend_poses(a: ArrayLike, b: ArrayLike, fraction: float) -> F64:
    """The pose ``fraction`` of the way from ``a`` to ``b`` (4, 4): SLERP for the rotation,
    linear for the translation; 0 gives ``a``, 1 gives ``b``."""
    pa = np.asarray(a, dtype=np.float64)
    pb = np.asarray(b, dtype=np.float64)
    q = slerp(matrix_to_quat_wxyz(pa[:3, :3]), matrix_to_quat_wxyz(pb[:3, :3]), fraction)
    t = pa[:3, 3] + fraction * (pb[:3, 3] - pa[:3, 3])
    return make_pose(quat_wxyz_to_matrix(q), t)


def interpolate_poses(
    stamps_ns: ArrayLike, world_from_body: ArrayLike, query_ns: ArrayLike
) -> tuple[NDArray[np.bool_], F64]:
    """Interpolate a pose stack at query times: SLERP for rotation, linear for translation.

    Args:
        stamps_ns: (N,) int64 strictly increasing.
        world_from_body: (N,4,4).
        query_ns: (M,) int64.

    Returns:
        valid: (M,) bool, False where the query lies outside [stamps[0], stamps[-1]].
        poses: (M,4,4); rows where ``valid`` is False hold the nearest end pose.
    """
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    poses = np.asarray(world_from_body, dtype=np.float64)
    query = np.asarray(query_ns, dtype=np.int64)
    valid = (query >= stamps[0]) & (query <= stamps[-1])
    if stamps.size == 1:
        return valid, np.repeat(poses[:1], query.size, axis=0)
    hi = np.clip(np.searchsorted(stamps, query, side="right"), 1, stamps.size - 1)
    lo = hi - 1
    span = (stamps[hi] - stamps[lo]).astype(np.float64)
    frac = np.clip((query - stamps[lo]).astype(np.float64) / span, 0.0, 1.0)
    q = slerp(matrix_to_quat_wxyz(poses[lo]), matrix_to_quat_wxyz(poses[hi]), frac)
    t = poses[lo, :3, 3] + frac[:, None] * (poses[hi, :3, 3] - poses[lo, :3, 3])
    return valid, make_pose(quat_wxyz_to_matrix(q), t)
