"""bundle_adjust on seeded synthetic scenes: convergence, fixed frames, outliers, determinism,
input errors and the gauge."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest

from slamcli.geometry.camera import project
from slamcli.geometry.se3 import compose, inverse, make_pose, rotation_angle, se3_exp, so3_exp
from slamcli.types import PinholeCamera
from slamcli.vision.bundle_adjustment import BundleResult, bundle_adjust

pytest.importorskip("pycolmap")

CAMERA = PinholeCamera(640, 480, 520.0, 520.0, 319.5, 239.5)


@dataclass(frozen=True)
class Scene:
    truth_poses: np.ndarray
    truth_points: np.ndarray
    poses: np.ndarray
    points: np.ndarray
    obs_frame: np.ndarray
    obs_point: np.ndarray
    obs_uv: np.ndarray
    obs_sigma: np.ndarray
    fixed: np.ndarray
    outlier: np.ndarray


def make_scene(
    seed: int,
    *,
    frames: int = 8,
    points: int = 400,
    per_point: int = 5,
    noise: float = 0.3,
    outliers: float = 0.0,
    n_fixed: int = 4,
) -> Scene:
    """Keyframes on a 1 m baseline looking at points 3-8 m away; ORB octave sigmas 1.2**o;
    pixel noise ``noise * sigma``; free poses perturbed by 3 cm / 0.6°, points by 10 cm."""
    rng = np.random.default_rng(seed)
    centres = np.stack(
        [np.linspace(0.0, 1.0, frames), rng.normal(0, 0.05, frames), rng.normal(0, 0.05, frames)],
        axis=1,
    )
    truth = inverse(make_pose(so3_exp(rng.normal(0, 0.05, (frames, 3))), centres))
    xyz = np.stack(
        [rng.uniform(-1.5, 2.5, points), rng.uniform(-1.2, 1.2, points), rng.uniform(3, 8, points)],
        axis=1,
    )
    obs_frame = np.concatenate(
        [rng.choice(frames, per_point, replace=False) for _ in range(points)]
    ).astype(np.int64)
    obs_point = np.repeat(np.arange(points, dtype=np.int64), per_point)
    sigma = 1.2 ** rng.integers(0, 8, obs_frame.size)
    pc = np.einsum("mij,mj->mi", truth[obs_frame, :3, :3], xyz[obs_point]) + truth[obs_frame, :3, 3]
    uv = pc[:, :2] / pc[:, 2:] * [CAMERA.fx, CAMERA.fy] + [CAMERA.cx, CAMERA.cy]
    uv += rng.normal(0.0, noise, uv.shape) * sigma[:, None]
    outlier = rng.random(obs_frame.size) < outliers
    n_out = int(outlier.sum())
    uv[outlier] += rng.uniform(20, 40, (n_out, 2)) * rng.choice([-1.0, 1.0], (n_out, 2))
    fixed = np.arange(frames) < n_fixed
    poses = truth.copy()
    free = int((~fixed).sum())
    twist = np.concatenate([rng.normal(0, 0.03, (free, 3)), rng.normal(0, 0.01, (free, 3))], 1)
    poses[~fixed] = compose(se3_exp(twist), truth[~fixed])
    pts = xyz + rng.normal(0, 0.1, xyz.shape)
    return Scene(truth, xyz, poses, pts, obs_frame, obs_point, uv, sigma, fixed, outlier)


def solve(scene: Scene, **kwargs: object) -> BundleResult:
    args: dict[str, object] = {"fixed_frames": scene.fixed, **kwargs}
    return bundle_adjust(
        CAMERA,
        scene.poses,
        scene.points,
        scene.obs_frame,
        scene.obs_point,
        scene.obs_uv,
        scene.obs_sigma,
        **args,  # type: ignore[arg-type]
    )


def pose_errors(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera-centre distances (m) and rotation angles (deg) between two pose stacks."""
    centre = np.linalg.norm(inverse(a)[:, :3, 3] - inverse(b)[:, :3, 3], axis=1)
    angle = np.degrees(rotation_angle(a[:, :3, :3] @ np.swapaxes(b[:, :3, :3], 1, 2)))
    return centre, angle


@pytest.fixture(scope="module")
def clean() -> Scene:
    return make_scene(0)


@pytest.fixture(scope="module")
def clean_result(clean: Scene) -> BundleResult:
    return solve(clean, max_iterations=20)


def test_converges_to_truth(clean: Scene, clean_result: BundleResult) -> None:
    free = ~clean.fixed
    centre0, angle0 = pose_errors(clean.poses[free], clean.truth_poses[free])
    centre, angle = pose_errors(clean_result.cam_from_world[free], clean.truth_poses[free])
    assert centre0.max() > 0.02 and angle0.max() > 0.3  # the start is really off
    assert centre.max() < 0.006, centre
    assert angle.max() < 0.1, angle
    point0 = np.linalg.norm(clean.points - clean.truth_points, axis=1)
    point = np.linalg.norm(clean_result.points - clean.truth_points, axis=1)
    assert np.median(point0) > 0.1
    assert np.median(point) < 0.03
    # Pixel noise is 0.3 sigma: the whitened RMSE per axis comes down to about 0.3.
    assert np.sqrt(np.mean(clean_result.obs_chi2) / 2.0) < 0.35
    assert clean_result.inlier.all()
    assert clean_result.final_cost < 0.01 * clean_result.initial_cost
    assert 1 <= clean_result.iterations <= 20
    # The noise, not the solver, limits the errors above: started at the truth, BA finds the
    # same minimum.
    oracle = solve(replace(clean, poses=clean.truth_poses, points=clean.truth_points))
    centre_gap, angle_gap = pose_errors(clean_result.cam_from_world, oracle.cam_from_world)
    assert centre_gap.max() < 1e-4 and angle_gap.max() < 1e-3
    gap = np.linalg.norm(clean_result.points - oracle.points, axis=1)
    assert np.median(gap) < 1e-4


def test_fixed_frames_and_points_stay_bit_exact(clean: Scene, clean_result: BundleResult) -> None:
    assert np.array_equal(clean_result.cam_from_world[clean.fixed], clean.poses[clean.fixed])
    assert not np.array_equal(clean_result.cam_from_world[~clean.fixed], clean.poses[~clean.fixed])
    fixed_points = np.zeros(clean.points.shape[0], dtype=bool)
    fixed_points[::3] = True
    res = solve(clean, fixed_points=fixed_points)
    assert np.array_equal(res.points[fixed_points], clean.points[fixed_points])
    assert np.array_equal(res.cam_from_world[clean.fixed], clean.poses[clean.fixed])
    assert not np.array_equal(res.points[~fixed_points], clean.points[~fixed_points])


def test_outliers_are_flagged_and_do_not_pull() -> None:
    scene = make_scene(1, outliers=0.05)
    res = solve(scene)
    good = ~scene.outlier
    assert scene.outlier.sum() > 50
    assert not res.inlier[scene.outlier].any()
    assert res.inlier[good].mean() > 0.99
    centre, angle = pose_errors(res.cam_from_world[~scene.fixed], scene.truth_poses[~scene.fixed])
    assert centre.max() < 0.015 and angle.max() < 0.1


def test_a_point_behind_the_cameras_is_an_outlier(clean: Scene) -> None:
    mirrored = clean.points.copy()
    mirrored[0] = -mirrored[0]  # behind every camera; held there
    fixed_points = np.zeros(mirrored.shape[0], dtype=bool)
    fixed_points[0] = True
    res = solve(replace(clean, points=mirrored), fixed_points=fixed_points)
    rows = clean.obs_point == 0
    assert np.isinf(res.obs_chi2[rows]).all()
    assert not res.inlier[rows].any()
    assert res.inlier[~rows].all()
    free = ~clean.fixed
    centre, _ = pose_errors(res.cam_from_world[free], clean.truth_poses[free])
    assert centre.max() < 0.005


def test_points_seen_once_are_kept_and_do_not_stop_the_solve(clean: Scene) -> None:
    # Points 0-9 keep one observation each (a monocular point whose other views were culled);
    # point 10 keeps one left observation plus its stereo depth (two rows, so it is solved).
    first = np.r_[True, clean.obs_point[1:] != clean.obs_point[:-1]]
    keep = (clean.obs_point >= 11) | ((clean.obs_point < 11) & first)
    scene = replace(
        clean,
        obs_frame=clean.obs_frame[keep],
        obs_point=clean.obs_point[keep],
        obs_uv=clean.obs_uv[keep],
        obs_sigma=clean.obs_sigma[keep],
    )
    depth = np.full(scene.obs_point.size, np.nan)
    row10 = int(np.flatnonzero(scene.obs_point == 10)[0])
    pose = scene.truth_poses[scene.obs_frame[row10]]
    depth[row10] = (pose[:3, :3] @ scene.truth_points[10] + pose[:3, 3])[2]
    res = solve(scene, obs_depth=depth)
    assert np.array_equal(res.points[:10], scene.points[:10])
    assert not np.array_equal(res.points[10], scene.points[10])
    free = ~scene.fixed
    centre, _ = pose_errors(res.cam_from_world[free], scene.truth_poses[free])
    assert centre.max() < 0.005


def test_sigmas_weight_the_observations() -> None:
    """Half the observations get 5 px of noise and say so: honouring the sigmas beats ignoring
    them."""
    scene = make_scene(2)
    rng = np.random.default_rng(5)
    noisy = rng.random(scene.obs_sigma.size) < 0.5
    uv = scene.obs_uv + rng.normal(0.0, 5.0, scene.obs_uv.shape) * noisy[:, None]
    sigma = np.where(noisy, 5.0, 0.3 * scene.obs_sigma)
    weighted = solve(replace(scene, obs_uv=uv, obs_sigma=sigma))
    flat = solve(replace(scene, obs_uv=uv, obs_sigma=np.ones_like(sigma)))
    free = ~scene.fixed
    err_w = pose_errors(weighted.cam_from_world[free], scene.truth_poses[free])[0]
    err_f = pose_errors(flat.cam_from_world[free], scene.truth_poses[free])[0]
    assert np.mean(err_w) < 0.7 * np.mean(err_f)
    # obs_chi2 is the squared pixel error whitened with each observation's own sigma.
    poses, pts = weighted.cam_from_world, weighted.points
    pc = project(
        CAMERA,
        np.einsum("mij,mj->mi", poses[scene.obs_frame, :3, :3], pts[scene.obs_point])
        + poses[scene.obs_frame, :3, 3],
    )
    expected = np.sum((pc - uv) ** 2, axis=1) / sigma**2
    np.testing.assert_allclose(weighted.obs_chi2, expected, rtol=1e-9)
    assert np.sqrt(np.mean(weighted.obs_chi2[noisy]) / 2.0) == pytest.approx(1.0, abs=0.15)


def test_many_distinct_sigmas_still_converge() -> None:
    scene = make_scene(3)
    rng = np.random.default_rng(7)
    sigma = rng.uniform(1.0, 3.0, scene.obs_sigma.size)  # > MAX_SIGMA_GROUPS distinct values
    res = solve(replace(scene, obs_sigma=sigma * scene.obs_sigma))
    centre, _ = pose_errors(res.cam_from_world[~scene.fixed], scene.truth_poses[~scene.fixed])
    assert centre.max() < 0.01


def test_two_calls_are_bit_identical() -> None:
    scene = make_scene(4, outliers=0.05)
    a, b = solve(scene), solve(scene)
    assert np.array_equal(a.cam_from_world, b.cam_from_world)
    assert np.array_equal(a.points, b.points)
    assert np.array_equal(a.obs_chi2, b.obs_chi2)
    assert np.array_equal(a.inlier, b.inlier)
    assert (a.initial_cost, a.final_cost, a.iterations) == (
        b.initial_cost,
        b.final_cost,
        b.iterations,
    )


def test_fix_gauge_holds_the_first_pose_and_the_scale() -> None:
    scene = make_scene(5, n_fixed=0)
    res = solve(scene)
    assert np.array_equal(res.cam_from_world[0], scene.poses[0])
    centres_in = inverse(scene.poses)[:, :3, 3]
    centres_out = inverse(res.cam_from_world)[:, :3, 3]
    base_in = np.linalg.norm(centres_in[1] - centres_in[0])
    base_out = np.linalg.norm(centres_out[1] - centres_out[0])
    assert base_out == pytest.approx(base_in, rel=1e-9)
    assert res.final_cost < 0.01 * res.initial_cost
    loose = solve(scene, fix_gauge=False)
    assert not np.array_equal(loose.cam_from_world[0], scene.poses[0])


def test_input_errors_are_clear(clean: Scene) -> None:
    empty = np.zeros(0, dtype=np.int64)
    with pytest.raises(ValueError, match="empty problem"):
        bundle_adjust(
            CAMERA,
            clean.poses,
            clean.points,
            empty,
            empty,
            np.zeros((0, 2)),
            np.zeros(0),
            fixed_frames=clean.fixed,
        )
    frames = clean.obs_frame.copy()
    frames[3] = 8
    with pytest.raises(ValueError, match=r"obs_frame\[3\] = 8 is out of range \[0, 8\)"):
        solve(replace(clean, obs_frame=frames))
    points = clean.obs_point.copy()
    points[7] = -1
    with pytest.raises(ValueError, match=r"obs_point\[7\] = -1 is out of range"):
        solve(replace(clean, obs_point=points))
    with pytest.raises(ValueError, match="obs_sigma_px must be finite and > 0"):
        solve(replace(clean, obs_sigma=np.zeros_like(clean.obs_sigma)))
    with pytest.raises(ValueError, match=r"fixed_frames must be a \(8,\) bool array"):
        solve(clean, fixed_frames=np.zeros(3, dtype=bool))
    with pytest.raises(ValueError, match=r"cam_from_world must be \(K, 4, 4\)"):
        solve(replace(clean, poses=clean.poses[:, :3]))


@pytest.mark.parametrize("loss", ["cauchy", "huber"])
@pytest.mark.parametrize("with_depth", [False, True])
def test_compiled_solver_takes_colmaps_steps(
    monkeypatch: pytest.MonkeyPatch, loss: str, with_depth: bool
) -> None:
    """The compiled solver is COLMAP's Levenberg-Marquardt on the same cost: on a scene with
    outliers (and with depth, the virtual right camera), stopped after the pipeline's 10
    iterations or at the tolerance, both take the same steps and end at the same poses,
    points, cost and inliers, to rounding."""
    import slamcli.vision.bundle_adjustment as bam

    scene = make_scene(3, outliers=0.05)
    kwargs: dict[str, object] = {"robust_loss": loss, "max_iterations": 10}
    if with_depth:
        pc = np.einsum(
            "mij,mj->mi",
            scene.truth_poses[scene.obs_frame, :3, :3],
            scene.truth_points[scene.obs_point],
        )
        depth = pc[:, 2] + scene.truth_poses[scene.obs_frame, 2, 3]
        depth = depth * (1.0 + np.random.default_rng(4).normal(0.0, 0.005, depth.size))
        depth[::3] = np.nan
        kwargs.update(obs_depth=depth, baseline_m=0.08)
    compiled = solve(scene, **kwargs)
    monkeypatch.setattr(bam, "COMPILED_MAX_FRAMES", 0)
    colmap = solve(scene, **kwargs)
    assert compiled.final_cost < 0.2 * compiled.initial_cost
    assert compiled.iterations == colmap.iterations
    assert abs(compiled.final_cost - colmap.final_cost) <= 1e-9 * colmap.final_cost
    assert np.abs(compiled.cam_from_world - colmap.cam_from_world).max() < 1e-9
    assert np.abs(compiled.points - colmap.points).max() < 1e-8
    assert (compiled.inlier == colmap.inlier).all()
    assert not compiled.inlier.all()  # the outliers are found


def test_compiled_solver_lets_a_point_go_behind_a_camera_as_colmap_does(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A point whose observations pull it through a camera's plane: as in COLMAP's cost, an
    observation from behind has no residual, and the result calls it an outlier."""
    import slamcli.vision.bundle_adjustment as bam

    scene = make_scene(0, frames=4, points=60, per_point=3, n_fixed=2)
    # Two of the first point's three observations moved far off the image, to one side:
    # the fit carries the point behind the cameras.
    uv = scene.obs_uv.copy()
    uv[:2] = [-5000.0, 3000.0]
    bent = replace(scene, obs_uv=uv)
    compiled = solve(bent)
    monkeypatch.setattr(bam, "COMPILED_MAX_FRAMES", 0)
    colmap = solve(bent)
    behind = np.isinf(compiled.obs_chi2)
    assert behind[:3].any() and not behind[3:].any()
    assert not compiled.inlier[behind].any()
    assert np.array_equal(behind, np.isinf(colmap.obs_chi2))
    assert np.abs(compiled.points - colmap.points).max() < 1e-8
