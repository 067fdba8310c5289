"""Inertial-only initialisation: scale, gravity, velocities and biases from a visual map and
an IMU (ORB-SLAM3's inertial-only MAP estimate, Campos et al., "Inertial-Only Optimization for
Visual-Inertial Initialization", ICRA 2020, and "ORB-SLAM3", T-RO 2021).

A visual map made by one camera knows its keyframes' poses only up to a similarity: a map
scale, and a world frame whose "up" is arbitrary. A stereo map has its scale but not its up.
Over a few seconds of motion the IMU fixes both. The visual map is taken as a measurement and
only the inertial state is estimated:

- ``s``, metres per map unit, as ``λ = log s`` (a ``Vector1``): a multiplicative update, as
  ORB-SLAM3's scale vertex, that can never make the scale negative. A stereo or RGB-D map
  passes its scale and it is held fixed.
- the direction of gravity in the map's frame, a GTSAM ``Unit3`` (2 degrees of freedom: roll
  and pitch of the map; its yaw about gravity is unobservable, and a 2-DoF unknown leaves no
  gauge to fix). The magnitude is the known 9.80665 m/s².
- one velocity per keyframe (m/s, map orientation, metric);
- one accelerometer and gyroscope bias shared by the window (the biases drift by
  ``random_walk · √T``, about 0.005 m/s² and 3e-5 rad/s over 2 s on EuRoC's IMU, far below
  what the window can resolve), with a zero-mean Gaussian prior;
- one metric body position per keyframe (map orientation), about the map's.

Keyframe ``i``'s body (IMU) pose is the camera's with the camera-to-body offset: rotation
``R_i = R_wc,i R_cb`` and position ``s · p_wc,i + R_wc,i t_cb``. The map's positions scale,
the lever arm ``t_cb`` does not: it is metric, from the calibration. The rotations are held as
the map gives them. ORB-SLAM3 holds the positions too; here each is an unknown that the map
measures with an isotropic ``position_sigma_m``. Held positions make every millimetre of map
noise count as motion, where the IMU's own error between keyframes 0.25 s apart is a fraction
of a millimetre. With 1.7 cm of noise on 4 s of EuRoC MH_05, held positions weighed by the
IMU alone give a scale 14 % off at a chi-square per degree of freedom near 30000; with the
noise added to the weights the fit shrinks the scale instead, which shrinks that noise with
it, and comes out about 45 % low (the attenuation bias of errors in the regressor). The
residual of the map's measurement is taken in map units, ``(p_i - l_i) / s - p̄_i``, with
``position_sigma_m / s``: the noise is the map's, and a metric residual of fixed sigma would
score it by ``s²`` and reward a small scale the same way. The sigma in map units is
re-derived from the scale found until the two agree. As ``position_sigma_m`` goes to zero the
model becomes ORB-SLAM3's.

Between consecutive keyframes, GTSAM's ``ImuFactorWithGravityDirection`` compares the
preintegrated ``ΔR, Δv, Δp`` with the poses, the velocities, the bias (first-order bias
correction) and gravity; a ``CustomFactor`` per interval wraps it with the rotations fixed.
Before that MAP estimate, two closed-form steps give it a start:

1. the gyroscope bias, by Gauss-Newton on the rotation residuals ``Log(ΔR(b_g)ᵀ R_iᵀ R_j)``
   alone (the keyframes' rotations against the integrated gyroscope); the intervals are then
   preintegrated again around it so that the MAP step's first-order corrections stay small;
2. scale, gravity and velocities by linear least squares on the velocity and position
   equations with zero accelerometer bias (as Mur-Artal and Tardós 2017, Qin et al. 2018),
   written in map units so that the map's positions enter as measurements too; the gravity
   is then given its known magnitude and the rest solved again.

Refusal. An initialisation that the motion does not support is worse than none: a wrong scale
or tilt sticks to the map. ORB-SLAM3 waits for enough keyframes and time. Here a window is
refused (:func:`initialise_inertial` returns None and logs why) when

- it spans fewer than :data:`MIN_KEYFRAMES` keyframes or less than ``min_duration_s``;
- the keyframes' rotations disagree with the gyroscope by more than
  :data:`MAX_ROTATION_RESIDUAL_DEG` RMS per interval even after the bias is fitted (a wrong
  ``body_from_camera``, or a broken visual map);
- the map and the IMU disagree far beyond their stated noise: ``2 · cost`` per degree of
  freedom above :data:`MAX_CHI2_PER_DOF` (a diverged solve, a clock offset, a wrong
  calibration, or a map far noisier than ``position_sigma_m``);
- the MAP estimate leaves the scale or gravity poorly determined: the marginal standard
  deviation of ``λ`` (the scale's relative uncertainty) above ``max_scale_std``, or of the
  gravity direction above ``max_gravity_std_deg``. Both are marginals of the linearised
  problem at the solution, i.e. say how well the map's noise, the IMU's, the bias prior and
  the motion pin them down: a window without acceleration (at rest, or at constant
  velocity) leaves the scale free, and a short or gentle one lets the accelerometer bias and
  the map's noise absorb the motion.

The accelerometer bias prior decides how much of the motion the bias may explain.
:data:`ACCEL_BIAS_SIGMA` of 0.1 m/s² (a tenth of a degree of tilt is 0.017 m/s²) lets a
MEMS IMU's real bias (EuRoC's ADIS16448 carries 0.05-0.15 m/s²) come out instead of tilting
gravity, while a 2 s window's gravity stays determined (0.3 m/s² lets its marginal sigma grow
to 0.7-1.7°). ORB-SLAM3's first monocular initialisation holds the bias near zero
(information 1e10) and frees it in later refinements; its stereo one uses 1e5 (0.003 m/s²).
On 4 s windows of EuRoC MH_05 a prior of 0.01 m/s² tilts gravity by 0.6-0.9° to make up for
the real bias (0.125 m/s² along y); 0.1 leaves 0.4-0.8° and brings the bias within
0.04-0.13 m/s² of EuRoC's. The gyroscope bias is well observed by the rotations alone and
gets a loose prior (:data:`GYRO_BIAS_SIGMA`, ORB-SLAM3's information 1e2).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from itertools import pairwise
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.errors import ConfigError, InputError
from slamcli.geometry import inverse, so3_exp
from slamcli.inertial.preintegration import ImuNoise, check_imu_samples, preintegrate

if TYPE_CHECKING:
    import gtsam

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

MIN_KEYFRAMES = 4
"""Fewest keyframes (three intervals) an initialisation is tried on: the linear step has
``6K + 4`` unknowns and ``9K - 6`` equations."""
MIN_DURATION_S = 1.0
"""Shortest window, s. ORB-SLAM3 waits for 10 keyframes over 2 s (monocular) or 1 s
(stereo); here the marginals judge whether a window longer than 1 s is enough."""
MAX_SCALE_STD = 0.05
"""Largest accepted marginal standard deviation of ``log s``: 5 % of the scale, which the
visual-inertial bundle adjustments that follow an initialisation refine."""
MAX_GRAVITY_STD_DEG = 1.0
"""Largest accepted marginal standard deviation of the gravity direction, degrees."""
MAX_ROTATION_RESIDUAL_DEG = 1.0
"""Largest accepted RMS disagreement, per interval, between the keyframes' relative rotations
and the integrated gyroscope once the gyroscope bias is fitted, degrees."""
MAX_CHI2_PER_DOF = 25.0
"""Largest accepted ``2 · cost`` per degree of freedom: residuals five times their stated
sigma on average mean a wrong calibration, clock offset or noise setting, not a scale."""
ACCEL_BIAS_SIGMA = 0.1
"""Prior standard deviation of the accelerometer bias, m/s² (see the module docstring)."""
GYRO_BIAS_SIGMA = 0.1
"""Prior standard deviation of the gyroscope bias, rad/s."""
POSITION_SIGMA_M = 0.003
"""Standard deviation of a keyframe's metric position about the map's, m: a bundle-adjusted
map of a room-sized scene."""
ROTATION_SIGMA_DEG = 0.05
"""Standard deviation of a keyframe's rotation, degrees; it adds ``2 σ²`` to the rotation
block of each interval's covariance (the rotations are not unknowns)."""
LOG_SCALE_PRIOR_SIGMA = 3.0
"""A weak prior on ``log s`` around the linear step's value: a factor of e³ ≈ 20 either way.
Where the motion fixes the scale it changes nothing (its information is 1e-4 of a 1 % scale
estimate's); where it does not, it keeps the system regular so that the marginals exist and
report the scale as undetermined instead of failing."""
MAX_ITERATIONS = 50

_GYRO_STEPS = 5
_REWEIGHT_ROUNDS = 5
_REWEIGHT_TOL = 0.01
_L, _G, _B = 0, 1, 2


def _v(i: int) -> int:
    """Key of keyframe ``i``'s velocity."""
    return 1_000_000 + i


def _p(i: int) -> int:
    """Key of keyframe ``i``'s position."""
    return 2_000_000 + i


@dataclass(frozen=True)
class InertialInit:
    """The inertial state that makes a visual map metric and gravity-aligned.

    The gravity-aligned world ("world") is the map's frame turned by :attr:`world_from_visual`
    so that gravity points along -z, and scaled by :attr:`scale`; the map's origin stays the
    origin. Its yaw about z is the map's (the smallest rotation that levels the map), as the
    IMU cannot observe it.

    Attributes:
        stamps_ns: (K,) int64 keyframe stamps.
        scale: metres per map unit (the fixed value when the map's scale was given).
        world_from_visual: (3, 3) rotation of the map's frame into the gravity-aligned world.
        gravity_visual: (3,) gravity in the map's frame, m/s² (magnitude 9.80665).
        velocities: (K, 3) velocity of the body (IMU) at each keyframe, m/s, in the world.
        gyro_bias: (3,) rad/s, IMU frame.
        accel_bias: (3,) m/s², IMU frame.
        scale_std: marginal standard deviation of ``log s`` (the scale's relative
            uncertainty); 0 when the scale was fixed.
        gravity_std_deg: marginal standard deviation of the gravity direction (the larger
            axis of its 2-D covariance), degrees.
        cost: GTSAM's final error, ``½ Σ`` squared whitened residuals (IMU, positions,
            priors).
        chi2_per_dof: ``2 · cost`` over the degrees of freedom (residual dimensions minus
            unknowns): about 1 when the stated noise fits the data.
        residuals: (K - 1, 9) each interval's IMU residual at the solution, in GTSAM's order:
            rotation (rad), position (m), velocity (m/s).
        position_residuals: (K, 3) the estimated body positions minus the map's, m.
        rotation_rms_deg: RMS per interval of the rotation residual after the gyroscope bias
            step, degrees.
        iterations: Levenberg-Marquardt iterations.
    """

    stamps_ns: I64
    scale: float
    world_from_visual: F64
    gravity_visual: F64
    velocities: F64
    gyro_bias: F64
    accel_bias: F64
    scale_std: float
    gravity_std_deg: float
    cost: float
    chi2_per_dof: float
    residuals: F64
    position_residuals: F64
    rotation_rms_deg: float
    iterations: int

    def gravity_aligned(self, world_from_camera: ArrayLike) -> F64:
        """Poses of the visual map, (..., 4, 4) ``visual_from_camera``, in the metric,
        gravity-aligned world: rotation ``R_wv R``, position ``s R_wv p``."""
        pose = np.asarray(world_from_camera, dtype=np.float64)
        out = pose.copy()
        out[..., :3, :3] = self.world_from_visual @ pose[..., :3, :3]
        out[..., :3, 3] = self.scale * np.einsum(
            "ij,...j->...i", self.world_from_visual, pose[..., :3, 3]
        )
        return out


def check_keyframes(keyframes: Sequence[tuple[int, ArrayLike]]) -> tuple[I64, F64]:
    """Keyframes as (K,) int64 strictly increasing stamps and (K, 4, 4) float64 poses.

    Raises:
        InputError: a pose that is not a finite rigid (4, 4) transform, or stamps that do
            not increase.
    """
    stamps = np.array([int(s) for s, _ in keyframes], dtype=np.int64)
    poses = [np.asarray(p, dtype=np.float64) for _, p in keyframes]
    if any(p.shape != (4, 4) for p in poses):
        raise InputError("keyframes: expected (stamp_ns, (4, 4) world_from_camera) pairs")
    stack = np.array(poses).reshape(-1, 4, 4)
    if not np.isfinite(stack).all():
        raise InputError("keyframes: a pose is not finite")
    rot = stack[:, :3, :3]
    bad = np.abs(np.einsum("nji,njk->nik", rot, rot) - np.eye(3)).max(axis=(1, 2)) > 1e-6
    if bad.any():
        raise InputError(
            f"keyframes: pose {int(np.flatnonzero(bad)[0])} has no rotation matrix in its "
            "upper-left 3x3",
            hint="give world_from_camera rigid transforms; keep the map's scale in the positions",
        )
    if stamps.size > 1 and not (np.diff(stamps) > 0).all():
        raise InputError("keyframes: stamps must increase", hint="sort the keyframes by time")
    return stamps, stack


def initialise_inertial(
    keyframes: Sequence[tuple[int, ArrayLike]],
    imu: tuple[ArrayLike, ArrayLike, ArrayLike],
    noise: ImuNoise,
    body_from_camera: ArrayLike,
    prior_scale: float | None = None,
    *,
    accel_bias_sigma: float = ACCEL_BIAS_SIGMA,
    gyro_bias_sigma: float = GYRO_BIAS_SIGMA,
    position_sigma_m: float = POSITION_SIGMA_M,
    rotation_sigma_deg: float = ROTATION_SIGMA_DEG,
    min_duration_s: float = MIN_DURATION_S,
    max_scale_std: float = MAX_SCALE_STD,
    max_gravity_std_deg: float = MAX_GRAVITY_STD_DEG,
    max_chi2_per_dof: float = MAX_CHI2_PER_DOF,
    max_iterations: int = MAX_ITERATIONS,
    refusals: list[str] | None = None,
) -> InertialInit | None:
    """Scale, gravity, velocities and biases of a window of keyframes (module docstring).

    Args:
        keyframes: (stamp_ns, (4, 4) ``world_from_camera``) of the visual map, in time order;
            positions in the map's units.
        imu: (M,) int64 stamps, (M, 3) gyro rad/s and (M, 3) accel m/s², IMU frame, covering
            the keyframes' span.
        noise: the IMU's noise model (:meth:`ImuNoise.from_yaml`).
        body_from_camera: (4, 4) the camera's pose on the body (its ``T_BS``), metric.
        prior_scale: the map's metres per unit when it is known (a stereo or RGB-D map: 1.0);
            it is then held fixed. None estimates it (a monocular map).
        accel_bias_sigma, gyro_bias_sigma: zero-mean priors on the biases, m/s² and rad/s.
        position_sigma_m: how far, in metres, a keyframe's position may be from the truth.
        rotation_sigma_deg: the same for its rotation, degrees.
        min_duration_s, max_scale_std, max_gravity_std_deg: refusal thresholds.
        max_iterations: Levenberg-Marquardt iterations.
        refusals: when given, a refused window's reason is appended to it.

    Returns:
        The estimate, or None when the window is refused (the reason is logged at INFO, and
        kept in ``refusals``).

    Raises:
        InputError: malformed keyframes or IMU samples, or IMU samples that do not cover the
            keyframes.
        ConfigError: a non-positive ``prior_scale``, sigma or iteration count.
    """
    stamps, world_from_camera = check_keyframes(keyframes)
    samples = check_imu_samples(*imu)
    _check_settings(
        prior_scale=prior_scale,
        accel_bias_sigma=accel_bias_sigma,
        gyro_bias_sigma=gyro_bias_sigma,
        position_sigma_m=position_sigma_m,
        rotation_sigma_deg=rotation_sigma_deg,
        max_iterations=max_iterations,
    )
    duration = float(stamps[-1] - stamps[0]) * 1e-9 if stamps.size else 0.0
    if stamps.size < MIN_KEYFRAMES or duration < min_duration_s:
        return _refuse(
            refusals,
            f"{stamps.size} keyframes over {duration:.2f} s: an inertial initialisation needs "
            f"at least {MIN_KEYFRAMES} keyframes over {min_duration_s:g} s",
        )
    import gtsam

    frames = _BodyFrames(world_from_camera, np.asarray(body_from_camera, dtype=np.float64))
    params = noise.params()
    rotation_cov = np.diag(np.repeat([2 * math.radians(rotation_sigma_deg) ** 2, 0.0, 0.0], 3))
    pims = _integrate(stamps, samples, params, gtsam.imuBias.ConstantBias())
    gyro_bias, rotation_rms = _gyro_bias(
        pims, [pim.preintMeasCov() + rotation_cov for pim in pims], frames, gyro_bias_sigma
    )
    if rotation_rms > MAX_ROTATION_RESIDUAL_DEG:
        return _refuse(
            refusals,
            f"the keyframes' rotations disagree with the gyroscope by {rotation_rms:.2f} deg "
            f"RMS per interval (at most {MAX_ROTATION_RESIDUAL_DEG:g}): check body_from_camera "
            "and the clock offset between camera and IMU",
        )
    bias0 = gtsam.imuBias.ConstantBias(np.zeros(3), gyro_bias)
    pims = _integrate(stamps, samples, params, bias0)
    covs = [pim.preintMeasCov() + rotation_cov for pim in pims]
    start = _linear_alignment(pims, covs, frames, noise.gravity_mps2, prior_scale, position_sigma_m)
    graph, result, iterations = _optimise(
        pims,
        covs,
        frames,
        start,
        _start_values(frames, start, bias0, prior_scale),
        prior_scale,
        position_sigma_m,
        np.repeat([accel_bias_sigma, gyro_bias_sigma], 3),
        max_iterations,
    )
    init = _collect(graph, result, pims, frames, stamps, prior_scale, noise.gravity_mps2)
    if init is None:
        return _refuse(
            refusals, "the scale and gravity are not determined: their information is singular"
        )
    init = replace(init, rotation_rms_deg=rotation_rms, iterations=iterations)
    if init.chi2_per_dof > max_chi2_per_dof:
        return _refuse(
            refusals,
            f"the map and the IMU disagree far beyond their noise (chi2 per degree of freedom "
            f"{init.chi2_per_dof:.3g}, at most {max_chi2_per_dof:g}): check the clock offset, "
            "body_from_camera and position_sigma_m",
        )
    if init.scale_std > max_scale_std or init.gravity_std_deg > max_gravity_std_deg:
        return _refuse(
            refusals,
            f"too little excitation: the scale's relative uncertainty is {init.scale_std:.3g} "
            f"(at most {max_scale_std:g}) and gravity's {init.gravity_std_deg:.3g} deg (at most "
            f"{max_gravity_std_deg:g}) over {stamps.size} keyframes and {duration:.2f} s",
        )
    return init


def _check_settings(prior_scale: float | None, max_iterations: int, **sigmas: float) -> None:
    if prior_scale is not None and not (math.isfinite(prior_scale) and prior_scale > 0):
        raise ConfigError(f"prior_scale: expected a positive number of metres, got {prior_scale}")
    for name, value in sigmas.items():
        if not (math.isfinite(value) and value > 0):
            raise ConfigError(f"{name}: expected a positive standard deviation, got {value}")
    if max_iterations < 1:
        raise ConfigError(f"max_iterations: expected at least 1, got {max_iterations}")


def _refuse(refusals: list[str] | None, reason: str) -> InertialInit | None:
    """None, the answer for a refused window, with ``reason`` logged and appended to
    ``refusals`` when given."""
    if refusals is not None:
        refusals.append(reason)
    log.info("inertial initialisation refused: %s", reason)
    return None


class _BodyFrames:
    """The keyframes' body (IMU) poses as functions of the scale.

    Attributes:
        rotations: (K, 3, 3) ``R_vb``, body to map frame.
        positions: (K, 3) camera positions in map units, relative to the first keyframe's.
        lever: (K, 3) the body's offset from the camera in the map frame, metres.
    """

    def __init__(self, world_from_camera: F64, body_from_camera: F64) -> None:
        camera_from_body = inverse(body_from_camera)
        world_from_body = world_from_camera @ camera_from_body
        self.rotations: F64 = world_from_body[:, :3, :3]
        self.positions: F64 = world_from_camera[:, :3, 3] - world_from_camera[0, :3, 3]
        self.lever: F64 = world_from_camera[:, :3, :3] @ camera_from_body[:3, 3]

    def position(self, i: int, scale: float) -> F64:
        """(3,) keyframe ``i``'s metric body position for map scale ``scale``."""
        return scale * self.positions[i] + self.lever[i]

    def pose(self, i: int, position: ArrayLike) -> gtsam.Pose3:
        """Keyframe ``i``'s body pose with its rotation and ``position``."""
        import gtsam

        return gtsam.Pose3(gtsam.Rot3(self.rotations[i]), np.asarray(position, dtype=np.float64))


def _integrate(
    stamps: I64,
    imu: tuple[I64, F64, F64],
    params: gtsam.PreintegrationParams,
    bias: gtsam.imuBias.ConstantBias,
) -> list[gtsam.PreintegratedImuMeasurements]:
    return [preintegrate(*imu, int(a), int(b), bias, params) for a, b in pairwise(stamps)]


def _imu_values(
    pose_i: gtsam.Pose3,
    vel_i: F64,
    pose_j: gtsam.Pose3,
    vel_j: F64,
    bias: gtsam.imuBias.ConstantBias,
    gravity: gtsam.Unit3,
) -> gtsam.Values:
    """Values for an ``ImuFactorWithGravityDirection(0, 1, 2, 3, 4, 5, pim)``."""
    import gtsam

    v = gtsam.Values()
    v.insert(0, pose_i)
    v.insert(1, np.asarray(vel_i, dtype=np.float64))
    v.insert(2, pose_j)
    v.insert(3, np.asarray(vel_j, dtype=np.float64))
    v.insert(4, bias)
    v.insert(5, gravity)
    return v


def _unwhitened(factor: gtsam.NoiseModelFactor, values: gtsam.Values) -> F64:
    """(rows, dim + 1) the factor's Jacobian and error ``[H | e]`` at ``values``, unwhitened
    (``linearize`` gives the whitened ``[R H | -R e]``)."""
    a, rhs = factor.linearize(values).jacobian()
    model: Any = factor.noiseModel()
    return np.linalg.solve(model.R(), np.column_stack([a, -rhs]))


def _gyro_bias(
    pims: list[gtsam.PreintegratedImuMeasurements],
    covariances: list[F64],
    frames: _BodyFrames,
    sigma: float,
) -> tuple[F64, float]:
    """Step 1: the gyroscope bias that best turns the integrated gyroscope into the
    keyframes' relative rotations, and the RMS rotation residual per interval (degrees).

    The rotation rows of GTSAM's IMU factor depend on the rotations and the gyroscope bias
    only. Their unwhitened Jacobian with respect to the bias (columns 3-5 of its 6: GTSAM's
    bias is ``[accel, gyro]``) drives a few Gauss-Newton steps, each residual weighted by the
    rotation block of ``covariances``.
    """
    import gtsam

    bias = np.zeros(3)
    down = gtsam.Unit3(np.array([0.0, 0.0, -1.0]))
    factors = [gtsam.ImuFactorWithGravityDirection(0, 1, 2, 3, 4, 5, pim) for pim in pims]
    weights = [np.linalg.inv(c[:3, :3]) for c in covariances]
    zero = np.zeros(3)
    rms = math.nan
    for _ in range(_GYRO_STEPS):
        h = np.eye(3) / sigma**2
        g = bias / sigma**2
        sq = 0.0
        b = gtsam.imuBias.ConstantBias(zero, bias)
        for k, (factor, w) in enumerate(zip(factors, weights, strict=True)):
            values = _imu_values(
                frames.pose(k, zero), zero, frames.pose(k + 1, zero), zero, b, down
            )
            system = _unwhitened(factor, values)
            r, j = system[:3, -1], system[:3, 21:24]
            h += j.T @ w @ j
            g += j.T @ w @ r
            sq += float(r @ r)
        rms = math.degrees(math.sqrt(sq / len(pims)))
        step = np.linalg.solve(h, -g)
        bias = bias + step
        if np.linalg.norm(step) < 1e-9:
            break
    return bias, rms


@dataclass(frozen=True)
class _Start:
    """The linear step's answer: metres per map unit, gravity in the map frame (m/s²) and
    (K, 3) velocities (m/s, map orientation)."""

    scale: float
    gravity: F64
    velocities: F64


def _linear_alignment(
    pims: list[gtsam.PreintegratedImuMeasurements],
    covariances: list[F64],
    frames: _BodyFrames,
    gravity_mps2: float,
    prior_scale: float | None,
    position_sigma_m: float,
) -> _Start:
    """Step 2: scale, gravity and velocities (map orientation) by linear least squares,
    accelerometer bias taken as zero.

    The unknowns are in map units: ``u = 1 / s``, ``h = g / s``, ``w_i = v_i / s`` and the
    camera's true map position ``q_i``, which the map measures as ``p̄_i`` with
    ``position_sigma_m``. For interval ``i -> j`` of ``Δt`` seconds, with body rotations
    ``R`` and lever arms ``l``, the IMU's equations divided by ``s``::

        w_j - w_i - h Δt                   = u R_i Δv
        q_j - q_i - w_i Δt - ½ h Δt²       = u (R_i Δp + l_i - l_j)

    are linear in all of them, and so are the map's ``q_i = p̄_i``. Holding the map's
    positions as exact instead (``s (p̄_j - p̄_i)`` on the left) would make a linear system
    too, but a biased one: the noise of the positions would have to be explained as motion,
    and the scale would come out the smaller the noisier they are. Rows are weighted by the
    inverse standard deviations of ``covariances`` and ``position_sigma_m`` (all in metres;
    in map units each is divided by the same ``s``). The gravity found is then given its
    known magnitude, ``h = u G n``, and the rest solved again around its direction ``n``. A
    fixed scale moves to the right-hand side. A scale that comes out non-positive (no
    acceleration to see it by) starts the MAP step at 1, which then reports it undetermined.
    """
    k = len(pims) + 1
    u_fixed = None if prior_scale is None else 1.0 / prior_scale

    def solve(down: F64 | None) -> F64:
        # Columns: [u] [h (3) while gravity is free] q (3K) w (3K).
        c_h = 0 if u_fixed is not None else 1
        c_q = c_h + (3 if down is None else 0)
        c_w = c_q + 3 * k
        cols = c_w + 3 * k
        rows_a: list[F64] = []
        rows_b: list[F64] = []

        def add(a: F64, u_coef: F64, sd: F64) -> None:
            # a x - u u_coef = 0, with u a column or fixed.
            b = np.zeros(3)
            if u_fixed is None:
                a[:, 0] = -u_coef
            else:
                b = u_fixed * u_coef
            rows_a.append(a / sd[:, None])
            rows_b.append(b / sd)

        eye = np.eye(3)
        for i, pim in enumerate(pims):
            dt = pim.deltaTij()
            ri = frames.rotations[i]
            sd = np.sqrt(np.diag(covariances[i]))
            dv = ri @ pim.deltaVij()
            dp = ri @ pim.deltaPij() + frames.lever[i] - frames.lever[i + 1]
            a_v = np.zeros((3, cols))
            a_p = np.zeros((3, cols))
            a_v[:, c_w + 3 * i + 3 : c_w + 3 * i + 6] = eye
            a_v[:, c_w + 3 * i : c_w + 3 * i + 3] = -eye
            a_p[:, c_q + 3 * i + 3 : c_q + 3 * i + 6] = eye
            a_p[:, c_q + 3 * i : c_q + 3 * i + 3] = -eye
            a_p[:, c_w + 3 * i : c_w + 3 * i + 3] = -dt * eye
            if down is None:
                a_v[:, c_h : c_h + 3] = -dt * eye
                a_p[:, c_h : c_h + 3] = -0.5 * dt**2 * eye
            else:
                dv = dv + gravity_mps2 * dt * down
                dp = dp + 0.5 * gravity_mps2 * dt**2 * down
            add(a_v, dv, sd[6:9])
            add(a_p, dp, sd[3:6])
        a_map = np.zeros((3 * k, cols))
        a_map[:, c_q:c_w] = np.eye(3 * k)
        rows_a.append(a_map / position_sigma_m)
        rows_b.append(frames.positions.reshape(-1) / position_sigma_m)
        return np.linalg.lstsq(np.concatenate(rows_a), np.concatenate(rows_b), rcond=None)[0]

    x = solve(None)
    u = u_fixed if u_fixed is not None else float(x[0])
    first = 0 if u_fixed is not None else 1
    h = x[first : first + 3] * (1.0 if u >= 0 else -1.0)
    norm = float(np.linalg.norm(h))
    # Without a usable direction, start from the map's own -z.
    down = h / norm if math.isfinite(norm) and norm > 1e-12 else np.array([0.0, 0.0, -1.0])
    x = solve(down)
    if u_fixed is None:
        u = float(x[0])
        scale = 1.0 / u if math.isfinite(u) and u > 1e-9 else 1.0
    else:
        scale = float(prior_scale)  # type: ignore[arg-type]
    velocities = x[-3 * k :].reshape(k, 3) * scale
    return _Start(scale, gravity_mps2 * down, velocities)


def _imu_interval_factor(
    pim: gtsam.PreintegratedImuMeasurements,
    covariance: F64,
    frames: _BodyFrames,
    i: int,
) -> gtsam.CustomFactor:
    """The IMU factor of interval ``i -> i + 1`` on gravity, the two positions and velocities
    and the bias.

    GTSAM's ``ImuFactorWithGravityDirection`` is evaluated on the two body poses (the map's
    rotation, the position unknown); its error and Jacobians are unwhitened with its own
    square-root information (the IMU's covariance alone), the pose Jacobians reduced to their
    position columns (a pose moves by ``R v`` for a tangent ``v``, so ``∂/∂p = H_v Rᵀ``), and
    the factor is weighed by ``covariance`` instead, which adds the keyframes' rotation noise.
    """
    import gtsam

    inner = gtsam.ImuFactorWithGravityDirection(0, 1, 2, 3, 4, 5, pim)
    keys = [_G, _p(i), _v(i), _p(i + 1), _v(i + 1), _B]
    rot_i, rot_j = frames.rotations[i], frames.rotations[i + 1]

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians: Any) -> F64:
        v = _imu_values(
            frames.pose(i, values.atPoint3(_p(i))),
            values.atVector(_v(i)),
            frames.pose(i + 1, values.atPoint3(_p(i + 1))),
            values.atVector(_v(i + 1)),
            values.atConstantBias(_B),
            values.atUnit3(_G),
        )
        if jacobians is None:
            return np.asarray(inner.unwhitenedError(v), dtype=np.float64)
        h = _unwhitened(inner, v)
        blocks = [
            h[:, 24:26],
            h[:, 3:6] @ rot_i.T,
            h[:, 6:9],
            h[:, 12:15] @ rot_j.T,
            h[:, 15:18],
            h[:, 18:24],
        ]
        for n, block in enumerate(blocks):
            jacobians[n] = np.ascontiguousarray(block)
        return np.ascontiguousarray(h[:, -1])

    return gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(covariance), keys, error)


def _position_factor(
    frames: _BodyFrames, i: int, map_sigma: float, fixed_scale: float | None
) -> gtsam.NonlinearFactor:
    """Keyframe ``i``'s body position against the map's.

    With the scale fixed, a prior ``p_i - (s p̄_i + l_i)`` of ``map_sigma`` metres.
    Otherwise the residual is in map units, ``(p_i - l_i) / s - p̄_i``, of ``map_sigma`` map
    units: the map's noise is in its own units, and a metric residual of fixed sigma would
    score every solution's noise by ``s²`` and reward a smaller scale for it (the
    log-determinant a least-squares cost leaves out). ``∂/∂λ = -(p_i - l_i) / s``,
    ``∂/∂p_i = I / s``.
    """
    import gtsam

    model = gtsam.noiseModel.Isotropic.Sigma(3, map_sigma)
    if fixed_scale is not None:
        return gtsam.PriorFactorPoint3(_p(i), frames.position(i, fixed_scale), model)
    map_position = frames.positions[i]
    lever = frames.lever[i]

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians: Any) -> F64:
        inv_scale = math.exp(-values.atVector(_L)[0])
        arm = np.asarray(values.atPoint3(_p(i)), dtype=np.float64) - lever
        if jacobians is not None:
            jacobians[0] = (-inv_scale * arm).reshape(3, 1)
            jacobians[1] = inv_scale * np.eye(3)
        return inv_scale * arm - map_position

    return gtsam.CustomFactor(model, [_L, _p(i)], error)


def _optimise(
    pims: list[gtsam.PreintegratedImuMeasurements],
    covariances: list[F64],
    frames: _BodyFrames,
    start: _Start,
    values: gtsam.Values,
    prior_scale: float | None,
    position_sigma_m: float,
    bias_sigmas: F64,
    max_iterations: int,
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, int]:
    """Step 3: Levenberg-Marquardt on the graph of :func:`_map_problem`.

    The map's position noise is weighed in map units, ``position_sigma_m / s``; each round
    re-derives it from the scale the previous round found, until the scale moves by less
    than 1 % (a fixed scale needs one round).

    Returns:
        The last round's graph, its solution and the iterations of all rounds.
    """
    import gtsam

    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(max_iterations)
    lm.setRelativeErrorTol(1e-10)
    lm.setAbsoluteErrorTol(1e-12)
    noise_scale = start.scale if prior_scale is None else 1.0
    iterations = 0
    for _ in range(_REWEIGHT_ROUNDS):
        graph = _map_problem(
            pims,
            covariances,
            frames,
            start,
            prior_scale,
            position_sigma_m / noise_scale,
            bias_sigmas,
        )
        optimiser = gtsam.LevenbergMarquardtOptimizer(graph, values, lm)
        values = optimiser.optimize()
        iterations += int(optimiser.iterations())
        if prior_scale is not None:
            break
        scale = math.exp(values.atVector(_L)[0])
        if abs(math.log(scale / noise_scale)) < _REWEIGHT_TOL:
            break
        noise_scale = scale
    return graph, values, iterations


def _map_problem(
    pims: list[gtsam.PreintegratedImuMeasurements],
    covariances: list[F64],
    frames: _BodyFrames,
    start: _Start,
    prior_scale: float | None,
    map_sigma: float,
    bias_sigmas: F64,
) -> gtsam.NonlinearFactorGraph:
    """Step 3: the inertial-only factor graph, the map's positions weighed by ``map_sigma``
    in map units (metres when the scale is fixed)."""
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    for i, pim in enumerate(pims):
        graph.add(_imu_interval_factor(pim, covariances[i], frames, i))
    for i in range(len(pims) + 1):
        graph.add(_position_factor(frames, i, map_sigma, prior_scale))
    if prior_scale is None:
        graph.add(
            gtsam.PriorFactorVector(
                _L,
                np.array([math.log(start.scale)]),
                gtsam.noiseModel.Isotropic.Sigma(1, LOG_SCALE_PRIOR_SIGMA),
            )
        )
    graph.add(
        gtsam.PriorFactorConstantBias(
            _B, gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Diagonal.Sigmas(bias_sigmas)
        )
    )
    return graph


def _start_values(
    frames: _BodyFrames,
    start: _Start,
    bias0: gtsam.imuBias.ConstantBias,
    prior_scale: float | None,
) -> gtsam.Values:
    """The MAP step's starting point: the linear step's scale, gravity and velocities, the
    positions the scale places, the gyroscope bias of step 1."""
    import gtsam

    values = gtsam.Values()
    for i in range(len(frames.positions)):
        values.insert(_p(i), frames.position(i, start.scale))
        values.insert(_v(i), np.asarray(start.velocities[i], dtype=np.float64))
    if prior_scale is None:
        values.insert(_L, np.array([math.log(start.scale)]))
    values.insert(_G, gtsam.Unit3(start.gravity))
    values.insert(_B, bias0)
    return values


def _collect(
    graph: gtsam.NonlinearFactorGraph,
    result: gtsam.Values,
    pims: list[gtsam.PreintegratedImuMeasurements],
    frames: _BodyFrames,
    stamps: I64,
    prior_scale: float | None,
    gravity_mps2: float,
) -> InertialInit | None:
    """The estimate as an :class:`InertialInit`; None when its marginals do not exist."""
    import gtsam

    cov = _marginal_covariance(graph, result, [_G] if prior_scale is not None else [_G, _L])
    if cov is None:
        return None
    gravity_cov = cov[:2, :2]
    scale_var = 0.0 if prior_scale is not None else float(cov[2, 2])
    scale = prior_scale if prior_scale is not None else math.exp(result.atVector(_L)[0])
    down = result.atUnit3(_G)
    direction = np.asarray(down.point3(), dtype=np.float64)
    bias = result.atConstantBias(_B)
    velocities = np.array([result.atVector(_v(i)) for i in range(stamps.size)])
    positions = np.array([result.atPoint3(_p(i)) for i in range(stamps.size)])
    residuals = np.array(
        [
            gtsam.ImuFactorWithGravityDirection(0, 1, 2, 3, 4, 5, pim).unwhitenedError(
                _imu_values(
                    frames.pose(i, positions[i]),
                    velocities[i],
                    frames.pose(i + 1, positions[i + 1]),
                    velocities[i + 1],
                    bias,
                    down,
                )
            )
            for i, pim in enumerate(pims)
        ]
    ).reshape(-1, 9)
    world_from_visual = levelling_rotation(direction)
    cost = float(graph.error(result))
    dof = sum(graph.at(k).dim() for k in range(graph.size())) - result.dim()
    return InertialInit(
        stamps_ns=stamps,
        scale=float(scale),
        world_from_visual=world_from_visual,
        gravity_visual=direction * gravity_mps2,
        velocities=velocities @ world_from_visual.T,
        gyro_bias=np.asarray(bias.gyroscope(), dtype=np.float64),
        accel_bias=np.asarray(bias.accelerometer(), dtype=np.float64),
        scale_std=math.sqrt(max(scale_var, 0.0)),
        gravity_std_deg=math.degrees(math.sqrt(max(np.linalg.eigvalsh(gravity_cov).max(), 0))),
        cost=cost,
        chi2_per_dof=2.0 * cost / max(dof, 1),
        residuals=residuals,
        position_residuals=positions
        - np.array([frames.position(i, scale) for i in range(stamps.size)]),
        rotation_rms_deg=math.nan,
        iterations=0,
    )


def _marginal_covariance(
    graph: gtsam.NonlinearFactorGraph, result: gtsam.Values, last: list[int]
) -> F64 | None:
    """The joint marginal covariance of the variables ``last`` at ``result``; None when the
    system leaves them undetermined.

    The linearised system's dense whitened Jacobian, with ``last`` ordered last, is
    factorised by Householder QR; the bottom-right block of ``R`` is the square root of
    their marginal information. ``gtsam.Marginals`` does the same by Cholesky on the normal
    equations, which squares the condition number and gives up on windows (a weak scale,
    centimetre map noise, sub-millimetre IMU noise) whose marginals are still well defined.
    """
    import gtsam

    ordering = gtsam.Ordering()
    keys = result.keys()
    for key in keys:
        if key not in last:
            ordering.push_back(key)
    for key in last:
        ordering.push_back(key)
    a, _ = graph.linearize(result).jacobian(ordering)
    r = np.linalg.qr(a).R
    dim = sum(result.atUnit3(k).dim() if k == _G else 1 for k in last)
    tail = r[-dim:, -dim:]
    diag = np.abs(np.diag(tail))
    if not np.isfinite(tail).all() or diag.min() <= 1e-12 * max(np.abs(np.diag(r)).max(), 1.0):
        return None
    inv = np.linalg.solve(tail, np.eye(dim))
    return inv @ inv.T


def levelling_rotation(down: ArrayLike) -> F64:
    """(3, 3) the smallest rotation that turns the unit vector ``down`` onto (0, 0, -1).

    A turn about ``down × (0, 0, -1)`` by the angle between them; a ``down`` pointing
    straight up turns by π about x.
    """
    d = np.asarray(down, dtype=np.float64)
    d = d / np.linalg.norm(d)
    target = np.array([0.0, 0.0, -1.0])
    c = float(d @ target)
    if c < -1.0 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    v = np.cross(d, target)
    sin = float(np.linalg.norm(v))
    if sin < 1e-15:
        return np.eye(3)
    return so3_exp(v / sin * math.atan2(sin, c))


def gravity_angle_deg(a: ArrayLike, b: ArrayLike) -> float:
    """Angle between two gravity vectors, degrees."""
    u = np.asarray(a, dtype=np.float64)
    w = np.asarray(b, dtype=np.float64)
    cos = float(u @ w) / float(np.linalg.norm(u) * np.linalg.norm(w))
    return math.degrees(math.acos(min(1.0, max(-1.0, cos))))


__all__ = [
    "InertialInit",
    "check_keyframes",
    "gravity_angle_deg",
    "initialise_inertial",
    "levelling_rotation",
]
