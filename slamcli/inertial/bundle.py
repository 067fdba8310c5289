"""Visual-inertial bundle adjustment of a window of keyframes, on GTSAM.

Once a map knows its scale and gravity (:mod:`slamcli.inertial.initialisation`), its local
bundle adjustment is ORB-SLAM3's ``LocalInertialBA``: the reprojection errors of the window's
points, and between consecutive keyframes of the window an IMU term on GTSAM's
``CombinedImuFactor`` (preintegrated rotation, velocity and position with their bias
Jacobians, and the biases' random walk from one keyframe to the next). Each keyframe of the
chain carries a velocity and a bias; the keyframe before the chain is held (pose, velocity
and bias) and fixes the gauge, which an inertial map has only in yaw and position.

The problem's arrays are those of :func:`slamcli.vision.bundle_adjustment.bundle_adjust` (the
map's keyframes as ``cam_from_world``, points, observations with their sigma and, RGB-D or
stereo, depth), with :class:`InertialTerms` added; the result has the same fields, plus the
velocities and biases. Numpy in, numpy out, so that the job runs on the side process as the
visual one does.

**Unknowns.** GTSAM's poses are the body's (``world_from_body``, the IMU frame): a camera's
pose is ``world_from_body @ body_from_camera``, and the projection factors carry
``body_from_camera`` as their sensor offset. Keyframes outside the chain that see the
window's points are held, as in ORB-SLAM3.

**Observations.** A keypoint without depth is a ``GenericProjectionFactorCal3_S2`` (2-D), one
with depth a ``GenericStereoFactor3D`` whose right coordinate is the virtual one,
``u - fx·b/z`` (the weighting the visual adjustment gives depth). Both whitened by the
keypoint's sigma, with a Huber kernel at the 95 % χ² quantile as ORB-SLAM3's; an observation
whose χ² exceeds it afterwards is an outlier, as in the visual adjustment.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry import inverse
from slamcli.inertial.preintegration import ImuNoise, bias_of, integrate
from slamcli.types import PinholeCamera

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

CHI2_MONO = 5.991
"""95 % χ² quantile of 2 degrees of freedom."""
CHI2_STEREO = 7.815
"""95 % χ² quantile of 3 degrees of freedom (u, v and the virtual right u)."""
logger = logging.getLogger(__name__)

HELD_SIGMA = 1e-6
"""Standard deviation of the priors that hold a keyframe's pose, velocity and bias."""
RELATIVE_ERROR_TOL = 1e-4
"""Levenberg-Marquardt stops when an iteration lowers the cost by less than this share
(GTSAM's default, 1e-5, spends a third more time on V1_01's windows to move poses by less
than 0.07 mm)."""
ANCHOR_ACCEL_BIAS_SIGMA = 0.01
"""m/s²: how loosely an anchored keyframe's accelerometer bias is tied to its estimate."""
ANCHOR_ROTATION_SIGMA = 0.1
"""rad: how loosely an anchored keyframe's rotation is tied to its value (the yaw, which
nothing else observes, stays put; the tilt follows the IMU)."""


@dataclass(frozen=True)
class InertialTerms:
    """The inertial part of a bundle adjustment.

    Attributes:
        chain: (C,) indices of the problem's frames linked in time, oldest first; an IMU term
            joins each to the next.
        velocities: (C, 3) their velocities, m/s, world frame.
        biases: (C, 6) their gyroscope (rad/s) and accelerometer (m/s²) biases.
        intervals: C - 1 piecewise-constant readings ``(dt_s, gyro, accel)`` between
            consecutive chain frames (:func:`slamcli.inertial.preintegration.interval_readings`).
        held: how many of the chain's first frames are held (pose, velocity and bias).
        anchored: with ``held = 0``, the chain's first frame is anchored instead: its
            position held, its rotation and bias weakly tied to their current values
            (:data:`ANCHOR_ROTATION_SIGMA`, the initialisation's bias priors), its velocity
            free. The gauge of a whole map's adjustment: its tilt stays free for the IMU to
            correct, as ORB-SLAM3's full inertial adjustment frees gravity's direction.
        noise: the IMU's noise model.
        body_from_camera: (4, 4) the camera's pose on the body.
    """

    chain: I64
    velocities: F64
    biases: F64
    intervals: list[tuple[F64, F64, F64]]
    held: int
    noise: ImuNoise
    body_from_camera: F64
    anchored: bool = False


@dataclass(frozen=True)
class InertialBundleResult:
    """The adjusted window: the fields of
    :class:`slamcli.vision.bundle_adjustment.BundleResult` that the map reads, with the
    chain's velocities and biases."""

    cam_from_world: F64
    points: F64
    obs_chi2: F64
    inlier: NDArray[np.bool_]
    velocities: F64
    biases: F64
    initial_error: float
    final_error: float
    iterations: int
    ms: float


def inertial_bundle_adjust(
    camera: PinholeCamera,
    cam_from_world: F64,
    points: F64,
    obs_frame: I64,
    obs_point: I64,
    obs_uv: F64,
    obs_sigma_px: F64,
    *,
    fixed_frames: NDArray[np.bool_],
    max_iterations: int,
    obs_depth: F64 | None,
    baseline_m: float,
    inertial: InertialTerms,
) -> InertialBundleResult:
    """Adjust the free keyframes, the points and the chain's velocities and biases (module
    docstring). Fixed frames and held chain states come back bit-exact."""
    import gtsam

    start = time.perf_counter()
    X = gtsam.symbol_shorthand.X
    V = gtsam.symbol_shorthand.V
    B = gtsam.symbol_shorthand.B
    L = gtsam.symbol_shorthand.L
    body_from_camera = np.asarray(inertial.body_from_camera, np.float64)
    camera_from_body = inverse(body_from_camera)
    sensor = gtsam.Pose3(body_from_camera)
    n_frames = cam_from_world.shape[0]
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    held = np.asarray(fixed_frames, bool).copy()
    held[inertial.chain[: inertial.held]] = True
    # Poses: free keyframes are unknowns; held ones get a tight prior.
    world_from_body = np.stack([inverse(c) @ camera_from_body for c in cam_from_world])
    seen = np.zeros(n_frames, bool)
    seen[obs_frame] = True
    seen[inertial.chain] = True
    hold = gtsam.noiseModel.Isotropic.Sigma(6, HELD_SIGMA)
    for i in np.flatnonzero(seen).tolist():
        pose = gtsam.Pose3(world_from_body[i])
        values.insert(X(i), pose)
        if held[i]:
            graph.add(gtsam.PriorFactorPose3(X(i), pose, hold))
    for j in range(points.shape[0]):
        values.insert(L(j), points[j])
    # Observations.
    depth = obs_depth if obs_depth is not None else np.full(obs_frame.size, np.nan)
    has_depth = np.isfinite(depth) & (depth > 0)
    K = gtsam.Cal3_S2(camera.fx, camera.fy, 0.0, camera.cx, camera.cy)
    K_stereo = gtsam.Cal3_S2Stereo(camera.fx, camera.fy, 0.0, camera.cx, camera.cy, baseline_m)
    models: dict[tuple[float, bool], gtsam.noiseModel.Base] = {}

    def model(sigma: float, stereo: bool) -> gtsam.noiseModel.Base:
        key = (sigma, stereo)
        if key not in models:
            k = float(np.sqrt(CHI2_STEREO if stereo else CHI2_MONO))
            base = gtsam.noiseModel.Isotropic.Sigma(3 if stereo else 2, sigma)
            models[key] = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Huber.Create(k), base
            )
        return models[key]

    right_u = obs_uv[:, 0] - camera.fx * baseline_m / np.where(has_depth, depth, 1.0)
    for m, (f, p, (u, v), s, d) in enumerate(
        zip(
            obs_frame.tolist(),
            obs_point.tolist(),
            obs_uv.tolist(),
            obs_sigma_px.tolist(),
            has_depth.tolist(),
            strict=True,
        )
    ):
        if d:
            graph.add(
                gtsam.GenericStereoFactor3D(
                    gtsam.StereoPoint2(u, float(right_u[m]), v),
                    model(s, True),
                    X(f),
                    L(p),
                    K_stereo,
                    sensor,
                )
            )
        else:
            graph.add(
                gtsam.GenericProjectionFactorCal3_S2(
                    np.array([u, v]), model(s, False), X(f), L(p), K, sensor
                )
            )
    # The chain: velocities, biases and IMU terms.
    params = inertial.noise.combined_params()
    chain = inertial.chain.tolist()
    hold3 = gtsam.noiseModel.Isotropic.Sigma(3, HELD_SIGMA)
    for c, i in enumerate(chain):
        values.insert(V(i), inertial.velocities[c])
        bias = bias_of(inertial.biases[c])
        values.insert(B(i), bias)
        if c < inertial.held:
            graph.add(gtsam.PriorFactorVector(V(i), inertial.velocities[c], hold3))
            graph.add(
                gtsam.PriorFactorConstantBias(
                    B(i), bias, gtsam.noiseModel.Isotropic.Sigma(6, HELD_SIGMA)
                )
            )
    if inertial.anchored and inertial.held == 0:
        from slamcli.inertial.initialisation import GYRO_BIAS_SIGMA

        i = chain[0]
        sigmas = np.array([ANCHOR_ROTATION_SIGMA] * 3 + [HELD_SIGMA] * 3)
        graph.add(
            gtsam.PriorFactorPose3(
                X(i), gtsam.Pose3(world_from_body[i]), gtsam.noiseModel.Diagonal.Sigmas(sigmas)
            )
        )
        bias = bias_of(inertial.biases[0])
        bias_sigmas = np.array([ANCHOR_ACCEL_BIAS_SIGMA] * 3 + [GYRO_BIAS_SIGMA] * 3)
        graph.add(
            gtsam.PriorFactorConstantBias(B(i), bias, gtsam.noiseModel.Diagonal.Sigmas(bias_sigmas))
        )
    for c, readings in enumerate(inertial.intervals):
        i, j = chain[c], chain[c + 1]
        pim = gtsam.PreintegratedCombinedMeasurements(params, bias_of(inertial.biases[c]))
        integrate(pim, readings)
        graph.add(gtsam.CombinedImuFactor(X(i), V(i), X(j), V(j), B(i), B(j), pim))
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(int(max_iterations))
    lm.setlambdaUpperBound(1e10)
    lm.setRelativeErrorTol(RELATIVE_ERROR_TOL)
    initial_error = graph.error(values)
    optimiser = gtsam.LevenbergMarquardtOptimizer(graph, values, lm)
    try:
        out = optimiser.optimize()
        iterations = optimiser.iterations()
    except RuntimeError as exc:
        # An indeterminate system (a point seen along one ray only): keep the input.
        logger.warning("visual-inertial bundle adjustment failed (%s): the input is kept", exc)
        out, iterations = values, 0
    # Read back: held frames and states bit-exact.
    new_cfw = cam_from_world.copy()
    for i in np.flatnonzero(seen & ~held).tolist():
        new_cfw[i] = inverse(out.atPose3(X(i)).matrix() @ body_from_camera)
    new_points = np.stack([out.atPoint3(L(j)) for j in range(points.shape[0])]).reshape(-1, 3)
    velocities = inertial.velocities.copy()
    biases = inertial.biases.copy()
    for c, i in enumerate(chain):
        if c < inertial.held:
            continue
        velocities[c] = out.atVector(V(i))
        b = out.atConstantBias(B(i))
        biases[c] = np.concatenate([b.gyroscope(), b.accelerometer()])
    chi2 = _chi2(
        camera,
        baseline_m,
        new_cfw,
        new_points,
        obs_frame,
        obs_point,
        obs_uv,
        obs_sigma_px,
        np.where(has_depth, right_u, np.nan),
    )
    inlier = np.isfinite(chi2) & (chi2 < np.where(has_depth, CHI2_STEREO, CHI2_MONO))
    final_error = float(graph.error(out))
    logger.debug(
        "visual-inertial BA: %d frames, %d points, %d observations, %d IMU terms; error "
        "%.4g -> %.4g in %d iterations",
        n_frames,
        points.shape[0],
        obs_frame.size,
        len(inertial.intervals),
        initial_error,
        final_error,
        iterations,
    )
    return InertialBundleResult(
        cam_from_world=new_cfw,
        points=new_points,
        obs_chi2=chi2,
        inlier=inlier,
        velocities=velocities,
        biases=biases,
        initial_error=float(initial_error),
        final_error=final_error,
        iterations=int(iterations),
        ms=(time.perf_counter() - start) * 1e3,
    )


def _chi2(
    camera: PinholeCamera,
    baseline_m: float,
    cam_from_world: F64,
    points: F64,
    obs_frame: I64,
    obs_point: I64,
    obs_uv: F64,
    sigma: F64,
    right_u: F64,
) -> F64:
    """Squared whitened reprojection error of each observation, with the virtual right
    coordinate's where ``right_u`` is finite; inf behind the camera."""
    pose = cam_from_world[obs_frame]
    pc = np.einsum("mij,mj->mi", pose[:, :3, :3], points[obs_point]) + pose[:, :3, 3]
    front = pc[:, 2] > 1e-9
    z = np.where(front, pc[:, 2], 1.0)
    u = camera.fx * pc[:, 0] / z + camera.cx
    v = camera.fy * pc[:, 1] / z + camera.cy
    e = (u - obs_uv[:, 0]) ** 2 + (v - obs_uv[:, 1]) ** 2
    ur = camera.fx * (pc[:, 0] - baseline_m) / z + camera.cx
    e = np.where(np.isfinite(right_u), e + (ur - right_u) ** 2, e)
    return np.where(front, e / sigma**2, np.inf)


__all__ = ["InertialBundleResult", "InertialTerms", "inertial_bundle_adjust"]
