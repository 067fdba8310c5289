"""Search of map points in an image by projection: which points a camera can see, and which
keypoint each projected point matches (ORB-SLAM's SearchByProjection)."""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from slamcli.pipelines.visual.atlas import SparseMap
from slamcli.types import PinholeCamera
from slamcli.vision.matching import TH_HIGH, match_by_projection

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


class Keypoints(Protocol):
    """An image's undistorted keypoints (N, 2), their ORB descriptors (N, 32) and pyramid
    levels (N,): a frame being tracked or a keyframe."""

    @property
    def keypoints(self) -> F64: ...

    @property
    def descriptors(self) -> NDArray[np.uint8]: ...

    @property
    def octaves(self) -> NDArray[np.int16]: ...


def in_view(
    camera: PinholeCamera, smap: SparseMap, cam_from_world: F64, pids: I64
) -> tuple[NDArray[np.bool_], F64]:
    """Which points ``pids`` project into the image at a distance and angle their scale range
    and viewing direction allow; and their distances (m)."""
    cam = camera
    p = smap.pos[pids] @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = cam.fx * p[:, 0] / z + cam.cx
        v = cam.fy * p[:, 1] / z + cam.cy
    ok = (z > 1e-6) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    center = -cam_from_world[:3, :3].T @ cam_from_world[:3, 3]
    ray = smap.pos[pids] - center
    dist = np.linalg.norm(ray, axis=1)
    ok &= smap.in_range(pids, dist)
    cos = np.einsum("ij,ij->i", ray, smap.normal[pids]) / np.maximum(dist, 1e-12)
    ok &= cos >= 0.5
    return ok, dist


def project_match(
    camera: PinholeCamera,
    sigma: F64,
    target: Keypoints,
    cam_from_world: F64,
    world: F64,
    desc: NDArray[np.uint8],
    octaves: I64,
    radius: float,
    ratio: float,
    max_distance: int = TH_HIGH,
) -> I64:
    """(K, 2) pairs (row of ``world``, keypoint of ``target``) found by projecting the points
    ``world`` (M, 3) from ``cam_from_world`` and matching their descriptors ``desc`` within
    ``radius`` pixels times the scale ``sigma`` of their predicted ``octaves``."""
    cam = camera
    p = world @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
    z = p[:, 2]
    front = np.flatnonzero(z > 1e-6)
    if front.size == 0:
        return np.zeros((0, 2), np.int64)
    uv = np.stack(
        [cam.fx * p[front, 0] / z[front] + cam.cx, cam.fy * p[front, 1] / z[front] + cam.cy],
        axis=1,
    )
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    front, uv = front[inside], uv[inside]
    if front.size == 0:
        return np.zeros((0, 2), np.int64)
    pairs = match_by_projection(
        uv,
        desc[front],
        radius * sigma[octaves[front]],
        target.keypoints,
        target.descriptors,
        kp_octaves=target.octaves,
        predicted_octaves=octaves[front],
        ratio=ratio,
        max_distance=max_distance,
    )
    pairs[:, 0] = front[pairs[:, 0]]
    return pairs
