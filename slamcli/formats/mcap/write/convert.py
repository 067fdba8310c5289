"""Conversions both flavours share: colour and depth images to bytes, the camera model as ROS
and Foxglove store it, stamps and poses.

Depth encodings: ``16UC1`` is millimetres (the ROS convention for 16-bit depth), rounded to the
nearest millimetre, so TUM's 0.2 mm raw steps are lost (at most 0.5 mm off); ``32FC1`` is float32
metres, bit-identical to the source's depth. Compressed depth (ros2 only) is
``"16UC1; compressedDepth png"``: the 12-byte ``compressed_depth_image_transport`` header
(int32 format 0 and two float32 quantisation parameters, 0 and 0, which 16-bit depth does not
use) followed by a lossless 16-bit PNG of the millimetres. Foxglove's ``CompressedImage`` has no
depth convention (browsers decode a 16-bit PNG to 8 bits), so the foxglove flavour keeps depth
raw, and ``32FC1`` depth stays raw in both flavours because it is chosen for exactness.
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ExportError
from slamcli.types import PinholeCamera

COMPRESSED_DEPTH_FORMAT = "16UC1; compressedDepth png"
_COMPRESSED_DEPTH_HEADER = struct.pack("<iff", 0, 0.0, 0.0)
_MM_MAX = 65535


def depth_to_millimetres(depth_m: NDArray[np.floating[Any]]) -> NDArray[np.uint16]:
    """(H, W) metres -> (H, W) uint16 millimetres, rounded; NaN, <= 0 or > 65.535 m -> 0."""
    mm = np.rint(np.asarray(depth_m, dtype=np.float64) * 1000.0)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(mm) & (mm > 0) & (mm <= _MM_MAX)
    return np.where(ok, mm, 0.0).astype(np.uint16)


def _imencode(ext: str, image: NDArray[Any], params: list[int]) -> bytes:
    """``image`` encoded by OpenCV as ``ext`` (``".png"``, ``".jpg"``)."""
    import cv2

    ok, buf = cv2.imencode(ext, image, params)
    if not ok:
        raise ExportError(f"OpenCV could not encode a {image.shape} {image.dtype} image as {ext}")
    return bytes(buf)


def encode_color(rgb: NDArray[np.uint8], fmt: str, jpeg_quality: int) -> bytes:
    """(H, W, 3) RGB -> JPEG or PNG bytes."""
    import cv2

    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    if fmt == "jpeg":
        return _imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
    return _imencode(".png", bgr, [])


def compressed_depth(mm: NDArray[np.uint16]) -> bytes:
    """The ``compressedDepth png`` payload: the 12-byte header, then a 16-bit PNG."""
    return _COMPRESSED_DEPTH_HEADER + _imencode(".png", mm, [])


def depth_bytes(depth_m: NDArray[np.float32], encoding: str) -> tuple[bytes, int]:
    """Raw little-endian depth bytes and bytes per pixel for ``16UC1`` (mm) or ``32FC1`` (m)."""
    if encoding == "16UC1":
        return depth_to_millimetres(depth_m).astype("<u2").tobytes(), 2
    return np.ascontiguousarray(depth_m, dtype="<f4").tobytes(), 4


def camera_model(camera: PinholeCamera) -> tuple[str, list[float], list[float], list[float]]:
    """(distortion model, D, K row-major, P row-major) as ROS and Foxglove store them."""
    d = [float(c) for c in camera.distortion]
    if len(d) <= 5:
        model, d = "plumb_bob", d + [0.0] * (5 - len(d))
    elif len(d) == 8:
        model = "rational_polynomial"
    else:
        raise ExportError(
            f"camera has {len(d)} distortion coefficients; CameraInfo takes 5 (plumb_bob) or "
            "8 (rational_polynomial)"
        )
    k = camera.K.reshape(-1).tolist()
    p = np.hstack([camera.K, np.zeros((3, 1))]).reshape(-1).tolist()
    return model, d, k, p


def split_ns(stamp_ns: int) -> tuple[int, int]:
    """A stamp (ns) as whole seconds and nanoseconds."""
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return sec, nsec


def pose_parts(world_from_body: NDArray[np.float64]) -> tuple[list[float], list[float]]:
    """(4, 4) pose -> translation [x, y, z] (m) and unit quaternion [x, y, z, w]."""
    from slamcli.geometry import matrix_to_quat_xyzw

    t = world_from_body[:3, 3].tolist()
    q = matrix_to_quat_xyzw(world_from_body[:3, :3]).tolist()
    return t, q
