"""Absolute pose by OpenCV: EPnP inside RANSAC, then Levenberg-Marquardt on the inliers.

This is the PnP the dense pipeline seeds its tracking and verifies its loops with; the visual
pipeline uses COLMAP's LO-RANSAC (:func:`slamcli.vision.pnp.absolute_pose`). Poses cross this
module as (4, 4) float64 matrices; OpenCV's rotation vectors never leave it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry import inverse

F64 = NDArray[np.float64]


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
