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
from slamcli.inertial.preintegration import ImuNoise, check_imu_samples, preintegrate

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

    def delta(t0: int, t1: int, accel: F64) -> tuple[F64, F64]:
        pim = preintegrate(*samples, t0, t1, gtsam.imuBias.ConstantBias(accel, gyro), params)
        return np.concatenate([pim.deltaPij(), pim.deltaVij()]), pim.preintMeasCov()[3:, 3:]

    intervals = []
    for t0, t1 in pairwise(stamps.tolist()):
        measured, cov = delta(t0, t1, hat)
        jac = np.stack([delta(t0, t1, hat + axis)[0] - measured for axis in np.eye(3)], axis=1)
        intervals.append((float(t1 - t0) * 1e-9, measured, jac, np.linalg.inv(cov)))

    from slamcli.inertial.initialisation import ACCEL_BIAS_SIGMA

    k = stamps.size
    n = 3 + 3 * k + 3 * (k - 1)  # scale, gravity tilt (2), velocities, biases
    g0 = np.array([0.0, 0.0, -noise.gravity_mps2])
    rotation = np.eye(3)
    scale, velocities, biases = 1.0, np.zeros((k, 3)), np.zeros((k - 1, 3))
    info = np.eye(n)
    for _ in range(_STEPS):
        gravity = rotation @ g0
        # d(gravity)/d(tilt) for a small rotation about the world's x and y axes.
        tilt = np.cross(np.eye(3), gravity).T[:, :2]
        rows: list[F64] = []
        rhs: list[F64] = []
        weights: list[F64] = []
        for i, (dt, measured, jac, weight) in enumerate(intervals):
            r_t = poses[i, :3, :3].T
            a = np.zeros((6, n))
            moved = poses[i + 1, :3, 3] - poses[i, :3, 3]
            a[:3, 0] = r_t @ moved
            a[:3, 1:3] = -0.5 * dt * dt * r_t @ tilt
            a[3:, 1:3] = -dt * r_t @ tilt
            a[:3, 3 + 3 * i : 6 + 3 * i] = -dt * r_t
            a[3:, 3 + 3 * i : 6 + 3 * i] = -r_t
            a[3:, 6 + 3 * i : 9 + 3 * i] = r_t
            a[:, 3 + 3 * k + 3 * i : 6 + 3 * k + 3 * i] = -jac
            model = np.concatenate(
                [
                    r_t @ (scale * moved - velocities[i] * dt - 0.5 * gravity * dt * dt),
                    r_t @ (velocities[i + 1] - velocities[i] - gravity * dt),
                ]
            )
            rows.append(a)
            rhs.append(measured + jac @ biases[i] - model)
            weights.append(weight)
            if i + 1 < len(intervals):
                walk = np.zeros((3, n))
                walk[:, 3 + 3 * k + 3 * i : 6 + 3 * k + 3 * i] = -np.eye(3)
                walk[:, 6 + 3 * k + 3 * i : 9 + 3 * k + 3 * i] = np.eye(3)
                rows.append(walk)
                rhs.append(biases[i] - biases[i + 1])
                weights.append(np.eye(3) / (noise.accel_random_walk**2 * dt))
        prior = np.zeros((3, n))
        prior[:, 3 + 3 * k : 6 + 3 * k] = np.eye(3)
        rows.append(prior)
        rhs.append(-(hat + biases[0]))
        weights.append(np.eye(3) / ACCEL_BIAS_SIGMA**2)
        info = np.zeros((n, n))
        grad = np.zeros(n)
        for a, r, w in zip(rows, rhs, weights, strict=True):
            aw = a.T @ w
            info += aw @ a
            grad += aw @ r
        step = np.linalg.solve(info, grad)
        scale += step[0]
        rotation = _small_rotation(step[1], step[2]) @ rotation
        velocities += step[3 : 3 + 3 * k].reshape(k, 3)
        biases += step[3 + 3 * k :].reshape(k - 1, 3)
    covariance = np.linalg.inv(info)
    return ScaleInformation(
        scale=float(scale),
        std=float(math.sqrt(max(covariance[0, 0], 0.0))) / max(abs(scale), 1e-12),
        keyframes=int(k),
        duration_s=float(stamps[-1] - stamps[0]) * 1e-9,
    )


def _small_rotation(x: float, y: float) -> F64:
    from slamcli.geometry import so3_exp

    return so3_exp(np.array([x, y, 0.0]))
