"""Pinhole cameras: projection, unprojection and lens undistortion.

Pixel coordinates follow OpenCV: ``(u, v)`` = (column, row) in pixels, with the centre of the
top-left pixel at ``(0, 0)``. Camera-frame points are optical: x right, y down, z forward, in
metres; depth is z-depth along the optical axis, not the range along the ray.

:func:`project` and :func:`unproject` are the ideal pinhole maps of ``camera.K``; they ignore
the lens distortion. Raw pixels of a distorted camera go through :func:`undistort_points` (or
the whole image through :func:`undistort_image`) first.

**Undistortion target.** Both undistortion functions map onto ``camera.undistorted()``: the
same ``K`` with the distortion removed. Keeping ``K`` (rather than OpenCV's
``getOptimalNewCameraMatrix``, whose ``alpha`` trades black borders against lost pixels) keeps
the image size, the principal point and the focal lengths a user gave, so intrinsics stay the
ones in the camera file; the price is a thin black rim where a barrel-distorted lens saw less
than the pinhole does. It is also what :func:`undistort_points` returns by default in pixels,
where ``cv2.undistortPoints`` without ``P`` would return normalised coordinates.

**Who undistorts.** Readers hand frames over as recorded, with the camera that took them
(``TumRgbdSource(undistort=False)``, the CLI's ``--undistort`` off): TUM advises against
undistorting its Kinect images, whose depth was registered with the factory colour model.
Consumers that need pinhole geometry undistort what they are given: the dense pipeline
(``dense.undistort``, on by default) remaps distorted frames itself, so ``slamcli run dense``
works on the true pinhole with or without ``--undistort``; with it, the reader has already
done the remap and the pipeline has nothing left to do.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.types import PinholeCamera

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]


def project(camera: PinholeCamera, points: ArrayLike) -> F64:
    """(..., 3) camera-frame points (m) -> (..., 2) float64 pixel coordinates (u, v).

    The pinhole map ``u = fx x / z + cx``, ``v = fy y / z + cy``; points at z <= 0 give
    meaningless (or infinite) pixels, and callers that may have them mask them first.
    """
    p = np.asarray(points, dtype=np.float64)
    z = p[..., 2]
    return np.stack(
        [camera.fx * p[..., 0] / z + camera.cx, camera.fy * p[..., 1] / z + camera.cy], axis=-1
    )


def unproject(camera: PinholeCamera, pixels: ArrayLike, depth: ArrayLike) -> F64:
    """Pixels and their z-depths -> camera-frame points, the inverse of :func:`project`.

    Args:
        camera: the pinhole whose ``K`` the pixels follow.
        pixels: (..., 2) pixel coordinates (u, v), any real dtype (converted to float64).
        depth: z-depth in metres, broadcastable to ``pixels.shape[:-1]``; 1 gives rays with
            unit z. NaN depths give NaN points.

    Returns:
        (..., 3) float64 points ``((u - cx) / fx z, (v - cy) / fy z, z)`` in metres.
    """
    uv = np.asarray(pixels, dtype=np.float64)
    z = np.broadcast_to(np.asarray(depth, dtype=np.float64), uv.shape[:-1])
    x = (uv[..., 0] - camera.cx) / camera.fx * z
    y = (uv[..., 1] - camera.cy) / camera.fy * z
    return np.stack([x, y, z], axis=-1)


def undistort_points(camera: PinholeCamera, pixels: ArrayLike) -> F64:
    """(..., 2) raw pixel coordinates of a distorted camera -> (..., 2) float64 pixel
    coordinates in ``camera.undistorted()`` (see the module docstring), by OpenCV's iterative
    inversion of the distortion model. An undistorted camera returns the pixels unchanged.

    OpenCV's default five iterations leave errors of a tenth of a pixel in the corners of a
    strong lens (TUM fr1); iterating until the reprojection error is below 1e-9 in normalised
    coordinates (under a micro-pixel) makes the result the inverse of the model the image
    remap uses.
    """
    uv = np.asarray(pixels, dtype=np.float64)
    if not camera.is_distorted or uv.size == 0:
        return uv.copy()
    import cv2

    k = camera.K
    out = cv2.undistortPoints(
        uv.reshape(-1, 1, 2),
        k,
        np.asarray(camera.distortion, dtype=np.float64),
        R=None,
        P=k,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-9),
    )
    return np.asarray(out, dtype=np.float64).reshape(uv.shape)


def undistort_image(
    camera: PinholeCamera, image: NDArray[Any], *, nearest: bool = False
) -> NDArray[Any]:
    """An (H, W) or (H, W, C) image of ``camera`` remapped onto ``camera.undistorted()``.

    Args:
        camera: the camera that took the image; its size must match the image's.
        image: any dtype OpenCV remaps (uint8 colour, uint16 or float32 depth).
        nearest: sample the nearest source pixel instead of interpolating bilinearly. Depth
            images need it: blending a foreground and a background reading across an edge
            invents a surface in between. Depth values are z-depths, which undistortion (no
            rotation, same optical centre) leaves unchanged.

    Returns:
        The remapped image, same shape and dtype; pixels that fall outside the raw image are 0.
        An undistorted camera returns the image itself.
    """
    if not camera.is_distorted:
        return image
    import cv2

    mx, my = _undistort_maps(camera)
    mode = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    return np.asarray(cv2.remap(image, mx, my, mode, borderMode=cv2.BORDER_CONSTANT))


@functools.lru_cache(maxsize=4)
def _undistort_maps(camera: PinholeCamera) -> tuple[F32, F32]:
    """(H, W) float32 source x and y of every pixel of ``camera.undistorted()``; cached because
    a sequence remaps every frame with the same camera."""
    import cv2

    k = camera.K
    # Float maps rather than fixed-point ones, so nearest sampling rounds to the nearest source
    # pixel instead of truncating.
    mx, my = cv2.initUndistortRectifyMap(
        k,
        np.asarray(camera.distortion, dtype=np.float64),
        None,
        k,
        (camera.width, camera.height),
        cv2.CV_32FC1,
    )
    return np.asarray(mx, dtype=np.float32), np.asarray(my, dtype=np.float32)
