"""Planar evaluation: ``--align se2``, the SE(2) RPE of Kümmerle et al. (2009) over pairs in
seconds, and ``.relations`` files, against answers worked out by hand on a circular path.

The ground truth drives two laps of a circle of radius ``R`` at 10 Hz, heading along the
tangent. Over ``n`` steps (angle ``β = n Δ``) its motion in the body frame of the first pose is
``(R sin β, R (1 - cos β))`` with yaw ``β``. Two estimates are built from it:

- ``radial``: every position pushed off the circle by ``±D`` (alternating), then the whole path
  moved by a planar rigid motion. The offsets sum to zero and are radial, so the SE(2) fit
  undoes the motion exactly and every position error is ``D``; over an even number of steps the
  relative translation error is ``D |u_j - u_i| = 2 D sin(β / 2)``, the rotation error 0.
- ``drift``: the heading of pose ``k`` turned by ``k ε`` about the body's own origin (a constant
  per-step heading error), then moved rigidly. Positions are exact (ATE 0); over ``n`` steps the
  rotation error is ``n ε`` and the translation error ``2 sin(i ε / 2) · 2 R sin(β / 2)`` for a
  pair starting at pose ``i``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import FormatError, InputError
from slamcli.evaluation import evaluate, planar_rpe, relations_error
from slamcli.formats.relations import (
    Relations,
    read_relations,
    rotation_from_rpy,
    rpy_from_rotation,
    write_relations,
)
from slamcli.formats.trajectory import write_kitti, write_tum
from slamcli.geometry import compose, inverse, make_pose, planar_to_se3, so3_exp
from slamcli.types import Trajectory

runner = CliRunner()

R = 5.0
CENTRE = (2.0, -1.0)
HZ = 10
STEPS = 1200  # two laps of 60 s
DELTA = 2.0 * math.pi / 600.0  # circle angle per step
D = 0.05  # radial position error, m
EPS = 0.001  # heading error added per step, rad
T0_S = 1_700_000_000
MOTION = (1.5, -0.7, 0.9)  # the rigid motion applied to the estimates: x, y, yaw


def _stamps() -> np.ndarray:
    return T0_S * 1_000_000_000 + np.arange(STEPS, dtype=np.int64) * 100_000_000


def _circle(radial: np.ndarray | None = None, drift: float = 0.0) -> np.ndarray:
    """(STEPS, 3) x, y, yaw on the circle, radius R + radial[k], heading + k * drift."""
    k = np.arange(STEPS)
    alpha = 0.3 + k * DELTA
    radius = R + (radial if radial is not None else 0.0)
    x = CENTRE[0] + radius * np.cos(alpha)
    y = CENTRE[1] + radius * np.sin(alpha)
    return np.stack([x, y, alpha + math.pi / 2 + k * drift], axis=1)


def _moved(xy_yaw: np.ndarray) -> Trajectory:
    motion = planar_to_se3(MOTION)[0]
    return Trajectory(_stamps(), compose(motion, planar_to_se3(xy_yaw)))


def _gt() -> Trajectory:
    return Trajectory(_stamps(), planar_to_se3(_circle()))


def _radial_est() -> Trajectory:
    signs = np.where(np.arange(STEPS) % 2 == 0, 1.0, -1.0)
    return _moved(_circle(radial=D * signs))


def _drift_est() -> Trajectory:
    return _moved(_circle(drift=EPS))


def _chord(n: int) -> float:
    """|t*| of a motion over n steps: the chord of the circle."""
    return 2.0 * R * math.sin(n * DELTA / 2.0)


def _relations_text(starts: list[int], n: int, shift_ns: int = 0) -> str:
    """Relations between poses k and k + n written by hand from the circle's geometry."""
    beta = n * DELTA
    lines = ["# t1 t2 x y z roll pitch yaw (from the circle)"]
    for k in starts:
        t1 = T0_S * 10**9 + k * 10**8 + shift_ns
        t2 = t1 + n * 10**8
        lines.append(
            f"{t1 // 10**9}.{t1 % 10**9:09d} {t2 // 10**9}.{t2 % 10**9:09d} "
            f"{R * math.sin(beta):.12f} {R * (1 - math.cos(beta)):.12f} 0 0 0 {beta:.12f}"
        )
    return "\n".join(lines) + "\n"


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


# ---------------------------------------------------------------- alignment and ATE


def test_se2_alignment_undoes_the_motion_and_ate_is_the_radial_error() -> None:
    result = evaluate(_gt(), _radial_est(), align="se2")
    # The fit maps the estimate onto the ground truth: it is the inverse of MOTION.
    fitted = np.eye(4)
    fitted[:3, :3], fitted[:3, 3] = result.rotation, result.translation
    np.testing.assert_allclose(compose(fitted, planar_to_se3(MOTION)[0]), np.eye(4), atol=1e-12)
    assert math.isclose(math.atan2(result.rotation[1, 0], result.rotation[0, 0]), -MOTION[2])
    assert result.scale == 1.0 and result.pairs == STEPS
    np.testing.assert_allclose(result.ate_m, D, rtol=0, atol=1e-12)
    assert math.isclose(result.ate.rmse, D, abs_tol=1e-12)
    assert math.isclose(result.ate.mean, D, abs_tol=1e-12)


def test_se2_ate_is_measured_in_the_plane() -> None:
    est = _radial_est()
    lifted = est.world_from_body.copy()
    lifted[:, 2, 3] = 3.0  # a constant height: not a planar error
    result = evaluate(_gt(), Trajectory(est.stamps_ns, lifted), align="se2")
    assert math.isclose(result.ate.max, D, abs_tol=1e-12)
    # In 3-D the same poses are 3 m off everywhere.
    assert evaluate(_gt(), Trajectory(est.stamps_ns, lifted), align="none").ate.min > 3.0


def test_se2_warns_when_the_poses_are_not_planar(caplog: pytest.LogCaptureFixture) -> None:
    gt = _gt()
    tilted = gt.world_from_body.copy()
    tilted[:, :3, :3] = tilted[:, :3, :3] @ so3_exp([math.pi / 2, 0.0, 0.0])  # a camera frame
    with caplog.at_level("WARNING", logger="slamcli.evaluation"):
        evaluate(gt, Trajectory(gt.stamps_ns, tilted), align="se2")
    assert "estimate's body z axis tilts up to 90.0 deg" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING", logger="slamcli.evaluation"):
        evaluate(gt, _radial_est(), align="se2")
    assert caplog.text == ""


# ---------------------------------------------------------------- RPE in SE(2), in seconds


@pytest.mark.parametrize(("delta_s", "n", "count"), [(1.0, 10, 119), (10.0, 100, 11)])
def test_planar_rpe_of_the_radial_error(delta_s: float, n: int, count: int) -> None:
    rpe = planar_rpe(_gt(), _radial_est(), delta_s, 0.01)
    assert rpe.planar and rpe.delta_unit == "seconds" and rpe.count == count
    assert np.all(np.diff(rpe.pairs, axis=1) == n)
    expected = 2.0 * D * math.sin(n * DELTA / 2.0)
    np.testing.assert_allclose(rpe.trans_m, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rpe.rot_deg, 0.0, atol=1e-9)
    assert math.isclose(rpe.trans.mean, expected, abs_tol=1e-12)
    assert rpe.to_dict()["pairs"] == count


@pytest.mark.parametrize(("delta_s", "n", "count"), [(1.0, 10, 119), (10.0, 100, 11)])
def test_planar_rpe_of_the_heading_drift(delta_s: float, n: int, count: int) -> None:
    rpe = planar_rpe(_gt(), _drift_est(), delta_s, 0.01)
    assert rpe.count == count
    starts = np.arange(count) * n
    expected_trans = 2.0 * np.sin(starts * EPS / 2.0) * _chord(n)
    np.testing.assert_allclose(rpe.trans_m, expected_trans, rtol=0, atol=1e-11)
    np.testing.assert_allclose(rpe.rot_deg, math.degrees(n * EPS), rtol=1e-9)
    assert math.isclose(rpe.trans.mean, float(np.mean(expected_trans)), rel_tol=1e-9)
    assert math.isclose(rpe.rot.mean, math.degrees(n * EPS), rel_tol=1e-9)


def test_evaluate_se2_gives_the_planar_rpe_and_ate_of_the_drift() -> None:
    result = evaluate(_gt(), _drift_est(), align="se2", rpe_delta=10, delta_unit="seconds")
    assert result.ate.max < 1e-12
    alone = planar_rpe(_gt(), _drift_est(), 10.0)
    assert result.rpe is not None and result.rpe.planar
    np.testing.assert_array_equal(result.rpe.pairs, alone.pairs)
    np.testing.assert_allclose(result.rpe.trans_m, alone.trans_m, atol=1e-12)
    np.testing.assert_allclose(result.rpe.rot_deg, alone.rot_deg, atol=1e-9)
    data = result.to_dict()
    assert list(data["rpe"]) == ["pairs", "trans", "rot_deg"] and data["rpe"]["pairs"] == 11


def test_planar_rpe_ignores_height_and_wraps_the_yaw_difference(tmp_path: Path) -> None:
    est = _drift_est()
    wobbly = est.world_from_body.copy()
    wobbly[:, 2, 3] = 0.2 * np.sin(np.arange(STEPS))  # height noise: not a planar error
    wobbly_est = Trajectory(est.stamps_ns, wobbly)
    planar = evaluate(_gt(), wobbly_est, align="se2", rpe_delta=1, delta_unit="seconds").rpe
    assert planar is not None
    np.testing.assert_allclose(planar.trans_m, planar_rpe(_gt(), est, 1.0).trans_m, atol=1e-12)
    spatial = evaluate(_gt(), wobbly_est, align="se3", rpe_delta=1, delta_unit="seconds").rpe
    assert spatial is not None and not spatial.planar and spatial.trans.min > 0.01
    # Over half a lap (yaw π, written as π; the estimate turned π + 0.3, which wraps to
    # -π + 0.3) the rotation error is 0.3 rad, not 2π - 0.3.
    rel = read_relations(_write(tmp_path / "half.relations", _relations_text([0, 600], 300)))
    assert math.isclose(rel.first_from_second[0, 1, 0], 0.0, abs_tol=1e-11)
    result = relations_error(est, rel)
    np.testing.assert_allclose(result.rot_deg, math.degrees(300 * EPS), rtol=1e-8)
    rpe = planar_rpe(_gt(), est, 30.0)
    np.testing.assert_allclose(rpe.rot_deg, math.degrees(300 * EPS), rtol=1e-8)


def test_pairs_in_seconds_follow_the_stamps_not_the_rows() -> None:
    gt, est = _gt(), _radial_est()
    keep = np.ones(STEPS, dtype=bool)
    keep[::3] = False  # irregular rows: 0.1 s and 0.2 s steps
    thinned = Trajectory(est.stamps_ns[keep], est.world_from_body[keep])
    rpe = planar_rpe(gt, thinned, 1.0)
    stamps = thinned.stamps_ns
    spans = stamps[rpe.pairs[:, 1]] - stamps[rpe.pairs[:, 0]]
    # Each pair ends at the first pose at least 1 s on: 1.0 s, or 1.1 s where 1.0 s was dropped.
    assert set(spans.tolist()) <= {1_000_000_000, 1_100_000_000}
    assert np.all(rpe.pairs[1:, 0] == rpe.pairs[:-1, 1])


def test_planar_rpe_uses_the_association_window() -> None:
    est = _radial_est()
    late = Trajectory(est.stamps_ns + 3_000_000, est.world_from_body)  # 3 ms late
    rpe = planar_rpe(_gt(), late, 10.0, 0.005)
    assert rpe.count == 11
    with pytest.raises(InputError, match="0 of 1200 poses matched"):
        planar_rpe(_gt(), late, 10.0, 0.001)
    with pytest.raises(InputError, match="no pose pairs"):
        planar_rpe(_gt(), est, 200.0)


# ---------------------------------------------------------------- relations


@pytest.fixture
def relations_file(tmp_path: Path) -> Path:
    return _write(tmp_path / "circle.relations", _relations_text(list(range(0, 1100, 50)), 100))


def test_relations_from_the_ground_truth_give_zero_error_on_it(relations_file: Path) -> None:
    rel = read_relations(relations_file)
    assert len(rel) == 22 and rel.lines[0] == 2  # line 1 is a comment
    result = relations_error(_gt(), rel, 0.01)
    assert result.pairs == 22 and result.missing.size == 0
    assert result.trans.max < 1e-9 and result.rot.max < 1e-8
    np.testing.assert_array_equal(result.est_pairs[:, 1] - result.est_pairs[:, 0], 100)
    # In SE(3) the same figures: the relations and the poses are planar.
    full = relations_error(_gt(), rel, 0.01, planar=False)
    assert full.trans.max < 1e-9 and full.rot.max < 1e-8


def test_relations_give_the_known_error_of_each_estimate(relations_file: Path) -> None:
    rel = read_relations(relations_file)
    radial = relations_error(_radial_est(), rel)
    np.testing.assert_allclose(radial.trans_m, 2 * D * math.sin(100 * DELTA / 2), atol=1e-9)
    assert radial.rot.max < 1e-7
    drift = relations_error(_drift_est(), rel)
    starts = np.arange(0, 1100, 50)
    expected = 2.0 * np.sin(starts * EPS / 2.0) * _chord(100)
    np.testing.assert_allclose(drift.trans_m, expected, atol=1e-9)
    np.testing.assert_allclose(drift.rot_deg, math.degrees(100 * EPS), rtol=1e-8)
    assert math.isclose(drift.rot.mean, math.degrees(0.1), rel_tol=1e-8)
    # The same through evaluate(), with se2 (planar) and with se3 (SE(3) errors, equal here).
    for align in ("se2", "se3"):
        ev = evaluate(_gt(), _drift_est(), align=align, relations=rel).relations
        assert ev is not None and ev.planar == (align == "se2")
        np.testing.assert_allclose(ev.trans_m, expected, atol=1e-9)


def test_relations_take_the_sim3_scale(relations_file: Path) -> None:
    gt = _gt()
    half = gt.world_from_body.copy()
    half[:, :3, 3] *= 0.5
    result = evaluate(
        gt, Trajectory(gt.stamps_ns, half), align="sim3", relations=read_relations(relations_file)
    )
    assert math.isclose(result.scale, 2.0, rel_tol=1e-12)
    assert result.relations is not None and result.relations.trans.max < 1e-9
    # Without the scale every relation is half as long as the truth.
    plain = relations_error(Trajectory(gt.stamps_ns, half), read_relations(relations_file))
    np.testing.assert_allclose(plain.trans_m, _chord(100) / 2, rtol=1e-9)


def test_relations_without_both_poses_are_counted_missing(tmp_path: Path) -> None:
    est = _radial_est()
    keep = np.ones(STEPS, dtype=bool)
    keep[300:320] = False  # 2 s without an estimate
    gapped = Trajectory(est.stamps_ns[keep], est.world_from_body[keep])
    starts = [0, 200, 305, 400, 1150]  # 200 -> 300: t2 in the gap; 305: t1 in it; 1150 -> 1250
    text = _relations_text(starts, 100) + _relations_text([600], 100, shift_ns=5_000_000)
    text += _relations_text([700], 100, shift_ns=20_000_000)  # 20 ms off both poses
    rel = read_relations(_write(tmp_path / "gaps.relations", text))
    result = relations_error(gapped, rel, 0.01)
    assert result.relations == 7
    assert result.used.tolist() == [0, 3, 5]  # 0, 400 and 600 (5 ms off: within 10 ms)
    assert result.missing.tolist() == [1, 2, 4, 6]
    assert result.to_dict()["missing"] == 4 and result.to_dict()["pairs"] == 3
    np.testing.assert_allclose(result.trans_m, 2 * D * math.sin(100 * DELTA / 2), atol=1e-9)
    with pytest.raises(InputError, match="none of the 1 relations"):
        relations_error(
            gapped, Relations(rel.t1_ns[2:3], rel.t2_ns[2:3], rel.first_from_second[2:3])
        )


@pytest.mark.parametrize(
    ("text", "line", "words"),
    [
        ("# ok\n1 2 0 0 0 0 0 0\n1 2 0 0 0 0 0\n", 3, "expected 8 columns"),
        ("1 2 0 0 0 0 0 0\n\n1.5 2 0 0 zero 0 0 0\n", 3, "column 5: value 'zero' is not a number"),
        ("1 x 0 0 0 0 0 0\n", 1, "timestamp 'x' is not a number"),
        ("1 2 0 0 0 0 0 nan\n", 1, "column 8: value 'nan' is not finite"),
    ],
)
def test_a_malformed_line_is_a_format_error_naming_file_and_line(
    tmp_path: Path, text: str, line: int, words: str
) -> None:
    path = _write(tmp_path / "bad.relations", text)
    with pytest.raises(FormatError) as info:
        read_relations(path)
    assert info.value.line == line
    assert f"{path}:{line}: " in str(info.value) and words in str(info.value)


def test_an_empty_relations_file_is_a_format_error(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="no relations"):
        read_relations(_write(tmp_path / "empty.relations", "# t1 t2 x y z roll pitch yaw\n"))


def test_relations_round_trip_in_3d_and_roll_pitch_yaw_order(tmp_path: Path) -> None:
    a = 0.4
    # Rz(yaw) Ry(pitch) Rx(roll): each angle alone turns about its own axis.
    np.testing.assert_allclose(
        rotation_from_rpy(np.array([a]), np.zeros(1), np.zeros(1))[0],
        np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]]),
    )
    np.testing.assert_allclose(
        rotation_from_rpy(np.zeros(1), np.array([a]), np.zeros(1))[0],
        np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]]),
    )
    rng = np.random.default_rng(7)
    rpy = rng.uniform([-3, -1.5, -3], [3, 1.5, 3], size=(50, 3))
    np.testing.assert_allclose(rpy_from_rotation(rotation_from_rpy(*rpy.T)), rpy, atol=1e-12)
    # A 3-D path: relations written from it give zero SE(3) error on it.
    stamps = np.arange(40, dtype=np.int64) * 250_000_000 + 10**9
    poses = make_pose(so3_exp(rng.normal(scale=0.8, size=(40, 3))), rng.normal(size=(40, 3)))
    traj = Trajectory(stamps, poses)
    i, j = np.arange(0, 30, 3), np.arange(0, 30, 3) + 7
    motion = compose(inverse(poses[i]), poses[j])
    path = write_relations(tmp_path / "3d.relations", Relations(stamps[i], stamps[j], motion))
    back = read_relations(path)
    np.testing.assert_array_equal(back.t1_ns, stamps[i])
    np.testing.assert_allclose(back.first_from_second, motion, atol=1e-8)
    result = relations_error(traj, back, planar=False)
    assert result.pairs == 10 and result.trans.max < 1e-8 and result.rot.max < 1e-6


# ---------------------------------------------------------------- the command


def _files(tmp_path: Path) -> tuple[Path, Path, Path]:
    gt = write_tum(tmp_path / "gt.tum", _gt())
    est = write_tum(tmp_path / "est.tum", _radial_est())
    rel = _write(tmp_path / "c.relations", _relations_text([0, 100, 3000], 100))
    return gt, est, rel


def test_eval_se2_json_has_the_known_figures(tmp_path: Path) -> None:
    gt, est, rel = _files(tmp_path)
    args = ["eval", str(gt), str(est), "--align", "se2", "--rpe-delta", "1"]
    res = runner.invoke(app, [*args, "--delta-unit", "seconds", "--relations", str(rel), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert list(data) == ["alignment", "pairs", "ate", "rpe", "relations", "scale"]
    assert data["alignment"] == "se2" and data["pairs"] == STEPS
    assert math.isclose(data["ate"]["rmse"], D, abs_tol=1e-8)
    assert data["rpe"]["pairs"] == 119
    assert math.isclose(data["rpe"]["trans"]["mean"], 2 * D * math.sin(5 * DELTA), abs_tol=1e-8)
    assert data["rpe"]["rot_deg"]["max"] < 1e-6
    relations = data["relations"]
    assert relations["file"] == str(rel) and relations["planar"] is True
    assert (relations["relations"], relations["pairs"], relations["missing"]) == (3, 2, 1)
    assert math.isclose(relations["trans"]["mean"], 2 * D * math.sin(50 * DELTA), abs_tol=1e-8)


def test_eval_se2_table_reports_pair_counts_and_missing_relations(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from slamcli.cli import render

    # The console's width is read once per process; the table needs room for every column.
    monkeypatch.setattr(render.out, "width", 250)
    gt, est, rel = _files(tmp_path)
    args = [
        "eval",
        str(gt),
        str(est),
        "--align",
        "se2",
        "--rpe-delta",
        "10",
        "--delta-unit",
        "seconds",
    ]
    res = runner.invoke(app, [*args, "--relations", str(rel)], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    assert "11 (10 s apart)" in res.stdout
    assert "2 of 3 in" in res.stdout and "1 missing" in res.stdout
    assert "REL trans (m)" in res.stdout and "RPE rot (deg)" in res.stdout
    # Two estimates: one row each, with the relations matched and their mean errors.
    many = runner.invoke(app, [*args, str(est), "--relations", str(rel)], env={"COLUMNS": "250"})
    assert many.exit_code == 0, many.output
    assert "REL trans mean" in many.stdout and many.stdout.count("2 of 3") == 2


def test_eval_relations_errors_exit_1_naming_the_line(tmp_path: Path) -> None:
    gt, est, _ = _files(tmp_path)
    bad = _write(tmp_path / "bad.relations", "1 2 0 0 0 0 0 0\n1 2 3\n")
    res = runner.invoke(app, ["eval", str(gt), str(est), "--relations", str(bad)])
    assert res.exit_code == 1
    assert f"{bad}:2: expected 8 columns" in res.stderr and res.stdout == ""


def test_eval_seconds_and_relations_need_stamps(tmp_path: Path) -> None:
    gt = write_kitti(tmp_path / "gt.txt", _gt())
    est = write_kitti(tmp_path / "est.txt", _radial_est())
    _, _, rel = _files(tmp_path)
    base = ["eval", str(gt), str(est), "--format", "kitti"]
    res = runner.invoke(app, [*base, "--rpe-delta", "1", "--delta-unit", "seconds"])
    assert res.exit_code == 1 and "--delta-unit seconds needs timestamps" in res.stderr
    res = runner.invoke(app, [*base, "--relations", str(rel)])
    assert res.exit_code == 1 and "--relations needs timestamps" in res.stderr
    # Pairs by frame need no stamps.
    assert runner.invoke(app, [*base, "--rpe-delta", "10", "--align", "se2"]).exit_code == 0
