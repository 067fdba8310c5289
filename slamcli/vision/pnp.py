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
    pycolmap's refinement has no depth term, so this one is written out here; it is small
    (6 unknowns) and vectorised.
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
    delta = np.sqrt(th)
    rot = np.array(cam_from_world, dtype=np.float64)[:3, :3]
    trans = np.array(cam_from_world, dtype=np.float64)[:3, 3]
    terms = _StereoTerms(camera, points, pixels, ur_meas, stereo, bf)
    inlier = np.ones(m, dtype=bool)
    for _ in range(rounds):
        for _ in range(iterations):
            res, front = terms.residuals(rot, trans)
            chi2 = (res[0] ** 2 + res[1] ** 2 + res[2] ** 2) * info
            use = inlier & front
            if np.count_nonzero(use) < 4:
                return None
            # Huber weights on the whitened norm.
            norm = np.sqrt(chi2)
            w = np.where(norm <= delta, info, info * delta / np.maximum(norm, 1e-12))
            w[~use] = 0.0
            h, g = terms.normal_equations(w, res)
            try:
                step = np.asarray(-np.linalg.solve(h, g), dtype=np.float64)
            except np.linalg.LinAlgError:
                return None
            rot, trans = _left_update(step, rot, trans)
            if float(step @ step) < 1e-12:
                break
        res, front = terms.residuals(rot, trans)
        chi2 = (res[0] ** 2 + res[1] ** 2 + res[2] ** 2) * info
        now = front & (chi2 <= th)
        same = bool(np.array_equal(now, inlier))
        inlier = now
        if same:
            break
    if np.count_nonzero(inlier) < 4:
        return None
    # Products of many small rotations drift off SO(3) in the last bits: project back.
    u, _, vt = np.linalg.svd(rot)
    pose = np.eye(4)
    pose[:3, :3] = u @ vt
    pose[:3, 3] = trans
    return PoseEstimate(pose, inlier)


def _left_update(step: F64, rot: F64, trans: F64) -> tuple[F64, F64]:
    """``exp(step) * (rot, trans)`` for a twist ``[rho, phi]`` (closed-form SE(3) exponential)."""
    rho, phi = step[:3], step[3:]
    theta2 = float(phi @ phi)
    k = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    k2 = k @ k
    if theta2 < 1e-12:
        a, b, c = 1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0, 1.0 / 6.0 - theta2 / 120.0
    else:
        theta = math.sqrt(theta2)
        a = math.sin(theta) / theta
        b = (1.0 - math.cos(theta)) / theta2
        c = (theta - math.sin(theta)) / (theta2 * theta)
    exp_r = np.eye(3) + a * k + b * k2
    exp_t = rho + b * (k @ rho) + c * (k2 @ rho)
    return exp_r @ rot, exp_r @ trans + exp_t


class _StereoTerms:
    """Residuals and Gauss-Newton normal equations of :func:`refine_pose_depth`'s
    observations, with what does not change between iterations computed once."""

    def __init__(
        self,
        camera: PinholeCamera,
        points: F64,
        pixels: F64,
        ur_meas: F64,
        stereo: NDArray[np.bool_],
        bf: float,
    ) -> None:
        self.fx, self.fy, self.cx, self.cy = camera.fx, camera.fy, camera.cx, camera.cy
        self.points = points
        self.px, self.py = pixels[:, 0].copy(), pixels[:, 1].copy()
        self.ur_meas = ur_meas
        self.stereo = stereo
        self.sidx = np.flatnonzero(stereo)
        self.bf = bf
        m, s = len(points), self.sidx.size
        # Jacobian rows: u of every point, v of every point, ur of the points with depth;
        # the entries that are always zero are set here once.
        self.jac = np.zeros((6, 2 * m + s))
        self.pc = points
        self.iz = np.ones(m)

    def residuals(self, rot: F64, trans: F64) -> tuple[F64, NDArray[np.bool_]]:
        """(3, M) residuals (predicted - measured; the third 0 without depth) and which
        points are in front of the camera."""
        pc = self.points @ rot.T + trans
        self.pc = pc
        z = pc[:, 2]
        front = z > 1e-6
        iz = 1.0 / np.where(front, z, 1.0)
        self.iz = iz
        u = self.fx * pc[:, 0] * iz + self.cx
        res = np.empty((3, len(pc)))
        res[0] = u - self.px
        res[1] = self.fy * pc[:, 1] * iz + self.cy - self.py
        res[2] = np.where(self.stereo, u - self.bf * iz - self.ur_meas, 0.0)
        return res, front

    def normal_equations(self, w: F64, res: F64) -> tuple[F64, F64]:
        """``J^T W J`` and ``J^T W r`` at the last :meth:`residuals` call's pose, for a left
        perturbation ``[rho, phi]`` (``d pc = rho + phi x pc``)."""
        x, y, z = self.pc[:, 0], self.pc[:, 1], self.pc[:, 2]
        iz = self.iz
        m = x.size
        s = self.sidx
        a = self.fx * iz
        b = self.fy * iz
        # Gradients of u, v and ur with respect to the point in the camera, (gx, gy, gz), and
        # rows [gx, gy, gz, gz*y - gy*z, gx*z - gz*x, gy*x - gx*y].
        gz_u = -a * x * iz
        gz_v = -b * y * iz
        j = self.jac
        ju, jv, jr = j[:, :m], j[:, m : 2 * m], j[:, 2 * m :]
        ju[0] = a
        ju[2] = gz_u
        ju[3] = gz_u * y
        ju[4] = a * z - gz_u * x
        ju[5] = -a * y
        jv[1] = b
        jv[2] = gz_v
        jv[3] = gz_v * y - b * z
        jv[4] = -gz_v * x
        jv[5] = b * x
        gz_r = gz_u[s] + self.bf * iz[s] * iz[s]
        jr[0] = a[s]
        jr[2] = gz_r
        jr[3] = gz_r * y[s]
        jr[4] = a[s] * z[s] - gz_r * x[s]
        jr[5] = -a[s] * y[s]
        ws = np.concatenate([w, w, w[s]])
        r = np.concatenate([res[0], res[1], res[2, s]])
        jw = j * ws
        return jw @ j.T, jw @ r


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
