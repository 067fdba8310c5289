"""run_pipeline and the demo: real runs scored against ground truth."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from reference_runs import SharedRun
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.demo import default_sample
from slamcli.formats.trajectory import read_trajectory
from slamcli.geometry import inverse, rotation_angle
from slamcli.run import run_pipeline

runner = CliRunner()


@pytest.fixture
def demo(shared_run: Any) -> SharedRun:
    """``slamcli demo``, run once per test session (the help and README examples run it too)."""
    run = shared_run("demo")
    assert run.exception is None, run.output
    return run


def test_demo_writes_an_accurate_run(demo: SharedRun) -> None:
    root, res = demo.out, demo
    assert res.exit_code == 0, res.output
    assert {p.name for p in root.iterdir()} == {"dense", "plan", "ekf", "visual"}
    out = root / "dense"
    products = {"trajectory.tum", "keyframes.tum", "mesh.ply", "mesh.glb", "points.ply"}
    maps = {"map.yaml", "map.pgm", "map.png", "map.json"}
    assert {p.name for p in out.iterdir()} == products | maps | {"report.png", "run.json"}
    record = json.loads((out / "run.json").read_text())
    ev = record["metrics"]["evaluation"]
    assert ev["pairs"] == 30
    # The sample camera moves about 9 mm and 0.8° per frame; dense SLAM must track it closely.
    assert ev["ate"]["rmse"] < 0.02
    assert ev["rpe"]["rot_deg"]["mean"] < 0.3
    assert record["counts"]["frames_processed"] == 30
    assert record["counts"]["frames_lost"] == 0
    assert set(record["outputs"]) == products | maps | {"report.png", "run.json"}
    import trimesh

    glb = trimesh.load(str(out / "mesh.glb"), file_type="glb", process=False)
    (geometry,) = glb.geometry.values()
    assert len(geometry.faces) > 10_000
    assert (out / "report.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "ATE (m)" in res.stdout
    # The map of the room has walls and boxes, and free floor between them.
    from slamcli.formats.occupancy import read_map_yaml

    grid = read_map_yaml(out / "map.yaml")
    assert np.sum(grid.prob == 1.0) > 100 and np.sum(grid.prob == 0.0) > 1000
    # The plan crosses the map: a path of several metres, followed closely by the robot.
    plan = json.loads((root / "plan" / "plan.json").read_text())
    assert plan["grid_cost_m"] > 2.0
    assert plan["length_m"] <= plan["grid_cost_m"] + 1e-9
    assert plan["min_clearance_m"] >= 0.15
    for name in ("path.csv", "path_smooth.csv", "trajectory.csv", "plan.png"):
        assert (root / "plan" / name).stat().st_size > 0
    # EKF on the landmark world: far better than dead reckoning, every landmark mapped.
    ekf = json.loads((root / "ekf" / "run.json").read_text())["metrics"]
    assert ekf["evaluation"]["ate"]["rmse"] < 0.2 * ekf["dead_reckoning"]["ate"]["rmse"]
    assert ekf["evaluation"]["landmarks"]["matched"] == 40
    # Visual SLAM on the same RGB-D sequence: every frame tracked, close to the truth.
    visual = json.loads((root / "visual" / "run.json").read_text())
    assert visual["counts"]["frames_tracked"] == 30
    assert visual["metrics"]["evaluation"]["ate"]["rmse"] < 0.01
    assert {"trajectory.tum", "keyframes.tum", "points.ply", "graph.g2o"} <= set(visual["outputs"])


def test_demo_is_deterministic_and_refuses_to_clobber(demo: SharedRun, tmp_path: Path) -> None:
    # The shared demo is the first run; this test's own is the second, and the one it
    # tries to overwrite.
    first, second = demo.out, tmp_path / "b"
    assert demo.exit_code == 0
    assert runner.invoke(app, ["demo", "--out", str(second)]).exit_code == 0
    for name in (
        "dense/trajectory.tum",
        "dense/map.pgm",
        "plan/path.csv",
        "ekf/trajectory.tum",
        "visual/trajectory.tum",
    ):
        assert (first / name).read_bytes() == (second / name).read_bytes(), name
    a = (second / "dense" / "trajectory.tum").read_bytes()
    res = runner.invoke(app, ["demo", "--out", str(second)])
    assert res.exit_code == 1
    assert "not empty" in res.output and "--force" in res.output
    assert (second / "dense" / "trajectory.tum").read_bytes() == a


def test_demo_names_missing_data(tmp_path: Path) -> None:
    res = runner.invoke(app, ["demo", "--out", str(tmp_path / "o"), "--data", str(tmp_path / "x")])
    assert res.exit_code == 1
    assert "no such file or folder" in res.output or "not found" in res.output
    assert "Traceback" not in res.output
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


@pytest.mark.slow
def test_odometry_tracks_the_real_tum_excerpt(tum_excerpt: Path, tmp_path: Path) -> None:
    outcome = run_pipeline(tum_excerpt, "odometry", tmp_path / "run", max_frames=40)
    ev = outcome.metrics["evaluation"]
    assert ev["pairs"] == 40
    assert outcome.counts["frames_read"] == 40
    # freiburg1_rpy turns about 1.4° per frame here; a camera assumed still would err by that.
    assert ev["rpe"]["rot_deg"]["mean"] < 0.5
    assert ev["ate"]["rmse"] < 0.03
    est = read_trajectory(tmp_path / "run" / "trajectory.tum")
    steps = inverse(est.world_from_body[:-1]) @ est.world_from_body[1:]
    assert np.degrees(rotation_angle(steps)).mean() > 0.8


def test_sample_is_where_the_demo_looks() -> None:
    assert (default_sample() / "rgb.txt").is_file()


def test_demo_on_data_with_a_missing_image_finishes_and_exits_3(tmp_path: Path) -> None:
    import shutil

    data = tmp_path / "room"
    shutil.copytree(default_sample(), data)
    missing = sorted((data / "rgb").iterdir())[3]
    missing.unlink()
    out = tmp_path / "run"
    res = runner.invoke(app, ["demo", "--data", str(data), "--out", str(out)])
    assert res.exit_code == 3, res.output
    assert missing.name in res.output
    assert "1 frame(s) skipped" in res.output
    record = json.loads((out / "dense" / "run.json").read_text())
    assert record["counts"]["frames_skipped"] == 1
    assert record["metrics"]["evaluation"]["pairs"] == 29


def test_run_odometry_command_writes_the_run_folder(tmp_path: Path) -> None:
    out = tmp_path / "odo"
    res = runner.invoke(
        app, ["run", "odometry", str(default_sample()), "--out", str(out), "--max-frames", "10"]
    )
    assert res.exit_code == 0, res.output
    record = json.loads((out / "run.json").read_text())
    assert record["command"] == "run odometry"
    assert record["counts"]["frames_processed"] == 10
    assert record["metrics"]["evaluation"]["pairs"] == 10
    assert record["data_loss"] == []


def test_an_option_the_format_does_not_take_is_refused_before_anything_is_written(
    tmp_path: Path,
) -> None:
    out = tmp_path / "odo"
    res = runner.invoke(
        app, ["run", "odometry", str(default_sample()), "--out", str(out), "--rgb-topic", "/c"]
    )
    assert res.exit_code == 1
    assert "--rgb-topic does not apply to tum inputs" in res.output
    assert not out.exists()


def test_run_dense_without_a_depth_stream_says_so(tmp_path: Path) -> None:
    import shutil

    from tests.test_mcap_source import _image_log

    folder = tmp_path / "room"
    shutil.copytree(default_sample(), folder)
    (folder / "depth.txt").unlink()
    res = runner.invoke(app, ["run", "dense", str(folder), "--out", str(tmp_path / "a")])
    assert res.exit_code == 1
    assert "no depth.txt" in res.output and "Traceback" not in res.output
    log = _image_log(tmp_path / "colour_only.mcap", {"/camera/color/image_raw": "rgb8"})
    res = runner.invoke(app, ["run", "dense", str(log), "--out", str(tmp_path / "b")])
    assert res.exit_code == 1
    assert "no depth topics found" in res.output and "--depth-topic" in res.output
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_run_dense_settings_are_checked_before_reading(tmp_path: Path) -> None:
    out = tmp_path / "d"
    res = runner.invoke(
        app, ["run", "dense", str(default_sample()), "--out", str(out), "--set", "voxel_size_m=-1"]
    )
    assert res.exit_code == 1
    assert "dense.voxel_size_m" in res.output
    assert not out.exists()


def test_run_json_names_the_pipeline_and_its_seeds(tmp_path: Path) -> None:
    records = {}
    for seed in (0, 7):
        out = tmp_path / f"seed{seed}"
        args = ["run", "dense", str(default_sample()), "--out", str(out), "--max-frames", "3"]
        res = runner.invoke(app, [*args, "--set", f"seed={seed}"])
        assert res.exit_code == 0, res.output
        records[seed] = json.loads((out / "run.json").read_text())
    for seed, record in records.items():
        assert record["pipeline"] == "dense"
        assert record["seeds"] == {"opencv": seed}
        assert record["config"]["dense"]["seed"] == seed
