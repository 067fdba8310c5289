"""The robot's path smoothed against the final map.

A filter's pose at time t uses only what was seen up to t: after a stretch without landmarks
the path is the dead-reckoned guess, and the landmarks of the first half of a run were less
well known when the robot used them than they are at the end. Offline, both can be fixed. With
the landmarks held at their final estimates (their covariances added to the measurement
noise), the robot pose alone is a Markov chain observed through the same odometry and
observations, so a forward localisation filter followed by a Rauch-Tung-Striebel backward pass
gives the smoothed path exactly for the linearised model. The observations are the ones the
SLAM filter accepted, paired with the landmarks it paired them with.

The landmarks are not changed, and the smoothed covariances treat the map as independent of
the path (the map was built from the same observations), so they are optimistic; the filter's
own covariances are the ones to judge consistency by.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slamcli.ekf.filter import arc_step, observe_jacobians, relative_motion
from slamcli.geometry.planar import wrap_angle

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Velocity:
    """(v, ω) held for ``dt`` seconds, with the control noise density (σv², σω²) per second."""

    dt: float
    v: float
    omega: float
    psd: tuple[float, float]


@dataclass(frozen=True)
class Step:
    """A relative pose (dx, dy, dθ) in the robot frame with its covariance."""

    delta: F64
    cov: F64


@dataclass(frozen=True)
class Observation:
    """A range-bearing observation of the landmark called ``ident``."""

    ident: int
    z: F64
    r_cov: F64


@dataclass(frozen=True)
class Row:
    """The path's row ``index`` ends here (one row per distinct stamp)."""

    index: int


Event = Velocity | Step | Observation | Row


def smooth_path(
    events: Sequence[Event],
    rows: int,
    start: F64,
    start_cov: F64,
    landmark: Callable[[int], tuple[F64, F64] | None],
    gate: float,
    with_cov: bool = False,
) -> tuple[F64, F64, int]:
    """Forward localisation against the final map, then the backward pass.

    Args:
        events: what the SLAM filter did, in order.
        rows: number of path rows.
        start, start_cov: the first pose and its covariance.
        landmark: final position and covariance of a landmark by its ident (None = dropped).
        gate: χ² threshold; observations beyond it (against the final map) are not used.
        with_cov: also smooth the covariances (else the filtered ones are returned).

    Returns:
        (rows, 3) smoothed poses, (rows, 3, 3) covariances, and the observations used.
    """
    # Per row: filtered and predicted pose and covariance terms, and the summed Jacobian terms.
    fr: list[tuple[float, ...]] = [()] * rows
    pr: list[tuple[float, ...]] = [()] * rows
    gr: list[list[float]] = [[0.0, 0.0] for _ in range(rows)]
    # The pose and its covariance as plain floats (x, y, θ; p00 p01 p02 p11 p12 p22): the
    # prediction runs once per odometry record, and small numpy arrays cost more than the maths.
    x, y, th = (float(v) for v in start)
    c = np.asarray(start_cov, dtype=np.float64)
    p00, p01, p02, p11, p12, p22 = c[0, 0], c[0, 1], c[0, 2], c[1, 1], c[1, 2], c[2, 2]
    pred = (x, y, th, p00, p01, p02, p11, p12, p22)
    # Motion Jacobians are [[1, 0, a], [0, 1, b], [0, 0, 1]]; their products add a and b.
    ga = gb = 0.0
    last = -1
    used = 0
    for ev in events:
        if isinstance(ev, Velocity):
            x, y, th, chord, phi, dl_dv, dl_dw = arc_step(x, y, th, ev.v, ev.omega, ev.dt)
            cs, sn = math.cos(phi), math.sin(phi)
            a, b = -chord * sn, chord * cs
            half = 0.5 * ev.dt
            j00, j01 = dl_dv * cs, dl_dw * cs - chord * sn * half
            j10, j11 = dl_dv * sn, dl_dw * sn + chord * cs * half
            m0, m1 = ev.psd[0] / ev.dt, ev.psd[1] / ev.dt
            r0, r1, r2 = p02 + a * p22, p12 + b * p22, p22
            p00, p01, p02, p11, p12 = (
                p00 + a * p02 + a * r0 + j00 * j00 * m0 + j01 * j01 * m1,
                p01 + a * p12 + b * r0 + j00 * j10 * m0 + j01 * j11 * m1,
                r0 + j01 * ev.dt * m1,
                p11 + b * p12 + b * r1 + j10 * j10 * m0 + j11 * j11 * m1,
                r1 + j11 * ev.dt * m1,
            )
            p22 = r2 + ev.dt * ev.dt * m1
            ga, gb = ga + a, gb + b
            pred = (x, y, th, p00, p01, p02, p11, p12, p22)
        elif isinstance(ev, Row):
            i = ev.index
            if i != last:
                pr[i] = pred
                gr[i] = [ga, gb]
            else:
                gr[i][0] += ga
                gr[i][1] += gb
            ga = gb = 0.0
            pred = (x, y, th, p00, p01, p02, p11, p12, p22)
            fr[i] = pred
            last = i
        elif isinstance(ev, Step):
            pose, g, jd = relative_motion(np.array([x, y, th]), ev.delta)
            pm = _matrix(p00, p01, p02, p11, p12, p22)
            pm = g @ pm @ g.T + jd @ ev.cov @ jd.T
            x, y, th = (float(v) for v in pose)
            p00, p01, p02, p11, p12, p22 = _terms(pm)
            ga, gb = ga + g[0, 2], gb + g[1, 2]
            pred = (x, y, th, p00, p01, p02, p11, p12, p22)
        else:
            lm = landmark(ev.ident)
            if lm is None:
                continue
            pose = np.array([x, y, th])
            pm = _matrix(p00, p01, p02, p11, p12, p22)
            zhat, hr, hl = observe_jacobians(pose, lm[0])
            r = hl @ lm[1] @ hl.T + ev.r_cov
            s = hr @ pm @ hr.T + r
            nu = np.array([ev.z[0] - zhat[0], wrap_angle(ev.z[1] - zhat[1])])
            if float(nu @ np.linalg.solve(s, nu)) >= gate:
                continue
            k = np.linalg.solve(s, hr @ pm).T
            pose = pose + k @ nu
            ikh = np.eye(3) - k @ hr
            pm = ikh @ pm @ ikh.T + k @ r @ k.T
            x, y, th = float(pose[0]), float(pose[1]), float(wrap_angle(pose[2]))
            p00, p01, p02, p11, p12, p22 = _terms(pm)
            used += 1
    xs, ps = rts(*_arrays(fr), *_arrays(pr), _jacobians(gr), with_cov=with_cov)
    return xs, ps, used


def _matrix(p00: float, p01: float, p02: float, p11: float, p12: float, p22: float) -> F64:
    return np.array([[p00, p01, p02], [p01, p11, p12], [p02, p12, p22]])


def _terms(m: F64) -> tuple[float, float, float, float, float, float]:
    return (
        float(m[0, 0]),
        float(m[0, 1]),
        float(m[0, 2]),
        float(m[1, 1]),
        float(m[1, 2]),
        float(m[2, 2]),
    )


def _arrays(rows: list[tuple[float, ...]]) -> tuple[F64, F64]:
    """(N, 3) poses and (N, 3, 3) covariances from rows of (x, y, θ, six covariance terms)."""
    a = np.asarray(rows, dtype=np.float64).reshape(-1, 9)
    cov = a[:, [3, 4, 5, 4, 6, 7, 5, 7, 8]].reshape(-1, 3, 3)
    return a[:, :3].copy(), cov


def _jacobians(terms: list[list[float]]) -> F64:
    g = np.tile(np.eye(3), (len(terms), 1, 1))
    t = np.asarray(terms, dtype=np.float64).reshape(-1, 2)
    g[:, 0, 2], g[:, 1, 2] = t[:, 0], t[:, 1]
    return g


def rts(
    filtered: F64,
    filtered_cov: F64,
    predicted: F64,
    predicted_cov: F64,
    motion: F64,
    with_cov: bool = True,
) -> tuple[F64, F64]:
    """Rauch-Tung-Striebel backward pass over (N, 3) poses: filtered and predicted means and
    covariances per row, and the motion Jacobian from the previous row. Without ``with_cov``
    the covariances returned are the filtered ones."""
    n = filtered.shape[0]
    xs = filtered.copy()
    ps = filtered_cov.copy()
    if n < 2:
        return xs, ps
    # Gains C_k = P_f(k) G(k+1)ᵀ P_p(k+1)⁻¹ for every row at once.
    pg = filtered_cov[:-1] @ np.transpose(motion[1:], (0, 2, 1))
    ppd = predicted_cov[1:] + 1e-12 * np.eye(3)
    gains = np.transpose(np.linalg.solve(ppd, np.transpose(pg, (0, 2, 1))), (0, 2, 1))
    gl = gains.tolist()
    fl = filtered.tolist()
    pl = predicted.tolist()
    out = [fl[-1]]
    nxt = fl[-1]
    for k in range(n - 2, -1, -1):
        pk = pl[k + 1]
        d0, d1 = nxt[0] - pk[0], nxt[1] - pk[1]
        d2 = math.remainder(nxt[2] - pk[2], 2.0 * math.pi)
        c = gl[k]
        f = fl[k]
        nxt = [
            f[0] + c[0][0] * d0 + c[0][1] * d1 + c[0][2] * d2,
            f[1] + c[1][0] * d0 + c[1][1] * d1 + c[1][2] * d2,
            f[2] + c[2][0] * d0 + c[2][1] * d1 + c[2][2] * d2,
        ]
        out.append(nxt)
        if with_cov:
            cm = gains[k]
            ps[k] = filtered_cov[k] + cm @ (ps[k + 1] - predicted_cov[k + 1]) @ cm.T
    xs = np.array(out[::-1])
    xs[:, 2] = wrap_angle(xs[:, 2])
    return xs, 0.5 * (ps + np.transpose(ps, (0, 2, 1)))
