"""Multi-scale RGB-D odometry that gives the same answer every time it is asked the same question.

Open3D's ``rgbd_odometry_multi_scale`` builds the intensity pyramid of its photometric losses
(hybrid and intensity) with ``Image.PyrDown``, whose Gaussian filter (Intel IPP) rounds the last
bit differently depending on how the image buffer happens to be aligned in memory. Where a buffer
lands depends on everything the process allocated before, so the same two frames registered twice
in one process, or in two runs, can get coarse levels that differ by one ulp; the solver grows
that into 1e-6 m, loop closures verify with slightly different transforms and information
matrices, and the optimised trajectory is no longer bit-identical.

:func:`rgbd_odometry_multi_scale` is a drop-in replacement: for the photometric losses it builds
the pyramids itself (intensity with OpenCV's separable Gaussian, which does not depend on
alignment; depth with a numpy copy of Open3D's ``PyrDownDepth``, which Python cannot call) and
runs Open3D's own per-level solver with the same coarse-to-fine loop and stopping rule as
``RGBDOdometryMultiScaleHybrid`` / ``...Intensity``. The geometric loss has no intensity pyramid
and goes to Open3D unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]

# Open3D's PyrDownDepth weights for offsets 0, 1, 2 from the centre of its 5 x 5 window.
_DEPTH_WEIGHTS = np.array([0.0625, 0.25, 0.375, 0.25, 0.0625], dtype=np.float32)


def rgbd_odometry_multi_scale(
    o3d: Any,
    source: Any,
    target: Any,
    intrinsics: Any,
    init_source_to_target: Any,
    depth_scale: float,
    depth_max: float,
    criteria: Sequence[Any],
    method: Any,
    params: Any,
) -> Any:
    """``o3d.t.pipelines.odometry.rgbd_odometry_multi_scale`` with the same arguments (after
    the Open3D module), reproducible for the photometric methods. Raises RuntimeError where
    Open3D does (a singular system, no correspondences)."""
    odo = o3d.t.pipelines.odometry
    if method not in (odo.Method.Hybrid, odo.Method.Intensity):
        return odo.rgbd_odometry_multi_scale(
            source,
            target,
            intrinsics,
            init_source_to_target,
            depth_scale,
            depth_max,
            criteria,
            method,
            params,
        )
    hybrid = method == odo.Method.Hybrid
    levels = _pyramid(
        o3d, source, target, intrinsics, depth_scale, depth_max, len(criteria), params
    )
    trans = np.array(_numpy(init_source_to_target), dtype=np.float64)
    fitness, rmse = 1.0, 0.0
    for level, crit in zip(levels, criteria, strict=True):
        for _ in range(crit.max_iteration):
            init = o3d.core.Tensor(np.ascontiguousarray(trans))
            if hybrid:
                delta = odo.compute_odometry_result_hybrid(
                    *level["hybrid"],
                    level["K"],
                    init,
                    params.depth_outlier_trunc,
                    params.depth_huber_delta,
                    params.intensity_huber_delta,
                )
            else:
                delta = odo.compute_odometry_result_intensity(
                    *level["intensity"],
                    level["K"],
                    init,
                    params.depth_outlier_trunc,
                    params.intensity_huber_delta,
                )
            trans = np.asarray(delta.transformation.numpy(), dtype=np.float64) @ trans
            if _settled(fitness, delta.fitness, crit.relative_fitness) and _settled(
                rmse, delta.inlier_rmse, crit.relative_rmse
            ):
                break
            fitness, rmse = delta.fitness, delta.inlier_rmse
    return odo.OdometryResult(o3d.core.Tensor(np.ascontiguousarray(trans)), rmse, fitness)


def pyr_down_depth(depth: F32, depth_diff: float) -> F32:
    """Half-size depth as Open3D's ``PyrDownDepth`` makes it, NaN for invalid: a 5 x 5
    Gaussian around every other pixel over the neighbours within ``depth_diff`` of the centre,
    with Open3D's weights, summation order and float32 precision."""
    rows, cols = depth.shape[0] // 2, depth.shape[1] // 2
    centre = depth[: 2 * rows : 2, : 2 * cols : 2]
    padded = np.pad(depth, 2, constant_values=np.nan)
    v_sum = np.zeros((rows, cols), np.float32)
    w_sum = np.zeros((rows, cols), np.float32)
    for dy in range(5):
        for dx in range(5):
            v = padded[dy : dy + 2 * rows : 2, dx : dx + 2 * cols : 2]
            with np.errstate(invalid="ignore"):
                near = np.abs(v - centre) < np.float32(depth_diff)
            w = _DEPTH_WEIGHTS[dy] * _DEPTH_WEIGHTS[dx]
            v_sum += np.where(near, w * v, np.float32(0.0))
            w_sum += np.where(near, w, np.float32(0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(w_sum == 0, np.float32(np.nan), v_sum / w_sum).astype(np.float32)


def pyr_down_intensity(intensity: F32) -> F32:
    """Half-size intensity: Open3D's ``PyrDown`` (5 x 5 Gaussian, sigma 1, replicated border,
    every other pixel) computed by OpenCV, whose result does not depend on buffer alignment."""
    import cv2

    kernel = cv2.getGaussianKernel(5, 1.0, cv2.CV_32F)
    blurred = cv2.sepFilter2D(
        intensity, cv2.CV_32F, kernel, kernel, borderType=cv2.BORDER_REPLICATE
    )
    rows, cols = intensity.shape[0] // 2, intensity.shape[1] // 2
    return np.ascontiguousarray(blurred[: 2 * rows : 2, : 2 * cols : 2])


def _pyramid(
    o3d: Any,
    source: Any,
    target: Any,
    intrinsics: Any,
    depth_scale: float,
    depth_max: float,
    n_levels: int,
    params: Any,
) -> list[dict[str, Any]]:
    """Per level, coarse first: the solver inputs of ``RGBDOdometryMultiScaleHybrid``."""
    image = o3d.t.geometry.Image
    nan = float("nan")

    def depth(rgbd: Any) -> F32:
        clipped = rgbd.depth.clip_transform(depth_scale, 0.0, depth_max, nan)
        return _plane(clipped)

    def gray(rgbd: Any) -> F32:
        return _plane(rgbd.color.rgb_to_gray().to(o3d.core.float32))

    src_d, tgt_d, src_i, tgt_i = depth(source), depth(target), gray(source), gray(target)
    K = np.array(_numpy(intrinsics), dtype=np.float64)
    levels: list[dict[str, Any]] = []
    for i in range(n_levels):
        # Open3D images alias the numpy arrays they are built from and keep them alive.
        sd, td, si, ti = (image(a) for a in (src_d, tgt_d, src_i, tgt_i))
        k = o3d.core.Tensor(K.copy())
        t_idx, t_idy = ti.filter_sobel()
        t_ddx, t_ddy = td.filter_sobel()
        vertex = sd.create_vertex_map(k, nan).as_tensor()
        planes = [x.as_tensor() for x in (sd, td, si, ti)]
        grads_i = [t_idx.as_tensor(), t_idy.as_tensor()]
        levels.append(
            {
                "K": k,
                "hybrid": [*planes, t_ddx.as_tensor(), t_ddy.as_tensor(), *grads_i, vertex],
                "intensity": [*planes, *grads_i, vertex],
            }
        )
        if i != n_levels - 1:
            diff = 2 * params.depth_outlier_trunc
            src_d, tgt_d = pyr_down_depth(src_d, diff), pyr_down_depth(tgt_d, diff)
            src_i, tgt_i = pyr_down_intensity(src_i), pyr_down_intensity(tgt_i)
            K = K / 2
            K[2, 2] = 1.0
    return levels[::-1]


def _plane(img: Any) -> F32:
    """An Open3D single-channel image as an owned, contiguous (rows, cols) float32 array."""
    a = np.asarray(img.as_tensor().numpy(), dtype=np.float32)
    return np.ascontiguousarray(a.reshape(a.shape[0], a.shape[1])).copy()


def _numpy(t: Any) -> NDArray[Any]:
    return t.numpy() if hasattr(t, "numpy") else np.asarray(t)


def _settled(previous: float, current: float, tolerance: float) -> bool:
    """Open3D's stopping test ``|previous - current| / previous < tolerance``, which is false
    when ``previous`` is 0 (a division giving inf or NaN in C++)."""
    return previous != 0 and abs(previous - current) / previous < tolerance
