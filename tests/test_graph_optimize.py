"""``slamcli graph optimize``: GTSAM's own optimum on the shared graphs, outliers, errors, files.

The reference optimum is computed here with gtsam directly, with default
``LevenbergMarquardtParams``: 2-D graphs through ``gtsam.readG2o`` (EDGE_SE2 information is in
Pose2's own (x, y, theta) order, and for an edge-only file readG2o chains the odometry as the
command does); 3-D graphs are built factor by factor, because readG2o's EDGE_SE3:QUAT import
takes the quaternion-vector information as if it were per radian (it drops g2o's factor 1/2),
which changes the problem being solved.
"""

from __future__ import annotations

import dataclasses
import json
import re
import shlex
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import typer
from conftest import SHARED_DATA, shared_path
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.cli.common import EXIT_INPUT
from slamcli.formats.g2o import PoseGraph, read_g2o, write_g2o
from slamcli.graphs.optimize import optimize_graph

GRAPHS = ("intel", "manhattan", "sphere2500")
_EXAMPLE = re.compile(r"\[bold\](slamcli\s[^\[]*?)\[/\]")


def _graph(name: str) -> Path:
    return shared_path("pose_graphs", f"{name}.g2o")


def _reference_error(path: Path, dim: int) -> float:
    """GTSAM's Levenberg–Marquardt optimum (default parameters) of the graph in ``path``."""
    import gtsam

    if dim == 2:
        graph, initial = gtsam.readG2o(str(path), False)
    else:
        graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
        # g2o's residual is [t, q.xyz], GTSAM's [omega, v]: e_g2o = P e_gtsam.
        p = np.zeros((6, 6))
        p[:3, 3:] = np.eye(3)
        p[3:, :3] = 0.5 * np.eye(3)
        upper = np.triu_indices(6)

        def pose(v: np.ndarray) -> gtsam.Pose3:
            return gtsam.Pose3(gtsam.Rot3.Quaternion(v[6], v[3], v[4], v[5]), v[:3])

        for line in path.read_text().splitlines():
            f = line.split()
            if f and f[0] == "VERTEX_SE3:QUAT":
                initial.insert(int(f[1]), pose(np.array(f[2:9], dtype=float)))
            elif f and f[0] == "EDGE_SE3:QUAT":
                info = np.zeros((6, 6))
                info[upper] = np.array(f[10:31], dtype=float)
                info = info + np.triu(info, 1).T
                noise = gtsam.noiseModel.Gaussian.Information(p.T @ info @ p)
                graph.add(
                    gtsam.BetweenFactorPose3(
                        int(f[1]), int(f[2]), pose(np.array(f[3:10], dtype=float)), noise
                    )
                )
    params = gtsam.LevenbergMarquardtParams()
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
    return float(graph.error(result))


def _invoke(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args), catch_exceptions=False)
    return result.exit_code, result.stdout + result.stderr


@pytest.mark.parametrize("name", GRAPHS)
def test_error_equals_gtsam_optimum_and_files(name: str, shared_run: Any) -> None:
    path = _graph(name)
    # Once per session: the README runs the same command on sphere2500.
    run = shared_run("graph", "optimize", path, "--json")
    out, code, text = run.out, run.exit_code, run.stdout + run.stderr
    assert run.exception is None, run.exception
    assert code == 0, text
    record = json.loads(text)
    g = record["graph"]
    source = read_g2o(path)
    reference = _reference_error(path, source.dim)
    assert g["error_after"] == pytest.approx(reference, rel=0.01)
    assert g["error_after"] < 0.1 * g["error_before"]
    assert g["dimension"] == source.dim
    assert record["inputs"][0]["hash"].startswith("sha256:")
    assert sorted(record["outputs"]) == sorted(
        ["optimized.g2o", "trajectory.tum", "report.png", "run.json"]
    )
    assert json.loads((out / "run.json").read_text())["graph"] == g

    optimized = read_g2o(out / "optimized.g2o")
    ids = np.union1d(source.vertex_ids, source.edges.ravel())
    assert optimized.dim == source.dim
    np.testing.assert_array_equal(optimized.vertex_ids, ids)
    np.testing.assert_array_equal(optimized.edges, source.edges)
    np.testing.assert_array_equal(optimized.measurements, source.measurements)
    assert g["vertices"] == ids.size and g["edges"] == source.edges.shape[0]

    rows = np.loadtxt(out / "trajectory.tum", comments="#")
    np.testing.assert_array_equal(rows[:, 0], ids.astype(float))
    np.testing.assert_allclose(rows[:, 1:3], optimized.poses[:, :2], atol=1e-8)
    if source.dim == 2:
        np.testing.assert_array_equal(rows[:, 3], 0.0)
        yaw = 2.0 * np.arctan2(rows[:, 6], rows[:, 7])
        dyaw = np.angle(np.exp(1j * (yaw - optimized.poses[:, 2])))
        np.testing.assert_allclose(dyaw, 0.0, atol=1e-7)
    assert (out / "report.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _ground_truth_sphere() -> np.ndarray:
    """(2500, 4, 4) poses chained from the noise-free consecutive EDGE3 records (x y z roll
    pitch yaw, R = Rz(yaw) Ry(pitch) Rx(roll))."""
    from scipy.spatial.transform import Rotation

    poses = [np.eye(4)]
    for line in shared_path("pose_graphs", "sphere2500_groundtruth.txt").read_text().splitlines():
        f = line.split()
        a, b = int(f[1]), int(f[2])
        if b != a + 1 or b != len(poses):
            continue
        v = np.array(f[3:9], dtype=float)
        rel = np.eye(4)
        rel[:3, :3] = Rotation.from_euler("ZYX", v[[5, 4, 3]]).as_matrix()
        rel[:3, 3] = v[:3]
        poses.append(poses[-1] @ rel)
    return np.stack(poses)


def test_sphere2500_close_to_ground_truth() -> None:
    from slamcli.geometry.se3 import make_pose, quat_xyzw_to_matrix

    result = optimize_graph(read_g2o(_graph("sphere2500")))
    est = result.optimized.poses
    truth = _ground_truth_sphere()
    assert truth.shape == (2500, 4, 4)
    # Same gauge: both expressed relative to pose 0.
    first = make_pose(quat_xyzw_to_matrix(est[:1, 3:7]), est[:1, :3])[0]
    est_t = (np.linalg.inv(first) @ np.c_[est[:, :3], np.ones(len(est))].T).T[:, :3]
    error = np.linalg.norm(est_t - truth[:, :3, 3], axis=1)
    initial = np.linalg.norm(
        result.initial.poses[:, :3] - result.initial.poses[:1, :3] - truth[:, :3, 3], axis=1
    )
    assert np.sqrt(np.mean(error**2)) < 0.1 * np.sqrt(np.mean(initial**2))


def _with_wrong_loops(
    seed: int, count: int, name: str = "manhattan"
) -> tuple[PoseGraph, np.ndarray]:
    """A shared 2-D graph plus ``count`` wrong loop closures between random pose pairs, with
    the information of a real odometry edge; returns the graph and the wrong edges' indices."""
    source = read_g2o(_graph(name))
    rng = np.random.default_rng(seed)
    ids = np.union1d(source.vertex_ids, source.edges.ravel())
    pairs: list[tuple[int, int]] = []
    while len(pairs) < count:
        a, b = sorted(rng.choice(ids, 2, replace=False).tolist())
        if b - a > 1 and (a, b) not in pairs:
            pairs.append((a, b))
    wrong = np.column_stack(
        [rng.uniform(-10, 10, count), rng.uniform(-10, 10, count), rng.uniform(-3, 3, count)]
    )
    graph = dataclasses.replace(
        source,
        edges=np.vstack([source.edges, pairs]),
        measurements=np.vstack([source.measurements, wrong]),
        information=np.concatenate([source.information, source.information[:count]]),
    )
    return graph, np.arange(len(source.edges), len(source.edges) + count)


def test_injected_wrong_loop_closures_are_found(tmp_path: Path) -> None:
    graph, injected = _with_wrong_loops(seed=14, count=20)
    path = write_g2o(tmp_path / "manhattan_wrong.g2o", graph)
    code, text = _invoke(
        "graph", "optimize", str(path), "--out", str(tmp_path / "run"), "--kernel", "dcs",
        "--outliers", "--json",
    )  # fmt: skip
    assert code == 0, text
    g = json.loads(text)["graph"]
    found = {o["edge"] for o in g["outliers"]}
    recall = len(found & set(injected.tolist())) / len(injected)
    false_positives = len(found - set(injected.tolist()))
    assert recall == 1.0
    # GNC drops 4 of manhattan's 1954 real loops on this graph (and on the clean one).
    assert false_positives <= 8
    assert all(o["chi2"] > g["outlier_chi2_bound"] for o in g["outliers"])
    assert g["outlier_search"]["kernel"] == "gnc-tls" and g["kernel"] == "dcs"

    clean = optimize_graph(read_g2o(_graph("manhattan")))
    est = read_g2o(tmp_path / "run" / "optimized.g2o").poses
    d = np.linalg.norm(est[:, :2] - clean.optimized.poses[:, :2], axis=1)
    # Pose 0 holds the gauge in both solves, so positions compare directly; the final DCS
    # solve moves manhattan by a few centimetres from the least-squares optimum.
    assert np.sqrt(np.mean(d**2)) < 0.13
    assert d.max() < 0.4


def test_clean_graph_has_few_outliers() -> None:
    result = optimize_graph(read_g2o(_graph("intel")), find_outliers=True)
    assert result.outliers.size == 0
    clean = optimize_graph(read_g2o(_graph("intel")))
    np.testing.assert_allclose(result.optimized.poses, clean.optimized.poses, atol=1e-6)


def test_without_kernel_outliers_come_from_a_robust_solve(tmp_path: Path) -> None:
    graph, injected = _with_wrong_loops(seed=3, count=20, name="intel")
    result = optimize_graph(graph, find_outliers=True)
    assert result.detection is not None and result.detection.kernel == "gnc-tls"
    assert result.final.kernel == "none"
    assert set(injected.tolist()) <= set(result.outliers.tolist())
    assert not result.final.edges_used[injected].any()
    summary = result.summary()
    assert summary["outlier_search"]["kernel"] == "gnc-tls"
    assert summary["edges_used"] == len(graph.edges) - result.outliers.size


def test_malformed_line_names_file_and_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.g2o"
    bad.write_text(
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 zero 1 0 0 1 0 1\n",
        encoding="utf-8",
    )
    code, text = _invoke("graph", "optimize", str(bad), "--out", str(tmp_path / "o"))
    assert code == EXIT_INPUT
    assert f"{bad}:3" in " ".join(text.split())
    assert not (tmp_path / "o").exists()

    code, text = _invoke(
        "graph", "optimize", str(tmp_path / "nope.g2o"), "--out", str(tmp_path / "o")
    )
    assert code == EXIT_INPUT
    assert "nope.g2o" in text and "no such file" in text


def test_bad_options_and_existing_folder(tmp_path: Path) -> None:
    path = str(_graph("intel"))
    code, text = _invoke("graph", "optimize", path, "--out", str(tmp_path / "a"), "--kernel", "l1")
    assert code == EXIT_INPUT and "--kernel" in text
    out = tmp_path / "b"
    assert _invoke("graph", "optimize", path, "--out", str(out))[0] == 0
    code, text = _invoke("graph", "optimize", path, "--out", str(out))
    assert code == EXIT_INPUT and "--force" in text
    assert _invoke("graph", "optimize", path, "--out", str(out), "--force")[0] == 0


def test_deterministic(tmp_path: Path) -> None:
    path = str(_graph("intel"))
    for name in ("a", "b"):
        args = ["graph", "optimize", path, "--out", str(tmp_path / name), "--kernel", "cauchy"]
        assert _invoke(*args)[0] == 0
    first = (tmp_path / "a" / "optimized.g2o").read_bytes()
    assert first == (tmp_path / "b" / "optimized.g2o").read_bytes()
    assert (tmp_path / "a" / "trajectory.tum").read_bytes() == (
        tmp_path / "b" / "trajectory.tum"
    ).read_bytes()


def test_help_examples_run(tmp_path: Path, shared_run: Any) -> None:
    shared_path()
    (tmp_path / "shared").symlink_to(SHARED_DATA.parent, target_is_directory=True)
    work = tmp_path / "work"
    work.mkdir()
    command = typer.main.get_command(app).commands["graph"].commands["optimize"]  # type: ignore[attr-defined]
    examples = [" ".join(m.split()) for m in _EXAMPLE.findall(command.help or "")]
    assert len(examples) >= 3
    for line in examples:
        # Once per session: test_help_examples runs every help example too (and intel's is a
        # reference run).
        result = shared_run(*shlex.split(line)[1:], cwd=work)
        assert result.exception is None, f"{line}\n{result.exception}"
        assert result.exit_code == 0, f"{line}\n{result.stdout}{result.stderr}"
        assert (result.out / "optimized.g2o").is_file()
