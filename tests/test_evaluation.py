"""ATE / RPE: known answers on synthetic trajectories, evo's association rules, statistics.

The figures against evo itself on real trajectories are in test_cli_eval.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slamcli.errors import ConfigError, InputError
from slamcli.evaluation import (
    ErrorStats,
    align,
    associate,
    associate_by_index,
    evaluate,
    rpe_pairs,
    seconds_f64,
)
from slamcli.geometry import compose, make_pose, so3_exp
from slamcli.types import Trajectory


@dataclass(frozen=True)
class Rows:
    """Stamped poses that may repeat a stamp (what a file can hold)."""

    stamps_ns: np.ndarray
    world_from_body: np.ndarray


def _wiggly(n: int = 200, seed: int = 0, t0_ns: int = 1_000_000_000_000) -> Trajectory:
    """A 3-D trajectory with turns, stamps every 33 ms."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 6.0, n)
    pos = np.stack([np.cos(s) * 2.0, np.sin(1.3 * s), 0.3 * s], axis=1)
    rot = so3_exp(np.stack([0.1 * np.sin(s), 0.2 * np.cos(s), s], axis=1))
    pos += rng.normal(scale=1e-4, size=pos.shape)
    stamps = t0_ns + np.arange(n, dtype=np.int64) * 33_000_000
    return Trajectory(stamps, make_pose(rot, pos))


def _similarity(scale: float = 1.0) -> np.ndarray:
    transform = make_pose(so3_exp([0.3, -0.5, 1.2]), [4.0, -2.0, 0.5])
    transform[:3, :3] *= scale
    return transform


def _moved(traj: Trajectory, transform: np.ndarray) -> Trajectory:
    """Apply a similarity to positions and its rotation to orientations."""
    s = np.cbrt(np.linalg.det(transform[:3, :3]))
    poses = traj.world_from_body.copy()
    poses[:, :3, 3] = poses[:, :3, 3] @ transform[:3, :3].T + transform[:3, 3]
    poses[:, :3, :3] = (transform[:3, :3] / s) @ poses[:, :3, :3]
    return Trajectory(traj.stamps_ns, poses)


def test_error_stats_known_values() -> None:
    stats = ErrorStats.of(np.array([1.0, 2.0, 3.0, 4.0]))
    assert stats.rmse == pytest.approx(np.sqrt(7.5))
    assert stats.mean == 2.5 and stats.median == 2.5
    assert stats.std == pytest.approx(np.sqrt(1.25))  # population std, ddof=0
    assert (stats.min, stats.max, stats.sse) == (1.0, 4.0, 30.0)
    assert list(stats.to_dict()) == ["rmse", "mean", "median", "std", "min", "max", "sse"]


def test_se3_alignment_recovers_a_rigid_motion() -> None:
    gt = _wiggly()
    est = _moved(gt, np.linalg.inv(_similarity()))
    res = evaluate(gt, est, align="se3")
    assert res.pairs == len(gt)
    assert res.ate.max < 1e-9
    np.testing.assert_allclose(make_pose(res.rotation, res.translation), _similarity(), atol=1e-9)
    none = evaluate(gt, est, align="none")
    assert none.ate.min > 1.0


def test_sim3_alignment_recovers_scale_and_se3_does_not() -> None:
    gt = _wiggly()
    est = _moved(gt, np.linalg.inv(_similarity(scale=2.5)))
    sim3 = evaluate(gt, est, align="sim3", rpe_delta=1)
    assert sim3.scale == pytest.approx(2.5, rel=1e-9)
    assert sim3.ate.rmse < 1e-9
    assert sim3.rpe is not None and sim3.rpe.trans.max < 1e-9 and sim3.rpe.rot.max < 1e-6
    se3 = evaluate(gt, est, align="se3", rpe_delta=1)
    assert se3.scale == 1.0
    assert se3.ate.rmse > 0.1
    assert se3.rpe is not None and se3.rpe.trans.mean > 0.01
    # Rotation errors do not depend on scale.
    np.testing.assert_allclose(se3.rpe.rot_deg, sim3.rpe.rot_deg, atol=1e-6)


def test_scale_only_alignment() -> None:
    gt = _wiggly()
    est = Trajectory(gt.stamps_ns, gt.world_from_body.copy())
    est.world_from_body[:, :3, 3] *= 0.5
    aligned, rot, trans, s = align(gt.world_from_body, est.world_from_body, "scale")
    assert s == pytest.approx(2.0, rel=1e-9)
    np.testing.assert_array_equal(rot, np.eye(3))
    np.testing.assert_array_equal(trans, np.zeros(3))
    np.testing.assert_allclose(aligned, gt.world_from_body, atol=1e-9)


def test_rpe_is_unchanged_by_a_rigid_alignment() -> None:
    gt = _wiggly(seed=1)
    noisy = gt.world_from_body.copy()
    rng = np.random.default_rng(7)
    noisy[:, :3, 3] += rng.normal(scale=0.01, size=(len(gt), 3))
    noisy = compose(
        noisy, make_pose(so3_exp(rng.normal(scale=0.01, size=(len(gt), 3))), np.zeros(3))
    )
    est = _moved(Trajectory(gt.stamps_ns, noisy), _similarity())
    a = evaluate(gt, est, align="none", rpe_delta=3)
    b = evaluate(gt, est, align="se3", rpe_delta=3)
    assert a.rpe is not None and b.rpe is not None
    np.testing.assert_allclose(a.rpe.trans_m, b.rpe.trans_m, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(a.rpe.rot_deg, b.rpe.rot_deg, rtol=1e-7, atol=1e-9)
    assert b.ate.rmse < a.ate.rmse


def test_rpe_known_rotation_drift() -> None:
    n = 30
    stamps = np.arange(n, dtype=np.int64) * 10**8
    pos = np.stack([np.arange(n) * 1.0, np.zeros(n), np.zeros(n)], axis=1)
    gt = Trajectory(stamps, make_pose(np.eye(3), pos))
    # The estimate turns 0.5 degree more about z per frame and moves 1.1 m per frame.
    yaw = np.deg2rad(0.5) * np.arange(n)
    rot = so3_exp(np.stack([np.zeros(n), np.zeros(n), yaw], axis=1))
    est = Trajectory(stamps, make_pose(rot, pos * 1.1))
    res = evaluate(gt, est, align="none", rpe_delta=2)
    assert res.rpe is not None
    assert res.rpe.pairs[:3].tolist() == [[0, 2], [2, 4], [4, 6]]
    np.testing.assert_allclose(res.rpe.rot_deg, 1.0, atol=1e-9)
    assert res.rpe.trans.min > 0.2  # 2 frames: 2.2 m turned vs 2 m straight


def test_rpe_pairs_by_path_length() -> None:
    pos = np.stack([np.arange(10) * 1.0, np.zeros(10), np.zeros(10)], axis=1)
    poses = make_pose(np.eye(3), pos)
    assert rpe_pairs(poses, 2.5, "m").tolist() == [[0, 3], [3, 6], [6, 9]]
    assert rpe_pairs(poses, 3.0, "m").tolist() == [[0, 3], [3, 6], [6, 9]]
    assert rpe_pairs(poses, 4, "frames").tolist() == [[0, 4], [4, 8]]
    assert rpe_pairs(poses, 20.0, "m").shape == (0, 2)


def _rows(stamps_s: list[float]) -> Rows:
    stamps = np.array([round(s * 1e9) for s in stamps_s], dtype=np.int64)
    poses = make_pose(np.eye(3), np.stack([np.arange(len(stamps)) * 1.0] * 3, axis=1))
    return Rows(stamps, poses)


def test_association_follows_evo() -> None:
    gt = _rows([0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
    est = _rows([0.004, 0.15, 0.201, 0.309, 0.6])
    m = associate(gt, est, max_diff_s=0.01)
    # 0.15 is 0.05 from both neighbours: too far. 0.6 is out of range.
    assert m.est_index.tolist() == [0, 2, 3]
    assert m.gt_index.tolist() == [0, 2, 3]
    assert m.possible == 5
    wide = associate(gt, est, max_diff_s=0.05)
    assert wide.est_index.tolist() == [0, 1, 2, 3] and wide.gt_index.tolist() == [0, 1, 2, 3]
    # The window is inclusive, and an exact tie goes to the earlier stamp.
    tie = associate(_rows([1.0, 1.5, 2.0]), _rows([1.25]), max_diff_s=0.25)
    assert tie.gt_index.tolist() == [0]
    assert len(associate(_rows([1.0, 1.5]), _rows([1.75]), max_diff_s=0.25)) == 1
    with pytest.raises(InputError):
        associate(_rows([1.0, 1.5]), _rows([1.75]), max_diff_s=0.2499)
    shifted = associate(gt, _rows([0.1, 0.2, 0.3]), offset_s=-0.1)
    assert shifted.gt_index.tolist() == [0, 1, 2] and shifted.est_index.tolist() == [0, 1, 2]
    np.testing.assert_array_equal(shifted.stamps_ns, [10**8, 2 * 10**8, 3 * 10**8])


def test_association_walks_the_shorter_trajectory() -> None:
    gt = _rows([1.0, 2.0])
    est = _rows([0.995, 0.998, 1.001, 1.004, 2.0])
    m = associate(gt, est)
    assert m.gt_index.tolist() == [0, 1] and m.est_index.tolist() == [2, 4]
    # The estimate is walked when it is the shorter one: several of its poses may take one GT pose.
    m2 = associate(_rows([0.0, 1.0, 2.0, 3.0, 4.0, 5.0]), _rows([0.998, 1.001, 1.004, 2.0]))
    assert m2.gt_index.tolist() == [1, 1, 1, 2] and m2.est_index.tolist() == [0, 1, 2, 3]


def test_association_with_repeated_stamps() -> None:
    gt = _rows([0.0, 0.1, 0.2, 0.2, 0.3, 0.4])
    # A stamp after a repeated stamp takes its last row, a stamp before it its first row.
    assert associate(gt, _rows([0.203]), max_diff_s=0.01).gt_index.tolist() == [3]
    assert associate(gt, _rows([0.197]), max_diff_s=0.01).gt_index.tolist() == [2]
    # Repeated stamps in the walked trajectory are each matched.
    m2 = associate(_rows([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6]), _rows([0.1, 0.2, 0.2, 0.3]))
    assert m2.gt_index.tolist() == [1, 2, 2, 3] and m2.est_index.tolist() == [0, 1, 2, 3]


def _nearest_reference(
    short: np.ndarray, long_: np.ndarray, max_diff: float
) -> list[tuple[int, int]]:
    """evo's rule written as a plain loop, for the property test."""
    out = []
    for i, s in enumerate(short):
        if s < long_[0] - max_diff or s > long_[-1] + max_diff:
            continue
        j = min(int(np.searchsorted(long_, s, side="right")), len(long_) - 1)
        ub = long_[j] - s
        lb = s - long_[j - 1] if j > 0 else np.inf
        if ub <= max_diff and ub < lb:
            out.append((i, j))
        elif lb <= max_diff and lb <= ub:
            out.append((i, j - 1))
    return out


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.integers(0, 400), min_size=1, max_size=25),
    st.lists(st.integers(0, 400), min_size=1, max_size=25),
    st.integers(0, 30),
)
def test_association_matches_the_plain_loop(a: list[int], b: list[int], window: int) -> None:
    gt, est = _rows(sorted(x / 100 for x in a)), _rows(sorted(x / 100 for x in b))
    try:
        m = associate(gt, est, max_diff_s=window / 1000)
        pairs = list(zip(m.gt_index.tolist(), m.est_index.tolist(), strict=True))
    except InputError:
        pairs = []
    gs, es = seconds_f64(gt.stamps_ns), seconds_f64(est.stamps_ns)
    if len(es) > len(gs):
        expected = _nearest_reference(gs, es, window / 1000)
    else:
        expected = [(j, i) for i, j in _nearest_reference(es, gs, window / 1000)]
    assert pairs == expected


def test_seconds_are_the_nearest_double() -> None:
    rng = np.random.default_rng(11)
    ns = np.concatenate(
        [
            rng.integers(0, 2**53, 5000),
            rng.integers(10**18, 2 * 10**18, 5000),
            [1_311_868_226_310_950_000, 1_403_715_524_907_143_168, -(2**60) - 7],
        ]
    ).astype(np.int64)
    expected = np.array([int(n) / 10**9 for n in ns])
    np.testing.assert_array_equal(seconds_f64(ns), expected)
    # The tie evo breaks by rounding: 226.31095 is exactly halfway between .3093 and .3126.
    t = seconds_f64(
        np.array([1_311_868_226_309_300_000, 1_311_868_226_310_950_000, 1_311_868_226_312_600_000])
    )
    assert (t[1] - t[0]) != (t[2] - t[1])


def test_too_few_matches_say_what_to_do() -> None:
    gt = _rows([0.0, 0.1, 0.2, 0.3])
    with pytest.raises(InputError, match=r"only 0 of 2 poses matched.*at least 3") as info:
        evaluate(gt, _rows([5.0, 6.0]))
    assert "--t-max-diff" in (info.value.hint or "") and "--t-offset" in (info.value.hint or "")
    with pytest.raises(InputError, match=r"only 2 of 2 .*at least 3"):
        evaluate(gt, _rows([0.1, 0.2]))
    assert evaluate(gt, _rows([0.1, 0.2]), align="none").pairs == 2
    with pytest.raises(InputError, match="only 0 of 1 poses matched"):
        associate(gt, _rows([5.0]))


def test_index_pairing_needs_equal_lengths() -> None:
    gt = _wiggly(n=10)
    assert len(associate_by_index(gt, gt)) == 10
    with pytest.raises(InputError, match="as many") as info:
        evaluate(gt, gt.subset(np.arange(9)), by_index=True)
    assert "--gt-times" in (info.value.hint or "")


def test_bad_options() -> None:
    gt = _wiggly(n=10)
    with pytest.raises(ConfigError, match="alignment"):
        evaluate(gt, gt, align="umeyama")
    with pytest.raises(ConfigError, match="whole number"):
        evaluate(gt, gt, rpe_delta=1.5)
    with pytest.raises(ConfigError, match="> 0"):
        evaluate(gt, gt, rpe_delta=0.0, delta_unit="m")
    with pytest.raises(ConfigError, match="unit"):
        evaluate(gt, gt, rpe_delta=1, delta_unit="s")
    with pytest.raises(ConfigError, match="window"):
        evaluate(gt, gt, max_diff_s=-1.0)
    with pytest.raises(InputError, match="no pose pairs"):
        evaluate(gt, gt, rpe_delta=10)


def test_to_dict_layout() -> None:
    gt = _wiggly(n=20)
    plain = evaluate(gt, gt).to_dict()
    assert list(plain) == ["alignment", "pairs", "ate", "scale"]
    full = evaluate(gt, gt, align="sim3", rpe_delta=1).to_dict()
    assert list(full) == ["alignment", "pairs", "ate", "rpe", "scale"]
    assert full["alignment"] == "sim3" and full["pairs"] == 20
    assert list(full["rpe"]) == ["trans", "rot_deg"]
