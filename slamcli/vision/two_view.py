"""Two-view geometry for monocular SLAM: initialisation from an essential matrix or a
homography, and checked triangulation.

:func:`two_view_geometry` follows ORB-SLAM's initialiser: both models are fitted by RANSAC
(OpenCV, seeded), each is scored by how many correspondences it explains within the χ² gates
(symmetric transfer error for the homography, distances to the epipolar lines for the essential
matrix), and the homography is chosen when it takes more than 45 % of the total score (a planar
or low-parallax scene). The relative pose of the chosen model is the one whose triangulated
points lie in front of both cameras; it is accepted only with enough such points and enough
parallax (a camera that only turns cannot be initialised: there is no baseline).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slamcli.types import PinholeCamera

F64 = NDArray[np.float64]


@dataclass
class TwoView:
    """The outcome of :func:`two_view_geometry`.

    Attributes:
        points: (M, 3) triangulated points in the first camera's frame (rows of ``good``
            valid), or None when initialisation was refused.
        good: (M,) bool, the correspondences triangulated and checked.
        cur_from_ref: (4, 4) the second camera's pose relative to the first (unit baseline).
        model: "essential" or "homography".
        parallax_deg: median parallax of the good points.
        reason: why it was refused (empty when accepted).
    """

    points: F64 | None
    good: NDArray[np.bool_]
    cur_from_ref: F64
    model: str
    parallax_deg: float
    reason: str = ""


def two_view_geometry(
    camera: PinholeCamera,
    ref_px: F64,
    cur_px: F64,
    sigma_px: F64,
    *,
    min_parallax_deg: float = 1.0,
    min_points: int = 50,
    seed: int = 0,
) -> TwoView:
    """Relative pose and points from (M, 2) undistorted pixel correspondences of two views."""
    import cv2

    k = camera.K
    m = len(ref_px)
    none = TwoView(None, np.zeros(m, bool), np.eye(4), "", 0.0)
    if m < 8:
        none.reason = "too_few_matches"
        return none
    cv2.setRNGSeed(seed)
    found_h, _ = cv2.findHomography(ref_px, cur_px, cv2.RANSAC, 3.0, maxIters=500)
    cv2.setRNGSeed(seed)
    found_e, _ = cv2.findEssentialMat(ref_px, cur_px, k, cv2.RANSAC, 0.999, 1.0, maxIters=500)
    h_mat = None if found_h is None else np.asarray(found_h, dtype=np.float64)
    e_mat = None if found_e is None else np.asarray(found_e, dtype=np.float64)
    score_h = _score_homography(h_mat, ref_px, cur_px, sigma_px) if h_mat is not None else 0.0
    score_f = (
        _score_fundamental(_fundamental(e_mat[:3], k), ref_px, cur_px, sigma_px)
        if e_mat is not None and e_mat.shape[0] >= 3
        else 0.0
    )
    if score_h + score_f <= 0:
        none.reason = "no_model"
        return none
    use_h = score_h / (score_h + score_f) > 0.45
    candidates: list[F64] = []
    if use_h:
        assert h_mat is not None
        _, rots, trans, _ = cv2.decomposeHomographyMat(h_mat, k)
        for r, t in zip(rots, trans, strict=True):
            pose = np.eye(4)
            pose[:3, :3] = r
            pose[:3, 3] = np.asarray(t).reshape(3)
            candidates.append(pose)
    else:
        assert e_mat is not None
        r1, r2, t = cv2.decomposeEssentialMat(e_mat[:3])
        for r in (r1, r2):
            for sign in (1.0, -1.0):
                pose = np.eye(4)
                pose[:3, :3] = r
                pose[:3, 3] = sign * np.asarray(t).reshape(3)
                candidates.append(pose)
    results = []
    for pose in candidates:
        n = float(np.linalg.norm(pose[:3, 3]))
        if n < 1e-9:
            continue
        pose = pose.copy()
        pose[:3, 3] /= n
        pts, ok, parallax = _triangulate_pair(camera, np.eye(4), pose, ref_px, cur_px, sigma_px)
        results.append((int(np.count_nonzero(ok)), pose, pts, ok, parallax))
    if not results:
        none.reason = "no_model"
        return none
    results.sort(key=lambda r: -r[0])
    best = results[0]
    model = "homography" if use_h else "essential"
    if best[0] < min_points:
        return TwoView(None, best[3], best[1], model, 0.0, "too_few_points")
    if len(results) > 1 and results[1][0] > 0.7 * best[0]:
        return TwoView(None, best[3], best[1], model, 0.0, "ambiguous")
    median_parallax = float(np.median(best[4][best[3]]))
    if median_parallax < min_parallax_deg:
        return TwoView(None, best[3], best[1], model, median_parallax, "low_parallax")
    return TwoView(best[2], best[3], best[1], model, median_parallax)


def _fundamental(e: F64, k: F64) -> F64:
    kinv = np.linalg.inv(k)
    return np.asarray(kinv.T @ e @ kinv, dtype=np.float64)


def _score_homography(h: F64, a: F64, b: F64, sigma: F64) -> float:
    """ORB-SLAM's homography score: sum over both transfer directions of (5.991 - chi2)
    for the correspondences within the gate."""
    th = 5.991
    inv_s2 = 1.0 / sigma**2
    score = 0.0
    for mat, src, dst in ((h, a, b), (np.linalg.inv(h), b, a)):
        p = np.c_[src, np.ones(len(src))] @ mat.T
        with np.errstate(divide="ignore", invalid="ignore"):
            proj = p[:, :2] / p[:, 2:3]
        chi2 = np.sum((proj - dst) ** 2, axis=1) * inv_s2
        chi2 = np.nan_to_num(chi2, nan=np.inf)
        score += float(np.sum(np.where(chi2 < th, th - chi2, 0.0)))
    return score


def _score_fundamental(f: F64, a: F64, b: F64, sigma: F64) -> float:
    """ORB-SLAM's fundamental score: distances to the epipolar lines in both images, gated at
    3.841 (one degree of freedom), credited against the homography's 5.991."""
    th, credit = 3.841, 5.991
    inv_s2 = 1.0 / sigma**2
    ha, hb = np.c_[a, np.ones(len(a))], np.c_[b, np.ones(len(b))]
    score = 0.0
    for lines, pts in ((ha @ f.T, hb), (hb @ f, ha)):
        num = np.sum(lines * pts, axis=1) ** 2
        den = lines[:, 0] ** 2 + lines[:, 1] ** 2
        chi2 = num / np.maximum(den, 1e-12) * inv_s2
        score += float(np.sum(np.where(chi2 < th, credit - chi2, 0.0)))
    return score


def _triangulate_pair(
    camera: PinholeCamera,
    pose_a: F64,
    pose_b: F64,
    px_a: F64,
    px_b: F64,
    sigma: F64,
    sigma_b: F64 | None = None,
    *,
    min_cos: float = 0.99998,
) -> tuple[F64, NDArray[np.bool_], F64]:
    """Linear triangulation of correspondences seen by cameras ``pose_a`` and ``pose_b``
    (cam_from_world); returns world points, which pass the checks (in front of both, parallax
    beyond ``min_cos`` of the rays, reprojection within 2 px x sigma... chi2 5.991), and the
    parallax of each in degrees."""
    import cv2

    k = camera.K
    pa = k @ pose_a[:3]
    pb = k @ pose_b[:3]
    hom = cv2.triangulatePoints(pa, pb, px_a.T.astype(np.float64), px_b.T.astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        world = (hom[:3] / hom[3]).T
    finite = np.all(np.isfinite(world), axis=1)
    world = np.where(finite[:, None], world, 0.0)
    sb = sigma if sigma_b is None else sigma_b
    ok = finite.copy()
    for pose, px, sg in ((pose_a, px_a, sigma), (pose_b, px_b, sb)):
        pc = world @ pose[:3, :3].T + pose[:3, 3]
        z = pc[:, 2]
        ok &= z > 0
        zs = np.where(z > 0, z, 1.0)
        uv = np.stack(
            [camera.fx * pc[:, 0] / zs + camera.cx, camera.fy * pc[:, 1] / zs + camera.cy], 1
        )
        ok &= np.sum((uv - px) ** 2, axis=1) <= 5.991 * sg**2
    ca = -pose_a[:3, :3].T @ pose_a[:3, 3]
    cb = -pose_b[:3, :3].T @ pose_b[:3, 3]
    ra, rb = world - ca, world - cb
    cos = np.einsum("ij,ij->i", ra, rb) / np.maximum(
        np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1), 1e-12
    )
    ok &= cos < min_cos
    parallax = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return world, ok, parallax


def triangulate_checked(
    camera: PinholeCamera,
    pose_a: F64,
    pose_b: F64,
    px_a: F64,
    px_b: F64,
    sigma_a: F64,
    sigma_b: F64,
) -> tuple[F64, NDArray[np.bool_]]:
    """World points of correspondences between two keyframes (cam_from_world poses) and
    which pass ORB-SLAM's checks: the epipolar constraint, parallax (rays at least about
    0.36 deg apart), positive depth in both and reprojection within the χ² gate."""
    if len(px_a) == 0:
        return np.zeros((0, 3)), np.zeros(0, bool)
    # Epipolar check first: b's point near the line of a's.
    rel = pose_b @ np.linalg.inv(pose_a)
    t = rel[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    f = _fundamental(tx @ rel[:3, :3], camera.K)
    ha, hb = np.c_[px_a, np.ones(len(px_a))], np.c_[px_b, np.ones(len(px_b))]
    lines = ha @ f.T
    num = np.sum(lines * hb, axis=1) ** 2
    den = lines[:, 0] ** 2 + lines[:, 1] ** 2
    epi_ok = num / np.maximum(den, 1e-12) < 3.84 * sigma_b**2
    world, ok, _ = _triangulate_pair(
        camera, pose_a, pose_b, px_a, px_b, sigma_a, sigma_b, min_cos=0.9998
    )
    return world, ok & epi_ok
