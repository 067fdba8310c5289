"""The shared vision layer as the dense pipeline uses it: lifting keypoints with depth, ratio
matching, pose gates and PnP, on synthetic data with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slamcli.geometry import compose, inverse, make_pose, so3_exp
from slamcli.geometry.camera import project
from slamcli.types import PinholeCamera
from slamcli.vision.features import lift
from slamcli.vision.matching import match_ratio
from slamcli.vision.pnp import pnp_opencv, pose_change, within

CAMERA = PinholeCamera(640, 480, 525.0, 520.0, 319.5, 239.5)


def test_lift_puts_points_on_the_depth_and_nan_where_depth_is_missing() -> None:
    cam = PinholeCamera(8, 6, 100.0, 50.0, 3.5, 2.5)
    depth = np.full((6, 8), 2.0, dtype=np.float32)
    depth[1, 6] = 0.0
    # (u, v): a pixel centre, a keypoint that rounds onto the hole, and one outside the image
    # whose depth comes from the nearest border pixel.
    keypoints = np.array([[5.0, 4.0], [6.2, 0.8], [9.0, -1.0]], dtype=np.float32)
    points = lift(keypoints, depth, cam)
    assert points.shape == (3, 3) and points.dtype == np.float64
    np.testing.assert_allclose(
        points[0], [(5.0 - 3.5) / 100.0 * 2.0, (4.0 - 2.5) / 50.0 * 2.0, 2.0]
    )
    assert np.isnan(points[1]).all()
    # The point keeps its own pixel, only the depth is read at the border.
    np.testing.assert_allclose(
        points[2], [(9.0 - 3.5) / 100.0 * 2.0, (-1.0 - 2.5) / 50.0 * 2.0, 2.0]
    )


def test_match_ratio_recovers_a_permutation() -> None:
    rng = np.random.default_rng(3)
    desc_a = rng.integers(0, 256, size=(200, 32), dtype=np.uint8)
    perm = rng.permutation(200)
    desc_b = desc_a[perm].copy()
    # A few flipped bits: matches are near, not exact.
    desc_b[:, 0] ^= np.uint8(0b101)
    pairs = match_ratio(desc_a, desc_b, 0.8)
    assert pairs.shape == (200, 2)
    np.testing.assert_array_equal(pairs[:, 1], np.arange(200))
    np.testing.assert_array_equal(pairs[:, 0], perm)


def test_match_ratio_is_one_to_one_and_keeps_the_closest() -> None:
    rng = np.random.default_rng(4)
    desc_a = rng.integers(0, 256, size=(50, 32), dtype=np.uint8)
    # b0 and b1 both pick a7; b1 is the exact copy, b0 is one bit off.
    desc_b = np.stack([desc_a[7].copy(), desc_a[7].copy(), desc_a[9].copy()])
    desc_b[0, 5] ^= np.uint8(1)
    pairs = match_ratio(desc_a, desc_b, 0.8)
    np.testing.assert_array_equal(pairs, [[7, 1], [9, 2]])
    assert len(np.unique(pairs[:, 0])) == len(pairs)


def test_match_ratio_drops_ambiguous_matches() -> None:
    rng = np.random.default_rng(5)
    desc_a = rng.integers(0, 256, size=(20, 32), dtype=np.uint8)
    desc_a[1] = desc_a[0]
    assert len(match_ratio(desc_a, desc_a[:1], 0.8)) == 0
    assert len(match_ratio(desc_a[:1], desc_a[:1], 0.8)) == 0


def test_pose_change_and_within_of_a_known_motion() -> None:
    a = make_pose(so3_exp([0.1, -0.2, 0.3]), [1.0, 2.0, 3.0])
    step = make_pose(so3_exp([0.0, 0.0, math.radians(12.0)]), [0.03, 0.04, 0.0])
    b = compose(a, step)
    m, deg = pose_change(a, b)
    assert m == pytest.approx(0.05, abs=1e-12)
    assert deg == pytest.approx(12.0, abs=1e-9)
    assert within(a, b, 0.05 + 1e-9, 12.0 + 1e-6)
    assert not within(a, b, 0.049, 15.0)
    assert not within(a, b, 0.1, 11.9)


def _pnp_scene(
    seed: int, outlier_share: float = 0.2
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points seen by a camera at a known pose, a share of the pixels replaced by outliers.

    Returns (ref_from_cam (4, 4), points in the ref frame (N, 3), pixels (N, 2), outlier mask).
    """
    rng = np.random.default_rng(seed)
    n = 300
    pts_cam = np.column_stack(
        [rng.uniform(-1.2, 1.2, n), rng.uniform(-0.9, 0.9, n), rng.uniform(1.0, 4.0, n)]
    )
    pixels = project(CAMERA, pts_cam) + rng.normal(0.0, 0.3, (n, 2))
    outliers = rng.random(n) < outlier_share
    pixels[outliers] = rng.uniform([0, 0], [640, 480], (int(outliers.sum()), 2))
    ref_from_cam = make_pose(so3_exp([0.05, -0.3, 0.1]), [0.4, -0.1, 0.25])
    pts_ref = pts_cam @ ref_from_cam[:3, :3].T + ref_from_cam[:3, 3]
    return ref_from_cam, pts_ref, pixels, outliers


def test_pnp_opencv_recovers_a_known_pose_through_outliers() -> None:
    truth, pts, pixels, outliers = _pnp_scene(11)
    pose, inliers = pnp_opencv(
        pts, pixels, CAMERA.K, seed=0, iterations=200, threshold_px=3.0, min_inliers=25
    )
    assert pose is not None
    m, deg = pose_change(truth, pose)
    assert m < 0.01 and deg < 0.2
    # Every true correspondence is an inlier and (almost) no outlier is.
    assert (~outliers).sum() <= inliers <= (~outliers).sum() + 3


def test_pnp_opencv_is_deterministic_with_a_seed() -> None:
    _, pts, pixels, _ = _pnp_scene(12)
    runs = [
        pnp_opencv(pts, pixels, CAMERA.K, seed=5, iterations=50, threshold_px=3.0, min_inliers=25)
        for _ in range(3)
    ]
    poses = [r[0] for r in runs]
    assert all(p is not None for p in poses)
    assert all(np.array_equal(poses[0], p) for p in poses[1:])
    assert len({r[1] for r in runs}) == 1


def test_pnp_opencv_refuses_too_few_inliers() -> None:
    _, pts, pixels, _ = _pnp_scene(13)
    pose, inliers = pnp_opencv(
        pts, pixels, CAMERA.K, seed=0, iterations=200, threshold_px=3.0, min_inliers=len(pts)
    )
    assert pose is None
    assert 0 < inliers < len(pts)
    pose, inliers = pnp_opencv(
        pts[:3], pixels[:3], CAMERA.K, seed=0, iterations=200, threshold_px=3.0, min_inliers=4
    )
    assert pose is None and inliers == 0


def test_pnp_pose_is_object_from_camera() -> None:
    """The pose maps camera-frame points into the object frame (dense composes it as
    ref_from_cur); its inverse would be off by the whole motion."""
    truth, pts, pixels, outliers = _pnp_scene(14)
    pose, _ = pnp_opencv(
        pts[~outliers],
        pixels[~outliers],
        CAMERA.K,
        seed=0,
        iterations=100,
        threshold_px=3.0,
        min_inliers=4,
    )
    assert pose is not None
    assert pose_change(truth, pose)[0] < 0.01
    assert pose_change(inverse(truth), pose)[0] > 0.1
