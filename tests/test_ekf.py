"""`slamcli run ekf` on real and synthetic landmark logs, scored against ground truth."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.formats.landmark_map import read_landmarks_csv
from slamcli.formats.trajectory import read_trajectory
from slamcli.run import RunOutcome, run_pipeline
from slamcli.synth.landmarks import generate_landmark_world
from tests.conftest import shared_path

runner = CliRunner()

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "landmarks"

# Accuracy thresholds on MRCLAM robots 1-5, shared with the perturbed runs of tests/robust.
MRCLAM_MAX_ATE_M = 0.35
MRCLAM_MEAN_ATE_M = 0.25
MRCLAM_MEAN_LANDMARK_M = 0.30


def _record(out: Path) -> dict:
    return json.loads((out / "run.json").read_text())


def test_mrclam_all_robots_meet_the_accuracy_goals(shared_run: Any) -> None:
    """Dataset 6, robots 1-5, known correspondences, default settings for every robot."""
    folder = shared_path("landmarks", "MRCLAM_Dataset6")
    ate, dr, lm = [], [], []
    for robot in range(1, 6):
        # Once per session: test_merge joins these runs, and robot 1 is a reference run.
        run = shared_run("run", "ekf", folder, "--robot", str(robot))
        assert run.exit_code == 0, run.output
        record = _record(run.out)
        metrics, counts = record["metrics"], record["counts"]
        ev = metrics["evaluation"]
        assert ev["alignment"] == "se2"
        assert ev["trajectory"] == "smoothed"
        ate.append(ev["ate"]["rmse"])
        # Smoothing against the final map never makes the path worse than the filter's.
        assert ev["ate"]["rmse"] <= metrics["filtered"]["ate"]["rmse"]
        dr.append(metrics["dead_reckoning"]["ate"]["rmse"])
        lm.append(ev["landmarks"]["rmse_m"])
        assert ev["landmarks"]["matched"] == 15
        # Every landmark of the survey is mapped, under its own id.
        mapped = read_landmarks_csv(run.out / "landmarks.csv")
        assert sorted(mapped.ids.tolist()) == list(range(6, 21))
        assert mapped.cov is not None and np.all(np.linalg.eigvalsh(mapped.cov) > 0)
        # The filter is never locked out: almost every observation is used.
        assert counts["rejected_by_gate"] < 0.02 * counts["observations"]
    print(f"ATE per robot {np.round(ate, 3)}, dead reckoning {np.round(dr, 3)}")
    print(f"landmark RMSE per robot {np.round(lm, 3)}")
    assert max(ate) <= MRCLAM_MAX_ATE_M
    assert np.mean(ate) <= MRCLAM_MEAN_ATE_M
    assert np.mean(lm) <= MRCLAM_MEAN_LANDMARK_M
    # Dead reckoning alone is an order of magnitude worse.
    assert min(dr) > 1.0


def test_mrclam_run_folder_and_cli(shared_run: Any) -> None:
    folder = shared_path("landmarks", "MRCLAM_Dataset6")
    res = shared_run("run", "ekf", folder, "--robot", "4")
    out = res.out
    assert res.exit_code == 0, res.output
    assert {p.name for p in out.iterdir()} == {
        "trajectory.tum",
        "trajectory_filtered.tum",
        "landmarks.csv",
        "report.png",
        "run.json",
    }
    assert "SE(2)" in res.output and "dead reckoning" in res.output
    record = _record(out)
    nees = record["metrics"]["evaluation"]["nees"]
    assert nees["dof"] == 3
    # The filter's pose uncertainty is honest on real data within a factor of about three.
    assert 1.0 < nees["mean"] < 9.35
    assert record["metrics"]["nis"]["dof"] == 2
    for key in ("updates", "rejected_by_gate", "landmarks_new", "landmarks_pruned"):
        assert key in record["counts"]
    traj = read_trajectory(out / "trajectory.tum")
    # Planar poses as SE(3): z = 0 and rotations about +z only.
    assert np.allclose(traj.world_from_body[:, 2, 3], 0.0)
    assert np.allclose(traj.world_from_body[:, 2, 2], 1.0)
    # The run starts at the ground-truth pose.
    start = record["metrics"]["evaluation"]["ate_unaligned"]["min"]
    assert start < 0.05


def _world(tmp_path: Path, seed: int) -> Path:
    out = tmp_path / f"world{seed}"
    generate_landmark_world(out, seed=seed, landmarks=40, duration_s=90.0)
    return out


@pytest.fixture(scope="module")
def world7_known(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, RunOutcome]:
    """World 7 and its known-correspondence run, the yardstick of both associations."""
    root = tmp_path_factory.mktemp("world7")
    world = _world(root, seed=7)
    return world, run_pipeline(world, "ekf", root / "known")


@pytest.mark.parametrize("association", ["nn", "jcbb"])
def test_unknown_correspondences_make_no_false_landmarks(
    tmp_path: Path, association: str, world7_known: tuple[Path, RunOutcome]
) -> None:
    world, known = world7_known
    cfg_cls = __import__("slamcli.pipelines.ekf", fromlist=["EkfConfig"]).EkfConfig
    unknown = run_pipeline(
        world,
        "ekf",
        tmp_path / "unknown",
        source_options={"ignore_ids": True},
        config=cfg_cls(association=association),
    )
    ev_k, ev_u = known.metrics["evaluation"], unknown.metrics["evaluation"]
    assert unknown.metrics["association"] == association
    lms = ev_u["landmarks"]
    assert lms["spurious"] == 0 and lms["duplicates"] == 0
    assert lms["matched"] >= 0.9 * ev_k["landmarks"]["matched"]
    assert ev_u["ate"]["rmse"] <= 2.0 * ev_k["ate"]["rmse"]
    # Consistency: the average NEES lies inside the 95 % chi-square band for 3 dof.
    lo, hi = ev_u["nees"]["band95"]
    assert lo <= ev_u["nees"]["mean"] <= hi
    assert ev_u["nees"]["consistent"] is True


def test_sample_world_known_ids_is_accurate_and_deterministic(
    tmp_path: Path, shared_run: Any
) -> None:
    # The first run is shared with test_run_folder (the same command), the second this test's.
    a = shared_run("run", "ekf", SAMPLE)
    assert a.exit_code == 0, a.output
    b = run_pipeline(SAMPLE, "ekf", tmp_path / "b").run_dir
    assert (a.out / "trajectory.tum").read_bytes() == (b / "trajectory.tum").read_bytes()
    assert (a.out / "landmarks.csv").read_bytes() == (b / "landmarks.csv").read_bytes()
    metrics = _record(a.out)["metrics"]
    ev = metrics["evaluation"]
    dr = metrics["dead_reckoning"]["ate"]["rmse"]
    assert ev["ate"]["rmse"] < 0.5 * dr
    assert ev["landmarks"]["matched"] == 40
    assert ev["nees"]["consistent"] is True


def test_victoria_park_unknown_correspondences_runs_to_the_end(shared_run: Any) -> None:
    path = shared_path("landmarks", "victoria_park.txt")
    # Once per session: the README runs the same command.
    res = shared_run("run", "ekf", path, "--ignore-ids")
    out = res.out
    assert res.exit_code == 0, res.output
    record = _record(out)
    counts = record["counts"]
    # Every pose of the file is processed and the trajectory covers them all.
    assert counts["odometry"] == 6969
    assert len(read_trajectory(out / "trajectory.tum")) == 6969
    mapped = read_landmarks_csv(out / "landmarks.csv")
    # The file names 151 distinct landmarks; without ids the map must come close, not explode.
    assert 100 <= len(mapped) <= 250
    assert counts["updates"] > 0.8 * counts["observations"]
    assert (out / "report.png").stat().st_size > 50_000


def _copy_mrclam(tmp_path: Path) -> Path:
    src = shared_path("landmarks", "MRCLAM_Dataset6")
    dst = tmp_path / "mrclam"
    dst.mkdir()
    for name in ("Barcodes.dat", "Landmark_Groundtruth.dat"):
        shutil.copy(src / name, dst / name)
    for kind in ("Odometry", "Measurement", "Groundtruth"):
        shutil.copy(src / f"Robot1_{kind}.dat", dst / f"Robot1_{kind}.dat")
    return dst


def _replace_line(path: Path, number: int, text: str) -> None:
    lines = path.read_text().splitlines(keepends=True)
    lines[number - 1] = text + "\n"
    path.write_text("".join(lines))


def test_bad_measurement_line_names_file_and_line(tmp_path: Path) -> None:
    folder = _copy_mrclam(tmp_path)
    _replace_line(folder / "Robot1_Measurement.dat", 40, "1248444201.1 \t 14 \t oops \t 0.1")
    res = runner.invoke(app, ["run", "ekf", str(folder), "--out", str(tmp_path / "o")])
    assert res.exit_code == 1
    assert "Robot1_Measurement.dat:40" in res.output
    assert not (tmp_path / "o").exists()


def test_odometry_time_going_backwards_is_an_error(tmp_path: Path) -> None:
    folder = _copy_mrclam(tmp_path)
    _replace_line(folder / "Robot1_Odometry.dat", 100, "1248444100.000 \t 0.1 \t 0.0")
    res = runner.invoke(app, ["run", "ekf", str(folder), "--out", str(tmp_path / "o")])
    assert res.exit_code == 1
    assert "Robot1_Odometry.dat:100" in res.output and "backwards" in res.output


def test_barcode_not_in_barcodes_dat(tmp_path: Path) -> None:
    folder = _copy_mrclam(tmp_path)
    path = folder / "Robot1_Measurement.dat"
    stamp = path.read_text().splitlines()[39].split()[0]
    _replace_line(path, 40, f"{stamp} \t 77 \t 2.0 \t 0.1")
    out = tmp_path / "o"
    res = runner.invoke(app, ["run", "ekf", str(folder), "--out", str(out)])
    # Ignored with a warning naming the barcode (the real logs have a few such codes) ...
    assert res.exit_code == 0, res.output
    assert "77" in res.output
    # ... and an error naming file and line with --strict.
    res = runner.invoke(app, ["run", "ekf", str(folder), "--strict", "--out", str(tmp_path / "s")])
    assert res.exit_code == 1
    assert "Robot1_Measurement.dat:40" in res.output and "77" in res.output


def test_robot_not_in_the_folder(tmp_path: Path) -> None:
    folder = _copy_mrclam(tmp_path)
    res = runner.invoke(
        app, ["run", "ekf", str(folder), "--robot", "3", "--out", str(tmp_path / "o")]
    )
    assert res.exit_code == 1
    assert "no robot 3" in res.output and "robots: 1" in res.output
