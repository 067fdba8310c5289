"""Compiled pose refinement of :func:`slamcli.vision.pnp.refine_pose_depth`.

Tracking refines a frame's pose several times per frame against a few hundred points; written
with numpy, each Gauss-Newton iteration's dozen small array operations cost more than their
arithmetic. Here one loop over the observations builds the 6x6 normal equations.

This module imports numba: import it only where a pose is refined.
"""

from __future__ import annotations

import numpy as np

from slamcli.kernels import load_numba

numba = load_numba()


@numba.njit(cache=True, nogil=True)
def _solve6(h: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, bool]:
    """``h x = g`` by Gaussian elimination with partial pivoting; False when ``h`` is
    singular."""
    a = h.copy()
    b = g.copy()
    n = 6
    for col in range(n):
        piv = col
        best = abs(a[col, col])
        for r in range(col + 1, n):
            if abs(a[r, col]) > best:
                best = abs(a[r, col])
                piv = r
        if not (best > 0.0):
            return b, False
        if piv != col:
            for c in range(n):
                a[col, c], a[piv, c] = a[piv, c], a[col, c]
            b[col], b[piv] = b[piv], b[col]
        for r in range(col + 1, n):
            f = a[r, col] / a[col, col]
            for c in range(col, n):
                a[r, c] -= f * a[col, c]
            b[r] -= f * b[col]
    for r in range(n - 1, -1, -1):
        s = b[r]
        for c in range(r + 1, n):
            s -= a[r, c] * b[c]
        b[r] = s / a[r, r]
    return b, True


@numba.njit(cache=True, nogil=True)
def _left_update(step: np.ndarray, rot: np.ndarray, trans: np.ndarray) -> None:
    """``(rot, trans) <- exp(step) * (rot, trans)`` in place, for a twist ``[rho, phi]``."""
    r0, r1, r2 = step[0], step[1], step[2]
    p0, p1, p2 = step[3], step[4], step[5]
    theta2 = p0 * p0 + p1 * p1 + p2 * p2
    if theta2 < 1e-12:
        a = 1.0 - theta2 / 6.0
        b = 0.5 - theta2 / 24.0
        c_ = 1.0 / 6.0 - theta2 / 120.0
    else:
        theta = np.sqrt(theta2)
        a = np.sin(theta) / theta
        b = (1.0 - np.cos(theta)) / theta2
        c_ = (theta - np.sin(theta)) / (theta2 * theta)
    # Written out, not with ``@``: numba's matrix product would load a BLAS (and scipy).
    k = np.array([[0.0, -p2, p1], [p2, 0.0, -p0], [-p1, p0, 0.0]])
    k2 = np.zeros((3, 3))
    for r in range(3):
        for c in range(3):
            k2[r, c] = k[r, 0] * k[0, c] + k[r, 1] * k[1, c] + k[r, 2] * k[2, c]
    rho = (r0, r1, r2)
    e = np.zeros((3, 3))
    et = np.zeros(3)
    for r in range(3):
        e[r, r] = 1.0
        for c in range(3):
            e[r, c] += a * k[r, c] + b * k2[r, c]
            et[r] += b * k[r, c] * rho[c] + c_ * k2[r, c] * rho[c]
        et[r] += rho[r]
    new_rot = np.zeros((3, 3))
    new_trans = np.zeros(3)
    for r in range(3):
        for c in range(3):
            new_rot[r, c] = e[r, 0] * rot[0, c] + e[r, 1] * rot[1, c] + e[r, 2] * rot[2, c]
        new_trans[r] = e[r, 0] * trans[0] + e[r, 1] * trans[1] + e[r, 2] * trans[2] + et[r]
    rot[:, :] = new_rot
    trans[:] = new_trans


@numba.njit(cache=True, nogil=True)
def refine(
    rot: np.ndarray,
    trans: np.ndarray,
    points: np.ndarray,
    pixels: np.ndarray,
    ur_meas: np.ndarray,
    stereo: np.ndarray,
    info: np.ndarray,
    th: np.ndarray,
    intr: np.ndarray,
    rounds: int,
    iterations: int,
) -> tuple[bool, np.ndarray]:
    """Gauss-Newton rounds of :func:`~slamcli.vision.pnp.refine_pose_depth` on ``rot`` and
    ``trans`` (changed in place); returns whether it held, and the last round's inliers.

    ``intr`` is ``fx, fy, cx, cy, bf``; ``th`` each observation's chi-square gate (which is
    also the square of its Huber threshold), ``info`` its ``1 / sigma^2``.
    """
    fx, fy, cx, cy, bf = intr[0], intr[1], intr[2], intr[3], intr[4]
    m = points.shape[0]
    inlier = np.ones(m, dtype=np.bool_)
    h = np.zeros((6, 6))
    g = np.zeros(6)
    jac = np.zeros((3, 6))
    res = np.zeros(3)
    for _ in range(rounds):
        for _ in range(iterations):
            h[:, :] = 0.0
            g[:] = 0.0
            used = 0
            for i in range(m):
                x = rot[0, 0] * points[i, 0] + rot[0, 1] * points[i, 1] + rot[0, 2] * points[i, 2]
                y = rot[1, 0] * points[i, 0] + rot[1, 1] * points[i, 1] + rot[1, 2] * points[i, 2]
                z = rot[2, 0] * points[i, 0] + rot[2, 1] * points[i, 1] + rot[2, 2] * points[i, 2]
                x += trans[0]
                y += trans[1]
                z += trans[2]
                if not (inlier[i] and z > 1e-6):
                    continue
                used += 1
                iz = 1.0 / z
                u = fx * x * iz + cx
                res[0] = u - pixels[i, 0]
                res[1] = fy * y * iz + cy - pixels[i, 1]
                res[2] = u - bf * iz - ur_meas[i] if stereo[i] else 0.0
                chi2 = (res[0] * res[0] + res[1] * res[1] + res[2] * res[2]) * info[i]
                norm = np.sqrt(chi2)
                delta = np.sqrt(th[i])
                w = info[i] if norm <= delta else info[i] * delta / max(norm, 1e-12)
                a = fx * iz
                b = fy * iz
                gz_u = -a * x * iz
                gz_v = -b * y * iz
                jac[0, 0], jac[0, 1], jac[0, 2] = a, 0.0, gz_u
                jac[0, 3], jac[0, 4], jac[0, 5] = gz_u * y, a * z - gz_u * x, -a * y
                jac[1, 0], jac[1, 1], jac[1, 2] = 0.0, b, gz_v
                jac[1, 3], jac[1, 4], jac[1, 5] = gz_v * y - b * z, -gz_v * x, b * x
                rows = 2
                if stereo[i]:
                    gz_r = gz_u + bf * iz * iz
                    jac[2, 0], jac[2, 1], jac[2, 2] = a, 0.0, gz_r
                    jac[2, 3], jac[2, 4], jac[2, 5] = gz_r * y, a * z - gz_r * x, -a * y
                    rows = 3
                for k in range(rows):
                    for r in range(6):
                        wj = w * jac[k, r]
                        g[r] += wj * res[k]
                        for c in range(r, 6):
                            h[r, c] += wj * jac[k, c]
            if used < 4:
                return False, inlier
            for r in range(6):
                for c in range(r):
                    h[r, c] = h[c, r]
            sol, ok = _solve6(h, g)
            if not ok:
                return False, inlier
            step = -sol
            _left_update(step, rot, trans)
            norm2 = 0.0
            for r in range(6):
                norm2 += step[r] * step[r]
            if norm2 < 1e-12:
                break
        now = np.zeros(m, dtype=np.bool_)
        same = True
        for i in range(m):
            x = rot[0, 0] * points[i, 0] + rot[0, 1] * points[i, 1] + rot[0, 2] * points[i, 2]
            y = rot[1, 0] * points[i, 0] + rot[1, 1] * points[i, 1] + rot[1, 2] * points[i, 2]
            z = rot[2, 0] * points[i, 0] + rot[2, 1] * points[i, 1] + rot[2, 2] * points[i, 2]
            x += trans[0]
            y += trans[1]
            z += trans[2]
            if z > 1e-6:
                iz = 1.0 / z
                u = fx * x * iz + cx
                r0 = u - pixels[i, 0]
                r1 = fy * y * iz + cy - pixels[i, 1]
                r2 = u - bf * iz - ur_meas[i] if stereo[i] else 0.0
                now[i] = (r0 * r0 + r1 * r1 + r2 * r2) * info[i] <= th[i]
            if now[i] != inlier[i]:
                same = False
        inlier = now
        if same:
            break
    return True, inlier
