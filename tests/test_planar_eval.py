"""Planar (SE(2)) evaluation of landmark SLAM, NEES consistency and the landmark run report."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.stats import chi2

from slamcli.errors import InputError
from slamcli.geometry import planar_to_se3, wrap_angle
from slamcli.planar_eval import (
    dead_reckoning_ate,
    evaluate_common_frame,
    evaluate_planar,
    nees_band,
)
from slamcli.report import plot_landmark_run
from slamcli.types import LandmarkMap, Trajectory

S = 1_000_000_000


def _gt_path(n: int = 600, dt_s: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (ns) and (x, y, yaw) of a figure-eight-ish drive, heading along the path."""
    t = np.arange(n) * dt_s
    x = 10.0 * np.sin(0.05 * t) + 0.5 * t
    y = 6.0 * np.sin(0.1 * t)
    yaw = np.arctan2(np.gradient(y), np.gradient(x))
    stamps = (1_700_000_000 * S + np.round(t * S)).astype(np.int64)
    return stamps, np.stack([x, y, yaw], axis=1)


def _traj(stamps: np.ndarray, xyt: np.ndarray) -> Trajectory:
    return Trajectory(stamps, planar_to_se3(xyt))


def _se2_apply(angle: float, t: np.ndarray, xyt: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    r = np.array([[c, -s], [s, c]])
    out = xyt.copy()
    out[:, :2] = xyt[:, :2] @ r.T + t
    if xyt.shape[1] == 3:
        out[:, 2] = wrap_angle(xyt[:, 2] + angle)
    return out


def _se2_inverse(angle: float, t: np.ndarray) -> tuple[float, np.ndarray]:
    c, s = np.cos(angle), np.sin(angle)
    r = np.array([[c, -s], [s, c]])
    return -angle, -(r.T @ t)


def test_se2_alignment_is_recovered_and_aligned_ate_is_the_noise() -> None:
    rng = np.random.default_rng(1)
    stamps, gt = _gt_path()
    # The estimate lives in a frame rotated by 0.7 rad and shifted: gt = T(est).
    angle, t = 0.7, np.array([3.0, -2.0])
    inv_angle, inv_t = _se2_inverse(angle, t)
    est = _se2_apply(inv_angle, inv_t, gt)
    sigma = 0.02
    est[:, :2] += rng.normal(0.0, sigma, size=(len(est), 2))
    res = evaluate_planar(_traj(stamps, gt), _traj(stamps, est))

    assert res.matched == res.possible == len(stamps)
    assert res.angle_rad == pytest.approx(angle, abs=2e-3)
    np.testing.assert_allclose(res.translation, t, atol=0.01)
    # 2-D isotropic noise: E|e|² = 2σ².
    assert res.ate.rmse == pytest.approx(np.sqrt(2) * sigma, rel=0.1)
    assert res.ate_unaligned.rmse > 3.0
    assert res.heading.max < 0.2  # degrees
    assert res.heading_unaligned.median == pytest.approx(np.rad2deg(angle), abs=0.2)

    d = res.to_dict()
    json.dumps(d)
    assert d["alignment"] == "se2"
    assert d["ate"].keys() == {"rmse", "mean", "median", "std", "min", "max", "sse"}
    assert d["ate_unaligned"]["rmse"] == res.ate_unaligned.rmse
    assert d["matched"] == d["possible"] == len(stamps)
    assert d["transform"]["yaw_deg"] == pytest.approx(np.rad2deg(angle), abs=0.2)
    assert "nees" not in d and "landmarks" not in d


def test_estimate_at_other_stamps_compares_with_interpolated_gt() -> None:
    stamps, gt = _gt_path(n=200, dt_s=0.1)
    fine = np.arange(stamps[0], stamps[-1] + 1, S // 100, dtype=np.int64)  # 100 Hz
    from slamcli.geometry import interpolate_planar

    exact = interpolate_planar(stamps, gt, fine)
    res = evaluate_planar(_traj(stamps, gt), _traj(fine, exact))
    assert res.matched == len(fine)
    assert res.ate_unaligned.max < 1e-9
    assert res.heading_unaligned.max < 1e-7


def test_landmarks_transformed_by_the_same_se2_have_zero_rmse() -> None:
    rng = np.random.default_rng(2)
    stamps, gt = _gt_path()
    angle, t = -1.2, np.array([-5.0, 8.0])
    inv_angle, inv_t = _se2_inverse(angle, t)
    est = _se2_apply(inv_angle, inv_t, gt)
    true_xy = rng.uniform(-20, 20, size=(40, 2))
    ids = np.arange(100, 140, dtype=np.int64)
    est_xy = _se2_apply(inv_angle, inv_t, true_xy)
    # One estimated landmark the survey does not have.
    lm = LandmarkMap(np.append(ids, 999), np.vstack([est_xy, [[50.0, 50.0]]]))
    res = evaluate_planar(
        _traj(stamps, gt),
        _traj(stamps, est),
        landmarks=lm,
        true_landmarks=LandmarkMap(ids, true_xy),
    )
    le = res.landmarks
    assert le is not None
    assert le.matched == 40
    assert le.rmse_m == pytest.approx(0.0, abs=1e-9)
    assert le.missed.size == 0
    assert le.estimated_ids[le.spurious].tolist() == [999]
    d = res.to_dict()["landmarks"]
    assert d["rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert (d["matched"], d["spurious"], d["duplicates"], d["missed"]) == (40, 1, 0, 0)
    assert d["unmatched_ids"] == [999]
    assert d["alignment"] == "se2 (trajectory)"

    # Without ids: the assignment on aligned positions finds the same pairs.
    res2 = evaluate_planar(
        _traj(stamps, gt),
        _traj(stamps, est),
        landmarks=LandmarkMap(np.arange(41, dtype=np.int64), lm.xy),
        true_landmarks=LandmarkMap(ids, true_xy),
        known_ids=False,
    )
    le2 = res2.landmarks
    assert le2 is not None
    assert le2.matched == 40
    assert le2.rmse_m == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_array_equal(le2.pairs[:, 0], le2.pairs[:, 1])
    assert le2.spurious.tolist() == [40]


def test_unknown_ids_counts_spurious_duplicates_and_missed() -> None:
    stamps, gt = _gt_path(n=100)
    traj = _traj(stamps, gt)
    true_xy = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0], [30.0, 30.0]])
    est_xy = np.array(
        [
            [0.1, 0.0],  # 0 -> true 0
            [10.0, 0.2],  # 1 -> true 1
            [0.3, 9.8],  # 2 -> true 2
            [0.05, -0.3],  # 3: true 0 mapped a second time (duplicate)
            [10.0, 10.4],  # 4 -> true 3
            [20.0, -20.0],  # 5: nothing near (spurious)
            [12.0, 12.0],  # 6: 2.8 m from true 3, beyond the radius (spurious)
        ]
    )
    res = evaluate_planar(
        traj,
        traj,
        landmarks=LandmarkMap(np.arange(7, dtype=np.int64), est_xy),
        true_landmarks=LandmarkMap(np.arange(5, dtype=np.int64), true_xy),
        known_ids=False,
        match_radius_m=1.0,
    )
    le = res.landmarks
    assert le is not None
    assert sorted(map(tuple, le.pairs.tolist())) == [(0, 0), (1, 1), (2, 2), (4, 3)]
    assert le.duplicates.tolist() == [3]
    assert sorted(le.spurious.tolist()) == [5, 6]
    assert le.missed.tolist() == [4]
    expected = np.sqrt(np.mean(np.array([0.1, 0.2, np.hypot(0.3, 0.2), 0.4]) ** 2))
    assert le.rmse_m == pytest.approx(expected)
    d = res.to_dict()["landmarks"]
    assert (d["matched"], d["spurious"], d["duplicates"], d["missed"]) == (4, 2, 1, 1)


def test_assignment_prefers_more_gated_pairs_over_a_smaller_sum() -> None:
    # est 0 sits between true 0 and 1; est 1 is only near true 1. Greedy nearest would pair
    # est 0 with true 1 and leave est 1 out; the optimal assignment matches both.
    stamps, gt = _gt_path(n=50)
    traj = _traj(stamps, gt)
    res = evaluate_planar(
        traj,
        traj,
        landmarks=LandmarkMap(np.arange(2, dtype=np.int64), np.array([[0.55, 0.0], [1.6, 0.0]])),
        true_landmarks=LandmarkMap(
            np.arange(2, dtype=np.int64), np.array([[0.0, 0.0], [1.0, 0.0]])
        ),
        known_ids=False,
        match_radius_m=0.7,
    )
    assert res.landmarks is not None
    assert sorted(map(tuple, res.landmarks.pairs.tolist())) == [(0, 0), (1, 1)]


def _nees_case(scale: float, n: int = 20_000) -> tuple[Trajectory, Trajectory, np.ndarray]:
    rng = np.random.default_rng(7)
    stamps = (np.arange(n) * (S // 50)).astype(np.int64)
    t = np.arange(n) * 0.02
    gt = np.stack([np.cos(0.01 * t) * 20, np.sin(0.01 * t) * 20, wrap_angle(0.01 * t + 1.5)], 1)
    a = np.array([[0.3, 0.0, 0.0], [0.1, 0.2, 0.0], [0.02, -0.01, 0.05]])
    p = a @ a.T
    err = rng.multivariate_normal(np.zeros(3), p, size=n)
    est = gt + err
    est[:, 2] = wrap_angle(est[:, 2])
    cov = np.broadcast_to(p * scale, (n, 3, 3)).copy()
    return _traj(stamps, gt), _traj(stamps, est), cov


def test_nees_of_samples_from_the_covariance_is_three_and_consistent() -> None:
    gt, est, cov = _nees_case(1.0)
    res = evaluate_planar(gt, est, est_cov=cov)
    nees = res.nees
    assert nees is not None
    assert nees.mean == pytest.approx(3.0, rel=0.05)
    assert nees.position_mean == pytest.approx(2.0, rel=0.05)
    assert nees.median == pytest.approx(chi2.ppf(0.5, 3), rel=0.05)
    assert nees.fraction_in_band == pytest.approx(0.95, abs=0.01)
    assert nees.consistent
    d = res.to_dict()["nees"]
    assert d["dof"] == 3
    assert d["band95"] == pytest.approx([chi2.ppf(0.025, 3), chi2.ppf(0.975, 3)])
    assert d["consistent"] is True
    json.dumps(d)


def test_nees_with_ten_times_too_small_covariance_is_inconsistent() -> None:
    gt, est, cov = _nees_case(0.1)
    nees = evaluate_planar(gt, est, est_cov=cov).nees
    assert nees is not None
    assert nees.mean == pytest.approx(30.0, rel=0.05)
    assert not nees.consistent
    assert nees.fraction_in_band < 0.5


def test_nees_skips_singular_covariances_and_checks_shape() -> None:
    gt, est, cov = _nees_case(1.0, n=100)
    cov[0] = 0.0  # the filter's exactly known first pose
    nees = evaluate_planar(gt, est, est_cov=cov).nees
    assert nees is not None
    assert nees.skipped == 1 and nees.values.size == 99
    with pytest.raises(InputError, match=r"\(100, 3, 3\)"):
        evaluate_planar(gt, est, est_cov=cov[:50])


def test_nees_band_matches_chi2() -> None:
    assert nees_band(3) == pytest.approx((chi2.ppf(0.025, 3), chi2.ppf(0.975, 3)))
    lo, hi = nees_band(2, n_runs=50)
    assert (lo, hi) == pytest.approx((chi2.ppf(0.025, 100) / 50, chi2.ppf(0.975, 100) / 50))


def test_stamps_in_long_gt_gaps_are_left_out() -> None:
    stamps, gt = _gt_path(n=300)  # 10 Hz
    # Drop 2 s of ground truth (a motion-capture drop-out) and keep a 0.3 s hole elsewhere.
    keep = np.ones(len(stamps), dtype=bool)
    keep[100:120] = False
    keep[200:202] = False
    est_stamps = stamps + S // 20  # 50 ms: half-way between gt samples
    est_stamps = est_stamps[:-1]
    res = evaluate_planar(_traj(stamps[keep], gt[keep]), _traj(est_stamps, gt[:-1]), max_gap_s=0.5)
    # Estimate stamps from 9.95 s to 11.95 s lie between gt 9.9 s and 12.0 s: 21 left out.
    assert res.in_gaps == 21
    assert res.outside_span == 0
    gap_lo, gap_hi = stamps[99], stamps[120]
    inside = (est_stamps > gap_lo) & (est_stamps < gap_hi)
    assert not np.any(np.isin(res.stamps_ns, est_stamps[inside]))
    # The 0.3 s hole is shorter than max_gap_s: its stamps are kept.
    assert res.matched == len(est_stamps) - 21
    assert res.to_dict()["in_gt_gaps"] == 21
    # A stricter limit also drops the short hole (3 stamps in it).
    res2 = evaluate_planar(_traj(stamps[keep], gt[keep]), _traj(est_stamps, gt[:-1]), max_gap_s=0.2)
    assert res2.in_gaps == 24


def test_stamps_outside_the_gt_span_are_counted() -> None:
    stamps, gt = _gt_path(n=100)
    res = evaluate_planar(_traj(stamps[10:90], gt[10:90]), _traj(stamps, gt))
    assert res.matched == 80
    assert res.outside_span == 20
    assert res.possible == 100


def test_no_overlap_raises_with_both_spans() -> None:
    stamps, gt = _gt_path(n=50)
    later = stamps + 100 * S
    with pytest.raises(InputError, match="do not overlap") as info:
        evaluate_planar(_traj(stamps, gt), _traj(later, gt))
    msg = str(info.value)
    assert f"{stamps[0] * 1e-9:.3f}" in msg and f"{later[0] * 1e-9:.3f}" in msg


def test_dead_reckoning_is_evaluated_like_the_estimate() -> None:
    stamps, gt = _gt_path(n=200)
    drift = gt.copy()
    drift[:, 0] += np.linspace(0.0, 2.0, len(gt))
    res = dead_reckoning_ate(_traj(stamps, gt), _traj(stamps, drift))
    assert res.ate_unaligned.max == pytest.approx(2.0)
    assert res.nees is None and res.landmarks is None


def _png_shape(path: Path) -> tuple[int, int]:
    assert path.stat().st_size > 0
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None
    return img.shape[0], img.shape[1]


@dataclass(frozen=True)
class _Run:
    gt: Trajectory
    est: Trajectory
    dr: Trajectory
    cov: np.ndarray
    lm: LandmarkMap
    true: LandmarkMap
    nis: np.ndarray
    count: np.ndarray


def _run_case(n_poses: int, n_lm: int) -> _Run:
    rng = np.random.default_rng(3)
    stamps = (1_000 * S + np.arange(n_poses) * (S // 40)).astype(np.int64)
    t = np.arange(n_poses) / 40.0
    gt = np.stack([30 * np.sin(0.01 * t), 20 * np.sin(0.02 * t), wrap_angle(0.01 * t)], 1)
    est = gt + rng.normal(0, 0.05, size=gt.shape)
    dr = gt.copy()
    dr[:, :2] += np.linspace(0, 5, n_poses)[:, None]
    cov = np.broadcast_to(np.diag([0.0025, 0.0025, 0.0025]), (n_poses, 3, 3)).copy()
    true_xy = rng.uniform(-40, 40, size=(n_lm, 2))
    lm_cov = np.einsum(
        "kij,klj->kil", rng.normal(0, 0.2, (n_lm, 2, 2)), rng.normal(0, 0.2, (n_lm, 2, 2))
    )
    lm_cov = lm_cov @ np.swapaxes(lm_cov, 1, 2) + 1e-3 * np.eye(2)
    ids = np.arange(n_lm, dtype=np.int64)
    return _Run(
        gt=_traj(stamps, gt),
        est=_traj(stamps, est),
        dr=_traj(stamps, dr),
        cov=cov,
        lm=LandmarkMap(ids, true_xy + rng.normal(0, 0.1, true_xy.shape), lm_cov),
        true=LandmarkMap(ids, true_xy),
        nis=np.stack([stamps[::10] * 1e-9, rng.chisquare(2, len(stamps[::10]))], 1),
        count=np.stack([stamps[::100] * 1e-9, np.linspace(0, n_lm, len(stamps[::100]))], 1),
    )


def test_plot_landmark_run_with_ground_truth(tmp_path: Path) -> None:
    c = _run_case(3000, 60)
    ev = evaluate_planar(c.gt, c.est, est_cov=c.cov, landmarks=c.lm, true_landmarks=c.true)
    out = plot_landmark_run(
        tmp_path / "report.png",
        estimate=c.est,
        landmarks=c.lm,
        evaluation=ev,
        true_landmarks=c.true,
        dead_reckoning=c.dr,
        title="synthetic",
    )
    assert out == tmp_path / "report.png"
    assert _png_shape(out) == (700, 1400)
    assert [p.name for p in tmp_path.iterdir()] == ["report.png"]  # no temporary left


def test_plot_landmark_run_without_ground_truth(tmp_path: Path) -> None:
    c = _run_case(2000, 40)
    out = plot_landmark_run(
        tmp_path / "vp.png",
        estimate=c.est,
        landmarks=c.lm,
        series={"nis": c.nis, "landmarks": c.count},
    )
    assert _png_shape(out) == (700, 1400)
    # Nothing but the estimate: still a picture.
    out2 = plot_landmark_run(tmp_path / "bare.png", estimate=c.est, landmarks=None)
    assert _png_shape(out2) == (700, 1400)


def test_plot_landmark_run_large(tmp_path: Path) -> None:
    """60 k poses and 500 landmarks: must work; the time is reported, not asserted."""
    c = _run_case(60_000, 500)
    ev = evaluate_planar(c.gt, c.est, est_cov=c.cov, landmarks=c.lm, true_landmarks=c.true)
    start = time.perf_counter()
    plot_landmark_run(
        tmp_path / "big.png",
        estimate=c.est,
        landmarks=c.lm,
        evaluation=ev,
        true_landmarks=c.true,
        dead_reckoning=c.dr,
    )
    with_gt = time.perf_counter() - start
    start = time.perf_counter()
    plot_landmark_run(
        tmp_path / "big_nogt.png",
        estimate=c.est,
        landmarks=c.lm,
        series={"nis": c.nis, "landmarks": c.count},
    )
    without = time.perf_counter() - start
    print(
        f"plot_landmark_run 60k poses/500 landmarks: {with_gt:.2f} s with gt, "
        f"{without:.2f} s without"
    )
    assert _png_shape(tmp_path / "big.png") == (700, 1400)


def test_landmark_covariances_rotate_with_the_alignment_and_give_3_sigma_ellipses() -> None:
    from matplotlib.collections import EllipseCollection
    from matplotlib.figure import Figure

    from slamcli.report import _ellipses

    stamps, gt = _gt_path(n=200)
    est = _se2_apply(-np.pi / 2, np.zeros(2), gt)  # gt = est rotated by +90°
    res = evaluate_planar(_traj(stamps, gt), _traj(stamps, est))
    assert res.angle_rad == pytest.approx(np.pi / 2)
    cov = np.array([[[4.0, 0.0], [0.0, 1.0]]])
    np.testing.assert_allclose(res.transform_cov(cov)[0], np.diag([1.0, 4.0]), atol=1e-12)

    ax = Figure().add_subplot()
    _ellipses(ax, np.zeros((1, 2)), res.transform_cov(cov))
    (coll,) = [c for c in ax.collections if isinstance(c, EllipseCollection)]
    # Full axis lengths: 2 · 3σ along the major (now y) and minor axes.
    assert coll.get_widths()[0] == pytest.approx(12.0)
    assert coll.get_heights()[0] == pytest.approx(6.0)
    assert abs(coll.get_angles()[0]) == pytest.approx(90.0)


# --- several robots in one frame ---------------------------------------------------------------


def _robots(offsets: dict[int, float]) -> tuple[dict[int, Trajectory], dict[int, Trajectory]]:
    """Ground truths of robots driving the figure-eight shifted by ``offsets`` (m, in y) and
    estimates in one frame rotated by 0.4 rad and shifted from the ground truth's, each with
    its own noise."""
    stamps, gt = _gt_path(n=300)
    angle, t = _se2_inverse(0.4, np.array([1.0, 2.0]))
    truths, estimates = {}, {}
    for k, dy in offsets.items():
        path = gt + np.array([0.0, dy, 0.0])
        est = _se2_apply(angle, t, path)
        est[:, :2] += np.random.default_rng(k).normal(0.0, 0.02, size=(len(est), 2))
        truths[k], estimates[k] = _traj(stamps, path), _traj(stamps, est)
    return truths, estimates


def test_common_frame_fits_one_transform_for_all_robots() -> None:
    truths, estimates = _robots({1: 0.0, 2: 5.0, 3: -4.0})
    del truths[3]  # a robot without ground truth is left out
    ev = evaluate_common_frame(truths, estimates)
    assert ev is not None and list(ev.robots) == [1, 2]
    assert ev.transform[2] == pytest.approx(0.4, abs=2e-3)
    np.testing.assert_allclose(ev.transform[:2], [1.0, 2.0], atol=0.02)
    for k, robot in ev.robots.items():
        assert robot.own.ate.rmse == evaluate_planar(truths[k], estimates[k]).ate.rmse
        assert robot.matched == 300 and robot.ate.rmse == pytest.approx(0.02 * np.sqrt(2), rel=0.2)
        assert robot.own.ate_unaligned.rmse > 1.0
    assert ev.matched == 600
    pooled = np.concatenate([r.errors_m for r in ev.robots.values()])
    assert ev.ate.rmse == pytest.approx(float(np.sqrt(np.mean(pooled**2))))

    d = ev.to_dict()
    json.dumps(d)
    assert d["alignment"] == "se2, one transform for all robots"
    assert d["transform"] == [float(v) for v in ev.transform]
    assert {"rmse", "mean", "max", "matched"} <= d["ate_common"].keys()
    assert d["ate_common"]["matched"] == 600
    assert set(d["per_robot"]) == {"1", "2"}
    one = d["per_robot"]["1"]
    assert one["ate"] == ev.robots[1].own.ate.to_dict()
    assert {"rmse", "mean", "max", "matched"} <= one["ate_common"].keys()


def test_one_robot_in_the_common_frame_is_the_robot_alone() -> None:
    truths, estimates = _robots({7: 0.0})
    ev = evaluate_common_frame(truths, estimates)
    assert ev is not None
    own = ev.robots[7].own
    assert ev.ate == own.ate == ev.robots[7].ate
    assert ev.transform[2] == own.angle_rad
    np.testing.assert_array_equal(ev.transform[:2], own.translation)


def test_a_robot_that_cannot_be_evaluated_is_left_out(caplog: pytest.LogCaptureFixture) -> None:
    truths, estimates = _robots({1: 0.0, 2: 3.0})
    late = estimates[2].stamps_ns + 3600 * S
    estimates[2] = Trajectory(late, estimates[2].world_from_body)
    ev = evaluate_common_frame(truths, estimates)
    assert ev is not None and list(ev.robots) == [1]
    assert "2: no accuracy figures" in caplog.text and "do not overlap" in caplog.text
    assert evaluate_common_frame({}, estimates) is None
    assert evaluate_common_frame({2: truths[2]}, {2: estimates[2]}) is None
