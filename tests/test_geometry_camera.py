"""Pinhole projection, unprojection and undistortion against OpenCV."""

from __future__ import annotations

import inspect

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from slamcli.formats.camera import PRESETS
from slamcli.geometry.camera import project, undistort_image, undistort_points, unproject
from slamcli.types import PinholeCamera

FR1 = PRESETS["fr1"]


@settings(max_examples=50, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.floats(100.0, 1000.0),
    st.floats(100.0, 1000.0),
    st.floats(0.0, 640.0),
    st.floats(0.0, 480.0),
)
def test_project_unproject_round_trip(
    seed: int, fx: float, fy: float, cx: float, cy: float
) -> None:
    cam = PinholeCamera(640, 480, fx, fy, cx, cy)
    rng = np.random.default_rng(seed)
    pts = np.column_stack([rng.uniform(-3, 3, (20, 2)), rng.uniform(0.1, 10.0, 20)])
    uv = project(cam, pts)
    assert uv.shape == (20, 2)
    np.testing.assert_allclose(unproject(cam, uv, pts[:, 2]), pts, rtol=1e-12, atol=1e-12)
    pixels = rng.uniform(0, 640, (4, 5, 2))
    depth = rng.uniform(0.1, 5.0, (4, 5))
    back = unproject(cam, pixels, depth)
    assert back.shape == (4, 5, 3)
    np.testing.assert_allclose(project(cam, back), pixels, rtol=1e-12, atol=1e-9)


def test_unproject_matches_the_pinhole_formula_and_broadcasts_depth() -> None:
    cam = PinholeCamera(320, 240, 256.0, 250.0, 159.5, 119.5)
    uv = np.array([[159.5, 119.5], [0.0, 0.0], [319.0, 239.0]], dtype=np.float32)
    rays = unproject(cam, uv, 1.0)
    assert rays.dtype == np.float64
    np.testing.assert_array_equal(rays[0], [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(rays[1], [-159.5 / 256.0, -119.5 / 250.0, 1.0])
    pts = unproject(cam, uv, np.array([2.0, np.nan, 0.5]))
    np.testing.assert_array_equal(pts[0], [0.0, 0.0, 2.0])
    assert np.isnan(pts[1]).all()
    np.testing.assert_allclose(pts[2], rays[2] * 0.5)


def test_undistort_points_matches_opencv_in_pixels() -> None:
    rng = np.random.default_rng(1)
    raw = rng.uniform([20.0, 20.0], [620.0, 460.0], (200, 2))
    ours = undistort_points(FR1, raw)
    d = np.asarray(FR1.distortion)
    cv = cv2.undistortPoints(raw.reshape(-1, 1, 2), FR1.K, d, P=FR1.K).reshape(-1, 2)
    # OpenCV's default stops after five iterations, a tenth of a pixel short in the corners.
    np.testing.assert_allclose(ours, cv, atol=0.1)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-9)
    cv = cv2.undistortPoints(raw.reshape(-1, 1, 2), FR1.K, d, R=None, P=FR1.K, criteria=crit)
    np.testing.assert_allclose(ours, cv.reshape(-1, 2), atol=1e-9)
    # Distorting the result again (OpenCV's forward model) lands on the raw pixels.
    rays = unproject(FR1, ours, 1.0)
    again, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), FR1.K, d)
    np.testing.assert_allclose(again.reshape(-1, 2), raw, atol=1e-6)
    # Shapes are kept; an undistorted camera leaves pixels alone.
    assert undistort_points(FR1, raw.reshape(10, 20, 2)).shape == (10, 20, 2)
    np.testing.assert_array_equal(undistort_points(FR1.undistorted(), raw), raw)


def test_undistort_image_default_keeps_k_and_interpolates_like_cv2_undistort() -> None:
    """The one default: the same K, bilinear; nearest sampling only when asked (depth)."""
    v, u = np.mgrid[0:480, 0:640].astype(np.float32)
    smooth = (100.0 + 50.0 * np.sin(u / 40.0) * np.cos(v / 30.0)).astype(np.float32)
    ours = undistort_image(FR1, smooth)
    assert ours.shape == smooth.shape and ours.dtype == np.float32
    # cv2.undistort's default new camera matrix is K too (its maps are fixed-point: 1/32 px).
    ref = cv2.undistort(smooth, FR1.K, np.asarray(FR1.distortion))
    inner = (slice(40, 440), slice(40, 600))
    np.testing.assert_allclose(ours[inner], ref[inner], atol=0.1)
    # Nearest sampling only ever copies source values: no depth is invented at an edge.
    steps = np.where(u < 320, 1000, 3000).astype(np.uint16)
    near = undistort_image(FR1, steps, nearest=True)
    assert near.dtype == np.uint16
    assert set(np.unique(near).tolist()) <= {0, 1000, 3000}
    # A point's undistorted pixel is where the undistorted image shows it.
    dot = np.zeros((480, 640), dtype=np.float32)
    dot[100:103, 500:503] = 1.0
    moved = undistort_image(FR1, dot)
    centre = np.argwhere(moved > 0.5).mean(axis=0)[::-1]
    np.testing.assert_allclose(undistort_points(FR1, [501.0, 101.0]), centre, atol=0.5)
    plain = FR1.undistorted()
    assert undistort_image(plain, smooth) is smooth


def test_undistortion_defaults_reader_off_dense_pipeline_on() -> None:
    """As documented in slamcli.geometry.camera: readers keep the recorded images, the dense
    pipeline (which needs a pinhole) removes the distortion itself."""
    from slamcli.formats.tum_rgbd import TumRgbdSource
    from slamcli.pipelines.dense import DenseConfig

    assert inspect.signature(TumRgbdSource).parameters["undistort"].default is False
    assert DenseConfig().undistort is True
