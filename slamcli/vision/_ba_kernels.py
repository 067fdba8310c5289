"""Compiled Levenberg-Marquardt bundle adjustment of :mod:`slamcli.vision.bundle_adjustment`.

The problem is the one COLMAP's bundle adjuster solves there (whitened pinhole reprojection
errors, one residual block of two per observation, a right-camera copy shifted by the baseline,
a robust loss per block), with the Jacobians written out: Ceres' automatic differentiation over
a rig per pixel sigma costs most of a local adjustment's time, and a local adjustment's few
dozen free poses make the reduced camera system small enough to be dense.

- **Parameters.** As COLMAP's: a free pose's rotation turns by ``R <- Exp(phi) R`` and its
  translation moves by ``t <- t + rho`` (``cam_from_world``); a free point by ``X <- X + dX``.
- **Behind a camera.** As in COLMAP's cost, an observation whose point is behind its camera
  (or on its plane) has no residual: a step may carry a point there, and
  :func:`~slamcli.vision.bundle_adjustment.bundle_adjust` then calls that observation an
  outlier, which the map drops.
- **Robust loss.** Each block's squared whitened error ``s`` is weighed by ``rho'(s)``
  (iteratively reweighted least squares): the same stationary points as Ceres' corrected
  residuals, with Ceres' ``0.5 * sum(rho(s))`` as the cost the steps are accepted on.
- **Step.** Ceres' Levenberg-Marquardt: the normal equations damped by ``diag(J^T J) / mu``
  (the diagonal of the Jacobi-scaled system clamped to [1e-6, 1e32]), ``mu`` from 1e4, grown
  or shrunk by the ratio of the actual to the predicted decrease; a step is taken when that
  ratio is above 1e-3. The points are eliminated (Schur complement, one 3x3 block each) and
  the reduced camera system is solved by a dense Cholesky factorisation.
- **Stops** after ``max_iterations`` steps (taken or not), or at a step that would change the
  cost by less than ``function_tolerance`` of it or move the parameters by less than
  ``parameter_tolerance`` of their size (that step is neither taken nor counted), as Ceres
  does: on the same
  problem the two take the same steps, to the last few bits.

Single-threaded and in a fixed order: the same input gives bit-identical output on one machine.
This module imports numba: import it only where an adjustment runs.
"""

from __future__ import annotations

import numpy as np

from slamcli.kernels import load_numba

numba = load_numba()

HUBER, CAUCHY = 0, 1
# A point nearer a camera's plane than this, or behind it, has no residual there (COLMAP's
# cost: its projection returns zero for such a point).
_Z_MIN = float(np.finfo(np.float64).eps)


@numba.njit(cache=True, nogil=True, inline="always")
def _loss(s: float, kind: int, a2: float) -> tuple[float, float]:
    """Ceres' robust loss ``rho(s)`` of a squared norm ``s``, and its derivative."""
    if kind == CAUCHY:
        return a2 * np.log1p(s / a2), 1.0 / (1.0 + s / a2)
    if s <= a2:
        return s, 1.0
    root = np.sqrt(s)
    a = np.sqrt(a2)
    return 2.0 * a * root - a2, a / root


@numba.njit(cache=True, nogil=True, inline="always")
def _camera_point(
    rot: np.ndarray, trans: np.ndarray, pts: np.ndarray, k: int, j: int, shift: float
) -> tuple[float, float, float]:
    """Point ``j`` in camera ``k``'s frame, moved by ``-shift`` along x (a right camera)."""
    x = rot[k, 0, 0] * pts[j, 0] + rot[k, 0, 1] * pts[j, 1] + rot[k, 0, 2] * pts[j, 2]
    y = rot[k, 1, 0] * pts[j, 0] + rot[k, 1, 1] * pts[j, 1] + rot[k, 1, 2] * pts[j, 2]
    z = rot[k, 2, 0] * pts[j, 0] + rot[k, 2, 1] * pts[j, 1] + rot[k, 2, 2] * pts[j, 2]
    return x + trans[k, 0] - shift, y + trans[k, 1], z + trans[k, 2]


@numba.njit(cache=True, nogil=True)
def total_cost(
    rot: np.ndarray,
    trans: np.ndarray,
    pts: np.ndarray,
    intr: np.ndarray,
    of: np.ndarray,
    op: np.ndarray,
    uv: np.ndarray,
    inv_sig: np.ndarray,
    shift: np.ndarray,
    kind: int,
    a2: float,
) -> float:
    """``0.5 * sum(rho(s))`` over the observations (``intr`` = fx, fy, cx, cy)."""
    fx, fy, cx, cy = intr[0], intr[1], intr[2], intr[3]
    cost = 0.0
    for m in range(of.size):
        x, y, z = _camera_point(rot, trans, pts, of[m], op[m], shift[m])
        if z < _Z_MIN:
            continue
        ex = (fx * x / z + cx - uv[m, 0]) * inv_sig[m]
        ey = (fy * y / z + cy - uv[m, 1]) * inv_sig[m]
        r, _ = _loss(ex * ex + ey * ey, kind, a2)
        cost += r
    return 0.5 * cost


@numba.njit(cache=True, nogil=True)
def _linearise(
    rot: np.ndarray,
    trans: np.ndarray,
    pts: np.ndarray,
    intr: np.ndarray,
    obs: tuple,
    groups: tuple,
    frame_par: np.ndarray,
    point_par: np.ndarray,
    kind: int,
    a2: float,
    n_cam: int,
    n_pt: int,
) -> tuple:
    """The weighted normal equations at the current estimate.

    Returns ``(U, gc, V, gp, W)``: the (6F, 6F) camera block (its point couplings not yet
    eliminated), the cameras' gradient, the (Q, 3, 3) point blocks and their gradient, and
    the (G, 6, 3) camera-point block of each (point, frame) group of observations.
    """
    _, op, uv, inv_sig, shift = obs
    g_start, g_frame = groups
    fx, fy, cx, cy = intr[0], intr[1], intr[2], intr[3]
    u_cc = np.zeros((6 * n_cam, 6 * n_cam))
    gc = np.zeros(6 * n_cam)
    v_pp = np.zeros((n_pt, 3, 3))
    gp = np.zeros((n_pt, 3))
    w_cp = np.zeros((g_frame.size, 6, 3))
    jc = np.zeros((2, 6))
    jp = np.zeros((2, 3))
    for g in range(g_frame.size):
        k = g_frame[g]
        fc = frame_par[k]
        for m in range(g_start[g], g_start[g + 1]):
            j = op[m]
            fp = point_par[j]
            x, y, z = _camera_point(rot, trans, pts, k, j, shift[m])
            if z < _Z_MIN:
                continue
            iz = 1.0 / z
            isg = inv_sig[m]
            ex = (fx * x * iz + cx - uv[m, 0]) * isg
            ey = (fy * y * iz + cy - uv[m, 1]) * isg
            _, w = _loss(ex * ex + ey * ey, kind, a2)
            # d(whitened pixel) / d(point in the camera frame)
            a00 = fx * iz * isg
            a02 = -fx * x * iz * iz * isg
            a11 = fy * iz * isg
            a12 = -fy * y * iz * iz * isg
            # The world point turned into the camera (R X): a rotation step turns it alone.
            qx = x + shift[m] - trans[k, 0]
            qy = y - trans[k, 1]
            qz = z - trans[k, 2]
            if fc >= 0:
                # d p / d rho = I, d p / d phi = -[R X]x
                jc[0, 0], jc[0, 1], jc[0, 2] = a00, 0.0, a02
                jc[1, 0], jc[1, 1], jc[1, 2] = 0.0, a11, a12
                jc[0, 3] = a02 * qy
                jc[0, 4] = a00 * qz - a02 * qx
                jc[0, 5] = -a00 * qy
                jc[1, 3] = -a11 * qz + a12 * qy
                jc[1, 4] = -a12 * qx
                jc[1, 5] = a11 * qx
                base = 6 * fc
                for r in range(6):
                    gc[base + r] += w * (jc[0, r] * ex + jc[1, r] * ey)
                    for c in range(r, 6):
                        u_cc[base + r, base + c] += w * (jc[0, r] * jc[0, c] + jc[1, r] * jc[1, c])
            if fp >= 0:
                for c in range(3):
                    jp[0, c] = a00 * rot[k, 0, c] + a02 * rot[k, 2, c]
                    jp[1, c] = a11 * rot[k, 1, c] + a12 * rot[k, 2, c]
                for r in range(3):
                    gp[fp, r] += w * (jp[0, r] * ex + jp[1, r] * ey)
                    for c in range(3):
                        v_pp[fp, r, c] += w * (jp[0, r] * jp[0, c] + jp[1, r] * jp[1, c])
                if fc >= 0:
                    for r in range(6):
                        for c in range(3):
                            w_cp[g, r, c] += w * (jc[0, r] * jp[0, c] + jc[1, r] * jp[1, c])
    for r in range(6 * n_cam):
        for c in range(r):
            u_cc[r, c] = u_cc[c, r]
    return u_cc, gc, v_pp, gp, w_cp


@numba.njit(cache=True, nogil=True, inline="always")
def _inv3(a: np.ndarray, out: np.ndarray) -> bool:
    """``out = inv(a)`` of a symmetric 3x3; False when it is singular."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    scale = abs(a[0, 0]) + abs(a[1, 1]) + abs(a[2, 2])
    if not (abs(det) > 1e-12 * scale * scale * scale):
        return False
    inv = 1.0 / det
    out[0, 0] = c00 * inv
    out[1, 0] = c01 * inv
    out[2, 0] = c02 * inv
    out[0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) * inv
    out[1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) * inv
    out[2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) * inv
    out[0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) * inv
    out[1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) * inv
    out[2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) * inv
    return True


@numba.njit(cache=True, nogil=True)
def _cholesky_solve(a: np.ndarray, b: np.ndarray) -> bool:
    """Solve ``a x = b`` in place (``b`` becomes ``x``; ``a`` its Cholesky factor) for a
    symmetric positive definite ``a``; False when it is not."""
    n = a.shape[0]
    for j in range(n):
        d = a[j, j]
        for k in range(j):
            d -= a[j, k] * a[j, k]
        if not (d > 0.0):
            return False
        d = np.sqrt(d)
        a[j, j] = d
        for i in range(j + 1, n):
            s = a[i, j]
            for k in range(j):
                s -= a[i, k] * a[j, k]
            a[i, j] = s / d
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= a[i, k] * b[k]
        b[i] = s / a[i, i]
    for i in range(n - 1, -1, -1):
        s = b[i]
        for k in range(i + 1, n):
            s -= a[k, i] * b[k]
        b[i] = s / a[i, i]
    return True


@numba.njit(cache=True, nogil=True, inline="always")
def _damping(h: float) -> float:
    """Ceres' damping of a parameter whose ``J^T J`` diagonal is ``h``: the diagonal of the
    Jacobi-scaled system (columns scaled by ``1 / (1 + |J_i|)``), clamped to [1e-6, 1e32],
    in the unscaled parameter."""
    col = 1.0 + np.sqrt(h)
    return min(max(h / (col * col), 1e-6), 1e32) * col * col


@numba.njit(cache=True, nogil=True)
def _step(
    u_cc: np.ndarray,
    gc: np.ndarray,
    v_pp: np.ndarray,
    gp: np.ndarray,
    w_cp: np.ndarray,
    g_frame: np.ndarray,
    point_groups: np.ndarray,
    frame_par: np.ndarray,
    lam: float,
) -> tuple:
    """The damped step ``(dc, dp)`` and the decrease the linear model predicts for it; ``ok``
    False when the damped system is not positive definite."""
    pg_start = point_groups
    n_c = gc.size
    n_pt = gp.shape[0]
    s = u_cc.copy()
    rhs = -gc
    diag_c = np.empty(n_c)
    for r in range(n_c):
        d = _damping(u_cc[r, r]) * lam
        diag_c[r] = d
        s[r, r] += d
    vinv = np.zeros((n_pt, 3, 3))
    diag_p = np.empty((n_pt, 3))
    vd = np.empty((3, 3))
    y = np.empty((6, 3))
    for q in range(n_pt):
        for r in range(3):
            for c in range(3):
                vd[r, c] = v_pp[q, r, c]
            d = _damping(v_pp[q, r, r]) * lam
            diag_p[q, r] = d
            vd[r, r] += d
        if not _inv3(vd, vinv[q]):
            return np.zeros(n_c), np.zeros((n_pt, 3)), 0.0, False
        for ga in range(pg_start[q], pg_start[q + 1]):
            fa = frame_par[g_frame[ga]]
            if fa < 0:
                continue
            for r in range(6):
                for c in range(3):
                    y[r, c] = (
                        w_cp[ga, r, 0] * vinv[q, 0, c]
                        + w_cp[ga, r, 1] * vinv[q, 1, c]
                        + w_cp[ga, r, 2] * vinv[q, 2, c]
                    )
            for r in range(6):
                rhs[6 * fa + r] += y[r, 0] * gp[q, 0] + y[r, 1] * gp[q, 1] + y[r, 2] * gp[q, 2]
            for gb in range(pg_start[q], pg_start[q + 1]):
                fb = frame_par[g_frame[gb]]
                if fb < 0:
                    continue
                for r in range(6):
                    for c in range(6):
                        s[6 * fa + r, 6 * fb + c] -= (
                            y[r, 0] * w_cp[gb, c, 0]
                            + y[r, 1] * w_cp[gb, c, 1]
                            + y[r, 2] * w_cp[gb, c, 2]
                        )
    dc = rhs
    if n_c and not _cholesky_solve(s, dc):
        return np.zeros(n_c), np.zeros((n_pt, 3)), 0.0, False
    dp = np.empty((n_pt, 3))
    b = np.empty(3)
    for q in range(n_pt):
        for r in range(3):
            b[r] = -gp[q, r]
        for ga in range(pg_start[q], pg_start[q + 1]):
            fa = frame_par[g_frame[ga]]
            if fa < 0:
                continue
            for c in range(3):
                for r in range(6):
                    b[c] -= w_cp[ga, r, c] * dc[6 * fa + r]
        for r in range(3):
            dp[q, r] = vinv[q, r, 0] * b[0] + vinv[q, r, 1] * b[1] + vinv[q, r, 2] * b[2]
    # Predicted decrease of 0.5 |f + J d|^2: -g.d - 0.5 d.H d = 0.5 (-g.d + d.D d).
    pred = 0.0
    for r in range(n_c):
        pred += -gc[r] * dc[r] + diag_c[r] * dc[r] * dc[r]
    for q in range(n_pt):
        for r in range(3):
            pred += -gp[q, r] * dp[q, r] + diag_p[q, r] * dp[q, r] * dp[q, r]
    return dc, dp, 0.5 * pred, True


@numba.njit(cache=True, nogil=True)
def _moved(
    rot: np.ndarray,
    trans: np.ndarray,
    pts: np.ndarray,
    dc: np.ndarray,
    dp: np.ndarray,
    cam_frames: np.ndarray,
    pt_ids: np.ndarray,
) -> tuple:
    """The estimate moved by a step, and the step's size against the parameters' size."""
    rot2 = rot.copy()
    trans2 = trans.copy()
    pts2 = pts.copy()
    step2 = 0.0
    size2 = 0.0
    e = np.empty((3, 3))
    for f in range(cam_frames.size):
        k = cam_frames[f]
        rx, ry, rz = dc[6 * f], dc[6 * f + 1], dc[6 * f + 2]
        px, py, pz = dc[6 * f + 3], dc[6 * f + 4], dc[6 * f + 5]
        step2 += rx * rx + ry * ry + rz * rz + px * px + py * py + pz * pz
        theta2 = px * px + py * py + pz * pz
        theta = np.sqrt(theta2)
        if theta < 1e-8:
            a, b = 1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0
        else:
            a, b = np.sin(theta) / theta, (1.0 - np.cos(theta)) / theta2
        # Rodrigues: I + a [p]x + b [p]x^2
        e[0, 0] = 1.0 - b * (py * py + pz * pz)
        e[1, 1] = 1.0 - b * (px * px + pz * pz)
        e[2, 2] = 1.0 - b * (px * px + py * py)
        e[0, 1] = -a * pz + b * px * py
        e[1, 0] = a * pz + b * px * py
        e[0, 2] = a * py + b * px * pz
        e[2, 0] = -a * py + b * px * pz
        e[1, 2] = -a * px + b * py * pz
        e[2, 1] = a * px + b * py * pz
        for r in range(3):
            for c in range(3):
                rot2[k, r, c] = (
                    e[r, 0] * rot[k, 0, c] + e[r, 1] * rot[k, 1, c] + e[r, 2] * rot[k, 2, c]
                )
        trans2[k, 0] += rx
        trans2[k, 1] += ry
        trans2[k, 2] += rz
        for r in range(3):
            size2 += trans[k, r] * trans[k, r]
    for q in range(pt_ids.size):
        j = pt_ids[q]
        for r in range(3):
            pts2[j, r] = pts[j, r] + dp[q, r]
            step2 += dp[q, r] * dp[q, r]
            size2 += pts[j, r] * pts[j, r]
    return rot2, trans2, pts2, np.sqrt(step2), np.sqrt(size2)


@numba.njit(cache=True, nogil=True)
def solve(
    rot: np.ndarray,
    trans: np.ndarray,
    pts: np.ndarray,
    intr: np.ndarray,
    obs: tuple,
    groups: tuple,
    point_groups: np.ndarray,
    frame_par: np.ndarray,
    point_par: np.ndarray,
    cam_frames: np.ndarray,
    pt_ids: np.ndarray,
    kind: int,
    a2: float,
    max_iterations: int,
    function_tolerance: float,
    parameter_tolerance: float,
) -> tuple:
    """Levenberg-Marquardt over the free poses and points (see the module docstring).

    Args:
        rot, trans, pts: (K, 3, 3), (K, 3) cam_from_world and (P, 3) points: the start.
        intr: fx, fy, cx, cy.
        obs: ``(frame, point, uv, 1 / sigma, shift)`` of each observation, ordered by point,
            then frame; ``shift`` the right camera's baseline, 0 for a left one.
        groups: ``(start, frame)``: the runs of observations of one point by one frame.
        point_groups: (Q + 1,) the runs of groups of each free point (in ``pt_ids`` order);
            the groups of points held fixed come after them.
        frame_par, point_par: (K,), (P,) parameter index of each frame and point, -1 if held.
        cam_frames, pt_ids: the frame of each camera parameter and the point of each point
            parameter.

    Returns:
        ``(rot, trans, pts, iterations, cost)`` at the end.
    """
    of, op, uv, inv_sig, shift = obs
    n_cam = cam_frames.size
    n_pt = pt_ids.size
    cost = total_cost(rot, trans, pts, intr, of, op, uv, inv_sig, shift, kind, a2)
    mu = 1e4
    nu = 2.0
    iterations = 0
    fresh = False
    u_cc, gc, v_pp, gp, w_cp = _linearise(
        rot, trans, pts, intr, obs, groups, frame_par, point_par, kind, a2, n_cam, n_pt
    )
    while iterations < max_iterations:
        if fresh:
            u_cc, gc, v_pp, gp, w_cp = _linearise(
                rot, trans, pts, intr, obs, groups, frame_par, point_par, kind, a2, n_cam, n_pt
            )
            fresh = False
        iterations += 1
        dc, dp, pred, ok = _step(
            u_cc, gc, v_pp, gp, w_cp, groups[1], point_groups, frame_par, 1.0 / mu
        )
        if not ok or not (pred > 0.0):
            mu /= nu
            nu *= 2.0
            continue
        rot2, trans2, pts2, step, size = _moved(rot, trans, pts, dc, dp, cam_frames, pt_ids)
        if step <= parameter_tolerance * (size + parameter_tolerance):
            iterations -= 1
            break
        new_cost = total_cost(rot2, trans2, pts2, intr, of, op, uv, inv_sig, shift, kind, a2)
        # As Ceres: a step that would change the cost by less than the tolerance ends the
        # solve, and is not taken.
        if abs(cost - new_cost) <= function_tolerance * cost:
            iterations -= 1
            break
        ratio = (cost - new_cost) / pred
        if ratio > 1e-3:
            rot, trans, pts, cost = rot2, trans2, pts2, new_cost
            fresh = True
            mu = mu / max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3)
            nu = 2.0
        else:
            mu /= nu
            nu *= 2.0
    return rot, trans, pts, iterations, cost
