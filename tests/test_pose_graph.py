"""Pose-graph optimisation on GTSAM: synthetic loops with known answers in SE(3) and SE(2),
Sim(3) scale drift, robust kernels and graduated non-convexity against wrong loop closures, the
g2o writer's round trip, and sphere2500."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path

from slamcli.formats.g2o import PoseGraph, read_g2o, write_g2o, write_g2o_se3
from slamcli.geometry.planar import between_planar, compose_planar
from slamcli.geometry.se3 import compose, inverse, make_pose, se3_exp, so3_exp
from slamcli.graphs.pose_graph import (
    Edge,
    edge_chi2,
    from_g2o,
    graph_error,
    optimize_gnc,
    optimize_se2,
    optimize_se3,
    optimize_sim3,
    save_g2o,
    se3_edges_from_poses,
)

N = 40
ROT_SIGMA, TRANS_SIGMA = 0.01, 0.05
# GTSAM order: rotation first, then translation.
INFO = np.diag([ROT_SIGMA**-2] * 3 + [TRANS_SIGMA**-2] * 3)


def circle(n: int = N, radius: float = 10.0) -> np.ndarray:
    """(n, 4, 4) poses on a horizontal circle with a gentle vertical wave, facing along it."""
    angle = 2 * np.pi * np.arange(n) / n
    rot = so3_exp(np.stack([0.05 * np.sin(3 * angle), np.zeros(n), angle], axis=-1))
    xyz = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.sin(2 * angle)], axis=-1)
    return make_pose(rot, xyz)


def noisy(rel: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``rel`` perturbed on the right by a twist with the INFO sigmas."""
    twist = np.concatenate(
        [
            rng.normal(0, TRANS_SIGMA, (*rel.shape[:-2], 3)),
            rng.normal(0, ROT_SIGMA, (*rel.shape[:-2], 3)),
        ],
        axis=-1,
    )
    return compose(rel, se3_exp(twist))


def chain(first: np.ndarray, edges: list[Edge]) -> np.ndarray:
    """Integrate consecutive odometry edges from ``first``."""
    poses = [first]
    for e in edges:
        poses.append(poses[-1] @ e.a_from_b)
    return np.stack(poses)


def loop_problem(seed: int = 0) -> tuple[np.ndarray, np.ndarray, list[Edge]]:
    """(truth, odometry-chain initial poses, edges): noisy odometry plus two loop closures."""
    rng = np.random.default_rng(seed)
    truth = circle()
    odo = se3_edges_from_poses(truth, [(i, i + 1) for i in range(N - 1)], information=INFO)
    for e in odo:
        e.a_from_b = noisy(e.a_from_b, rng)
    loops = se3_edges_from_poses(truth, [(N - 1, 0), (N // 2, 0)], information=INFO, robust=True)
    for e in loops:
        e.a_from_b = noisy(e.a_from_b, rng)
        e.kind = "loop"
    return truth, chain(truth[0], odo), odo + loops


def position_error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1).max())


def test_loop_closure_reduces_error_and_drift() -> None:
    truth, initial, edges = loop_problem()
    result = optimize_se3(initial, edges)
    assert result.error_after < 0.01 * result.error_before
    assert result.error_before == pytest.approx(graph_error(initial, edges), rel=1e-12)
    assert result.error_after == pytest.approx(graph_error(result.poses, edges), rel=1e-12)
    drift, corrected = position_error(initial, truth), position_error(result.poses, truth)
    assert drift > 0.5
    assert corrected < 0.25 * drift
    assert result.edge_chi2.shape == (len(edges),)
    # Without a kernel, the error is half the sum of the edges' chi2.
    assert result.error_after == pytest.approx(0.5 * result.edge_chi2.sum(), rel=1e-9)
    assert result.outliers.size == 0
    assert 1 <= result.iterations < 100
    assert result.scales is None


def test_matches_gtsams_own_levenberg_marquardt() -> None:
    gtsam = pytest.importorskip("gtsam")
    _, initial, edges = loop_problem(seed=1)
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for i, pose in enumerate(initial):
        values.insert(i, gtsam.Pose3(pose))
    for e in edges:
        noise = gtsam.noiseModel.Gaussian.Information(e.information)
        graph.add(gtsam.BetweenFactorPose3(e.a, e.b, gtsam.Pose3(e.a_from_b), noise))
    graph.add(gtsam.NonlinearEqualityPose3(0, gtsam.Pose3(initial[0])))
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams())
    solution = optimizer.optimize()
    result = optimize_se3(initial, edges)
    assert result.error_after == pytest.approx(optimizer.error(), rel=1e-12)
    assert result.iterations == optimizer.iterations()
    theirs = np.stack([solution.atPose3(i).matrix() for i in range(N)])
    np.testing.assert_allclose(result.poses, theirs, atol=1e-12)


def test_deterministic_byte_for_byte() -> None:
    _, initial, edges = loop_problem(seed=2)
    first = optimize_se3(initial, edges, kernel="cauchy")
    second = optimize_se3(initial, edges, kernel="cauchy")
    assert first.poses.tobytes() == second.poses.tobytes()
    assert first.edge_chi2.tobytes() == second.edge_chi2.tobytes()
    assert first.error_after == second.error_after


def test_fixed_nodes_stay_put() -> None:
    _, initial, edges = loop_problem(seed=3)
    result = optimize_se3(initial, edges, fixed=(5, 30))
    for i in (5, 30):
        assert result.poses[i].tobytes() == initial[i].tobytes()
    assert position_error(result.poses[:1], initial[:1]) > 1e-3  # node 0 is free this time


def wrong_loops_problem() -> tuple[np.ndarray, list[Edge], list[int]]:
    _, initial, edges = loop_problem(seed=4)
    rng = np.random.default_rng(44)
    wrong = []
    for a, b in [(3, 25), (10, 33), (15, 38)]:
        bogus = make_pose(so3_exp(rng.normal(0, 1.0, 3)), rng.uniform(-5, 5, 3))
        wrong.append(len(edges))
        edges.append(Edge(a, b, bogus, information=INFO, robust=True, kind="loop"))
    return initial, edges, wrong


@pytest.mark.parametrize("kernel", ["cauchy", "dcs"])
def test_robust_kernel_rejects_wrong_loops(kernel: str) -> None:
    initial, edges, wrong = wrong_loops_problem()
    clean = optimize_se3(initial, [e for k, e in enumerate(edges) if k not in wrong])
    robust = optimize_se3(initial, edges, kernel=kernel)
    plain = optimize_se3(initial, edges, kernel="none")
    assert robust.outliers.tolist() == wrong
    assert position_error(robust.poses, clean.poses) < 0.05
    assert position_error(plain.poses, clean.poses) > 1.0
    # Down-weighted, not fitted: the wrong loops keep a residual far beyond the bound.
    assert robust.edge_chi2[wrong].min() > 1e3


def test_kernel_applies_only_to_robust_edges() -> None:
    initial, edges, wrong = wrong_loops_problem()
    for k in wrong:
        edges[k].robust = False
    result = optimize_se3(initial, edges, kernel="cauchy")
    # Only robust edges are ever reported: here the two correct loops, which the wrong edges
    # (now trusted) have dragged away from their measurements.
    assert result.outliers.tolist() == [N - 1, N]
    clean = optimize_se3(initial, [e for k, e in enumerate(edges) if k not in wrong])
    assert position_error(result.poses, clean.poses) > 1.0


# --- SE(2) --------------------------------------------------------------------------------

INFO_2D = np.diag([TRANS_SIGMA**-2] * 2 + [ROT_SIGMA**-2])


def planar_loop_problem(seed: int = 0) -> tuple[np.ndarray, np.ndarray, list[Edge]]:
    """(truth (N, 3), odometry-chain initial poses, edges) on a planar circle: noisy odometry
    plus two loop closures."""
    rng = np.random.default_rng(seed)
    angle = 2 * np.pi * np.arange(N) / N
    truth = np.stack([10 * np.cos(angle), 10 * np.sin(angle), angle + np.pi / 2], axis=1)
    sigmas = [TRANS_SIGMA, TRANS_SIGMA, ROT_SIGMA]
    edges = []
    for a, b in [*((i, i + 1) for i in range(N - 1)), (N - 1, 0), (N // 2, 0)]:
        rel = between_planar(truth[a], truth[b]) + rng.normal(0.0, sigmas)
        loop = b != a + 1
        kind = "loop" if loop else "odometry"
        edges.append(Edge(a, b, rel, information=INFO_2D, robust=loop, kind=kind))
    initial = [truth[0]]
    for e in edges[: N - 1]:
        initial.append(compose_planar(initial[-1], e.a_from_b))
    return truth, np.stack(initial), edges


def test_se2_loop_closure_reduces_error_and_drift() -> None:
    truth, initial, edges = planar_loop_problem()
    result = optimize_se2(initial, edges)
    assert result.poses.shape == (N, 3) and result.scales is None
    assert result.error_after < 0.01 * result.error_before
    assert result.error_before == pytest.approx(graph_error(initial, edges), rel=1e-12)
    assert result.error_after == pytest.approx(0.5 * result.edge_chi2.sum(), rel=1e-9)
    np.testing.assert_allclose(edge_chi2(result.poses, edges), result.edge_chi2, rtol=1e-6)
    drift = np.linalg.norm(initial[:, :2] - truth[:, :2], axis=1).max()
    corrected = np.linalg.norm(result.poses[:, :2] - truth[:, :2], axis=1).max()
    assert drift > 0.5 and corrected < 0.25 * drift
    assert result.poses[0].tobytes() == initial[0].tobytes()


def test_se2_matches_gtsams_own_levenberg_marquardt() -> None:
    gtsam = pytest.importorskip("gtsam")
    _, initial, edges = planar_loop_problem(seed=1)
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for i, (x, y, theta) in enumerate(initial.tolist()):
        values.insert(i, gtsam.Pose2(x, y, theta))
    for e in edges:
        noise = gtsam.noiseModel.Gaussian.Information(e.information)
        graph.add(gtsam.BetweenFactorPose2(e.a, e.b, gtsam.Pose2(*e.a_from_b), noise))
    graph.add(gtsam.NonlinearEqualityPose2(0, values.atPose2(0)))
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams())
    solution = optimizer.optimize()
    result = optimize_se2(initial, edges)
    assert result.error_after == optimizer.error()
    assert result.iterations == optimizer.iterations()
    theirs = [[p.x(), p.y(), p.theta()] for p in map(solution.atPose2, range(N))]
    assert result.poses.tobytes() == np.array(theirs).tobytes()


def test_gnc_finds_wrong_planar_loops_and_keeps_the_right_ones() -> None:
    _, initial, edges = planar_loop_problem(seed=2)
    rng = np.random.default_rng(7)
    wrong = []
    for a, b in [(3, 25), (10, 33), (15, 38)]:
        wrong.append(len(edges))
        bogus = rng.uniform([-5, -5, -3], [5, 5, 3])
        edges.append(Edge(a, b, bogus, information=INFO_2D, robust=True, kind="loop"))
    found = optimize_gnc(initial, edges, inlier_chi2=30.0)
    assert found.outliers.tolist() == wrong
    assert found.iterations == 0 and found.edge_chi2[wrong].min() > 30.0
    clean = optimize_se2(initial, [e for k, e in enumerate(edges) if k not in wrong])
    assert np.abs(found.poses[:, :2] - clean.poses[:, :2]).max() < 0.05


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda p, e: (p[:, :2], e), r"planar poses must have shape \(N, 3\)"),
        (lambda p, e: (np.vstack([p, [np.nan, 0, 0]]), e), rf"poses\[{N}\] is not finite"),
        (lambda p, e: (p, [*e, Edge(1, 2, np.eye(4))]), r"not a finite \(3,\) x, y, yaw row"),
        (
            lambda p, e: (p, [*e, Edge(1, 2, np.zeros(3), information=np.eye(6))]),
            r"information must be \(3, 3\), got \(6, 6\)",
        ),
    ],
)
def test_bad_planar_input_raises(change, match: str) -> None:  # type: ignore[no-untyped-def]
    _, initial, edges = planar_loop_problem()
    poses, bad_edges = change(initial, edges)
    with pytest.raises(ValueError, match=match):
        optimize_se2(poses, bad_edges)


def test_unknown_solve_option_is_refused() -> None:
    _, initial, edges = planar_loop_problem()
    with pytest.raises(TypeError, match=r"unknown solve option.* kernl"):
        optimize_se2(initial, edges, kernl="cauchy")  # type: ignore[call-arg]


def test_sim3_recovers_scale_drift() -> None:
    truth = circle()
    drift = np.exp(0.01 * np.arange(N))  # node k's map is at drift[k] times the true scale
    odo = []
    for a in range(N - 1):
        rel = inverse(truth[a]) @ truth[a + 1]
        rel[:3, 3] *= drift[a]  # measured in node a's (drifting) units
        odo.append(Edge(a, a + 1, rel))  # a monocular tracker sees no scale change: scale 1
    initial = chain(truth[0], odo)
    # The loop closure aligns the two maps in 3-D, so it measures the true similarity
    # S_39⁻¹ S_0 with S_k = [R_k / drift_k, t_k]: scale drift_39 / drift_0.
    a, b = N - 1, 0
    rel = inverse(truth[a]) @ truth[b]
    rel[:3, 3] *= drift[a]
    loop = Edge(a, b, rel, scale=drift[a] / drift[b], information=100 * np.eye(7), kind="loop")
    result = optimize_sim3(initial, np.ones(N), [*odo, loop])
    assert result.scales is not None
    true_scales = 1 / drift
    assert np.abs(np.log(result.scales / true_scales)).max() < 0.05
    assert np.abs(np.log(true_scales)).max() > 0.35  # what the initial ones get wrong
    assert position_error(result.poses, truth) < 0.2 * position_error(initial, truth)
    assert result.error_after < 0.01 * result.error_before


def test_sim3_convention_is_p_a_equals_s_r_p_b_plus_t() -> None:
    """Two nodes related by an exact similarity: p_a = s R p_b + t, node 1 recovered exactly."""
    world_from = make_pose(so3_exp([[0, 0, 0], [0.3, -0.2, 0.5]]), [[0, 0, 0], [1.0, 2.0, -1.0]])
    scales = np.array([1.0, 2.5])
    sim = world_from.copy()
    sim[:, :3, :3] *= scales[:, None, None]
    rel_sim = np.linalg.inv(sim[0]) @ sim[1]
    s = np.cbrt(np.linalg.det(rel_sim[:3, :3]))
    rel = make_pose(rel_sim[:3, :3] / s, rel_sim[:3, 3])
    start = world_from @ make_pose(so3_exp([0.1, 0.1, -0.1]), [0.3, 0.0, 0.2])
    start[0] = world_from[0]
    result = optimize_sim3(start, [1.0, 1.0], [Edge(0, 1, rel, scale=s)])
    assert result.scales is not None
    np.testing.assert_allclose(result.scales, scales, rtol=1e-9)
    np.testing.assert_allclose(result.poses, world_from, atol=1e-9)
    assert result.error_after < 1e-15


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda p, e: (p, [*e, Edge(0, N, np.eye(4))]), rf"edges\[{N + 1}\] joins nodes 0 and {N}"),
        (lambda p, e: (p, [*e, Edge(-1, 2, np.eye(4))]), r"outside 0\.\.39"),
        (lambda p, e: (p, [*e, Edge(2, 2, np.eye(4))]), r"joins node 2 to itself"),
        (
            lambda p, e: (p, [*e, Edge(1, 2, 2 * np.eye(4))]),
            rf"edges\[{N + 1}\]\.a_from_b is not a rigid",
        ),
        (
            lambda p, e: (np.concatenate([p[:3], 1.1 * p[3:4], p[4:]]), e),
            r"poses\[3\] is not a rigid \(SE\(3\)\) transform",
        ),
        (lambda p, e: (p[:, :3], e), r"poses must have shape \(N, 4, 4\)"),
        (
            lambda p, e: (p, [*e, Edge(1, 2, np.eye(4), information=np.zeros((6, 6)))]),
            r"information is not symmetric positive definite",
        ),
        (
            lambda p, e: (p, [*e, Edge(1, 2, np.eye(4), information=np.eye(7))]),
            r"information must be \(6, 6\), got \(7, 7\)",
        ),
    ],
)
def test_bad_input_raises_value_error(change, match: str) -> None:  # type: ignore[no-untyped-def]
    _, initial, edges = loop_problem()
    poses, bad_edges = change(initial, edges)
    with pytest.raises(ValueError, match=match):
        optimize_se3(poses, bad_edges)


def test_bad_options_raise_value_error() -> None:
    _, initial, edges = loop_problem()
    with pytest.raises(ValueError, match=r"kernel must be one of none, huber, cauchy"):
        optimize_se3(initial, edges, kernel="l1")
    with pytest.raises(ValueError, match=r"kernel_width must be a finite number > 0"):
        optimize_se3(initial, edges, kernel="huber", kernel_width=0.0)
    with pytest.raises(ValueError, match=r"fixed node 40 is outside 0\.\.39"):
        optimize_se3(initial, edges, fixed=(40,))
    with pytest.raises(ValueError, match=r"scales must be finite and > 0"):
        optimize_sim3(initial, np.zeros(N), edges)


def test_g2o_round_trip(tmp_path: Path) -> None:
    _, initial, edges = loop_problem()
    edges[0].information = INFO + 0.1 * (np.ones((6, 6)) - np.eye(6))  # off-diagonal terms too
    path = save_g2o(tmp_path / "loop.g2o", initial, edges, fixed=(0,))
    graph = read_g2o(path)
    assert (graph.dim, graph.fixed, graph.summary()["loop_closure_edges"]) == (3, (0,), 2)
    poses, back, fixed = from_g2o(graph)
    assert fixed == (0,)
    np.testing.assert_allclose(poses, initial, atol=1e-12)
    assert [(e.a, e.b, e.robust) for e in back] == [(e.a, e.b, e.robust) for e in edges]
    for e, f in zip(edges, back, strict=True):
        np.testing.assert_allclose(f.a_from_b, e.a_from_b, atol=1e-12)
        np.testing.assert_allclose(f.information, e.information, rtol=1e-12)
    # The g2o information means the same chi2: the graph's error is unchanged.
    assert graph_error(poses, back) == pytest.approx(graph_error(initial, edges), rel=1e-9)
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


def test_g2o_writer_exact_both_dimensions(tmp_path: Path) -> None:
    planar = tmp_path / "planar.g2o"
    planar.write_text(
        "VERTEX_SE2 3 0 0 0\nVERTEX_SE2 7 1.25 -0.1 0.3\n"
        "EDGE_SE2 3 7 1.25 -0.1 0.30000000000000004 1 2 3 4 5 6\nFIX 3\n"
    )
    for source in (planar, shared_path("pose_graphs", "sphere2500.g2o")):
        graph = read_g2o(source)
        again = read_g2o(write_g2o(tmp_path / "again.g2o", graph))
        for name in ("vertex_ids", "poses", "edges", "measurements", "information"):
            np.testing.assert_array_equal(getattr(again, name), getattr(graph, name))
        assert (again.dim, again.fixed) == (graph.dim, graph.fixed)


def test_g2o_writer_rejects_bad_arrays_and_leaves_no_file(tmp_path: Path) -> None:
    target = tmp_path / "bad.g2o"
    poses = np.stack([np.eye(4), np.eye(4)])
    with pytest.raises(ValueError, match=r"measurements must have shape \(N, 4, 4\)"):
        write_g2o_se3(target, poses, np.array([[0, 1]]), np.eye(3)[None])
    nan = np.eye(4)[None].copy()
    nan[0, 0, 3] = np.nan
    with pytest.raises(ValueError, match=r"measurements has non-finite values"):
        write_g2o_se3(target, poses, np.array([[0, 1]]), nan)
    graph = PoseGraph(
        2,
        np.array([0]),
        np.zeros((1, 3)),
        np.zeros((0, 2)),
        np.zeros((0, 3)),
        np.zeros(0),
        (),
        target,
    )
    with pytest.raises(ValueError, match=r"information must have shape \(0, 3, 3\)"):
        write_g2o(target, graph)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_sphere2500_optimises() -> None:
    poses, edges, fixed = from_g2o(read_g2o(shared_path("pose_graphs", "sphere2500.g2o")))
    assert (len(poses), len(edges), fixed) == (2500, 4949, ())
    result = optimize_se3(poses, edges)
    assert result.error_after < 1e-3 * result.error_before
    assert result.iterations < 20
    # Every edge is consistent with the solution: the graph has no outliers to report.
    assert result.outliers.size == 0
    assert result.poses[0].tobytes() == poses[0].tobytes()
