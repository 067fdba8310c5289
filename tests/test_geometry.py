"""Invariants of the SE(3)/SO(3) and planar maths, Umeyama alignment and the planar rigid fit,
checked on random inputs."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from slamcli.errors import InputError
from slamcli.geometry import (
    between_planar,
    blend_poses,
    compose,
    compose_planar,
    interpolate_poses,
    inverse,
    invert_planar,
    make_pose,
    matrix_to_quat_wxyz,
    matrix_to_quat_xyzw,
    quat_wxyz_to_matrix,
    quat_xyzw_to_matrix,
    rigid_fit_2d,
    rotation_2d,
    rotation_angle,
    se3_exp,
    se3_log,
    slerp,
    so3_exp,
    so3_log,
    transform_points_planar,
    umeyama,
    wrap_angle,
)

finite = st.floats(-3.0, 3.0, allow_nan=False, allow_infinity=False)
twists = arrays(np.float64, (5, 6), elements=finite)


def random_poses(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return se3_exp(rng.normal(size=(n, 6)) * [2, 2, 2, 1, 1, 1])


@settings(max_examples=200, deadline=None)
@given(twists)
def test_inverse_composes_to_identity(xi: np.ndarray) -> None:
    t = se3_exp(xi)
    np.testing.assert_allclose(
        compose(t, inverse(t)), np.broadcast_to(np.eye(4), t.shape), atol=1e-9
    )
    np.testing.assert_allclose(inverse(inverse(t)), t, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(twists, twists)
def test_inverse_of_product(a: np.ndarray, b: np.ndarray) -> None:
    ta, tb = se3_exp(a), se3_exp(b)
    np.testing.assert_allclose(
        inverse(compose(ta, tb)), compose(inverse(tb), inverse(ta)), atol=1e-9
    )


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, (5, 6), elements=st.floats(-1.0, 1.0)))
def test_se3_log_inverts_exp(xi: np.ndarray) -> None:
    # Rotation vectors of norm < π are the principal branch, so log(exp(ξ)) = ξ.
    np.testing.assert_allclose(se3_log(se3_exp(xi)), xi, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, (7, 3), elements=finite))
def test_so3_exp_is_a_rotation(phi: np.ndarray) -> None:
    r = so3_exp(phi)
    np.testing.assert_allclose(
        r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), r.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    np.testing.assert_allclose(so3_exp(so3_log(r)), r, atol=1e-9)


def test_so3_log_at_pi_and_identity() -> None:
    for axis in np.eye(3):
        np.testing.assert_allclose(np.abs(so3_log(so3_exp(np.pi * axis))), np.pi * axis, atol=1e-7)
    np.testing.assert_allclose(so3_log(np.eye(3)), 0.0, atol=1e-15)
    assert rotation_angle(so3_exp([0.0, 0.0, 2.5])) == pytest.approx(2.5)


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, (6, 4), elements=st.floats(-1.0, 1.0)))
def test_quaternion_round_trips(q: np.ndarray) -> None:
    norms = np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(norms < 1e-3, [1.0, 0.0, 0.0, 0.0], q / np.maximum(norms, 1e-3))
    q = np.where(q[:, :1] < 0, -q, q)
    r = quat_wxyz_to_matrix(q)
    back = matrix_to_quat_wxyz(r)
    # q and -q are the same rotation; the canonical output has w >= 0.
    same = np.minimum(np.abs(back - q).max(axis=1), np.abs(back + q).max(axis=1))
    assert same.max() < 1e-9
    xyzw = matrix_to_quat_xyzw(r)
    np.testing.assert_allclose(xyzw[:, [3, 0, 1, 2]], back, atol=1e-15)
    np.testing.assert_allclose(quat_xyzw_to_matrix(xyzw), r, atol=1e-12)


def test_known_quaternion() -> None:
    # 90° about z: x axis goes to y.
    r = quat_xyzw_to_matrix([0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)])
    np.testing.assert_allclose(r @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)


def test_slerp_halfway_and_ends() -> None:
    q0 = matrix_to_quat_wxyz(so3_exp([0.0, 0.0, 0.0]))
    q1 = matrix_to_quat_wxyz(so3_exp([0.0, 0.0, 1.2]))
    mid = slerp(q0, q1, 0.5)
    np.testing.assert_allclose(so3_log(quat_wxyz_to_matrix(mid)), [0.0, 0.0, 0.6], atol=1e-12)
    np.testing.assert_allclose(slerp(q0, q1, 0.0), q0, atol=1e-15)
    np.testing.assert_allclose(slerp(q0, -q1, 1.0), q1, atol=1e-15)  # shorter arc


def test_interpolate_poses_constant_twist() -> None:
    xi = np.array([0.4, -0.2, 0.1, 0.0, 0.0, 0.8])
    stamps = np.array([0, 1_000_000_000], dtype=np.int64)
    poses = np.stack([np.eye(4), make_pose(so3_exp(xi[3:]), xi[:3])])
    valid, out = interpolate_poses(stamps, poses, np.array([-1, 250_000_000, 1_000_000_001]))
    assert valid.tolist() == [False, True, False]
    np.testing.assert_allclose(rotation_angle(out[1]), 0.2, atol=1e-12)
    np.testing.assert_allclose(out[1, :3, 3], 0.25 * xi[:3], atol=1e-12)


def test_blend_poses_moves_along_the_geodesic() -> None:
    a = make_pose(so3_exp([0.1, 0.2, -0.3]), [1.0, 0.0, 2.0])
    b = make_pose(so3_exp([0.5, -0.1, 0.4]), [0.0, 2.0, 1.0])
    np.testing.assert_allclose(blend_poses(a, b, 0.0), a, atol=1e-12)
    np.testing.assert_allclose(blend_poses(a, b, 1.0), b, atol=1e-12)
    quarter = blend_poses(a, b, 0.25)
    turn = rotation_angle(np.linalg.inv(a) @ b)
    np.testing.assert_allclose(rotation_angle(np.linalg.inv(a) @ quarter), 0.25 * turn, atol=1e-12)
    np.testing.assert_allclose(quarter[:3, 3], [0.75, 0.5, 1.75], atol=1e-12)


@pytest.mark.parametrize("with_scale", [False, True])
def test_umeyama_recovers_a_known_transform(with_scale: bool) -> None:
    rng = np.random.default_rng(3)
    src = rng.normal(size=(100, 3))
    r_true = so3_exp([0.3, -1.0, 2.0])
    s_true = 1.7 if with_scale else 1.0
    dst = s_true * src @ r_true.T + [1.0, 2.0, -3.0]
    r, t, s = umeyama(src, dst, with_scale=with_scale)
    np.testing.assert_allclose(r, r_true, atol=1e-12)
    np.testing.assert_allclose(t, [1.0, 2.0, -3.0], atol=1e-12)
    assert s == pytest.approx(s_true, rel=1e-12)


def test_umeyama_rejects_degenerate_input() -> None:
    pts = np.zeros((10, 3))
    with pytest.raises(InputError, match="degenerate"):
        umeyama(pts, pts)
    with pytest.raises(InputError, match="at least 2"):
        umeyama(pts[:1], pts[:1])


def test_random_pose_stack_shapes() -> None:
    t = random_poses(4, 0)
    assert inverse(t).shape == (4, 4, 4)
    assert se3_log(t).shape == (4, 6)


# --- planar poses and the planar rigid fit ---------------------------------------------------

planar_poses = arrays(np.float64, (6, 3), elements=st.floats(-10.0, 10.0))


@settings(max_examples=200, deadline=None)
@given(planar_poses, planar_poses)
def test_planar_inverse_and_between_agree_with_composition(a: np.ndarray, b: np.ndarray) -> None:
    identity = compose_planar(a, invert_planar(a))
    np.testing.assert_allclose(identity, 0.0, atol=1e-9)
    rel = between_planar(a, b)
    np.testing.assert_allclose(rel, compose_planar(invert_planar(a), b), atol=1e-9)
    back = compose_planar(a, rel)
    np.testing.assert_allclose(back[:, :2], b[:, :2], atol=1e-9)
    np.testing.assert_allclose(wrap_angle(back[:, 2] - b[:, 2]), 0.0, atol=1e-9)


def test_planar_points_move_like_composed_poses() -> None:
    rng = np.random.default_rng(3)
    pose, points = np.array([1.0, -2.0, 0.8]), rng.normal(size=(7, 2))
    as_poses = compose_planar(pose, np.column_stack([points, np.zeros(7)]))
    np.testing.assert_allclose(transform_points_planar(pose, points), as_poses[:, :2])
    rots = rotation_2d(np.array([0.0, np.pi / 2]))
    np.testing.assert_allclose(rots[1] @ [1.0, 0.0], [0.0, 1.0], atol=1e-15)
    assert rots.shape == (2, 2, 2) and rotation_2d(0.3).shape == (2, 2)


def _moved_points(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points, a known planar transform and the points it maps them to."""
    rng = np.random.default_rng(seed)
    src = rng.normal(size=(n, 2)) * 5.0
    truth = np.array([2.0, -1.5, 2.9])
    return src, truth, transform_points_planar(truth, src)


def test_rigid_fit_2d_recovers_a_known_transform_with_its_rms() -> None:
    src, truth, dst = _moved_points(12, seed=4)
    pose, rms = rigid_fit_2d(src, dst)
    np.testing.assert_allclose(pose, truth, atol=1e-12)
    assert rms < 1e-12
    noisy = dst + np.random.default_rng(5).normal(0.0, 0.1, size=dst.shape)
    pose, rms = rigid_fit_2d(src, noisy)
    res = transform_points_planar(pose, src) - noisy
    assert rms == pytest.approx(float(np.sqrt(np.mean(np.sum(res**2, axis=1)))))
    # The same transform as Umeyama's SVD in 2-D.
    rot, t, _ = umeyama(src, noisy)
    np.testing.assert_allclose(rotation_2d(pose[2]), rot, atol=1e-12)
    np.testing.assert_allclose(pose[:2], t, atol=1e-12)


def test_rigid_fit_2d_weights_ignore_what_weighs_nothing() -> None:
    src, truth, dst = _moved_points(10, seed=6)
    spoiled = dst.copy()
    spoiled[:3] += 4.0
    weights = np.r_[np.zeros(3), np.full(7, 2.5)]
    pose, rms = rigid_fit_2d(src, spoiled, weights)
    np.testing.assert_allclose(pose, truth, atol=1e-12)
    assert rms > 1.0  # the residuals' RMS counts every pair, weighted or not
    # Equal weights give the unweighted fit.
    equal, _ = rigid_fit_2d(src, spoiled, np.full(10, 0.3))
    np.testing.assert_allclose(equal, rigid_fit_2d(src, spoiled)[0], atol=1e-12)


def test_rigid_fit_2d_of_one_point_is_a_translation() -> None:
    pose, rms = rigid_fit_2d([[1.0, 2.0]], [[4.0, 6.0]])
    np.testing.assert_array_equal(pose, [3.0, 4.0, 0.0])
    assert rms == 0.0
