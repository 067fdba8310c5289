"""Planar landmark SLAM as a GTSAM factor graph: pose keys, odometry, range-bearing factors.

numpy in, numpy out: GTSAM objects never leave this module, and gtsam is imported inside the
functions that need it.

Conventions
-----------
- Planar poses are ``(3,)`` float64 ``(x, y, yaw)`` in metres and radians, world_from_body.
- Pose keys are ``gtsam.symbol("x", robot * POSE_STRIDE + k)`` for the k-th keypose of a
  robot; landmark keys are ``gtsam.symbol("l", ident)``.
- A relative pose ``(dx, dy, dθ)`` between two keyposes is expressed in the first one's frame,
  and its ``(3, 3)`` covariance is in that frame's axes; :func:`between_covariance` rotates it
  into the tangent space of ``BetweenFactorPose2`` (the end pose's frame).
- Range-bearing measurements are ``(range m, bearing rad)``, bearing counter-clockwise from the
  heading; GTSAM's ``BearingRangeFactor2D`` orders its residual (bearing, range), so noise
  models are built in that order here.
- :class:`Backend` solves incrementally (iSAM2) or in batch (Levenberg–Marquardt over the
  whole graph, every ``batch_every`` additions and at the end). The GTSAM wheel has no TBB, so
  both are deterministic.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.ekf.filter import arc_motion, relative_motion
from slamcli.geometry.planar import between_planar, compose_planar, wrap_angle

F64 = NDArray[np.float64]

POSE_STRIDE = 10_000_000
"""Pose keys of robot r are ``r * POSE_STRIDE + k``: room for ten million keyposes each."""


def pose_key(robot: int, index: int) -> int:
    """The GTSAM key of robot ``robot``'s ``index``-th keypose."""
    import gtsam

    return int(gtsam.symbol("x", robot * POSE_STRIDE + index))


def landmark_key(ident: int) -> int:
    """The GTSAM key of landmark ``ident`` (>= 0)."""
    import gtsam

    return int(gtsam.symbol("l", ident))


class Relative:
    """A relative pose integrated from odometry, with its covariance, from a keypose.

    Attributes:
        pose: (3,) float64 the current pose in the keypose's frame.
        cov: (3, 3) float64 its covariance in the keypose's axes.
    """

    def __init__(self) -> None:
        self.pose = np.zeros(3)
        self.cov = np.zeros((3, 3))

    def velocity(self, v: float, omega: float, dt: float, control_psd: F64) -> None:
        """Move by (v, ω) for ``dt`` s; ``control_psd`` = (σv², σω²) per second, as the EKF."""
        if dt <= 0.0:
            return
        new, g, jv = arc_motion(self.pose, v, omega, dt)
        self.cov = g @ self.cov @ g.T + (jv * (np.asarray(control_psd) / dt)) @ jv.T
        self.pose = new

    def step(self, delta: F64, delta_cov: F64) -> None:
        """Move by a relative pose (dx, dy, dθ) in the current frame with its covariance."""
        new, g, jd = relative_motion(self.pose, np.asarray(delta, dtype=np.float64))
        self.cov = g @ self.cov @ g.T + jd @ delta_cov @ jd.T
        self.pose = new


def between_covariance(delta: F64, cov: F64, floor: F64) -> F64:
    """The covariance of a relative pose in ``BetweenFactorPose2``'s tangent space (the end
    pose's axes), with ``floor`` (3,) variances added so that no factor is singular."""
    c, s = math.cos(float(delta[2])), math.sin(float(delta[2]))
    rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    out = rot @ cov @ rot.T + np.diag(floor)
    return np.asarray(0.5 * (out + out.T))


def blend_dense(
    key_stamps: NDArray[np.int64],
    key_poses: F64,
    key_rel: F64,
    stamps: NDArray[np.int64],
    rel: F64,
    key_index: NDArray[np.int64],
) -> F64:
    """Poses at every odometry stamp from the optimised keyposes and the odometry between them.

    Row i was integrated to ``rel[i]`` (in keypose ``key_index[i]``'s frame) after keypose
    ``key_index[i]``. It is placed forward from that keypose and backward from the next one
    (whose own odometry pose is ``key_rel[k + 1]`` in keypose k's frame), and the two are
    blended by time, so the path is continuous and passes through every keypose.

    Args:
        key_stamps: (K,) int64; key_poses: (K, 3) optimised; key_rel: (K, 3), row k + 1 is the
            odometry from keypose k to k + 1 (row 0 unused).
        stamps: (N,) int64; rel: (N, 3); key_index: (N,) int64 in [0, K).

    Returns:
        (N, 3) float64 planar poses.
    """
    forward = compose_planar(key_poses[key_index], rel)
    nxt = np.minimum(key_index + 1, len(key_stamps) - 1)
    has_next = nxt > key_index
    back_rel = between_planar(key_rel[nxt], rel)
    backward = compose_planar(key_poses[nxt], back_rel)
    t0 = key_stamps[key_index].astype(np.float64)
    t1 = key_stamps[nxt].astype(np.float64)
    span = np.where(has_next, t1 - t0, 1.0)
    f = np.where(has_next, np.clip((stamps - t0) / np.maximum(span, 1.0), 0.0, 1.0), 0.0)
    out = forward.copy()
    out[:, :2] = (1.0 - f)[:, None] * forward[:, :2] + f[:, None] * backward[:, :2]
    out[:, 2] = wrap_angle(forward[:, 2] + f * wrap_angle(backward[:, 2] - forward[:, 2]))
    return out


class Backend:
    """The factor graph and its solver.

    Args:
        solver: ``isam2`` (incremental: every :meth:`flush` updates the estimate) or ``batch``
            (Levenberg–Marquardt over the whole graph every ``batch_every`` flushes with new
            factors, and in :meth:`finish`; between them new values keep their predictions).
        robust_width: Huber width on the whitened residual of range-bearing factors; 0 = none.
        batch_every: see ``solver``.
    """

    def __init__(self, solver: str, robust_width: float, batch_every: int = 100) -> None:
        import gtsam

        self._gtsam = gtsam
        self.solver = solver
        self.robust_width = robust_width
        self.batch_every = batch_every
        self.graph = gtsam.NonlinearFactorGraph()
        self.values = gtsam.Values()
        self._new_graph = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._flushes = 0
        self._isam: Any = None
        if solver == "isam2":
            params = gtsam.ISAM2Params()
            params.setRelinearizeThreshold(0.05)
            params.relinearizeSkip = 10
            self._isam = gtsam.ISAM2(params)
        self._estimate = gtsam.Values()
        # Every value's latest estimate, read through pose() and point(). With iSAM2 it is
        # refreshed whole only when needed (error, marginals, finish): while ``_stale``, the
        # keys iSAM2 holds are read from it one by one (the same retraction).
        self._stale = False
        self.factor_counts = {"odometry": 0, "landmark": 0, "robot": 0, "prior": 0}

    # -- building ----------------------------------------------------------------------------

    def _gaussian(self, cov: F64) -> Any:
        return self._gtsam.noiseModel.Gaussian.Covariance(np.ascontiguousarray(cov))

    def _robust(self, model: Any) -> Any:
        if self.robust_width <= 0:
            return model
        nm = self._gtsam.noiseModel
        return nm.Robust.Create(nm.mEstimator.Huber.Create(self.robust_width), model)

    def add_pose(self, key: int, guess: F64) -> None:
        """A new pose with its initial value (x, y, yaw)."""
        pose = self._gtsam.Pose2(float(guess[0]), float(guess[1]), float(guess[2]))
        self._new_values.insert(key, pose)
        self._estimate.insert(key, pose)

    def add_point(self, key: int, guess: F64) -> None:
        """A new landmark with its initial value (x, y)."""
        point = np.array([float(guess[0]), float(guess[1])])
        self._new_values.insert(key, point)
        self._estimate.insert(key, point)

    def has(self, key: int) -> bool:
        return bool(self._estimate.exists(key))

    def prior(self, key: int, pose: F64, cov: F64) -> None:
        """A prior on a pose; ``cov`` (3, 3) in its tangent space."""
        g = self._gtsam
        self._add(g.PriorFactorPose2(key, g.Pose2(*map(float, pose)), self._gaussian(cov)), "prior")

    def odometry(self, a: int, b: int, delta: F64, cov: F64) -> None:
        """``BetweenFactorPose2(a, b)`` measuring ``delta`` with tangent covariance ``cov``."""
        g = self._gtsam
        self._add(
            g.BetweenFactorPose2(a, b, g.Pose2(*map(float, delta)), self._gaussian(cov)),
            "odometry",
        )

    def landmark(self, pose: int, point: int, z: F64, r_cov: F64) -> None:
        """A range-bearing observation ``z`` of landmark ``point`` from ``pose``; ``r_cov``
        (2, 2) in (range, bearing) order."""
        g = self._gtsam
        cov = np.array([[r_cov[1, 1], r_cov[1, 0]], [r_cov[0, 1], r_cov[0, 0]]])
        factor = g.BearingRangeFactor2D(
            pose, point, g.Rot2(float(z[1])), float(z[0]), self._robust(self._gaussian(cov))
        )
        self._add(factor, "landmark")

    def sighting(self, pose: int, other: int, z: F64, r_cov: F64) -> None:
        """A range-bearing observation of another robot's pose ``other`` (its position)."""
        g = self._gtsam
        cov = np.array([[r_cov[1, 1], r_cov[1, 0]], [r_cov[0, 1], r_cov[0, 0]]])
        factor = g.BearingRangeFactorPose2(
            pose, other, g.Rot2(float(z[1])), float(z[0]), self._robust(self._gaussian(cov))
        )
        self._add(factor, "robot")

    def _add(self, factor: Any, kind: str) -> None:
        self._new_graph.add(factor)
        self.factor_counts[kind] += 1

    # -- solving -----------------------------------------------------------------------------

    def flush(self) -> None:
        """Hand the new factors and values to the solver (iSAM2 updates its estimate; batch
        re-solves every ``batch_every`` flushes)."""
        if self._new_graph.size() == 0 and self._new_values.size() == 0:
            return
        self.graph.push_back(self._new_graph)
        self.values.insert(self._new_values)
        if self._isam is not None:
            self._isam.update(self._new_graph, self._new_values)
            self._stale = True
        else:
            self._flushes += 1
            if self._flushes % self.batch_every == 0:
                self._batch()
        self._new_graph = self._gtsam.NonlinearFactorGraph()
        self._new_values = self._gtsam.Values()

    def _batch(self) -> None:
        g = self._gtsam
        params = g.LevenbergMarquardtParams()
        params.setMaxIterations(100)
        optimizer = g.LevenbergMarquardtOptimizer(self.graph, self._estimate, params)
        self._estimate = optimizer.optimize()

    def finish(self) -> None:
        """The final estimate: everything flushed; batch runs Levenberg–Marquardt once more
        from its last estimate, iSAM2 two more updates without new factors."""
        self.flush()
        if self._isam is not None:
            for _ in range(2):
                self._isam.update()
            self._stale = True
            self._refresh()
        else:
            self._batch()

    def _solved(self, key: int) -> bool:
        return self._stale and bool(self._isam.valueExists(key))

    def _refresh(self) -> None:
        if self._stale:
            self._estimate = self._isam.calculateEstimate()
            self._stale = False

    def pose(self, key: int) -> F64:
        if self._solved(key):
            p = self._isam.calculateEstimatePose2(key)
        else:
            p = self._estimate.atPose2(key)
        return np.array([p.x(), p.y(), p.theta()])

    def point(self, key: int) -> F64:
        if self._solved(key):
            value = self._isam.calculateEstimatePoint2(key)
        else:
            value = self._estimate.atPoint2(key)
        return np.asarray(value, dtype=np.float64).reshape(2)

    def error(self) -> float:
        """The graph's total error at the estimate (robust factors as their kernel counts)."""
        self._refresh()
        return float(self.graph.error(self._estimate))

    def marginal_points(self, keys: list[int]) -> F64:
        """(n, 2, 2) marginal covariances of landmark ``keys`` at the estimate."""
        if not keys:
            return np.empty((0, 2, 2))
        self._refresh()
        if self._isam is not None:
            return np.stack([self._isam.marginalCovariance(k) for k in keys])
        marg = self._gtsam.Marginals(self.graph, self._estimate)
        return np.stack([marg.marginalCovariance(k) for k in keys])
