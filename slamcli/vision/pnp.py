"""Absolute pose from 2-D/3-D correspondences, and the gates that judge a pose.

:func:`absolute_pose` is COLMAP's LO-RANSAC P3P followed by a robust (Cauchy) non-linear
refinement (``pycolmap.estimate_and_refine_absolute_pose``), seeded so that the same input
gives the same pose. :func:`refine_pose` is the refinement alone, for a pose already close
(tracking with a motion prior). :func:`pnp_opencv` is OpenCV's EPnP inside RANSAC followed by
Levenberg-Marquardt, which the dense pipeline seeds its tracking and verifies its loops with
(3.7 times faster per call than COLMAP's there, at equal accuracy). Poses cross this module
as (4, 4) ``cam_from_world`` or ``world_from_cam`` float64 matrices, as each function says;
pycolmap objects and OpenCV's rotation vectors never leave it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry import compose, inverse, rotation_angle
from slamcli.types import PinholeCamera

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class PoseEstimate:
    """A camera pose and the correspondences it explains.

    Attributes:
        cam_from_world: (4, 4) float64.
        inliers: (M,) bool, which correspondences fit within the threshold.
    """

    cam_from_world: F64
    inliers: NDArray[np.bool_]

    @property
    def world_from_cam(self) -> F64:
        return inverse(self.cam_from_world)

    @property
    def num_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))


def _camera(camera: PinholeCamera) -> Any:
    import pycolmap

    return pycolmap.Camera(
        model="PINHOLE",
        width=camera.width,
        height=camera.height,
        params=[camera.fx, camera.fy, camera.cx, camera.cy],
    )


def _to_matrix(rigid: Any) -> F64:
    m = np.eye(4)
    m[:3, :4] = np.asarray(rigid.matrix(), dtype=np.float64)
    return m


def _to_rigid(cam_from_world: F64) -> Any:
    import pycolmap

    return pycolmap.Rigid3d(np.ascontiguousarray(cam_from_world[:3, :4], dtype=np.float64))


def absolute_pose(
    camera: PinholeCamera,
    pixels: F64,
    points: F64,
    *,
    threshold_px: float = 4.0,
    min_inliers: int = 15,
    seed: int = 0,
    max_trials: int = 1000,
) -> PoseEstimate | None:
    """Pose of a pinhole camera that sees world ``points`` (M, 3) at ``pixels`` (M, 2), by
    LO-RANSAC and refinement; None when fewer than ``min_inliers`` correspondences agree.

    ``pixels`` are undistorted (``camera`` is treated as a pinhole). ``seed`` seeds COLMAP's
    RANSAC sampler.
    """
    import pycolmap

    pixels = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 2)
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pixels) < max(4, min_inliers):
        return None
    est = pycolmap.AbsolutePoseEstimationOptions()
    est.ransac.max_error = float(threshold_px)
    est.ransac.random_seed = int(seed)
    est.ransac.max_num_trials = int(max_trials)
    est.ransac.min_num_trials = min(100, int(max_trials))
    est.ransac.num_threads = 1
    ref = pycolmap.AbsolutePoseRefinementOptions()
    ref.loss_function_scale = float(threshold_px) / 2.0
    result = pycolmap.estimate_and_refine_absolute_pose(pixels, points, _camera(camera), est, ref)
    if result is None:
        return None
    mask = np.asarray(result["inlier_mask"], dtype=bool).reshape(-1)
    if np.count_nonzero(mask) < min_inliers:
        return None
    return PoseEstimate(_to_matrix(result["cam_from_world"]), mask)


def reprojection_errors(
    camera: PinholeCamera, cam_from_world: F64, pixels: F64, points: F64
) -> F64:
    """(M,) pixel distance between ``pixels`` and the projections of ``points``; inf for
    points behind the camera."""
    p = points @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera.fx * p[:, 0] / z + camera.cx
        v = camera.fy * p[:, 1] / z + camera.cy
    err = np.hypot(u - pixels[:, 0], v - pixels[:, 1])
    err[~(z > 1e-6)] = np.inf
    return np.asarray(err, dtype=np.float64)


def refine_pose(
    camera: PinholeCamera,
    cam_from_world: F64,
    pixels: F64,
    points: F64,
    *,
    sigma_px: F64 | None = None,
    threshold_px: float = 5.991**0.5,
    rounds: int = 3,
) -> PoseEstimate | None:
    """Refine a pose close to the truth against all correspondences with a robust (Cauchy)
    loss, re-deciding the inliers between rounds (as ORB-SLAM's pose optimisation does: four
    rounds of optimisation with the outliers of the last one left out).

    ``sigma_px`` (M,) is each observation's pixel uncertainty (the ORB octave's scale); an
    observation is an inlier when its error is within ``threshold_px * sigma``. Returns None
    when the refinement fails or leaves fewer than 4 inliers.
    """
    import pycolmap

    pixels = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 2)
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pixels) < 4:
        return None
    sigma = np.ones(len(pixels)) if sigma_px is None else np.asarray(sigma_px, dtype=np.float64)
    cam = _camera(camera)
    pose = np.asarray(cam_from_world, dtype=np.float64)
    inliers = reprojection_errors(camera, pose, pixels, points) <= 2 * threshold_px * sigma
    opts = pycolmap.AbsolutePoseRefinementOptions()
    opts.loss_function_scale = float(threshold_px)
    for _ in range(rounds):
        if np.count_nonzero(inliers) < 4:
            return None
        out = pycolmap.refine_absolute_pose(
            _to_rigid(pose), pixels, points, inliers.reshape(-1, 1), cam, opts
        )
        if out is None:
            return None
        pose = _to_matrix(out["cam_from_world"])
        inliers = reprojection_errors(camera, pose, pixels, points) <= threshold_px * sigma
    if np.count_nonzero(inliers) < 4:
        return None
    return PoseEstimate(pose, inliers)


def pose_change(a: F64, b: F64) -> tuple[float, float]:
    """Translation (m) and rotation (deg) of ``b`` relative to ``a`` (two (4, 4) poses)."""
    rel = compose(inverse(a), b)
    return float(np.linalg.norm(rel[:3, 3])), math.degrees(float(rotation_angle(rel)))


def within(a: F64, b: F64, max_m: float, max_deg: float) -> bool:
    """Whether ``b`` is within ``max_m`` and ``max_deg`` of ``a``."""
    m, deg = pose_change(a, b)
    return m <= max_m and deg <= max_deg


def refine_pose_depth(
    camera: PinholeCamera,
    cam_from_world: F64,
    pixels: F64,
    points: F64,
    depth: F64,
    *,
    sigma_px: F64 | None = None,
    baseline_m: float = 0.08,
    rounds: int = 4,
    iterations: int = 10,
) -> PoseEstimate | None:
    """Refine a pose against 2-D/3-D correspondences where the keypoints may also carry a
    measured depth, as ORB-SLAM's RGB-D pose optimisation does.

    A keypoint with depth ``z`` is treated as a stereo observation ``(u, v, u - bf / z)`` of a
    virtual rig with baseline ``baseline_m`` (``bf = fx * baseline``): the depth then constrains
    the pose with the weight a stereo camera's disparity would, which is what pins down the
    translation when the camera mostly turns. A keypoint without depth (NaN) gives the usual
    ``(u, v)``. Gauss-Newton on SE(3) with Huber weights, up to ``rounds`` rounds of
    ``iterations`` with the outliers of a round (chi-square above 5.99 for two, 7.81 for three
    residuals, in units of ``sigma_px``) left out of the next; a round that leaves the inlier
    set as it was ends the refinement (another would start where this one converged).
    pycolmap's refinement has no depth term, so this one is written out here, compiled
    (:mod:`slamcli.vision._pose_kernels`).
    """
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    z_meas = np.asarray(depth, dtype=np.float64).reshape(-1)
    m = len(pixels)
    if m < 4:
        return None
    sigma = np.ones(m) if sigma_px is None else np.asarray(sigma_px, dtype=np.float64)
    info = 1.0 / sigma**2
    stereo = np.isfinite(z_meas) & (z_meas > 0)
    bf = camera.fx * baseline_m
    ur_meas = np.where(stereo, pixels[:, 0] - bf / np.where(stereo, z_meas, 1.0), 0.0)
    th = np.where(stereo, 7.815, 5.991)
    from slamcli.vision import _pose_kernels

    rot = np.array(cam_from_world, dtype=np.float64)[:3, :3].copy()
    trans = np.array(cam_from_world, dtype=np.float64)[:3, 3].copy()
    held, inlier = _pose_kernels.refine(
        rot,
        trans,
        np.ascontiguousarray(points),
        np.ascontiguousarray(pixels),
        ur_meas,
        stereo,
        info,
        th,
        np.array([camera.fx, camera.fy, camera.cx, camera.cy, bf]),
        rounds,
        iterations,
    )
    if not held or np.count_nonzero(inlier) < 4:
        return None
    # Products of many small rotations drift off SO(3) in the last bits: project back.
    u, _, vt = np.linalg.svd(rot)
    pose = np.eye(4)
    pose[:3, :3] = u @ vt
    pose[:3, 3] = trans
    return PoseEstimate(pose, inlier)


def pnp_opencv(
    object_points: F64,
    image_points: F64,
    K: F64,
    *,
    seed: int,
    iterations: int,
    threshold_px: float,
    min_inliers: int,
) -> tuple[F64 | None, int]:
    """Pose of a pinhole camera that sees ``object_points`` at ``image_points``.

    Args:
        object_points: (M, 3) float64 points in the object (reference) frame, metres.
        image_points: (M, 2) float64 undistorted pixels of those points in the camera.
        K: (3, 3) camera matrix.
        seed: seeds OpenCV's global RNG right before the RANSAC. OpenCV 5's PnP RANSAC
            measured the same pose for every seed (its sampler keeps its own RNG); the seed
            is set anyway so a build whose sampler does use it stays repeatable.
        iterations: RANSAC iterations.
        threshold_px: RANSAC inlier threshold, pixels.
        min_inliers: least inliers for a pose (EPnP needs 4).

    Returns:
        ``(object_from_cam, inliers)``: the (4, 4) pose, or None when RANSAC fails or finds
        fewer than ``min_inliers`` inliers, and the number of RANSAC inliers (0 on failure).
    """
    import cv2

    obj = np.ascontiguousarray(object_points, dtype=np.float64).reshape(-1, 3)
    img = np.ascontiguousarray(image_points, dtype=np.float64).reshape(-1, 2)
    if len(obj) < max(4, min_inliers):
        return None, 0
    cv2.setRNGSeed(seed)
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        obj,
        img,
        K,
        None,
        iterationsCount=iterations,
        reprojectionError=threshold_px,
        confidence=0.999,
        flags=cv2.SOLVEPNP_EPNP,
    )
    count = 0 if inliers is None else len(inliers)
    if not ok or inliers is None or count < min_inliers:
        return None, count
    inl = inliers.reshape(-1)
    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], K, None, rvec, tvec)
    cam_from_object = np.eye(4)
    cam_from_object[:3, :3] = cv2.Rodrigues(rvec)[0]
    cam_from_object[:3, 3] = tvec.reshape(3)
    return inverse(cam_from_object), count
