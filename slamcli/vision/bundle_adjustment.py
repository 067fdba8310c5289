"""Bundle adjustment of keyframe poses and map points: a compiled solver for problems of up to
:data:`COMPILED_MAX_FRAMES` free keyframes, pycolmap (Ceres underneath) for larger ones.

:func:`bundle_adjust` serves both of the visual pipeline's uses: local BA (a window of
keyframes refined, the other keyframes that see the same points held fixed) and global BA
after a loop closure (every keyframe free but the gauge). Numpy in, numpy out: pycolmap objects
never leave this module, and pycolmap is imported only when a large problem is solved.

**Two solvers, one cost.** Both minimise the robust cost below by Levenberg-Marquardt with the
points eliminated. The compiled one (:mod:`slamcli.vision._ba_kernels`) has the Jacobians
written out and a dense reduced camera system: on the local adjustments of the TUM and KITTI
excerpts it ends at the same cost as COLMAP's (within 1e-5 of it), the same inliers and poses
within 0.1 mm, in a tenth of the time (``benchmarks/bench_ba.py``). Its dense system grows with
the cube of the free keyframes, so a global adjustment of a long map goes to COLMAP, whose
Schur complement is sparse.

**Conventions.** Poses are ``cam_from_world`` (K, 4, 4) float64, the camera frame optical
(x right, y down, z forward), pixels ``(u, v)`` undistorted, in the pinhole ``K`` of the
:class:`~slamcli.types.PinholeCamera` (see :mod:`slamcli.geometry.camera`). Intrinsics are never
refined.

**Per-observation sigma** (COLMAP). COLMAP's bundle adjuster has no per-observation weight, but it
has one set of intrinsics per camera and a residual in pixels of that camera. An observation with
sigma ``s`` is therefore handed to a camera whose ``fx, fy, cx, cy`` are divided by ``s``, with its
pixel divided by ``s`` too: the residual ``(project(X) - uv) / s`` is then exactly the whitened
error. One camera per distinct sigma (ORB octaves give eight), all sensors of one rig with identity
``sensor_from_rig`` held constant, so every keyframe is one COLMAP frame holding one image per
sigma it observes with. More than :data:`MAX_SIGMA_GROUPS` distinct sigmas are snapped to that many
geometric levels between the smallest and the largest (a weight error of a few per cent at most).
The price of exact weights: COLMAP's rig cost (every image but the reference sensor's) is
autodiffed over the constant ``sensor_from_rig`` too, and ``benchmarks/bench_ba.py`` measures the
whole call at about twice the time of the same problem with the sigmas omitted (one plain camera).

**Robust loss.** Cauchy on the whitened error, scale ``robust_px`` (ORB-SLAM's sqrt(5.991), the
95 % χ² quantile of two degrees of freedom), by measurement: ``benchmarks/bench_ba.py`` runs both
kernels on a local-BA problem of ORB-SLAM's size. Without outliers they tie (pose error within
3 %); with 5 % gross outliers Cauchy's poses are 6 % (position) and 15 % (rotation) closer to the
truth, with 20 % about 30 % and 40 %. Huber, which ORB-SLAM uses (it then drops the outliers and
runs again without a kernel), bounds an outlier's pull but never removes it; Cauchy's redescends.
Huber stays available as ``robust_loss="huber"``: Cauchy is not convex, and an inlier with a
large error at the start (a poor initial pose) is down-weighted too.

**Gauge.** With ``fix_gauge`` and neither a fixed frame nor a fixed point, the first keyframe
that has an observation is held constant. Reprojections alone cannot see the scale, so while
fewer than two frames (and no point) are fixed, the solution is then scaled about the first fixed
camera's centre so that its distance to the first free keyframe is what it was on input; the
cost is invariant under that similarity, and the fixed camera is not touched.

**Determinism.** Both solvers run single-threaded, so two calls on the same input give
bit-identical output on one machine.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.types import PinholeCamera

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

logger = logging.getLogger(__name__)

CHI2_INLIER = 5.991
"""95 % χ² quantile with two degrees of freedom: the inlier gate on the whitened error."""
CHI2_STEREO = 9.488
"""95 % χ² quantile with four degrees of freedom: the gate of an observation with depth."""
COMPILED_MAX_FRAMES = 100
"""Free keyframes up to which the compiled solver runs (its reduced camera system is dense);
a larger problem goes to COLMAP's, whose Schur complement is sparse."""
MAX_SIGMA_GROUPS = 32
"""Distinct per-observation sigmas kept exactly; beyond, they are snapped to this many levels."""


@dataclass(frozen=True)
class BundleResult:
    """The refined problem.

    Attributes:
        cam_from_world: (K, 4, 4) float64 refined poses; fixed frames are the input, bit-exact.
        points: (P, 3) float64 refined world points (m); fixed and unobserved points unchanged.
        obs_chi2: (M,) float64 squared whitened reprojection error after (px² / sigma²); inf
            where the point is not in front of the camera.
        inlier: (M,) bool, ``obs_chi2 < 5.991`` and positive depth.
        initial_cost: ``0.5 * sum(rho(chi2))`` on the input, rho the robust loss (Ceres'
            convention), over the observations in front of their camera.
        final_cost: the same on the output.
        iterations: Levenberg-Marquardt iterations Ceres ran; 0 when nothing was free, or when
            Ceres failed (logged as a warning; the input is then returned unchanged).
        ms: wall time of the whole call in milliseconds.
    """

    cam_from_world: F64
    points: F64
    obs_chi2: F64
    inlier: BoolArray
    initial_cost: float
    final_cost: float
    iterations: int
    ms: float


def bundle_adjust(
    camera: PinholeCamera,
    cam_from_world: ArrayLike,
    points: ArrayLike,
    obs_frame: ArrayLike,
    obs_point: ArrayLike,
    obs_uv: ArrayLike,
    obs_sigma_px: ArrayLike,
    *,
    fixed_frames: ArrayLike,
    fixed_points: ArrayLike | None = None,
    robust_px: float = 2.45,
    robust_loss: Literal["huber", "cauchy"] = "cauchy",
    max_iterations: int = 10,
    fix_gauge: bool = True,
    obs_depth: ArrayLike | None = None,
    baseline_m: float = 0.08,
) -> BundleResult:
    """Refine keyframe poses and points by minimising robust whitened reprojection errors.

    Args:
        camera: undistorted pinhole (its distortion is ignored; pixels must be undistorted).
        cam_from_world: (K, 4, 4) keyframe poses, camera-from-world.
        points: (P, 3) world points (m).
        obs_frame: (M,) int, the keyframe index of each observation.
        obs_point: (M,) int, the point index of each observation.
        obs_uv: (M, 2) undistorted pixel observations (u, v).
        obs_sigma_px: (M,) pixel sigma of each observation, > 0 (ORB: 1.2**octave).
        fixed_frames: (K,) bool, frames held constant (local BA: the covisible keyframes
            outside the window).
        fixed_points: (P,) bool, points held constant; None = all free.
        robust_px: robust-loss threshold on the whitened error (sqrt(5.991) as in ORB-SLAM).
        robust_loss: "cauchy" (default, see the module docstring) or "huber".
        max_iterations: Levenberg-Marquardt iterations at most, >= 1.
        fix_gauge: hold the first keyframe and the scale when nothing else fixes the gauge.
        obs_depth: (M,) measured depth (m) of each observation (RGB-D), NaN where none. An
            observation with depth is also observed by a virtual right camera ``baseline_m``
            to the right, at ``(u - fx * baseline / z, v)``: ORB-SLAM's RGB-D residual, which
            lets the depth hold points and translations where reprojections alone are weak.
            Its ``obs_chi2`` is then the sum of both cameras' (gate 9.49, four residuals).
        baseline_m: the virtual stereo baseline.

    Returns:
        A :class:`BundleResult`; the inputs are not modified.

    Raises:
        ValueError: empty problem, shapes that disagree, non-finite values, an index out of
            range, a sigma <= 0, or a bad option.
    """
    start = time.perf_counter()
    prob = _check_problem(
        camera,
        cam_from_world,
        points,
        (obs_frame, obs_point, obs_uv, obs_sigma_px),
        fixed_frames,
        fixed_points,
    )
    _check_options(robust_px, robust_loss, max_iterations)
    if obs_depth is not None:
        prob = _with_stereo(prob, _check_depth(obs_depth, prob), baseline_m)
    chi2_before = _chi2(prob, prob.poses, prob.points)
    poses, pts, iterations = _refine(prob, fix_gauge, robust_px, robust_loss, max_iterations)
    chi2_after = _chi2(prob, poses, pts)
    rho = _huber if robust_loss == "huber" else _cauchy
    gate: F64 = np.full(chi2_after.shape, CHI2_INLIER)
    if prob.right_of is not None:
        right_of, m = prob.right_of, prob.n_obs
        chi2_after = _fold_right(chi2_after, right_of, m)
        chi2_before = _fold_right(chi2_before, right_of, m)
        gate = np.full(m, CHI2_INLIER)
        gate[right_of] = CHI2_STEREO
    return BundleResult(
        cam_from_world=poses,
        points=pts,
        obs_chi2=chi2_after,
        inlier=chi2_after < gate,
        initial_cost=_cost(rho, chi2_before, robust_px),
        final_cost=_cost(rho, chi2_after, robust_px),
        iterations=iterations,
        ms=(time.perf_counter() - start) * 1e3,
    )


def _refine(
    prob: _Problem, fix_gauge: bool, robust_px: float, robust_loss: str, max_iterations: int
) -> tuple[F64, F64, int]:
    """Fix the gauge, solve, and hand fixed and unobserved frames and points back unchanged.

    Returns:
        (K, 4, 4) poses, (P, 3) points, and the iterations Ceres ran (0 when nothing is free).
    """
    fixed_f = prob.fixed_frames.copy()
    observed_f = np.zeros(prob.poses.shape[0], dtype=bool)
    observed_f[prob.obs_frame] = True
    if fix_gauge and not fixed_f.any() and not prob.fixed_points.any():
        fixed_f[int(np.argmax(observed_f))] = True

    free_f = observed_f & ~fixed_f
    observed_p = np.zeros(prob.points.shape[0], dtype=bool)
    observed_p[prob.obs_point] = True
    free_p = observed_p & ~prob.fixed_points
    if not (free_f.any() or free_p.any()):
        return prob.poses.copy(), prob.points.copy(), 0
    solved = _seen_twice(prob)
    if solved.obs_point.size == 0:
        return prob.poses.copy(), prob.points.copy(), 0
    solve = _solve_compiled if np.count_nonzero(free_f) <= COMPILED_MAX_FRAMES else _solve_colmap
    poses, pts, iterations = solve(
        solved, fixed_f & observed_f, robust_px, robust_loss, max_iterations
    )
    # COLMAP keeps a pose as a quaternion, and the matrix round trip changes the last bits:
    # fixed and unobserved frames (and points) are handed back as they came.
    poses[~free_f] = prob.poses[~free_f]
    pts[~free_p] = prob.points[~free_p]
    # Depth fixes the scale itself; without it, the input's scale is kept.
    if (
        fix_gauge
        and prob.right is None
        and np.count_nonzero(fixed_f & observed_f) < 2
        and not prob.fixed_points.any()
    ):
        poses, pts = _restore_scale(prob.poses, poses, pts, fixed_f & observed_f, free_f)
    return poses, pts, iterations


def _seen_twice(prob: _Problem) -> _Problem:
    """The problem without the observations of points observed once (by one camera of one
    keyframe): such a point is free along its ray, and COLMAP refuses a track of one."""
    from dataclasses import replace

    keep = np.bincount(prob.obs_point, minlength=prob.points.shape[0])[prob.obs_point] >= 2
    if keep.all():
        return prob
    return replace(
        prob,
        obs_frame=prob.obs_frame[keep],
        obs_point=prob.obs_point[keep],
        obs_uv=prob.obs_uv[keep],
        obs_sigma=prob.obs_sigma[keep],
        right=None if prob.right is None else prob.right[keep],
    )


def _fold_right(chi2: F64, right_of: I64, m: int) -> F64:
    """(M,) chi2 per observation from the (M + R,) of the stereo problem: each right-camera
    residual (rows ``m..``) added to its observation's (``right_of``)."""
    folded = chi2[:m].copy()
    np.add.at(folded, right_of, chi2[m:])
    return folded


# -- validation ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Problem:
    camera: PinholeCamera
    poses: F64
    points: F64
    obs_frame: I64
    obs_point: I64
    obs_uv: F64
    obs_sigma: F64
    fixed_frames: BoolArray
    fixed_points: BoolArray
    # Virtual stereo: observations n_obs.. are right-camera copies of rows right_of, and
    # right[i] says which observations are right-camera ones.
    right: BoolArray | None = None
    right_of: I64 | None = None
    n_obs: int = 0
    baseline_m: float = 0.0


def _with_stereo(prob: _Problem, depth: F64, baseline_m: float) -> _Problem:
    """The problem with a right-camera observation appended for each observation with depth."""
    from dataclasses import replace

    has = np.flatnonzero(np.isfinite(depth) & (depth > 0))
    m = prob.obs_frame.size
    uv_r = prob.obs_uv[has].copy()
    uv_r[:, 0] -= prob.camera.fx * baseline_m / depth[has]
    right = np.zeros(m + has.size, dtype=bool)
    right[m:] = True
    return replace(
        prob,
        obs_frame=np.concatenate([prob.obs_frame, prob.obs_frame[has]]),
        obs_point=np.concatenate([prob.obs_point, prob.obs_point[has]]),
        obs_uv=np.concatenate([prob.obs_uv, uv_r]),
        obs_sigma=np.concatenate([prob.obs_sigma, prob.obs_sigma[has]]),
        right=right,
        right_of=has,
        n_obs=m,
        baseline_m=baseline_m,
    )


def _check_problem(
    camera: PinholeCamera,
    cam_from_world: ArrayLike,
    points: ArrayLike,
    observations: tuple[ArrayLike, ArrayLike, ArrayLike, ArrayLike],
    fixed_frames: ArrayLike,
    fixed_points: ArrayLike | None,
) -> _Problem:
    """Validate the arrays of :func:`bundle_adjust` and return them normalised (copies).

    ``observations`` are its ``obs_frame``, ``obs_point``, ``obs_uv`` and ``obs_sigma_px``.
    """
    where = "bundle_adjust"
    obs_frame, obs_point, obs_uv, obs_sigma_px = observations
    poses = np.array(cam_from_world, dtype=np.float64)
    pts = np.array(points, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or poses.shape[0] == 0:
        raise ValueError(
            f"{where}: cam_from_world must be (K, 4, 4) with K >= 1, got {poses.shape}"
        )
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] == 0:
        raise ValueError(f"{where}: points must be (P, 3) with P >= 1, got {pts.shape}")
    k, p = poses.shape[0], pts.shape[0]
    frame_idx = _check_index(obs_frame, "obs_frame", k)
    m = frame_idx.shape[0]
    if m == 0:
        raise ValueError(f"{where}: empty problem, no observations")
    point_idx = _check_index(obs_point, "obs_point", p)
    uv = np.array(obs_uv, dtype=np.float64)
    sigma = np.array(obs_sigma_px, dtype=np.float64)
    if point_idx.shape != (m,) or uv.shape != (m, 2) or sigma.shape != (m,):
        raise ValueError(
            f"{where}: observation arrays disagree: obs_frame {frame_idx.shape}, obs_point "
            f"{point_idx.shape}, obs_uv {uv.shape} (want (M, 2)), obs_sigma_px {sigma.shape}"
        )
    for name, arr in (("cam_from_world", poses), ("points", pts), ("obs_uv", uv)):
        if not np.isfinite(arr).all():
            raise ValueError(f"{where}: {name} has non-finite values")
    rot = poses[:, :3, :3]
    ortho = np.abs(rot @ np.swapaxes(rot, 1, 2) - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((ortho > 1e-6) | (np.linalg.det(rot) < 0.0))
    if bad.size or np.abs(poses[:, 3] - [0.0, 0.0, 0.0, 1.0]).max() > 0.0:
        which = f"frame {bad[0]}" if bad.size else "a last row"
        raise ValueError(f"{where}: cam_from_world must hold rigid transforms ({which} is not)")
    if not (np.isfinite(sigma).all() and (sigma > 0.0).all()):
        raise ValueError(f"{where}: obs_sigma_px must be finite and > 0")
    if not (camera.fx > 0 and camera.fy > 0):
        raise ValueError(f"{where}: camera focal lengths must be > 0, got {camera.fx}, {camera.fy}")
    fixed_f = _check_mask(fixed_frames, "fixed_frames", k)
    fixed_p = (
        np.zeros(p, dtype=bool)
        if fixed_points is None
        else _check_mask(fixed_points, "fixed_points", p)
    )
    return _Problem(camera, poses, pts, frame_idx, point_idx, uv, sigma, fixed_f, fixed_p)


def _check_options(robust_px: float, robust_loss: str, max_iterations: int) -> None:
    if not (np.isfinite(robust_px) and robust_px > 0.0):
        raise ValueError(f"bundle_adjust: robust_px must be a positive number, got {robust_px}")
    if robust_loss not in ("huber", "cauchy"):
        raise ValueError(
            f"bundle_adjust: robust_loss must be 'huber' or 'cauchy', got {robust_loss!r}"
        )
    if max_iterations < 1:
        raise ValueError(f"bundle_adjust: max_iterations must be >= 1, got {max_iterations}")


def _check_depth(obs_depth: ArrayLike, prob: _Problem) -> F64:
    """(M,) depths (m) of the observations, NaN where none."""
    depth = np.asarray(obs_depth, dtype=np.float64).reshape(-1)
    if depth.shape != prob.obs_frame.shape:
        raise ValueError(
            f"bundle_adjust: obs_depth must be ({prob.obs_frame.size},), got {depth.shape}"
        )
    return depth


def _check_index(values: ArrayLike, name: str, size: int) -> I64:
    arr = np.asarray(values)
    if arr.ndim != 1 or not (arr.size == 0 or np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(
            f"bundle_adjust: {name} must be a 1-D integer array, got {arr.dtype} {arr.shape}"
        )
    idx = arr.astype(np.int64)
    bad = np.flatnonzero((idx < 0) | (idx >= size))
    if bad.size:
        raise ValueError(
            f"bundle_adjust: {name}[{bad[0]}] = {idx[bad[0]]} is out of range [0, {size}) "
            f"({bad.size} observation(s) out of range)"
        )
    return idx


def _check_mask(values: ArrayLike, name: str, size: int) -> BoolArray:
    arr = np.asarray(values)
    if arr.shape != (size,) or arr.dtype != np.bool_:
        raise ValueError(
            f"bundle_adjust: {name} must be a ({size},) bool array, got {arr.dtype} {arr.shape}"
        )
    return arr.copy()


# -- errors and losses ----------------------------------------------------------------------------


def _chi2(prob: _Problem, poses: F64, pts: F64) -> F64:
    """(M,) squared whitened reprojection errors; inf behind the camera."""
    r = poses[prob.obs_frame, :3, :3]
    t = poses[prob.obs_frame, :3, 3]
    pc = np.einsum("mij,mj->mi", r, pts[prob.obs_point]) + t
    if prob.right is not None:
        pc[prob.right, 0] -= prob.baseline_m
    z = pc[:, 2]
    front = z > 0.0
    safe = np.where(front, z, 1.0)
    cam = prob.camera
    e = (
        np.stack([cam.fx * pc[:, 0] / safe + cam.cx, cam.fy * pc[:, 1] / safe + cam.cy], axis=-1)
        - prob.obs_uv
    )
    chi2 = np.sum(e * e, axis=1) / prob.obs_sigma**2
    return np.where(front, chi2, np.inf)


def _cost(rho: Callable[[F64, float], F64], chi2: F64, a: float) -> float:
    front = np.isfinite(chi2)
    return 0.5 * float(np.sum(rho(chi2[front], a)))


def _huber(s: F64, a: float) -> F64:
    """Ceres' HuberLoss(a) of squared norms s."""
    root = np.sqrt(s)
    return np.where(s <= a * a, s, 2.0 * a * root - a * a)


def _cauchy(s: F64, a: float) -> F64:
    """Ceres' CauchyLoss(a) of squared norms s."""
    return a * a * np.log1p(s / (a * a))


# -- gauge ----------------------------------------------------------------------------------------


def _restore_scale(
    before: F64, poses: F64, pts: F64, fixed: BoolArray, free: BoolArray
) -> tuple[F64, F64]:
    """Scale the free frames and all points about the first fixed camera's centre so that its
    distance to the first free frame with a baseline is the input's. Returns new arrays."""
    if not fixed.any() or not free.any():
        return poses, pts
    anchor = int(np.argmax(fixed))
    centre_in = _centres(before)
    centre_out = _centres(poses)
    base_in = np.linalg.norm(centre_in[free] - centre_in[anchor], axis=1)
    base_out = np.linalg.norm(centre_out[free] - centre_out[anchor], axis=1)
    usable = np.flatnonzero((base_in > 1e-9) & (base_out > 1e-9))
    if usable.size == 0:
        return poses, pts
    scale = base_in[usable[0]] / base_out[usable[0]]
    c0 = centre_out[anchor]
    new_pts = c0 + scale * (pts - c0)
    new_poses = poses.copy()
    # World x -> c0 + s (x - c0) keeps every projection: a camera centre c moves to
    # c0 + s (c - c0), and t = -R c with R unchanged.
    centres = c0 + scale * (centre_out[free] - c0)
    new_poses[free, :3, 3] = -np.einsum("kij,kj->ki", poses[free, :3, :3], centres)
    return new_poses, new_pts


def _centres(cam_from_world: F64) -> F64:
    r = cam_from_world[:, :3, :3]
    return -np.einsum("kji,kj->ki", r, cam_from_world[:, :3, 3])


# -- pycolmap -------------------------------------------------------------------------------------


def _sigma_groups(sigma: F64) -> tuple[F64, I64]:
    """(G,) group sigmas and the (M,) group of each observation (see the module docstring)."""
    levels, group = np.unique(sigma, return_inverse=True)
    if levels.size <= MAX_SIGMA_GROUPS:
        return levels, group.astype(np.int64)
    lo, hi = np.log(levels[0]), np.log(levels[-1])
    step = (hi - lo) / (MAX_SIGMA_GROUPS - 1)
    snapped = np.rint((np.log(sigma) - lo) / step).astype(np.int64)
    used, group = np.unique(snapped, return_inverse=True)
    return np.exp(lo + used * step), group.astype(np.int64)


def _solve_colmap(
    prob: _Problem,
    constant_frames: BoolArray,
    robust_px: float,
    robust_loss: str,
    max_iterations: int,
) -> tuple[F64, F64, int]:
    """Build a pycolmap Reconstruction of the problem, solve it, read the result back."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    config = pycolmap.BundleAdjustmentConfig()
    levels, group = _add_rig(rec, prob)
    frames, image_of_obs, idx_in_image = _add_images(
        rec, config, prob, levels, group, constant_frames
    )
    pids, point_ids = _add_tracks(rec, config, prob, image_of_obs, idx_in_image)
    options = _adjuster_options(robust_px, robust_loss, max_iterations)
    adjuster = pycolmap.create_default_bundle_adjuster(options, config, rec)
    # Typed as the backend-neutral summary; the Ceres backend's carries ``ceres_summary``.
    summary: Any = adjuster.solve()
    ceres_summary = summary.ceres_summary
    if not summary.is_solution_usable():
        logger.warning("bundle adjustment failed, input kept: %s", ceres_summary.message)
        return prob.poses.copy(), prob.points.copy(), 0
    # Ceres counts the evaluation at the start as a successful step.
    steps = ceres_summary.num_successful_steps + ceres_summary.num_unsuccessful_steps
    iterations = max(0, int(steps) - 1)

    poses = prob.poses.copy()
    for frame in frames:
        pose: Any = rec.frame(frame + 1).rig_from_world  # Rigid3d | None; every frame has one
        poses[frame, :3, :] = pose.matrix()
    pts = prob.points.copy()
    for j, pid in enumerate(pids.tolist()):
        pts[pid] = rec.point3D(int(point_ids[j])).xyz
    return poses, pts, iterations


def _add_rig(rec: Any, prob: _Problem) -> tuple[F64, I64]:
    """Add one camera per sigma group (and per eye) to ``rec``, all sensors of one rig.

    Returns:
        (G,) the sigma of each camera (camera ``g + 1``), and the (M,) camera index of each
        observation.
    """
    import pycolmap

    cam = prob.camera
    levels, group = _sigma_groups(prob.obs_sigma)
    sides = 2 if prob.right is not None else 1
    if prob.right is not None:
        # Right-camera copies are groups of their own: camera G + g is group g's right eye.
        group = group + levels.size * prob.right.astype(np.int64)
    rig = pycolmap.Rig(rig_id=1)
    sensors = []
    for side in range(sides):
        for g, s in enumerate(levels):
            colmap_cam = pycolmap.Camera(
                camera_id=side * levels.size + g + 1,
                model="PINHOLE",
                width=max(1, int(np.ceil(cam.width / s))),
                height=max(1, int(np.ceil(cam.height / s))),
                params=[cam.fx / s, cam.fy / s, cam.cx / s, cam.cy / s],
            )
            rec.add_camera(colmap_cam)
            sensors.append(colmap_cam.sensor_id)
    # Images of the rig's reference sensor get COLMAP's plain reprojection cost; the others get
    # the rig cost, whose autodiff also runs over the (constant) sensor_from_rig and takes about
    # four times as long: the most frequent sigma is the reference.
    # (The reference must be a left eye: the rig's frame is the keyframe's camera.)
    ref = int(np.argmax(np.bincount(group, minlength=len(sensors))[: levels.size]))
    rig.add_ref_sensor(sensors[ref])
    right_from_rig = np.eye(4)[:3]
    right_from_rig[0, 3] = -prob.baseline_m
    for g, sensor in enumerate(sensors):
        if g != ref:
            offset = g >= levels.size
            rig.add_sensor(
                sensor, pycolmap.Rigid3d(right_from_rig) if offset else pycolmap.Rigid3d()
            )
    rec.add_rig(rig)
    return np.tile(levels, sides), group


def _add_images(
    rec: Any,
    config: Any,
    prob: _Problem,
    levels: F64,
    group: I64,
    constant_frames: BoolArray,
) -> tuple[list[int], I64, I64]:
    """Add the keyframes to ``rec`` and ``config``, each with one image per camera it observes
    with (camera ``g + 1`` of sigma ``levels[g]``, ``group`` the (M,) camera of each observation).

    Returns:
        The frames added, and for each of the (M,) observations its image id and its index
        among that image's points.
    """
    import pycolmap

    # Observations sorted so that each image's points2D are a contiguous run.
    n_groups = levels.size
    key = prob.obs_frame * n_groups + group
    order = np.argsort(key, kind="stable")
    keys, first = np.unique(key[order], return_index=True)
    bounds = np.append(first, order.size)
    uv_scaled = prob.obs_uv / levels[group][:, None]
    image_of_obs = np.empty(order.size, dtype=np.int64)
    idx_in_image = np.empty(order.size, dtype=np.int64)
    frame_images: dict[int, list[Any]] = {}
    images = []
    for i, kk in enumerate(keys.tolist()):
        rows = order[bounds[i] : bounds[i + 1]]
        frame, g = divmod(kk, n_groups)
        image_id = i + 1
        image_of_obs[rows] = image_id
        idx_in_image[rows] = np.arange(rows.size)
        image = pycolmap.Image(
            name=f"kf{frame}_s{g}",
            keypoints=uv_scaled[rows],
            camera_id=g + 1,
            image_id=image_id,
        )
        images.append((image, frame))
        frame_images.setdefault(frame, []).append(image)

    for frame, imgs in frame_images.items():
        colmap_frame = pycolmap.Frame(frame_id=frame + 1, rig_id=1)
        for image in imgs:
            colmap_frame.add_data_id(image.data_id)
        colmap_frame.rig_from_world = pycolmap.Rigid3d(prob.poses[frame, :3, :])
        rec.add_frame(colmap_frame)
    for image, frame in images:
        image.frame_id = frame + 1
        rec.add_image(image)
        config.add_image(image.image_id)
    for frame in frame_images:
        if constant_frames[frame]:
            config.set_constant_rig_from_world_pose(frame + 1)
    for g in range(n_groups):
        config.set_constant_cam_intrinsics(g + 1)
    return list(frame_images), image_of_obs, idx_in_image


def _add_tracks(
    rec: Any, config: Any, prob: _Problem, image_of_obs: I64, idx_in_image: I64
) -> tuple[I64, I64]:
    """Add the observed points with their tracks (see :func:`_add_images`) to ``rec`` and
    ``config``.

    Returns:
        The (Q,) indices of the observed points and their (Q,) point ids in ``rec``.
    """
    import pycolmap

    by_point = np.argsort(prob.obs_point, kind="stable")
    pids, pfirst = np.unique(prob.obs_point[by_point], return_index=True)
    pbounds = np.append(pfirst, by_point.size)
    point_ids = np.empty(pids.size, dtype=np.int64)
    img_ids = image_of_obs.tolist()
    pt_idx = idx_in_image.tolist()
    for j, pid in enumerate(pids.tolist()):
        rows = by_point[pbounds[j] : pbounds[j + 1]].tolist()
        track = pycolmap.Track()
        for r in rows:
            track.add_element(img_ids[r], pt_idx[r])
        point_ids[j] = rec.add_point3D(prob.points[pid], track)
        if prob.fixed_points[pid]:
            config.add_constant_point(int(point_ids[j]))
        else:
            config.add_variable_point(int(point_ids[j]))
    return pids, point_ids


def _adjuster_options(robust_px: float, robust_loss: str, max_iterations: int) -> Any:
    """pycolmap bundle adjustment options: poses and points only, the robust loss, one thread."""
    import pycolmap

    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = False
    options.refine_principal_point = False
    options.refine_extra_params = False
    options.refine_sensor_from_rig = False
    options.print_summary = False
    options.min_track_length = 0
    ceres = options.ceres
    ceres.loss_function_type = (
        pycolmap.LossFunctionType.HUBER
        if robust_loss == "huber"
        else pycolmap.LossFunctionType.CAUCHY
    )
    ceres.loss_function_scale = robust_px
    ceres.use_gpu = False
    solver = ceres.solver_options
    # One thread: Ceres' multi-threaded Jacobian and Schur sums are not bit-reproducible.
    solver.num_threads = 1
    solver.max_num_iterations = max_iterations
    solver.function_tolerance = 1e-6
    solver.gradient_tolerance = 1e-10
    solver.parameter_tolerance = 1e-8
    ceres.solver_options = solver
    ceres.min_num_residuals_for_cpu_multi_threading = 2**31 - 1
    options.ceres = ceres
    return options


# -- compiled -------------------------------------------------------------------------------------


def _solve_compiled(
    prob: _Problem,
    constant_frames: BoolArray,
    robust_px: float,
    robust_loss: str,
    max_iterations: int,
) -> tuple[F64, F64, int]:
    """Solve the problem with :func:`slamcli.vision._ba_kernels.solve`: the same cost as
    :func:`_solve_colmap`, without building a COLMAP reconstruction."""
    from slamcli.vision import _ba_kernels as kernels

    k, p = prob.poses.shape[0], prob.points.shape[0]
    observed_f = np.zeros(k, dtype=bool)
    observed_f[prob.obs_frame] = True
    observed_p = np.zeros(p, dtype=bool)
    observed_p[prob.obs_point] = True
    cam_frames = np.flatnonzero(observed_f & ~constant_frames)
    pt_ids = np.flatnonzero(observed_p & ~prob.fixed_points)
    frame_par = np.full(k, -1, dtype=np.int64)
    frame_par[cam_frames] = np.arange(cam_frames.size)
    point_par = np.full(p, -1, dtype=np.int64)
    point_par[pt_ids] = np.arange(pt_ids.size)
    # Observations by point (free points first), then frame: each point's observations by one
    # frame (a left and its right copy) make one group, each free point's groups one run.
    held = point_par[prob.obs_point] < 0
    order = np.lexsort((prob.obs_frame, prob.obs_point, held))
    of, op = prob.obs_frame[order], prob.obs_point[order]
    new_group = np.ones(order.size, dtype=bool)
    new_group[1:] = (of[1:] != of[:-1]) | (op[1:] != op[:-1])
    g_first = np.flatnonzero(new_group)
    g_start = np.append(g_first, order.size)
    g_point = op[g_first]
    point_groups = np.searchsorted(g_point, pt_ids) if pt_ids.size else np.zeros(0, np.int64)
    point_groups = np.append(point_groups, np.count_nonzero(point_par[g_point] >= 0))
    shift = np.zeros(order.size)
    if prob.right is not None:
        shift[prob.right[order]] = prob.baseline_m
    cam = prob.camera
    rot, trans, pts, iterations, _cost_after = kernels.solve(
        np.ascontiguousarray(prob.poses[:, :3, :3]),
        np.ascontiguousarray(prob.poses[:, :3, 3]),
        prob.points.copy(),
        np.array([cam.fx, cam.fy, cam.cx, cam.cy]),
        (of, op, np.ascontiguousarray(prob.obs_uv[order]), 1.0 / prob.obs_sigma[order], shift),
        (g_start, of[g_first]),
        point_groups.astype(np.int64),
        frame_par,
        point_par,
        cam_frames,
        pt_ids,
        kernels.HUBER if robust_loss == "huber" else kernels.CAUCHY,
        robust_px * robust_px,
        max_iterations,
        1e-6,
        1e-8,
    )
    poses = prob.poses.copy()
    poses[:, :3, :3] = rot
    poses[:, :3, 3] = trans
    return poses, pts, int(iterations)
