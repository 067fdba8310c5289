"""How well a trajectory's motion lets an IMU determine its metric scale.

A monocular camera measures a trajectory's shape; its metric size comes from the
accelerometer alone. How precisely depends on the motion and on the IMU's noise, not on the
estimator: this module computes the best precision any estimator can reach, the Cramér-Rao
bound on the scale when vision is perfect (every keyframe's rotation known, and its position
known up to one common scale).

The model is the linear one behind visual-inertial alignment (Mur-Artal and Tardós 2017,
Qin et al. 2018), with the accelerometer bias as ORB-SLAM3's full inertial adjustment has it:
between keyframes ``i`` and ``j``, ``T`` seconds apart, in keyframe ``i``'s body frame,

    R_iᵀ (s (p_j - p_i) - v_i T - ½ g T²) = Δp + J_p (b_i - b̂)
    R_iᵀ (v_j - v_i - g T)                 = Δv + J_v (b_i - b̂)

with GTSAM's preintegrated ``Δp``, ``Δv`` and their covariance (the accelerometer's white
noise; the gyroscope's through the rotations it integrates), one accelerometer bias per
keyframe that random-walks at the IMU's rate from one to the next, a prior of
:data:`slamcli.inertial.initialisation.ACCEL_BIAS_SIGMA` on the first, one velocity per
keyframe, and gravity of known magnitude whose direction (2 degrees of freedom) is unknown.
``s`` scales the positions. The unknowns enter linearly but for gravity's direction, which is
linearised about the trajectory's own; a few Gauss-Newton steps give the IMU's own estimate
of ``s`` and the inverse of the information its standard deviation.

The bias's random walk is what limits the scale: a slowly varying bias can mimic a slowly
varying acceleration. On `synth stereo`'s 10 s loop (0.25 m/s² of acceleration), EuRoC's
accelerometer determines the scale to 1.0 % (1 sigma) with perfect vision; held constant, the
bias would allow 0.4 %.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.errors import InputError
from slamcli.geometry import so3_exp
from slamcli.inertial.preintegration import (
    ImuNoise,
    check_imu_samples,
    integrate,
    interval_readings,
)

F64 = NDArray[np.float64]

_STEPS = 3


@dataclass(frozen=True)
class ScaleInformation:
    """What an IMU says of a trajectory's metric scale.

    Attributes:
        scale: the factor on the trajectory's positions that fits the IMU best (1 for a
            trajectory at the IMU's scale).
        std: the smallest relative standard deviation of any estimate of the scale, given
            the motion and the IMU's noise (the Cramér-Rao bound with perfect vision).
        keyframes: how many poses it was computed over.
        duration_s: their span, seconds.
    """

    scale: float
    std: float
    keyframes: int
    duration_s: float


def scale_information(
    stamps_ns: ArrayLike,
    world_from_body: ArrayLike,
    imu: tuple[ArrayLike, ArrayLike, ArrayLike],
    noise: ImuNoise,
    gyro_bias: ArrayLike | None = None,
    accel_bias: ArrayLike | None = None,
) -> ScaleInformation:
    """The IMU's estimate of a trajectory's scale and the bound on its precision.

    Args:
        stamps_ns: (K,) increasing stamps of the poses (keyframes), K >= 3.
        world_from_body: (K, 4, 4) poses of the IMU's body in a metric, gravity-aligned world
            (gravity along -z).
        imu: (M,) int64 stamps, (M, 3) gyro rad/s and (M, 3) accel m/s², covering the poses.
        noise: the IMU's noise model.
        gyro_bias, accel_bias: (3,) the biases to integrate around (zero when None).

    Raises:
        InputError: fewer than three poses, stamps that do not increase, or IMU samples that
            do not cover them.
    """
    import gtsam

    stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    poses = np.asarray(world_from_body, dtype=np.float64).reshape(-1, 4, 4)
    if stamps.size < 3 or poses.shape[0] != stamps.size:
        raise InputError(f"scale information: expected 3 or more poses, got {stamps.size}")
    if not (np.diff(stamps) > 0).all():
        raise InputError("scale information: the poses' stamps must increase")
    samples = check_imu_samples(*imu)
    params = noise.params()
    hat = np.zeros(3) if accel_bias is None else np.asarray(accel_bias, dtype=np.float64)
    gyro = np.zeros(3) if gyro_bias is None else np.asarray(gyro_bias, dtype=np.float64)

    def predicted(pim: gtsam.PreintegratedImuMeasurements, accel: F64) -> F64:
        # From rest at the origin: GTSAM's first-order correction for another bias, gravity
        # included (it cancels in the differences).
        state = pim.predict(gtsam.NavState(), gtsam.imuBias.ConstantBias(accel, gyro))
        return np.concatenate([state.position(), state.velocity()])

    intervals = []
    for t0, t1 in pairwise(stamps.tolist()):
        pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias(hat, gyro))
        integrate(pim, interval_readings(*samples, t0, t1))
        measured = np.concatenate([pim.deltaPij(), pim.deltaVij()])
        base = predicted(pim, hat)
        jac = np.stack([predicted(pim, hat + axis) - base for axis in np.eye(3)], axis=1)
        # Whitening: root.T @ root is the inverse covariance.
        root = np.linalg.cholesky(np.linalg.inv(pim.preintMeasCov()[3:, 3:])).T
        intervals.append((float(t1 - t0) * 1e-9, measured, jac, root))

    from slamcli.inertial.initialisation import ACCEL_BIAS_SIGMA

    k = stamps.size
    n = 3 + 3 * k + 3 * (k - 1)  # scale, gravity tilt (2), velocities, biases
    g0 = np.array([0.0, 0.0, -noise.gravity_mps2])
    rotation = np.eye(3)
    scale, velocities, biases = 1.0, np.zeros((k, 3)), np.zeros((k - 1, 3))
    # Factored keyframe by keyframe (velocity, then bias), scale and tilt last: a band.
    per = np.concatenate([3 + 3 * np.arange(k)[:, None] + np.arange(3), np.zeros((k, 3), int)], 1)
    per[: k - 1, 3:] = 3 + 3 * k + 3 * np.arange(k - 1)[:, None] + np.arange(3)
    order = np.concatenate([per[: k - 1].ravel(), per[k - 1, :3], np.arange(3)])
    for _ in range(_STEPS):
        problem = _Problem(n)
        gravity = rotation @ g0
        # d(gravity)/d(tilt) for a small rotation about the world's x and y axes.
        tilt = np.cross(np.eye(3), gravity).T[:, :2]
        for i, (dt, measured, jac, root) in enumerate(intervals):
            r_t = poses[i, :3, :3].T
            moved = poses[i + 1, :3, 3] - poses[i, :3, 3]
            v, b = 3 + 3 * i, 3 + 3 * k + 3 * i
            blocks = np.zeros((6, 12))  # scale and tilt, v_i, v_j, b_i
            blocks[:3, 0] = r_t @ moved
            blocks[:3, 1:3] = -0.5 * dt * dt * r_t @ tilt
            blocks[3:, 1:3] = -dt * r_t @ tilt
            blocks[:3, 3:6] = -dt * r_t
            blocks[3:, 3:6] = -r_t
            blocks[3:, 6:9] = r_t
            blocks[:, 9:12] = -jac
            model = np.concatenate(
                [
                    r_t @ (scale * moved - velocities[i] * dt - 0.5 * gravity * dt * dt),
                    r_t @ (velocities[i + 1] - velocities[i] - gravity * dt),
                ]
            )
            columns = np.r_[0:3, v : v + 6, b : b + 3]
            problem.add(root @ blocks, columns, root @ (measured + jac @ biases[i] - model))
            if i + 1 < len(intervals):
                sigma = noise.accel_random_walk * math.sqrt(dt)
                walk = np.hstack([-np.eye(3), np.eye(3)]) / sigma
                problem.add(walk, np.r_[b : b + 6], (biases[i] - biases[i + 1]) / sigma)
        b0 = 3 + 3 * k
        prior = np.eye(3) / ACCEL_BIAS_SIGMA
        problem.add(prior, np.r_[b0 : b0 + 3], -prior @ (hat + biases[0]))
        step, variance = problem.solve(order)
        scale += step[0]
        rotation = so3_exp(np.array([step[1], step[2], 0.0])) @ rotation
        velocities += step[3 : 3 + 3 * k].reshape(k, 3)
        biases += step[3 + 3 * k :].reshape(k - 1, 3)
    return ScaleInformation(
        scale=float(scale),
        std=math.sqrt(max(variance, 0.0)) / max(abs(scale), 1e-12),
        keyframes=int(k),
        duration_s=float(stamps[-1] - stamps[0]) * 1e-9,
    )


class _Problem:
    """A sparse whitened linear least-squares problem ``min |A x - r|²`` built block by block."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.rows: list[NDArray[np.int64]] = []
        self.cols: list[NDArray[np.int64]] = []
        self.vals: list[F64] = []
        self.rhs: list[F64] = []
        self.m = 0

    def add(self, block: F64, columns: NDArray[np.int64], rhs: F64) -> None:
        """Rows ``block`` (whitened) over ``columns`` of the unknowns, with their ``rhs``."""
        r, c = block.shape
        self.rows.append(np.repeat(np.arange(self.m, self.m + r), c))
        self.cols.append(np.tile(columns, r))
        self.vals.append(block.ravel())
        self.rhs.append(rhs)
        self.m += r

    def solve(self, order: NDArray[np.int64]) -> tuple[F64, float]:
        """The least-squares step and the variance of its first unknown, factored with the
        unknowns in ``order`` (a banded order keeps the factor sparse)."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.linalg import splu

        a = coo_matrix(
            (np.concatenate(self.vals), (np.concatenate(self.rows), np.concatenate(self.cols))),
            shape=(self.m, self.n),
        ).tocsc()[:, order]
        lu = splu(
            (a.T @ a).tocsc(),
            permc_spec="NATURAL",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
        step = np.empty(self.n)
        step[order] = lu.solve(a.T @ np.concatenate(self.rhs))
        first = (order == 0).astype(np.float64)
        return step, float(lu.solve(first)[first > 0][0])
