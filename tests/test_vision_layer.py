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


# --- Hamming distances, search by projection, depth-aided pose refinement, ORB spread ---------


def test_hamming_counts_differing_bits_with_broadcasting() -> None:
    from slamcli.vision.matching import hamming

    rng = np.random.default_rng(3)
    a = rng.integers(0, 256, (40, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (40, 32), dtype=np.uint8)
    naive = np.unpackbits(a ^ b, axis=1).sum(axis=1)
    assert np.array_equal(hamming(a, b), naive)
    table = hamming(a[:, None, :], b[None, :, :])
    assert table.shape == (40, 40)
    assert np.array_equal(np.diag(table), naive)
    assert np.all(hamming(a, a) == 0)
    # Descriptors whose length is not a multiple of eight bytes take the byte table.
    assert np.array_equal(
        hamming(a[:, :5], b[:, :5]),
        np.unpackbits(a[:, :5] ^ b[:, :5], axis=1).sum(axis=1),
    )


def _match_by_projection_reference(
    projected: np.ndarray,
    point_desc: np.ndarray,
    radius: np.ndarray,
    keypoints: np.ndarray,
    kp_desc: np.ndarray,
    kp_oct: np.ndarray,
    pred_oct: np.ndarray,
    max_distance: int,
    ratio: float,
) -> list[tuple[int, int]]:
    """Point by point, as the docstring says: candidates in the radius within one level of the
    predicted one; best and second best; ratio test unless they differ in level; then each
    keypoint keeps its closest point."""
    best_for: dict[int, tuple[int, int]] = {}
    for p in range(len(projected)):
        cands = []
        for k in range(len(keypoints)):
            d2 = float(np.sum((keypoints[k] - projected[p]) ** 2))
            if d2 <= radius[p] ** 2 and abs(int(kp_oct[k]) - int(pred_oct[p])) <= 1:
                dist = int(np.unpackbits(point_desc[p] ^ kp_desc[k]).sum())
                cands.append((dist, k))
        if not cands:
            continue
        cands.sort()
        dist, k = cands[0]
        if dist > max_distance:
            continue
        if len(cands) > 1 and kp_oct[cands[1][1]] == kp_oct[k] and not dist < ratio * cands[1][0]:
            continue
        if k not in best_for or (dist, p) < best_for[k]:
            best_for[k] = (dist, p)
    return sorted((p, k) for k, (_d, p) in best_for.items())


def test_match_by_projection_agrees_with_a_point_by_point_search() -> None:
    from slamcli.vision.matching import match_by_projection

    rng = np.random.default_rng(11)
    for trial in range(4):
        n_kp, n_pt = 300, 150
        keypoints = rng.uniform(0, 200, (n_kp, 2))
        kp_desc = rng.integers(0, 256, (n_kp, 32), dtype=np.uint8)
        kp_oct = rng.integers(0, 4, n_kp).astype(np.int16)
        # Points near keypoints with descriptors a few bits away, and some anywhere.
        src = rng.integers(0, n_kp, n_pt)
        projected = keypoints[src] + rng.normal(0, 2.0, (n_pt, 2))
        projected[::5] = rng.uniform(0, 200, (len(projected[::5]), 2))
        point_desc = kp_desc[src].copy()
        flips = (
            rng.integers(0, 256, (n_pt, 32), dtype=np.uint8)
            & rng.integers(0, 256, (n_pt, 32), dtype=np.uint8)
            & 0x11
        )
        point_desc ^= flips.astype(np.uint8)
        pred_oct = kp_oct[src].astype(np.int64)
        radius = 4.0 * 1.2 ** pred_oct.astype(np.float64) * (1 + trial)
        got = match_by_projection(
            projected,
            point_desc,
            radius,
            keypoints,
            kp_desc,
            kp_octaves=kp_oct,
            predicted_octaves=pred_oct,
            max_distance=100,
            ratio=0.8,
        )
        want = _match_by_projection_reference(
            projected, point_desc, radius, keypoints, kp_desc, kp_oct, pred_oct, 100, 0.8
        )
        assert sorted(map(tuple, got.tolist())) == want
        assert len(want) > 50


def test_refine_pose_depth_recovers_a_pose_and_flags_outliers() -> None:
    from slamcli.vision.pnp import refine_pose_depth

    rng = np.random.default_rng(5)
    cam = PinholeCamera(640, 480, 525.0, 525.0, 319.5, 239.5)
    truth = make_pose(so3_exp(np.array([0.05, -0.1, 0.02])), np.array([0.1, -0.05, 0.2]))
    pts_cam = np.column_stack(
        [rng.uniform(-1.5, 1.5, 300), rng.uniform(-1, 1, 300), rng.uniform(1.0, 4.0, 300)]
    )
    world = (pts_cam - truth[:3, 3]) @ truth[:3, :3]
    pixels = project(cam, pts_cam) + rng.normal(0, 0.5, (300, 2))
    depth = pts_cam[:, 2] * (1 + rng.normal(0, 0.002, 300))
    depth[::4] = np.nan  # some keypoints have no depth
    bad = np.zeros(300, dtype=bool)
    bad[rng.choice(300, 45, replace=False)] = True
    pixels[bad] += rng.uniform(20, 60, (45, 2)) * rng.choice([-1, 1], (45, 2))
    start = make_pose(so3_exp(np.array([0.07, -0.12, 0.0])), np.array([0.13, -0.02, 0.17]))
    est = refine_pose_depth(cam, start, pixels, world, depth)
    assert est is not None
    metres, degrees = pose_change(truth, est.cam_from_world)
    assert metres < 0.005 and degrees < 0.1
    assert np.array_equal(est.inliers, ~bad)
    # The same call gives the same bits.
    again = refine_pose_depth(cam, start, pixels, world, depth)
    assert again is not None and np.array_equal(again.cam_from_world, est.cam_from_world)
    # Too few correspondences: no pose.
    assert refine_pose_depth(cam, start, pixels[:3], world[:3], depth[:3]) is None


def test_orb_spread_fills_the_level_quotas_and_visits_every_cell_first() -> None:
    import cv2

    from slamcli.vision.features import OrbSettings, _orb, _spread, level_quota

    rng = np.random.default_rng(2)
    img = cv2.GaussianBlur(rng.integers(0, 256, (240, 320), dtype=np.uint8), (3, 3), 0)
    settings = OrbSettings(n_features=400)
    detected = _orb(settings).detect(img, None)
    xy = np.array([k.pt for k in detected])
    octave = np.array([k.octave for k in detected], dtype=np.int64)
    response = np.array([k.response for k in detected])
    kept = _spread(xy, octave, response, settings)
    assert kept.size == settings.n_features
    assert np.array_equal(kept, np.unique(kept))
    quota = level_quota(settings.n_features, settings.levels, settings.scale)
    per_level = np.bincount(octave[kept], minlength=settings.levels)
    have = np.bincount(octave, minlength=settings.levels)
    for level in range(settings.levels):
        if have[level] >= quota[level] and level == 0:
            assert per_level[level] >= quota[level]
        idx = np.flatnonzero(octave == level)
        if idx.size == 0:
            continue
        size = settings.cell_px * settings.scale**level
        cells = np.floor(xy[idx] / size).astype(np.int64)
        cell_id = cells[:, 1] * 100_000 + cells[:, 0]
        chosen = np.isin(idx, kept)
        if chosen.all() or not chosen.any():
            continue
        # Round robin: a cell with two chosen corners means no cell was left without one.
        counts = {c: int(np.sum(chosen & (cell_id == c))) for c in np.unique(cell_id)}
        if max(counts.values()) >= 2:
            assert min(counts.values()) >= 1
        # Within a cell, the strongest corners are the ones chosen.
        for c in np.unique(cell_id):
            in_cell = cell_id == c
            if chosen[in_cell].any() and not chosen[in_cell].all():
                assert (
                    response[idx][in_cell & chosen].min() >= response[idx][in_cell & ~chosen].max()
                )
    assert np.array_equal(_spread(xy, octave, response, settings), kept)
