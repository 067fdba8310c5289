"""The EKF-SLAM filter: a planar robot pose and point landmarks in one Gaussian.

State ``[x, y, θ, l1x, l1y, l2x, l2y, ...]`` (metres, radians) with a dense covariance ``P``.
Landmarks are static: prediction touches only the robot's rows and columns, and every
measurement update is computed from the columns of the robot and of the one landmark observed.

**Motion from velocities** (v, ω) held for ``dt`` seconds moves the robot along the exact arc,
written in its chord form so the straight line (ω = 0) is the same formula's limit, not a
separate branch::

    a = ω dt / 2,  L = v dt sin(a) / a,  φ = θ + a
    x' = x + L cos φ,  y' = y + L sin φ,  θ' = θ + ω dt

Control noise is white with the given spectral densities: the control's covariance over an
interval is ``diag(σv², σω²) / dt``, mapped into the state through the Jacobian ``V`` of the
motion with respect to (v, ω), so the pose uncertainty grows with time and not with how often
odometry is sampled. **Motion from relative poses** (dx, dy, dθ in the robot frame, e.g. from
an odometry pose topic) composes the increment, its covariance mapped through the Jacobian of
the composition with respect to the increment.

**Measurements** are range and bearing (counter-clockwise from the heading) to one landmark::

    r = |l - p|,  b = atan2(ly - y, lx - x) - θ

with the bearing innovation wrapped to [-π, π). The update uses the Joseph form
``P' = (I - KH) P (I - KH)ᵀ + K R Kᵀ``, expanded for a sparse ``H``:
``P' = P - K Aᵀ - A Kᵀ + K S Kᵀ`` with ``A = P Hᵀ``; it holds for any gain, keeps ``P``
symmetric and costs three rank-two corrections of ``P`` and O(n) work to build them.
Gains come from ``solve``; no matrix is inverted.

**New landmarks** are placed at ``p + r (cos(θ + b), sin(θ + b))``; their covariance and their
cross-covariances with the whole state are propagated through the Jacobians of that function
with respect to the robot pose and the measurement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry.planar import sin_ratio, unicycle_step, wrap_angle

F64 = NDArray[np.float64]

_ROBOT = 3


def arc_step(
    x: float, y: float, th: float, v: float, omega: float, dt: float
) -> tuple[float, float, float, float, float, float, float]:
    """The exact arc of :func:`~slamcli.geometry.planar.unicycle_step` in plain floats: new
    (x, y, θ) with θ wrapped, then what the Jacobians need: the chord length L, the chord's
    heading φ, ∂L/∂v and ∂L/∂ω (the hot path of prediction: no array is built here)."""
    nx, ny, nth = unicycle_step(x, y, th, v, omega, dt)
    a = 0.5 * omega * dt
    s = float(sin_ratio(a))
    # The closed form of d(sin a / a)/da cancels to nothing near 0; its series is exact to
    # double precision there.
    ds = -a / 3.0 if abs(a) < 1e-4 else (a * math.cos(a) - math.sin(a)) / (a * a)
    return (
        float(nx),
        float(ny),
        math.remainder(float(nth), 2.0 * math.pi),
        v * dt * s,
        th + a,
        dt * s,
        v * dt * ds * 0.5 * dt,
    )


def arc_motion(pose: F64, v: float, omega: float, dt: float) -> tuple[F64, F64, F64]:
    """The pose after (v, ω) for ``dt`` seconds, its Jacobian G (3x3) on the pose and V (3x2) on
    the controls."""
    nx, ny, nth, chord, phi, dl_dv, dl_dw = arc_step(
        float(pose[0]), float(pose[1]), float(pose[2]), v, omega, dt
    )
    c, sn = math.cos(phi), math.sin(phi)
    g = np.array([[1.0, 0.0, -chord * sn], [0.0, 1.0, chord * c], [0.0, 0.0, 1.0]])
    jv = np.array(
        [
            [dl_dv * c, dl_dw * c - chord * sn * 0.5 * dt],
            [dl_dv * sn, dl_dw * sn + chord * c * 0.5 * dt],
            [0.0, dt],
        ]
    )
    return np.array([nx, ny, nth]), g, jv


def relative_motion(pose: F64, delta: F64) -> tuple[F64, F64, F64]:
    """``pose ⊕ delta`` with its Jacobians on the pose (3x3) and on the increment (3x3)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    dx, dy = float(delta[0]), float(delta[1])
    new = np.array(
        [pose[0] + c * dx - s * dy, pose[1] + s * dx + c * dy, wrap_angle(pose[2] + delta[2])]
    )
    g = np.eye(3)
    g[0, 2] = -s * dx - c * dy
    g[1, 2] = c * dx - s * dy
    jd = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return new, g, jd


def observe_jacobians(pose: F64, landmark: F64) -> tuple[F64, F64, F64]:
    """Predicted (range, bearing) of a landmark and the Jacobians on the pose (2x3) and on the
    landmark (2x2)."""
    dx, dy = landmark[0] - pose[0], landmark[1] - pose[1]
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    z = np.array([r, wrap_angle(np.arctan2(dy, dx) - pose[2])])
    hl = np.array([[dx / r, dy / r], [-dy / q, dx / q]])
    hr = np.hstack([-hl, np.array([[0.0], [-1.0]])])
    return z, hr, hl


def inverse_observation(pose: F64, z: F64) -> tuple[F64, F64, F64]:
    """A landmark position from a (range, bearing) and the Jacobians on the pose (2x3) and on
    the measurement (2x2)."""
    r, b = float(z[0]), float(z[1])
    ang = pose[2] + b
    c, s = np.cos(ang), np.sin(ang)
    lm = np.array([pose[0] + r * c, pose[1] + r * s])
    gr = np.array([[1.0, 0.0, -r * s], [0.0, 1.0, r * c]])
    gz = np.array([[c, -r * s], [s, r * c]])
    return lm, gr, gz


def joseph_correction(p: F64, k: F64, a: F64, s: F64) -> None:
    """The Joseph-form update for a sparse H in place: ``P - K Aᵀ - A Kᵀ + K S Kᵀ`` with
    ``A = P Hᵀ`` and ``S = H P Hᵀ + R``, as one rank-four correction."""
    u = np.hstack([k, a])
    c = np.zeros((4, 4))
    c[:2, :2] = s
    c[:2, 2:] = -np.eye(2)
    c[2:, :2] = -np.eye(2)
    _add_low_rank(p, u @ c, u)


def _add_low_rank(p: F64, w: F64, u: F64, rows: int = 256) -> None:
    """``p += w uᵀ`` in place, a band of rows at a time: no n x n temporary."""
    ut = np.ascontiguousarray(u.T)
    for r0 in range(0, p.shape[0], rows):
        p[r0 : r0 + rows] += w[r0 : r0 + rows] @ ut


@dataclass(frozen=True)
class Innovation:
    """A measurement's innovation for one landmark slot, before any update.

    Attributes:
        slot: the landmark's slot in the state.
        nu: (2,) innovation (range m, bearing rad wrapped).
        S: (2, 2) innovation covariance (robot, landmark and cross terms, plus R).
        H: (2, 5) Jacobian on (x, y, θ, lx, ly).
        d2: squared Mahalanobis distance νᵀ S⁻¹ ν.
    """

    slot: int
    nu: F64
    S: F64
    H: F64
    d2: float


class LandmarkEkf:
    """The filter's state and its operations; landmarks live in slots 0..n-1.

    The arrays are allocated with spare room and grow by doubling, so adding a landmark costs
    O(n) amortised (its covariance row) rather than a copy of ``P``.
    """

    def __init__(
        self, pose: F64, pose_cov: F64, capacity: int = 32, first_estimates: bool = False
    ) -> None:
        size = _ROBOT + 2 * max(capacity, 1)
        self._x = np.zeros(size)
        self._p = np.zeros((size, size))
        self.first_estimates = first_estimates
        # First-estimates Jacobians: each landmark's first position, and the robot position as
        # last predicted (before the updates of its time step).
        self._first = np.zeros((max(capacity, 1), 2))
        self._prior_xy = np.asarray(pose, dtype=np.float64)[:2].copy()
        self._x[:3] = pose
        self._x[2] = wrap_angle(self._x[2])
        self._p[:3, :3] = pose_cov
        self.count = 0
        # Product of the motion Jacobians not yet applied to the robot-landmark cross terms:
        # a run of predictions costs O(1) each, and the O(n) product is paid once before the
        # cross terms are next read.
        self._pending_g: F64 | None = None

    # -- views ------------------------------------------------------------------------------

    @property
    def dim(self) -> int:
        return _ROBOT + 2 * self.count

    @property
    def x(self) -> F64:
        """The state vector (a view)."""
        return self._x[: self.dim]

    @property
    def P(self) -> F64:
        """The covariance (a view)."""
        self._settle()
        n = self.dim
        return self._p[:n, :n]

    @property
    def pose(self) -> F64:
        return self._x[:3]

    @property
    def pose_cov(self) -> F64:
        return self._p[:3, :3]

    def landmark(self, slot: int) -> F64:
        i = _ROBOT + 2 * slot
        return self._x[i : i + 2]

    def landmark_cov(self, slot: int) -> F64:
        i = _ROBOT + 2 * slot
        return self._p[i : i + 2, i : i + 2]

    def landmarks(self) -> F64:
        """(n, 2) landmark positions (a copy)."""
        return self._x[_ROBOT : self.dim].reshape(-1, 2).copy()

    def landmark_covs(self) -> F64:
        """(n, 2, 2) landmark covariances (a copy)."""
        idx = _ROBOT + 2 * np.arange(self.count)
        p = self._p
        out = np.empty((self.count, 2, 2))
        out[:, 0, 0] = p[idx, idx]
        out[:, 0, 1] = p[idx, idx + 1]
        out[:, 1, 0] = p[idx + 1, idx]
        out[:, 1, 1] = p[idx + 1, idx + 1]
        return out

    # -- prediction -------------------------------------------------------------------------

    def predict_velocity(self, v: float, omega: float, dt: float, control_psd: F64) -> None:
        """Move the robot by (v, ω) for ``dt`` s; ``control_psd`` = (σv², σω²) per second."""
        if dt <= 0.0:
            return
        new, g, jv = arc_motion(self.pose, v, omega, dt)
        q = (jv * (np.asarray(control_psd) / dt)) @ jv.T
        self._propagate(new, g, q)

    def predict_relative(self, delta: F64, delta_cov: F64) -> None:
        """Move the robot by a relative pose (dx, dy, dθ) with covariance ``delta_cov``."""
        new, g, jd = relative_motion(self.pose, np.asarray(delta, dtype=np.float64))
        self._propagate(new, g, jd @ delta_cov @ jd.T)

    def inflate_pose(self, extra_cov: F64) -> None:
        """Add covariance to the robot pose alone (e.g. a heading noise floor)."""
        self._p[:3, :3] += extra_cov

    def _propagate(self, new: F64, g: F64, q: F64) -> None:
        p = self._p
        if self.first_estimates:
            # The Jacobian's position offset runs from the previous *predicted* position, so the
            # update's correction is not differentiated through (Huang et al. 2010).
            g = g.copy()
            g[0, 2] = -(new[1] - self._prior_xy[1])
            g[1, 2] = new[0] - self._prior_xy[0]
            self._prior_xy = np.asarray(new[:2], dtype=np.float64).copy()
        self._x[:3] = new
        p[:3, :3] = g @ p[:3, :3] @ g.T + q
        if self.count:
            self._pending_g = g if self._pending_g is None else g @ self._pending_g

    def _settle(self) -> None:
        """Apply the pending motion Jacobians to the robot-landmark cross-covariances."""
        g = self._pending_g
        if g is None:
            return
        self._pending_g = None
        n = self.dim
        p = self._p
        cross = g @ p[:3, _ROBOT:n]
        p[:3, _ROBOT:n] = cross
        p[_ROBOT:n, :3] = cross.T

    # -- measurements -----------------------------------------------------------------------

    def predicted(self, slot: int) -> tuple[F64, F64]:
        """Predicted (range, bearing) of a landmark and the (2, 5) Jacobian on (x, y, θ, lx, ly),
        at the current estimate or, with first estimates, at the landmark's first position and
        the robot's predicted position."""
        i = _ROBOT + 2 * slot
        zhat, hr, hl = observe_jacobians(self.pose, self._x[i : i + 2])
        if self.first_estimates:
            _, hr, hl = observe_jacobians(
                np.array([self._prior_xy[0], self._prior_xy[1], self._x[2]]), self._first[slot]
            )
        return zhat, np.hstack([hr, hl])

    def innovation(self, slot: int, z: F64, r_cov: F64) -> Innovation:
        """The innovation of measurement ``z`` = (range, bearing) of the landmark in ``slot``."""
        self._settle()
        i = _ROBOT + 2 * slot
        zhat, h = self.predicted(slot)
        idx = np.array([0, 1, 2, i, i + 1])
        block = self._p[np.ix_(idx, idx)]
        s = h @ block @ h.T + r_cov
        s = 0.5 * (s + s.T)
        nu = np.array([z[0] - zhat[0], wrap_angle(z[1] - zhat[1])])
        d2 = float(nu @ np.linalg.solve(s, nu))
        return Innovation(slot, nu, s, h, d2)

    def innovations_all(self, z: F64, r_cov: F64) -> tuple[F64, F64, F64]:
        """Innovations of ``z`` against every landmark at once, vectorised.

        Returns (n, 2) innovations, (n, 2, 2) innovation covariances with the full robot,
        landmark and cross terms, and (n,) squared Mahalanobis distances.
        """
        n = self.count
        if n == 0:
            return np.empty((0, 2)), np.empty((0, 2, 2)), np.empty(0)
        self._settle()
        pose = self.pose
        lm = self.landmarks()
        dx, dy = lm[:, 0] - pose[0], lm[:, 1] - pose[1]
        zr = np.sqrt(dx * dx + dy * dy)
        zb = np.arctan2(dy, dx) - pose[2]
        if self.first_estimates:
            first = self._first[:n]
            dx, dy = first[:, 0] - self._prior_xy[0], first[:, 1] - self._prior_xy[1]
        q = np.maximum(dx * dx + dy * dy, 1e-12)
        r = np.sqrt(q)
        hl = np.empty((n, 2, 2))
        hl[:, 0, 0], hl[:, 0, 1] = dx / r, dy / r
        hl[:, 1, 0], hl[:, 1, 1] = -dy / q, dx / q
        hr = np.zeros((n, 2, 3))
        hr[:, :, :2] = -hl
        hr[:, 1, 2] = -1.0
        p = self._p
        idx = _ROBOT + 2 * np.arange(n)
        prr = p[:3, :3]
        prl = np.stack([p[:3, idx], p[:3, idx + 1]], axis=2)  # (3, n, 2)
        prl = np.transpose(prl, (1, 0, 2))  # (n, 3, 2)
        pll = self.landmark_covs()
        cross = hr @ prl @ np.transpose(hl, (0, 2, 1))
        s = (
            hr @ prr @ np.transpose(hr, (0, 2, 1))
            + cross
            + np.transpose(cross, (0, 2, 1))
            + hl @ pll @ np.transpose(hl, (0, 2, 1))
            + r_cov
        )
        nu = np.stack([z[0] - zr, wrap_angle(z[1] - zb)], axis=1)
        d2 = np.einsum("ni,ni->n", nu, np.linalg.solve(s, nu[:, :, None])[:, :, 0])
        return nu, s, d2

    def update(self, inn: Innovation) -> None:
        """Apply one range-bearing update (Joseph form) from its innovation."""
        self._settle()
        n = self.dim
        i = _ROBOT + 2 * inn.slot
        p = self._p[:n, :n]
        # A = P Hᵀ from the five columns H touches: O(n).
        a = p[:, :3] @ inn.H[:, :3].T + p[:, i : i + 2] @ inn.H[:, 3:].T
        k = np.linalg.solve(inn.S, a.T).T
        dx = k @ inn.nu
        self._x[:n] += dx
        self._x[2] = wrap_angle(self._x[2])
        joseph_correction(p, k, a, inn.S)

    def update_iterated(self, inn: Innovation, z: F64, r_cov: F64, iterations: int) -> Innovation:
        """An iterated EKF update (Gauss-Newton on the measurement, Bell and Cathey 1993).

        The measurement is re-linearised at the updated robot and landmark estimate up to
        ``iterations`` times (until the step is below 1 mm and 0.01 deg), which matters when
        the heading is uncertain and the bearing model is far from linear over the
        uncertainty. Each iteration costs O(n); ``P`` is corrected once, with the last
        linearisation. Returns the innovation of that last linearisation.
        """
        self._settle()
        n = self.dim
        i = _ROBOT + 2 * inn.slot
        idx = np.array([0, 1, 2, i, i + 1])
        p = self._p[:n, :n]
        x0 = self._x[:n].copy()
        s0 = x0[idx]
        block = p[np.ix_(idx, idx)]
        si = s0.copy()
        last = inn
        dx = np.zeros(n)
        for _ in range(max(1, iterations)):
            zhat, hr, hl = observe_jacobians(si[:3], si[3:])
            h = np.hstack([hr, hl])
            s = h @ block @ h.T + r_cov
            s = 0.5 * (s + s.T)
            nu = np.array([z[0] - zhat[0], wrap_angle(z[1] - zhat[1])])
            diff = s0 - si
            diff[2] = wrap_angle(diff[2])
            resid = nu - h @ diff
            a = p[:, :3] @ h[:, :3].T + p[:, i : i + 2] @ h[:, 3:].T
            k = np.linalg.solve(s, a.T).T
            dx = k @ resid
            new = s0 + dx[idx]
            step = new - si
            step[2] = wrap_angle(step[2])
            si = new
            last = Innovation(inn.slot, nu, s, h, float(nu @ np.linalg.solve(s, nu)))
            if np.all(np.abs(step[:2]) < 1e-3) and abs(step[2]) < 1.7e-4:
                break
        self._x[:n] = x0 + dx
        self._x[2] = wrap_angle(self._x[2])
        joseph_correction(p, k, a, last.S)
        return last

    # -- map management ---------------------------------------------------------------------

    def add_landmark(self, z: F64, r_cov: F64) -> int:
        """Initialise a landmark from a measurement; returns its slot."""
        self._settle()
        n = self.dim
        if n + 2 > self._x.shape[0]:
            self._grow()
        lm, gr, gz = inverse_observation(self.pose, z)
        p = self._p
        j = n
        self._x[j : j + 2] = lm
        # Cross-covariances with the whole state through the pose Jacobian: O(n).
        cross = gr @ p[:3, :n]
        p[j : j + 2, :n] = cross
        p[:n, j : j + 2] = cross.T
        p[j : j + 2, j : j + 2] = gr @ p[:3, :3] @ gr.T + gz @ r_cov @ gz.T
        self._first[self.count] = lm
        self.count += 1
        return self.count - 1

    def merge_distance(self, a: int, b: int) -> float:
        """Squared Mahalanobis distance between two landmarks' positions (their difference
        under its covariance, cross terms included)."""
        self._settle()
        i, j = _ROBOT + 2 * a, _ROBOT + 2 * b
        p = self._p
        s = p[i : i + 2, i : i + 2] + p[j : j + 2, j : j + 2] - p[i : i + 2, j : j + 2]
        s = s - p[j : j + 2, i : i + 2]
        d = self._x[i : i + 2] - self._x[j : j + 2]
        return float(d @ np.linalg.solve(0.5 * (s + s.T) + 1e-12 * np.eye(2), d))

    def merge_landmarks(self, keep: int, drop: int) -> None:
        """Fuse landmark ``drop`` into ``keep`` (they are the same point) and delete ``drop``.

        The constraint ``l_keep - l_drop = 0`` is applied as a noise-free measurement, which
        moves both (and everything correlated with them) to their fused estimate; ``drop``
        then carries no information of its own and is marginalised out.
        """
        self._settle()
        n = self.dim
        i, j = _ROBOT + 2 * keep, _ROBOT + 2 * drop
        p = self._p[:n, :n]
        a = p[:, i : i + 2] - p[:, j : j + 2]
        s = a[i : i + 2] - a[j : j + 2]
        s = 0.5 * (s + s.T) + 1e-9 * np.eye(2)
        k = np.linalg.solve(s, a.T).T
        nu = -(self._x[i : i + 2] - self._x[j : j + 2])
        self._x[:n] += k @ nu
        self._x[2] = wrap_angle(self._x[2])
        joseph_correction(p, k, a, s)
        self.remove_landmark(drop)

    def remove_landmark(self, slot: int) -> None:
        """Delete a landmark (marginalise it out): the last slot moves into its place."""
        self._settle()
        last = self.count - 1
        n = self.dim
        i, j = _ROBOT + 2 * slot, _ROBOT + 2 * last
        p = self._p
        if slot != last:
            self._first[slot] = self._first[last]
            self._x[i : i + 2] = self._x[j : j + 2]
            p[i : i + 2, :n] = p[j : j + 2, :n]
            p[:n, i : i + 2] = p[:n, j : j + 2]
            p[i : i + 2, i : i + 2] = p[j : j + 2, j : j + 2]
        p[j : j + 2, :n] = 0.0
        p[:n, j : j + 2] = 0.0
        self._x[j : j + 2] = 0.0
        self.count -= 1

    def symmetrize(self) -> None:
        self._settle()
        n = self.dim
        p = self._p[:n, :n]
        p[...] = 0.5 * (p + p.T)

    def _grow(self) -> None:
        old = self._x.shape[0]
        new = _ROBOT + 2 * (2 * ((old - _ROBOT) // 2))
        x = np.zeros(new)
        p = np.zeros((new, new))
        x[:old] = self._x
        p[:old, :old] = self._p
        first = np.zeros(((new - _ROBOT) // 2, 2))
        first[: self._first.shape[0]] = self._first
        self._x, self._p, self._first = x, p, first
