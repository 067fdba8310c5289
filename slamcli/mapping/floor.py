"""Which way is up, where the floor is, and a 2-D frame on it.

**Up.** With an accelerometer, up is the mean specific force of its readings rotated into the
world by the camera poses (interpolated at each reading; a resting accelerometer measures the
reaction to gravity, so the specific force points up). The readings are taken to be in the
camera's optical frame. When the rotated readings do not agree (the norm of their mean is below
:data:`ACCEL_COHERENCE_MIN` times their mean norm, which happens when the sensor is mounted
otherwise), the 24 axis-aligned mountings are tried and the one whose rotated readings agree
best is used if they agree to :data:`ACCEL_COHERENCE_MIN`; TUM's Kinect accelerometer, for
one, has x and y opposite to the colour camera's. Without a usable accelerometer, up is the
cameras' mean ``-y`` axis (the optical frame's y points down), a rough guess that the floor
plane search then corrects.

**Floor.** Sequential RANSAC (seeded; :data:`RANSAC_ITERATIONS` triplets, each drawn within one
:data:`SAMPLE_VOXEL_M` voxel) over the points (at most :data:`MAX_RANSAC_POINTS`, a seeded
subset): among planes whose normal lies within :data:`MAX_TILT_DEG` of up and which lie at
least :data:`MIN_CAMERA_HEIGHT_M` below the mean camera position (so a ceiling is never taken),
the one with the most points within :data:`INLIER_M` is refined by least squares on its
inliers (normal oriented up), its points are removed, and the search repeats, up to
:data:`MAX_PLANES` planes. The floor is the one with the most inliers among those with at
most :data:`FLOOR_MAX_BELOW` times their inliers' count of points more than :data:`BELOW_M`
beneath them (else the one with the fewest beneath): a desk top often shows more points than
the floor beside it (TUM's fr1 sequences do), and a plane fitted through the floor's edges may
tilt across it, but only the floor has nothing below it.

**Floor frame.** ``z`` is the height above the plane along its normal; ``x`` is the world's x
axis projected onto the plane (the world's y when x is within 25 degrees of the normal), ``y =
normal x x``; the origin is the point of the plane nearest the world origin. A floor at world
z = 0 with normal +z gives back the world's own x and y.
"""

from __future__ import annotations

import itertools
import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.errors import InputError

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]

MAX_TILT_DEG = 30.0
"""Largest angle between a floor candidate's normal and up."""
INLIER_M = 0.03
"""Distance from the plane within which a point supports it."""
RANSAC_ITERATIONS = 512
MIN_CAMERA_HEIGHT_M = 0.1
"""The floor lies at least this far below the mean camera position."""
MAX_RANSAC_POINTS = 60_000
"""Points used by RANSAC (a seeded random subset of larger clouds)."""
ACCEL_COHERENCE_MIN = 0.9
"""|mean rotated reading| / mean |reading| needed to trust an accelerometer's up."""
MIN_FLOOR_INLIERS = 50
MAX_PLANES = 4
"""Horizontal planes extracted one after the other (each one's points removed)."""
BELOW_M = 0.1
FLOOR_MAX_BELOW = 0.1
"""A floor candidate may have at most this many points (as a share of its inliers) more than
:data:`BELOW_M` beneath it."""
SAMPLE_VOXEL_M = 0.5
"""RANSAC draws each triplet from one voxel of this edge."""


@dataclass(frozen=True)
class Up:
    """A world direction thought to be up, and how it was found.

    Attributes:
        direction: (3,) unit vector in the world frame.
        method: ``accelerometer``, ``accelerometer (axes remapped)`` or ``camera -y``.
        readings: accelerometer readings used (0 for the camera method).
        coherence: |mean rotated reading| / mean |reading| (None for the camera method).
    """

    direction: F64
    method: str
    readings: int = 0
    coherence: float | None = None


@dataclass(frozen=True)
class FloorPlane:
    """The plane ``normal . p + offset = 0`` (normal unit, pointing up) and its frame.

    Attributes:
        normal: (3,) unit normal, up.
        offset: metres.
        inliers: points within :data:`INLIER_M` of the refined plane.
        points: points RANSAC looked at.
        floor_from_world: (4, 4) float64 rigid transform into the floor frame (module
            docstring): z is the height above the floor.
    """

    normal: F64
    offset: float
    inliers: int
    points: int
    floor_from_world: F64

    def to_floor(self, points: ArrayLike) -> F64:
        """World points (N, 3) -> (N, 3) floor-frame x, y and height, metres."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return p @ self.floor_from_world[:3, :3].T + self.floor_from_world[:3, 3]


def up_from_accelerometer(world_from_cam: ArrayLike, accel_mps2: ArrayLike) -> Up | None:
    """Up from accelerometer readings (N, 3) m/s² and the camera poses at their stamps
    (N, 4, 4); None when there are none or no mounting makes them agree."""
    rot = np.asarray(world_from_cam, dtype=np.float64).reshape(-1, 4, 4)[:, :3, :3]
    acc = np.asarray(accel_mps2, dtype=np.float64).reshape(-1, 3)
    finite = np.all(np.isfinite(acc), axis=1) & (np.linalg.norm(acc, axis=1) > 0)
    rot, acc = rot[finite], acc[finite]
    if acc.shape[0] == 0:
        return None
    mean_norm = float(np.linalg.norm(acc, axis=1).mean())

    def coherence(mount: F64) -> tuple[float, F64]:
        world = np.einsum("nij,jk,nk->ni", rot, mount, acc)
        mean = world.mean(axis=0)
        return float(np.linalg.norm(mean)) / mean_norm, mean

    score, mean = coherence(np.eye(3))
    if score >= ACCEL_COHERENCE_MIN:
        return Up(mean / np.linalg.norm(mean), "accelerometer", int(acc.shape[0]), score)
    best = max(((*coherence(m), m) for m in _axis_mountings()), key=lambda t: t[0])
    if best[0] >= ACCEL_COHERENCE_MIN:
        log.info(
            "accelerometer axes disagree with the camera's (coherence %.2f); a remapped "
            "mounting agrees to %.2f",
            score,
            best[0],
        )
        up = best[1] / np.linalg.norm(best[1])
        return Up(up, "accelerometer (axes remapped)", int(acc.shape[0]), best[0])
    log.warning(
        "the accelerometer readings do not agree with the camera poses (coherence %.2f); "
        "up is guessed from the cameras",
        score,
    )
    return None


def _axis_mountings() -> list[F64]:
    """The 24 rotations that map axes onto signed axes."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[np.arange(3), perm] = signs
            if np.linalg.det(m) > 0:
                out.append(m)
    return out


def up_from_cameras(world_from_cam: ArrayLike) -> Up:
    """Up as the cameras' mean ``-y`` axis (optical frame: y points down)."""
    poses = np.asarray(world_from_cam, dtype=np.float64).reshape(-1, 4, 4)
    mean = -poses[:, :3, 1].mean(axis=0)
    return Up(mean / np.linalg.norm(mean), "camera -y")


def find_floor(
    points: ArrayLike, up: ArrayLike, camera_centre: ArrayLike, *, seed: int = 0
) -> FloorPlane:
    """The floor plane among ``points`` (N, 3) world metres (rules in the module docstring).

    Args:
        up: (3,) unit vector, world frame.
        camera_centre: (3,) mean camera position, metres.

    Raises:
        InputError: no plane within :data:`MAX_TILT_DEG` of up below the cameras has at least
            :data:`MIN_FLOOR_INLIERS` points.
    """
    rng = np.random.default_rng(seed)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if pts.shape[0] > MAX_RANSAC_POINTS:
        pts = pts[np.sort(rng.choice(pts.shape[0], MAX_RANSAC_POINTS, replace=False))]
    up_dir = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    centre = np.asarray(camera_centre, dtype=np.float64)
    planes: list[tuple[F64, float, int]] = []
    left = pts
    for _ in range(MAX_PLANES):
        found = _best_plane(left, up_dir, centre, rng)
        if found is None:
            break
        normal, offset = _refine(left, found[0], found[1], up_dir)
        near = np.abs(left @ normal + offset) <= INLIER_M
        if np.count_nonzero(near) < MIN_FLOOR_INLIERS:
            break
        planes.append(
            (normal, offset, int(np.count_nonzero(np.abs(pts @ normal + offset) <= INLIER_M)))
        )
        left = left[np.abs(left @ normal + offset) > 2 * INLIER_M]
    if not planes:
        raise InputError(
            f"no floor found: no plane within {MAX_TILT_DEG:g} degrees of up (from the "
            f"cameras or the accelerometer) and below the cameras has {MIN_FLOOR_INLIERS} "
            f"points within {INLIER_M} m",
            hint="the floor must be in view of some depth frames",
        )
    # A desk top can hold more points than the floor beside it, and a plane fitted through
    # the floor's edges may tilt across it; neither has nothing beneath it, as a floor does.
    below = [
        int(np.count_nonzero(pts @ n + o < -BELOW_M)) / max(count, 1) for n, o, count in planes
    ]
    clear = [k for k, b in enumerate(below) if b <= FLOOR_MAX_BELOW]
    if clear:
        pick = max(clear, key=lambda k: planes[k][2])
    else:
        pick = int(np.argmin(below))
        log.warning(
            "every horizontal plane has many points beneath it; the floor is the one with the "
            "fewest (%.0f%% of its own)",
            100 * below[pick],
        )
    normal, offset, inliers = planes[pick]
    return FloorPlane(normal, offset, inliers, int(pts.shape[0]), _floor_frame(normal, offset))


def _best_plane(
    pts: F64, up_dir: F64, centre: F64, rng: np.random.Generator
) -> tuple[F64, float, int] | None:
    """RANSAC: the candidate plane (normal up, offset, inliers) with the most points within
    :data:`INLIER_M`, among planes tilted at most :data:`MAX_TILT_DEG` from up and at least
    :data:`MIN_CAMERA_HEIGHT_M` below ``centre``. Triplets are drawn within one
    :data:`SAMPLE_VOXEL_M` voxel, so a small floor patch is found among larger surfaces."""
    if pts.shape[0] < MIN_FLOOR_INLIERS:
        return None
    vox = np.clip(np.floor(pts / SAMPLE_VOXEL_M).astype(np.int64), -(1 << 20), (1 << 20) - 1)
    vox += 1 << 20
    key = (vox[:, 0] << 42) | (vox[:, 1] << 21) | vox[:, 2]
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    order = np.argsort(inverse, kind="stable")
    begin = np.cumsum(counts) - counts
    seeds = rng.integers(0, pts.shape[0], size=RANSAC_ITERATIONS)
    voxel = inverse[seeds]
    picks = begin[voxel, None] + rng.integers(0, counts[voxel, None], size=(seeds.size, 2))
    tri = np.stack([pts[seeds], pts[order[picks[:, 0]]], pts[order[picks[:, 1]]]], axis=1)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normals, axis=1)
    ok = norm > 1e-9
    normals = normals[ok] / norm[ok, None]
    normals[normals @ up_dir < 0] *= -1.0
    offsets = -np.einsum("ij,ij->i", normals, tri[ok, 0])
    cos_tilt = math.cos(math.radians(MAX_TILT_DEG))
    keep = (normals @ up_dir >= cos_tilt) & (normals @ centre + offsets >= MIN_CAMERA_HEIGHT_M)
    normals, offsets = normals[keep], offsets[keep]
    best_count, best = 0, -1
    # Chunks bound the (candidates x points) distance matrix.
    for start in range(0, normals.shape[0], 64):
        d = np.abs(pts @ normals[start : start + 64].T + offsets[start : start + 64])
        counts_in = np.count_nonzero(d <= INLIER_M, axis=0)
        if counts_in.size and int(counts_in.max()) > best_count:
            best_count, best = int(counts_in.max()), start + int(counts_in.argmax())
    if best < 0 or best_count < MIN_FLOOR_INLIERS:
        return None
    return normals[best], float(offsets[best]), best_count


def _refine(pts: F64, normal: F64, offset: float, up_dir: F64) -> tuple[F64, float]:
    """Least-squares plane through the inliers, twice; normal oriented up."""
    for _ in range(3):
        inl = pts[np.abs(pts @ normal + offset) <= INLIER_M]
        if inl.shape[0] < 3:
            break
        c = inl.mean(axis=0)
        _, _, vt = np.linalg.svd(inl - c, full_matrices=False)
        normal = vt[2] if vt[2] @ up_dir >= 0 else -vt[2]
        offset = float(-normal @ c)
    return normal, offset


def _floor_frame(normal: F64, offset: float) -> F64:
    x_world, y_world = np.eye(3)[0], np.eye(3)[1]
    # x along the world's x unless that is nearly the normal (then its y).
    axis = x_world if abs(normal @ x_world) < math.cos(math.radians(25.0)) else y_world
    x = axis - (axis @ normal) * normal
    x /= np.linalg.norm(x)
    y = np.cross(normal, x)
    rot = np.stack([x, y, normal])
    origin = -offset * normal
    pose = np.eye(4)
    pose[:3, :3] = rot
    pose[:3, 3] = -rot @ origin
    return pose
