"""The EKF-SLAM filter, data association and the ekf pipeline against independent references.

- motion and measurement models against textbook formulas and central finite differences;
- :class:`LandmarkEkf` (sparse Joseph form, lazy cross-covariance propagation, slot swapping)
  against a dense full-state textbook EKF written here;
- the first-estimates Jacobians against a dense first-estimates reference;
- filter consistency (NEES of the robot pose) by Monte Carlo on a seeded landmark world;
- nearest neighbour and JCBB on crafted cases, the joint distance against a dense computation;
- the association and start settings the ekf and graph pipelines share.
"""

from __future__ import annotations

import copy
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy import stats

from slamcli.ekf.association import (
    UNMATCHED,
    Candidates,
    agree_with_mean,
    jcbb,
    joint_distance,
    nearest_neighbour,
)
from slamcli.ekf.filter import (
    LandmarkEkf,
    arc_motion,
    arc_step,
    inverse_observation,
    observe_jacobians,
    relative_motion,
)
from slamcli.geometry.chi2 import chi2_quantile
from slamcli.geometry.planar import se3_to_planar
from slamcli.pipelines.ekf import EkfConfig, EkfSlam, LandmarkAssociation, LandmarkNoise
from slamcli.pipelines.graph import GraphConfig
from slamcli.types import LandmarkFrame, OdometryFrame

F64 = NDArray[np.float64]
PSD = np.array([0.02, 0.004])


def wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def fd_jacobian(f: Callable[[F64], F64], x0: F64, angles: tuple[int, ...] = (), eps: float = 1e-6):
    """Central finite differences; output components in ``angles`` are differenced wrapped."""
    x0 = np.asarray(x0, dtype=np.float64)
    cols = []
    for k in range(len(x0)):
        dx = np.zeros_like(x0)
        dx[k] = eps
        d = np.asarray(f(x0 + dx), dtype=np.float64) - np.asarray(f(x0 - dx), dtype=np.float64)
        for a in angles:
            d[a] = wrap(d[a])
        cols.append(d / (2.0 * eps))
    return np.stack(cols, axis=1)


def textbook_arc(pose: F64, v: float, w: float, dt: float) -> F64:
    x, y, th = (float(p) for p in pose)
    if w == 0.0:
        return np.array([x + v * dt * math.cos(th), y + v * dt * math.sin(th), wrap(th)])
    return np.array(
        [
            x + v / w * (math.sin(th + w * dt) - math.sin(th)),
            y - v / w * (math.cos(th + w * dt) - math.cos(th)),
            wrap(th + w * dt),
        ]
    )


def observe(pose: F64, lm: F64) -> F64:
    dx, dy = lm[0] - pose[0], lm[1] - pose[1]
    return np.array([math.hypot(dx, dy), wrap(math.atan2(dy, dx) - pose[2])])


# -- motion model -------------------------------------------------------------------------------

ARCS = [
    (1.0, 0.5, 0.1),
    (0.3, -1.2, 0.7),
    (2.0, 3.0, 1.5),
    (-0.5, 0.8, 0.4),
    (0.7, -6.0, 1.3),  # more than a full turn
]


@pytest.mark.parametrize(("v", "w", "dt"), ARCS)
def test_arc_motion_matches_textbook_exact_arc(v: float, w: float, dt: float) -> None:
    for pose in (np.array([1.0, -2.0, 0.7]), np.array([-3.0, 0.5, -2.9]), np.array([0, 0, 3.1])):
        new, _, _ = arc_motion(pose, v, w, dt)
        np.testing.assert_allclose(new, textbook_arc(pose, v, w, dt), atol=1e-12)
        assert -math.pi <= new[2] <= math.pi


def test_arc_motion_straight_line_and_continuity_at_tiny_turn_rates() -> None:
    pose = np.array([1.0, 2.0, 0.9])
    v, dt = 1.3, 0.8
    straight = textbook_arc(pose, v, 0.0, dt)
    np.testing.assert_allclose(arc_motion(pose, v, 0.0, dt)[0], straight, atol=1e-15)
    for w in (1e-9, -1e-9, 1e-6, -1e-6):
        new = arc_motion(pose, v, w, dt)[0]
        # The lateral offset of the arc is v dt · w dt / 2 to first order.
        assert np.max(np.abs(new - straight)) <= abs(v * dt * w * dt) + 1e-15
        # Textbook formula: cancellation costs ~1e-16/|w| relative, so compare loosely.
        np.testing.assert_allclose(new, textbook_arc(pose, v, w, dt), atol=1e-16 / abs(w) * 10)
    # Across the series/closed-form switch (|ω dt / 2| = 1e-4) the motion is continuous.
    w0 = 2e-4 / dt
    lo = arc_motion(pose, v, w0 * (1 - 1e-9), dt)
    hi = arc_motion(pose, v, w0 * (1 + 1e-9), dt)
    for a, b in zip(lo, hi, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-11)
    np.testing.assert_allclose(lo[0], textbook_arc(pose, v, w0, dt), atol=1e-10)


def test_arc_motion_wraps_heading() -> None:
    new = arc_motion(np.array([0.0, 0.0, 3.0]), 1.0, 1.0, 0.5)[0]
    assert new[2] == pytest.approx(3.5 - 2 * math.pi, abs=1e-12)
    new = arc_motion(np.array([0.0, 0.0, -3.0]), 1.0, -1.0, 0.5)[0]
    assert new[2] == pytest.approx(-3.5 + 2 * math.pi, abs=1e-12)
    th = arc_step(0.0, 0.0, 0.0, 1.0, 2.0, 10.0)[2]
    assert -math.pi <= th <= math.pi
    assert th == pytest.approx(wrap(20.0), abs=1e-12)


@pytest.mark.parametrize(("v", "w", "dt"), [*ARCS, (1.1, 0.0, 0.5), (0.9, 1e-7, 0.3)])
def test_arc_motion_jacobians_match_finite_differences(v: float, w: float, dt: float) -> None:
    pose = np.array([0.4, -1.1, 2.8])
    _, g, jv = arc_motion(pose, v, w, dt)
    g_fd = fd_jacobian(lambda p: arc_motion(p, v, w, dt)[0], pose, angles=(2,))
    jv_fd = fd_jacobian(lambda u: arc_motion(pose, u[0], u[1], dt)[0], np.array([v, w]), (2,))
    np.testing.assert_allclose(g, g_fd, atol=1e-6)
    np.testing.assert_allclose(jv, jv_fd, atol=1e-6)


@pytest.mark.parametrize("seed", range(10))
def test_relative_motion_and_its_jacobians(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pose = rng.uniform([-5, -5, -math.pi], [5, 5, math.pi])
    delta = rng.uniform([-1, -1, -2], [1, 1, 2])
    new, g, jd = relative_motion(pose, delta)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    expect = [
        pose[0] + c * delta[0] - s * delta[1],
        pose[1] + s * delta[0] + c * delta[1],
        wrap(pose[2] + delta[2]),
    ]
    np.testing.assert_allclose(new, expect, atol=1e-12)
    assert -math.pi <= new[2] < math.pi
    g_fd = fd_jacobian(lambda p: relative_motion(p, delta)[0], pose, (2,))
    jd_fd = fd_jacobian(lambda d: relative_motion(pose, d)[0], delta, (2,))
    np.testing.assert_allclose(g, g_fd, atol=1e-6)
    np.testing.assert_allclose(jd, jd_fd, atol=1e-6)


# -- measurement model --------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(20))
def test_observe_and_inverse_observation_jacobians_and_round_trip(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    pose = rng.uniform([-5, -5, -math.pi], [5, 5, math.pi])
    lm = pose[:2] + rng.uniform(-8, 8, 2)
    z, hr, hl = observe_jacobians(pose, lm)
    np.testing.assert_allclose(z, observe(pose, lm), atol=1e-12)
    hr_fd = fd_jacobian(lambda p: observe_jacobians(p, lm)[0], pose, (1,))
    hl_fd = fd_jacobian(lambda q: observe_jacobians(pose, q)[0], lm, (1,))
    np.testing.assert_allclose(hr, hr_fd, atol=1e-6)
    np.testing.assert_allclose(hl, hl_fd, atol=1e-6)
    back, gr, gz = inverse_observation(pose, z)
    np.testing.assert_allclose(back, lm, atol=1e-10)
    gr_fd = fd_jacobian(lambda p: inverse_observation(p, z)[0], pose)
    gz_fd = fd_jacobian(lambda zz: inverse_observation(pose, zz)[0], z)
    np.testing.assert_allclose(gr, gr_fd, atol=1e-6)
    np.testing.assert_allclose(gz, gz_fd, atol=1e-6)
    # And the other way round: observe(inverse(z)) = z.
    zz = np.array([rng.uniform(0.5, 10), rng.uniform(-math.pi, math.pi)])
    np.testing.assert_allclose(observe(pose, inverse_observation(pose, zz)[0]), zz, atol=1e-10)


def test_bearing_innovation_is_wrapped_near_pi() -> None:
    pose = np.array([1.0, 2.0, 0.3])
    ang = pose[2] - math.pi + 0.01  # landmark almost straight behind, predicted b = -π + 0.01
    ekf = LandmarkEkf(pose, np.diag([0.01, 0.01, 0.001]))
    r_cov = np.diag([0.01, 0.01])
    slot = ekf.add_landmark(np.array([5.0, wrap(ang - pose[2])]), r_cov)
    z = np.array([5.0, math.pi - 0.01])
    inn = ekf.innovation(slot, z, r_cov)
    assert inn.nu[1] == pytest.approx(-0.02, abs=1e-9)
    assert inn.nu[0] == pytest.approx(0.0, abs=1e-9)
    nu_all, _, _ = ekf.innovations_all(z, r_cov)
    assert nu_all[0, 1] == pytest.approx(-0.02, abs=1e-9)
    before = ekf.pose[2]
    copy.deepcopy(ekf).update(inn)
    it = copy.deepcopy(ekf).update_iterated(inn, z, r_cov, 3)
    assert it.nu[1] == pytest.approx(-0.02, abs=1e-9)
    ekf.update(inn)
    # A small correction of the heading, not a turn of ~2π.
    assert abs(wrap(ekf.pose[2] - before)) < 0.02


# -- a dense textbook reference -----------------------------------------------------------------


@dataclass
class DenseEkf:
    """Full-state EKF with dense matrices, written from the textbook."""

    x: F64
    P: F64
    fej: bool = False
    first: list[F64] = field(default_factory=list)
    prior_xy: F64 = field(default_factory=lambda: np.zeros(2))

    @classmethod
    def start(cls, pose: F64, cov: F64, fej: bool = False) -> DenseEkf:
        x = np.array(pose, dtype=np.float64)
        x[2] = wrap(x[2])
        return cls(x, np.array(cov, dtype=np.float64), fej, [], x[:2].copy())

    def _propagate(self, new: F64, g: F64, q: F64) -> None:
        n = len(self.x)
        if self.fej:
            g = g.copy()
            g[0, 2] = -(new[1] - self.prior_xy[1])
            g[1, 2] = new[0] - self.prior_xy[0]
            self.prior_xy = new[:2].copy()
        f = np.eye(n)
        f[:3, :3] = g
        qf = np.zeros((n, n))
        qf[:3, :3] = q
        self.x[:3] = new
        self.P = f @ self.P @ f.T + qf

    def predict_velocity(self, v: float, w: float, dt: float, psd: F64) -> None:
        new, g, jv = arc_motion(self.x[:3], v, w, dt)
        self._propagate(new, g, jv @ np.diag(psd / dt) @ jv.T)

    def predict_relative(self, delta: F64, cov: F64) -> None:
        new, g, jd = relative_motion(self.x[:3], delta)
        self._propagate(new, g, jd @ cov @ jd.T)

    def jacobian(self, slot: int) -> tuple[F64, F64]:
        n = len(self.x)
        i = 3 + 2 * slot
        zhat = observe(self.x[:3], self.x[i : i + 2])
        if self.fej:
            pose = np.array([self.prior_xy[0], self.prior_xy[1], self.x[2]])
            _, hr, hl = observe_jacobians(pose, self.first[slot])
        else:
            _, hr, hl = observe_jacobians(self.x[:3], self.x[i : i + 2])
        h = np.zeros((2, n))
        h[:, :3] = hr
        h[:, i : i + 2] = hl
        return zhat, h

    def innovation(self, slot: int, z: F64, r: F64) -> tuple[F64, F64, F64]:
        zhat, h = self.jacobian(slot)
        s = h @ self.P @ h.T + r
        nu = np.array([z[0] - zhat[0], wrap(z[1] - zhat[1])])
        return nu, s, h

    def update(self, slot: int, z: F64, r: F64) -> None:
        nu, s, h = self.innovation(slot, z, r)
        k = np.linalg.solve(s, h @ self.P).T  # P Hᵀ S⁻¹ (P and S symmetric)
        self.x = self.x + k @ nu
        self.x[2] = wrap(self.x[2])
        ikh = np.eye(len(self.x)) - k @ h
        self.P = ikh @ self.P @ ikh.T + k @ r @ k.T

    def add(self, z: F64, r: F64) -> int:
        n = len(self.x)
        lm, gr, gz = inverse_observation(self.x[:3], z)
        # Jacobian of (x, z) -> (x, g(pose, z)) applied to blockdiag(P, R).
        j = np.zeros((n + 2, n + 2))
        j[:n, :n] = np.eye(n)
        j[n:, :3] = gr
        j[n:, n:] = gz
        big = np.zeros((n + 2, n + 2))
        big[:n, :n] = self.P
        big[n:, n:] = r
        self.P = j @ big @ j.T
        self.x = np.concatenate([self.x, lm])
        self.first.append(lm.copy())
        return (n - 3) // 2

    def remove(self, slot: int) -> None:
        """Marginalise: delete the slot's rows and columns; the last slot takes its place."""
        count = (len(self.x) - 3) // 2
        order = list(range(count))
        if slot != count - 1:
            order[slot] = count - 1
        order.pop()
        idx = [0, 1, 2] + [k for s in order for k in (3 + 2 * s, 4 + 2 * s)]
        self.x = self.x[idx]
        self.P = self.P[np.ix_(idx, idx)]
        self.first = [self.first[s] for s in order]


R_COV = np.diag([0.05**2, math.radians(2.0) ** 2])
START = np.array([0.5, -0.3, 2.9])
START_COV = np.diag([0.02, 0.03, 0.01])


def scripted(
    ekf: LandmarkEkf, ref: DenseEkf, check_each: bool, rng: np.random.Generator
) -> list[str]:
    """Apply the same operations to both; returns the operations applied."""
    log: list[str] = []

    def meas(slot: int) -> F64:
        zhat = ekf.predicted(slot)[0]
        return np.array([zhat[0] + rng.normal(0, 0.1), wrap(zhat[1] + rng.normal(0, 0.05))])

    def compare() -> None:
        np.testing.assert_allclose(ekf.x, ref.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(ekf.P, ref.P, rtol=0, atol=1e-9)

    ops: list[tuple] = [
        ("vel", 0.5, 0.2, 0.3),
        ("add", np.array([4.0, 0.3])),
        ("add", np.array([3.0, -1.0])),
        ("add", np.array([6.0, math.pi - 0.02])),  # behind: bearings across ±π
        ("vel", 0.5, 0.2, 0.3),
        ("vel", 0.6, -0.4, 0.5),
        ("vel", 0.0, 0.8, 0.2),
        ("upd", 1),
        ("vel", 0.4, 0.1, 1.0),
        ("vel", 0.4, 0.0, 1.0),
        ("upd", 0),
        ("upd", 2),
        ("rel", np.array([0.3, 0.05, 0.2]), np.diag([1e-3, 2e-3, 5e-4])),
        ("rel", np.array([0.2, -0.1, -0.4]), np.diag([2e-3, 1e-3, 1e-3])),
        ("upd", 2),
        ("vel", 0.3, 0.3, 0.4),
        ("add", np.array([2.0, 0.8])),  # grows past the initial capacity
        ("add", np.array([5.0, -2.0])),  # and again
        ("vel", 0.3, 0.3, 0.4),
        ("upd", 4),
        ("upd", 3),
        ("vel", 0.2, -0.3, 0.4),
        ("vel", 0.5, 0.3, 0.6),
        ("upd", 0),
        ("vel", 0.5, 0.3, 0.6),
        ("remove", 1),  # middle slot, with cross terms pending
        ("vel", 0.5, 0.3, 0.6),
        ("upd", 1),
        ("remove", 3),  # the last slot
        ("vel", 0.5, -0.3, 0.6),
        ("upd", 2),
        ("vel", 0.5, -0.3, 0.6),
        ("vel", 0.5, -0.3, 0.6),
    ]
    for op in ops:
        kind = op[0]
        if kind == "vel":
            ekf.predict_velocity(op[1], op[2], op[3], PSD)
            ref.predict_velocity(op[1], op[2], op[3], PSD)
        elif kind == "rel":
            ekf.predict_relative(op[1], op[2])
            ref.predict_relative(op[1], op[2])
        elif kind == "add":
            assert ekf.add_landmark(op[1], R_COV) == ref.add(op[1], R_COV)
        elif kind == "upd":
            z = meas(op[1])
            ekf.update(ekf.innovation(op[1], z, R_COV))
            ref.update(op[1], z, R_COV)
        elif kind == "remove":
            ekf.remove_landmark(op[1])
            ref.remove(op[1])
        log.append(kind)
        if check_each:
            compare()
    compare()
    return log


@pytest.mark.parametrize("fej", [False, True])
@pytest.mark.parametrize("check_each", [False, True])
def test_landmark_ekf_equals_dense_reference(fej: bool, check_each: bool) -> None:
    ekf = LandmarkEkf(START, START_COV, capacity=2, first_estimates=fej)
    ref = DenseEkf.start(START, START_COV, fej=fej)
    scripted(ekf, ref, check_each, np.random.default_rng(11))
    assert ekf.count == 3
    p = ekf.P
    np.testing.assert_allclose(p, p.T, rtol=0, atol=1e-12)
    assert np.linalg.eigvalsh(p).min() > 0
    np.testing.assert_allclose(ekf.landmarks(), ref.x[3:].reshape(-1, 2), atol=1e-9)
    covs = ekf.landmark_covs()
    for s in range(ekf.count):
        np.testing.assert_allclose(covs[s], ref.P[3 + 2 * s : 5 + 2 * s, 3 + 2 * s : 5 + 2 * s])


def test_lazy_settle_pose_cov_is_current_without_reading_p() -> None:
    ekf = LandmarkEkf(START, START_COV, capacity=4)
    ref = DenseEkf.start(START, START_COV)
    for z in (np.array([3.0, 0.2]), np.array([4.0, -0.7])):
        ekf.add_landmark(z, R_COV)
        ref.add(z, R_COV)
    for _ in range(5):
        ekf.predict_velocity(0.4, 0.3, 0.25, PSD)
        ref.predict_velocity(0.4, 0.3, 0.25, PSD)
        # The robot block and the landmark blocks are current even while cross terms wait.
        np.testing.assert_allclose(ekf.pose_cov, ref.P[:3, :3], atol=1e-12)
        np.testing.assert_allclose(ekf.landmark_cov(1), ref.P[5:7, 5:7], atol=1e-12)
    np.testing.assert_allclose(ekf.P, ref.P, atol=1e-12)


def test_innovations_all_equals_innovation_per_slot() -> None:
    for fej in (False, True):
        ekf = LandmarkEkf(START, START_COV, capacity=2, first_estimates=fej)
        ref = DenseEkf.start(START, START_COV, fej=fej)
        scripted(ekf, ref, False, np.random.default_rng(5))
        ekf.predict_velocity(0.5, 0.2, 0.4, PSD)  # leave cross terms pending
        ref.predict_velocity(0.5, 0.2, 0.4, PSD)
        for z in (np.array([3.0, 0.5]), np.array([7.0, -3.1]), np.array([2.0, 3.1])):
            nu, s, d2 = ekf.innovations_all(z, R_COV)
            assert nu.shape == (ekf.count, 2)
            for slot in range(ekf.count):
                inn = ekf.innovation(slot, z, R_COV)
                np.testing.assert_allclose(nu[slot], inn.nu, atol=1e-12)
                np.testing.assert_allclose(s[slot], inn.S, rtol=1e-10, atol=1e-14)
                assert d2[slot] == pytest.approx(inn.d2, rel=1e-9)
                rnu, rs, _ = ref.innovation(slot, z, R_COV)
                np.testing.assert_allclose(inn.nu, rnu, atol=1e-9)
                np.testing.assert_allclose(inn.S, rs, atol=1e-9)


def test_remove_every_slot_matches_marginalisation() -> None:
    for slot in range(4):
        ekf = LandmarkEkf(START, START_COV, capacity=8)
        ref = DenseEkf.start(START, START_COV)
        for z in ([3.0, 0.2], [4.0, -0.7], [5.0, 1.5], [2.5, -2.5]):
            ekf.add_landmark(np.array(z), R_COV)
            ref.add(np.array(z), R_COV)
        ekf.update(ekf.innovation(0, np.array([3.1, 0.25]), R_COV))
        ref.update(0, np.array([3.1, 0.25]), R_COV)
        ekf.predict_velocity(0.5, 0.1, 1.0, PSD)
        ref.predict_velocity(0.5, 0.1, 1.0, PSD)
        ekf.remove_landmark(slot)
        ref.remove(slot)
        np.testing.assert_allclose(ekf.x, ref.x, atol=1e-12)
        np.testing.assert_allclose(ekf.P, ref.P, atol=1e-12)
        # The freed slot leaves nothing behind: a new landmark there is initialised afresh.
        ekf.add_landmark(np.array([3.3, 0.4]), R_COV)
        ref.add(np.array([3.3, 0.4]), R_COV)
        np.testing.assert_allclose(ekf.P, ref.P, atol=1e-12)


def test_update_iterated_with_one_iteration_equals_update() -> None:
    ekf = LandmarkEkf(START, START_COV, capacity=2)
    scripted(ekf, DenseEkf.start(START, START_COV), False, np.random.default_rng(8))
    ekf.predict_velocity(0.5, 0.2, 0.4, PSD)
    z = np.array([4.0, 0.4])
    a, b = copy.deepcopy(ekf), copy.deepcopy(ekf)
    inn = a.innovation(1, z, R_COV)
    a.update(inn)
    last = b.update_iterated(b.innovation(1, z, R_COV), z, R_COV, 1)
    np.testing.assert_allclose(b.x, a.x, atol=1e-12)
    np.testing.assert_allclose(b.P, a.P, atol=1e-12)
    assert last.d2 == pytest.approx(inn.d2, rel=1e-12)


def _map_cost(x: F64, x0: F64, p0: F64, z: F64, r: F64) -> tuple[float, float]:
    """The MAP cost of the update on (x, y, θ, lx, ly) and its measurement part."""
    d = x - x0
    d[2] = wrap(d[2])
    res = z - observe(x[:3], x[3:5])
    res[1] = wrap(res[1])
    meas = float(res @ np.linalg.solve(r, res))
    return float(d @ np.linalg.solve(p0, d)) + meas, meas


def test_update_iterated_reduces_residual_when_heading_is_uncertain() -> None:
    # A well-known landmark 5 m ahead; the robot then drives 4 m with a very uncertain heading,
    # so its position uncertainty is a banana and range/bearing are far from linear over it.
    ekf = LandmarkEkf(np.zeros(3), np.diag([1e-6, 1e-6, 1e-6]))
    r_cov = np.diag([0.02**2, math.radians(1.0) ** 2])
    ekf.add_landmark(np.array([8.0, 0.5]), np.diag([1e-6, 1e-6]))
    ekf.inflate_pose(np.diag([0.0, 0.0, 0.6**2]))
    ekf.predict_velocity(1.0, 0.0, 4.0, np.array([1e-3, 1e-5]))
    true_pose = arc_motion(np.array([0.0, 0.0, 0.7]), 1.0, 0.0, 4.0)[0]
    lm = ekf.landmark(0).copy()
    z = observe(true_pose, lm)
    x0, p0 = ekf.x.copy(), ekf.P.copy()
    plain, iterated = copy.deepcopy(ekf), copy.deepcopy(ekf)
    plain.update(plain.innovation(0, z, r_cov))
    last = iterated.update_iterated(iterated.innovation(0, z, r_cov), z, r_cov, 10)
    cost_plain, meas_plain = _map_cost(plain.x.copy(), x0, p0, z, r_cov)
    cost_iter, meas_iter = _map_cost(iterated.x.copy(), x0, p0, z, r_cov)
    # Gauss-Newton on the MAP cost: a much lower cost and a much smaller measurement residual.
    assert cost_iter < 0.5 * cost_plain
    assert meas_iter < 0.1 * meas_plain
    # And closer to the truth.
    err_plain = np.hypot(*(plain.pose[:2] - true_pose[:2]))
    err_iter = np.hypot(*(iterated.pose[:2] - true_pose[:2]))
    assert err_iter < err_plain
    # The returned innovation is that of the last linearisation, not of the prior.
    assert not np.allclose(last.H, plain.innovation(0, z, r_cov).H, atol=1e-3)
    p = iterated.P
    np.testing.assert_allclose(p, p.T, atol=1e-12)
    assert np.linalg.eigvalsh(p).min() > 0


# -- first-estimates Jacobians ------------------------------------------------------------------


def test_first_estimates_measurement_jacobian_stays_at_first_position() -> None:
    ekf = LandmarkEkf(np.array([0.0, 0.0, 0.1]), np.diag([0.01, 0.01, 0.01]), first_estimates=True)
    slot = ekf.add_landmark(np.array([4.0, 0.3]), np.diag([0.3**2, 0.1**2]))
    first = ekf.landmark(slot).copy()
    zhat0, h0 = ekf.predicted(slot)
    inn = ekf.innovation(slot, np.array([4.6, 0.5]), np.diag([0.01, 0.001]))
    ekf.update(inn)
    moved = ekf.landmark(slot).copy()
    assert np.hypot(*(moved - first)) > 0.1
    zhat1, h1 = ekf.predicted(slot)
    assert abs(zhat1[0] - zhat0[0]) > 0.05  # the prediction follows the estimate...
    np.testing.assert_array_equal(h1, h0)  # ...the Jacobian does not
    _, hr, hl = observe_jacobians(np.array([0.0, 0.0, 0.0]), first)
    np.testing.assert_allclose(h1, np.hstack([hr, hl]), atol=1e-15)
    # The standard filter's Jacobian moves with the estimate.
    std_hr, std_hl = observe_jacobians(ekf.pose, moved)[1:]
    assert not np.allclose(np.hstack([std_hr, std_hl]), h0, atol=1e-3)


def test_first_estimates_prediction_uses_previous_predicted_position() -> None:
    pose0 = np.array([0.0, 0.0, 0.2])
    cov0 = np.diag([0.01, 0.01, 0.02])
    ekf = LandmarkEkf(pose0, cov0, first_estimates=True)
    ref = DenseEkf.start(pose0, cov0, fej=True)
    std = DenseEkf.start(pose0, cov0, fej=False)
    z0 = np.array([4.0, 0.3])
    for f in (ekf.add_landmark, ref.add, std.add):
        f(z0, R_COV)
    for e in (ekf, ref, std):
        e.predict_velocity(1.0, 0.3, 1.0, PSD)
    predicted_xy = ekf.pose[:2].copy()
    z = np.array([3.2, 0.6])
    ekf.update(ekf.innovation(0, z, R_COV))
    ref.update(0, z, R_COV)
    std.update(0, z, R_COV)
    updated_xy = ekf.pose[:2].copy()
    assert np.hypot(*(updated_xy - predicted_xy)) > 0.02
    for e in (ekf, ref, std):
        e.predict_velocity(1.0, 0.3, 1.0, PSD)
    # The Jacobian's position offset runs from the previous *predicted* position.
    new = ekf.pose
    g = np.eye(3)
    g[0, 2] = -(new[1] - predicted_xy[1])
    g[1, 2] = new[0] - predicted_xy[0]
    p = ekf.P
    np.testing.assert_allclose(p, ref.P, atol=1e-12)
    # Robot-landmark cross terms (they carry the prediction Jacobian) differ from the standard.
    assert not np.allclose(p[:3, 3:], std.P[:3, 3:], atol=1e-4)
    # Spelled out: cross' = G_fej cross_after_update.
    ekf2 = LandmarkEkf(pose0, cov0, first_estimates=True)
    ekf2.add_landmark(z0, R_COV)
    ekf2.predict_velocity(1.0, 0.3, 1.0, PSD)
    ekf2.update(ekf2.innovation(0, z, R_COV))
    cross = ekf2.P[:3, 3:].copy()
    ekf2.predict_velocity(1.0, 0.3, 1.0, PSD)
    np.testing.assert_allclose(ekf2.P[:3, 3:], g @ cross, atol=1e-12)


# -- consistency by Monte Carlo -----------------------------------------------------------------

MC_RUNS = 20
MC_STEPS = 520
MC_DT = 0.1
MC_EVERY = 2  # observations every other odometry step
MC_V, MC_W = 0.5, 0.125  # a circle of radius 4 m


def _mc_config(jacobians: str, iterations: int = 1) -> EkfConfig:
    return EkfConfig(
        start="groundtruth",
        v_noise_speed=0.1,
        v_noise_turn=0.05,
        w_noise_speed=0.08,
        w_noise_turn=0.1,
        v_noise_floor=0.01,
        heading_noise_floor=1.0,
        spot_turn_noise=1.0,
        spot_speed=0.05,
        range_sigma=0.05,
        range_sigma_rel=0.0,
        bearing_sigma=2.0,
        iterations=iterations,
        jacobians=jacobians,
        promote_after_known=1,
        initial_sigma_m=0.02,
        initial_sigma_deg=1.0,
    )


def _control_psd(c: EkfConfig, v: float, w: float) -> F64:
    """The pipeline's control noise model (documented in EkfConfig), written out again."""
    sv = c.v_noise_speed * abs(v) + c.v_noise_turn * abs(w) + c.v_noise_floor
    turn = c.spot_turn_noise if abs(v) < c.spot_speed else c.w_noise_turn
    sw = c.w_noise_speed * abs(v) + turn * abs(w) + math.radians(c.heading_noise_floor)
    return np.array([sv * sv, sw * sw])


MC_LANDMARKS = np.array(
    [
        [r * math.cos(a), r * math.sin(a)]
        for k, (r, a) in enumerate(
            (2.5 if k % 2 else 6.0, 2 * math.pi * k / 10 + 0.2) for k in range(10)
        )
    ]
)


def _simulate(seed: int, c: EkfConfig) -> tuple[list[object], F64, F64]:
    """Frames, the filter's start pose and the true poses at each stamp."""
    rng = np.random.default_rng(seed)
    start = np.array([0.0, -4.0, 0.0])
    p0 = np.diag([c.initial_sigma_m**2] * 2 + [math.radians(c.initial_sigma_deg) ** 2])
    truth = start + rng.multivariate_normal(np.zeros(3), p0)
    sr, sb = c.range_sigma, math.radians(c.bearing_sigma)
    psd = _control_psd(c, MC_V, MC_W)
    frames: list[object] = []
    poses = []
    for k in range(MC_STEPS):
        stamp = k * int(MC_DT * 1e9)
        if k:
            # The commanded (reported) control plus white noise of density psd, as modelled.
            dv, dw = rng.normal(0.0, np.sqrt(psd / MC_DT))
            truth = textbook_arc(truth, MC_V + dv, MC_W + dw, MC_DT)
        frames.append(OdometryFrame(stamp, v=MC_V, omega=MC_W))
        d = MC_LANDMARKS - truth[:2]
        rng_m = np.hypot(d[:, 0], d[:, 1])
        brg = (np.arctan2(d[:, 1], d[:, 0]) - truth[2] + np.pi) % (2 * np.pi) - np.pi
        vis = np.nonzero((rng_m < 5.0) & (np.abs(brg) < 2.0))[0]
        if k % MC_EVERY:
            vis = vis[:0]
        frames.append(
            LandmarkFrame(
                stamp,
                ids=vis.astype(np.int64),
                ranges_m=rng_m[vis] + rng.normal(0, sr, len(vis)),
                bearings_rad=brg[vis] + rng.normal(0, sb, len(vis)),
            )
        )
        poses.append(truth.copy())
    return frames, start, np.array(poses)


@functools.cache
def _anees(jacobians: str, iterations: int = 1) -> tuple[float, F64]:
    """The NEES of the robot pose averaged over runs and time, and per time step."""
    c = _mc_config(jacobians, iterations)
    nees = np.zeros((MC_RUNS, MC_STEPS))
    for run in range(MC_RUNS):
        frames, start, truth = _simulate(1000 + run, c)
        slam = EkfSlam(c)
        slam.set_start(start)
        for f in frames:
            slam.process(f)
        res = slam.finish()
        assert res.counts["recoveries"] == 0
        assert res.counts["landmarks"] >= len(MC_LANDMARKS) - 2
        assert res.trajectory is not None
        est = se3_to_planar(res.trajectory.world_from_body)
        covs = res.pose_covariances
        assert covs is not None and len(est) == MC_STEPS
        err = est - truth
        err[:, 2] = (err[:, 2] + np.pi) % (2 * np.pi) - np.pi
        nees[run] = np.einsum("ti,ti->t", err, np.linalg.solve(covs, err[:, :, None])[..., 0])
    return float(nees.mean()), nees.mean(axis=0)


def test_first_estimates_filter_is_consistent() -> None:
    lo = stats.chi2.ppf(0.025, 3 * MC_RUNS) / MC_RUNS
    hi = stats.chi2.ppf(0.975, 3 * MC_RUNS) / MC_RUNS
    anees, per_step = _anees("first-estimates")
    print(f"ANEES first-estimates {anees:.3f} (band {lo:.3f}..{hi:.3f})")
    assert lo <= anees <= hi
    # Not only on average: the last quarter (a map built, the loop closed) too.
    late = float(per_step[3 * MC_STEPS // 4 :].mean())
    assert lo <= late <= hi


@pytest.mark.slow
def test_standard_ekf_is_less_consistent_than_first_estimates() -> None:
    """Same seeds, same frames: the textbook EKF's pose NEES is clearly higher (over-confident),
    plainly or iterated; the first-estimates filter is what the pipeline defaults to."""
    fej, _ = _anees("first-estimates")
    std, _ = _anees("current", 1)
    iterated, _ = _anees("current", 3)
    print(f"ANEES first-estimates {fej:.3f}, current {std:.3f}, current iterated {iterated:.3f}")
    assert std > 1.15 * fej
    assert iterated > 1.15 * fej


def test_chi2_quantile_equals_scipy() -> None:
    for dof in (2, 4, 10):
        for p in (0.025, 0.5, 0.95, 0.999, 0.99999):
            assert chi2_quantile(p, dof) == pytest.approx(stats.chi2.ppf(p, dof), rel=1e-10)


# -- data association ---------------------------------------------------------------------------


def test_nearest_neighbour_pairs_uniquely_inside_the_gate() -> None:
    d2 = np.array(
        [
            [5.0, 1.0, 4.0, 50.0],  # obs 0: nearest is slot 1
            [7.0, 2.0, 3.0, 50.0],  # obs 1: also slot 1, but obs 0 is closer: takes slot 2
            [40.0, 30.0, 20.0, 14.0],  # obs 2: nothing inside the gate
            [0.5, 9.0, 9.0, 9.0],  # obs 3: slot 0
        ]
    )
    out = nearest_neighbour(Candidates(d2), gate=13.8)
    np.testing.assert_array_equal(out, [1, 2, UNMATCHED, 0])
    assert nearest_neighbour(Candidates(d2), gate=0.8).tolist() == [UNMATCHED] * 3 + [0]
    empty = nearest_neighbour(Candidates(np.zeros((2, 0))), gate=10.0)
    assert empty.tolist() == [UNMATCHED, UNMATCHED]


def test_nearest_neighbour_random_matrices_invariants() -> None:
    rng = np.random.default_rng(21)
    gate = 6.0
    for _ in range(200):
        d2 = rng.exponential(6.0, size=(rng.integers(1, 7), rng.integers(1, 7)))
        out = nearest_neighbour(Candidates(d2), gate)
        paired = out[out != UNMATCHED]
        assert len(set(paired.tolist())) == len(paired)  # one observation per landmark
        for i, j in enumerate(out):
            if j != UNMATCHED:
                assert d2[i, j] < gate
                # Every closer landmark went to an observation that is closer to it.
                for jj in np.nonzero(d2[i] < d2[i, j])[0]:
                    owner = np.nonzero(out == jj)[0]
                    assert len(owner) == 1 and d2[owner[0], jj] <= d2[i, jj]
            else:
                # Unpaired: every landmark inside the gate is taken by a closer pairing.
                for jj in np.nonzero(d2[i] < gate)[0]:
                    owner = np.nonzero(out == jj)[0]
                    assert len(owner) == 1 and d2[owner[0], jj] <= d2[i, jj]
        # Without conflicts each observation gets its nearest landmark.
        best = np.argmin(d2, axis=1)
        if len(set(best.tolist())) == len(best) and np.all(d2.min(axis=1) < gate):
            np.testing.assert_array_equal(out, best)


def _crafted_world() -> tuple[LandmarkEkf, F64, F64, dict[str, int]]:
    """Two pairs of close landmarks; the robot's heading is 0.1 rad off and uncertain."""
    ekf = LandmarkEkf(np.zeros(3), np.diag([1e-8, 1e-8, 1e-8]))
    tiny = np.diag([1e-8, 1e-8])
    world = {"A1": 0.30, "A2": 0.19, "B1": -0.50, "B2": -0.69}
    slots = {name: ekf.add_landmark(np.array([5.0, ang]), tiny) for name, ang in world.items()}
    ekf.inflate_pose(np.diag([0.0, 0.0, 0.15**2]))
    true_heading = 0.1
    zs = np.array([[5.0, world["A1"] - true_heading], [5.0, world["B1"] - true_heading]])
    r_covs = np.stack([np.diag([0.01**2, 0.01**2])] * 2)
    return ekf, zs, r_covs, slots


def test_jcbb_finds_the_jointly_consistent_pairing_nn_misses() -> None:
    ekf, zs, r_covs, slots = _crafted_world()
    gate = chi2_quantile(0.999, 2)
    joint_gates = np.array([0.0] + [chi2_quantile(0.999, 2 * k) for k in range(1, 8)])
    cands = Candidates.of(ekf, zs, r_covs)
    # Every observation is individually compatible with both landmarks of its pair.
    assert cands.d2[0, slots["A1"]] < gate and cands.d2[0, slots["A2"]] < gate
    assert cands.d2[1, slots["B1"]] < gate and cands.d2[1, slots["B2"]] < gate
    nn = nearest_neighbour(cands, gate)
    assert nn.tolist() == [slots["A2"], slots["B2"]]
    # ... and NN's pairs imply headings 0.08 rad apart: jointly incompatible.
    nn_pairs = [(0, slots["A2"]), (1, slots["B2"])]
    assert joint_distance(ekf, zs, r_covs, nn_pairs) > joint_gates[2]
    out = jcbb(ekf, zs, r_covs, cands, gate, lambda k: float(joint_gates[k]))
    assert out.tolist() == [slots["A1"], slots["B1"]]
    good = [(0, slots["A1"]), (1, slots["B1"])]
    assert joint_distance(ekf, zs, r_covs, good) < joint_gates[2]


def test_jcbb_leaves_an_incompatible_observation_unpaired() -> None:
    ekf, zs, r_covs, slots = _crafted_world()
    zs = np.vstack([zs, [[5.0, 2.5]]])  # nothing there
    r_covs = np.concatenate([r_covs, r_covs[:1]])
    gate = chi2_quantile(0.999, 2)
    joint_gates = np.array([0.0] + [chi2_quantile(0.999, 2 * k) for k in range(1, 8)])
    out = jcbb(
        ekf, zs, r_covs, Candidates.of(ekf, zs, r_covs), gate, lambda k: float(joint_gates[k])
    )
    assert out.tolist() == [slots["A1"], slots["B1"], UNMATCHED]


def test_joint_distance_equals_dense_computation() -> None:
    ekf = LandmarkEkf(START, START_COV, capacity=2)
    ref = DenseEkf.start(START, START_COV)
    scripted(ekf, ref, False, np.random.default_rng(2))
    ekf.predict_velocity(0.3, 0.2, 0.5, PSD)  # pending cross terms
    ref.predict_velocity(0.3, 0.2, 0.5, PSD)
    zs = np.array([[4.0, 0.3], [3.0, -1.0], [6.0, 3.0]])
    r_covs = np.stack([R_COV, np.diag([0.01, 0.002]), R_COV * 3])
    for pairs in ([(0, 1)], [(0, 2), (1, 0)], [(2, 0), (0, 1), (1, 2)]):
        m = len(pairs)
        h = np.zeros((2 * m, len(ref.x)))
        nu = np.zeros(2 * m)
        r = np.zeros((2 * m, 2 * m))
        for k, (i, j) in enumerate(pairs):
            zhat, hj = ref.jacobian(j)
            h[2 * k : 2 * k + 2] = hj
            nu[2 * k : 2 * k + 2] = [zs[i][0] - zhat[0], wrap(zs[i][1] - zhat[1])]
            r[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = r_covs[i]
        s = h @ ref.P @ h.T + r
        expect = float(nu @ np.linalg.solve(s, nu))
        assert joint_distance(ekf, zs, r_covs, pairs) == pytest.approx(expect, rel=1e-8)
    # One pair: the individual distance.
    inn = ekf.innovation(2, zs[1], r_covs[1])
    assert joint_distance(ekf, zs, r_covs, [(1, 2)]) == pytest.approx(inn.d2, rel=1e-10)
    np.testing.assert_allclose(
        Candidates.of(ekf, zs, r_covs).d2[1], ekf.innovations_all(zs[1], r_covs[1])[2]
    )


def test_jcbb_pipeline_handles_a_scan_of_more_than_63_observations() -> None:
    n = 70
    bearings = np.linspace(-1.5, 1.5, n)
    ranges = np.asarray(5.0 + 0.5 * np.arange(n), dtype=np.float64)
    slam = EkfSlam(EkfConfig(association="jcbb", start="origin", promote_after=1))
    slam.process(OdometryFrame(0, v=0.0, omega=0.0))
    for k in range(1, 3):
        ids = np.full(n, -1, dtype=np.int64)
        slam.process(LandmarkFrame(k * 10**8, ids=ids, ranges_m=ranges, bearings_rad=bearings))
    assert slam.finish().counts["landmarks"] == n


def test_merging_two_copies_of_one_landmark_fuses_them() -> None:
    """Two landmarks started from observations of one point are fused into one."""
    ekf = LandmarkEkf(np.zeros(3), np.diag([0.01, 0.01, 0.001]))
    r_cov = np.diag([0.05**2, np.radians(1.0) ** 2])
    a = ekf.add_landmark(np.array([3.0, 0.2]), r_cov)
    ekf.add_landmark(np.array([4.0, -0.5]), r_cov)  # another point, kept
    b = ekf.add_landmark(np.array([3.02, 0.205]), r_cov)
    before = ekf.landmarks()
    traces = np.trace(ekf.landmark_covs(), axis1=1, axis2=2)
    assert ekf.merge_distance(a, b) < chi2_quantile(0.999, 2)
    assert ekf.merge_distance(a, 1) > 100.0
    ekf.merge_landmarks(a, b)
    assert ekf.count == 2
    after = ekf.landmarks()
    # The fused point lies between the two copies; the other landmark barely moves.
    lo, hi = np.minimum(before[a], before[b]), np.maximum(before[a], before[b])
    assert np.all(after[a] >= lo - 1e-9) and np.all(after[a] <= hi + 1e-9)
    assert np.allclose(after[1], before[1], atol=0.02)
    p = ekf.P
    assert np.allclose(p, p.T, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(p) > 0)
    # Fusing two estimates leaves the point more certain than either copy was.
    assert np.trace(ekf.landmark_cov(a)) < min(traces[a], traces[b])


def test_agree_with_mean_uses_each_point_s_own_covariance() -> None:
    points = np.array([[0.0, 0.0], [0.2, 0.0], [0.1, 0.1]])
    tight = np.broadcast_to(np.eye(2) * 0.01**2, (3, 2, 2))
    loose = np.broadcast_to(np.eye(2) * 0.1**2, (3, 2, 2))
    gate = chi2_quantile(0.999, 2)
    assert agree_with_mean(points, loose, gate)
    assert not agree_with_mean(points, tight, gate)


def test_ekf_and_graph_share_their_association_and_start_settings() -> None:
    for cls in (EkfConfig, GraphConfig):
        assert issubclass(cls, LandmarkAssociation) and issubclass(cls, LandmarkNoise)
    shared = {f.name for f in fields(LandmarkAssociation)} | {f.name for f in fields(LandmarkNoise)}
    assert {"gate_prob", "association", "promote_after_known", "initial_sigma_m"} <= shared
    for name in shared:
        assert getattr(EkfConfig(), name) == getattr(GraphConfig(), name), name
    c = GraphConfig(gate_prob=0.99, new_landmark_prob=0.9999)
    assert c.gate == pytest.approx(chi2_quantile(0.99, 2))
    assert c.new_gate == pytest.approx(chi2_quantile(0.9999, 2))
    assert c.joint_gate(3) == chi2_quantile(0.99, 6)


@pytest.mark.parametrize(
    ("with_id", "without_id", "used"),
    [(5, 0, "known"), (0, 0, "known"), (0, 4, "jcbb"), (2, 4, "mixed")],
)
def test_association_used_follows_the_observations(
    with_id: int, without_id: int, used: str
) -> None:
    assert EkfConfig(association="jcbb").association_used(with_id, without_id) == used


def test_start_pose_is_the_source_s_only_with_start_groundtruth() -> None:
    pose = np.array([1.0, 2.0, 0.3])
    np.testing.assert_array_equal(EkfConfig().start_pose(pose), pose)
    assert EkfConfig().start_pose(None) is None
    assert GraphConfig(start="origin").start_pose(pose) is None
