"""``slamcli synth landmarks --robots N``: an MRCLAM folder of robots sharing a landmark field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import ConfigError
from slamcli.formats.landmarks import MrclamSource
from slamcli.geometry import se3_to_planar
from slamcli.run import run_pipeline
from slamcli.synth import landmarks as lm

runner = CliRunner()


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_one_robot_keeps_the_single_robot_layout(tmp_path: Path) -> None:
    lm.generate_landmark_world(tmp_path / "a", seed=3, landmarks=10, duration_s=10.0)
    lm.generate_landmark_world(tmp_path / "b", seed=3, landmarks=10, duration_s=10.0, robots=1)
    assert _files(tmp_path / "a") == _files(tmp_path / "b")
    assert "odometry.csv" in _files(tmp_path / "a")


def test_folder_is_read_by_the_mrclam_source(tmp_path: Path) -> None:
    summary = lm.generate_landmark_world(tmp_path, seed=2, landmarks=30, duration_s=40.0, robots=3)
    world = lm.simulate_multi_robot_world(seed=2, robots=3, landmarks=30, duration_s=40.0)
    meta = json.loads((tmp_path / "world.json").read_text())
    assert meta["robots"] == 3 and len(meta["per_robot"]) == 3
    sightings = 0
    for k in range(3):
        with MrclamSource(tmp_path, robot=k + 1) as source:
            assert source.robots == [1, 2, 3]
            w = world.robots[k]
            assert source.unknown_barcodes == {}
            np.testing.assert_array_equal(source.observations.ids, w.meas_ids + 6)
            np.testing.assert_allclose(source.observations.ranges_m, w.meas_range, atol=1e-6)
            assert source.robot_sightings == len(world.sightings[k].index) > 0
            sightings += source.robot_sightings
            gt = source.groundtruth()
            assert gt is not None
            np.testing.assert_array_equal(gt.stamps_ns, w.stamps_ns)
            np.testing.assert_allclose(
                se3_to_planar(gt.world_from_body)[:, :2], w.poses[:, :2], atol=1e-6
            )
            truth = source.landmark_truth()
            assert truth is not None
            np.testing.assert_array_equal(truth.ids, np.arange(30) + 6)
            np.testing.assert_allclose(truth.xy, w.landmarks, atol=1e-6)
    assert summary["sightings"] == sightings
    # Robots start at different places and not all drive the same way round.
    starts = np.array([r["start_pose"] for r in meta["per_robot"]])
    assert (
        np.min(
            np.linalg.norm(starts[:, None, :2] - starts[None, :, :2], axis=2)[np.triu_indices(3, 1)]
        )
        > 5.0
    )
    assert {r["clockwise"] for r in meta["per_robot"]} == {True, False}


def test_sightings_match_the_geometry(tmp_path: Path) -> None:
    sensor = lm.LandmarkSensor().noiseless()
    lm.generate_landmark_world(
        tmp_path, seed=5, landmarks=20, duration_s=60.0, sensor=sensor, robots=4
    )
    truth = {}
    for k in range(1, 5):
        rows = np.loadtxt(tmp_path / f"Robot{k}_Groundtruth.dat", ndmin=2)
        truth[k] = rows
    for k in range(1, 5):
        meas = np.loadtxt(tmp_path / f"Robot{k}_Measurement.dat", ndmin=2)
        robot = meas[meas[:, 1] <= 5]
        assert len(robot) > 0
        assert k not in robot[:, 1]
        me = truth[k]
        row = np.searchsorted(me[:, 0], robot[:, 0])
        np.testing.assert_allclose(me[row, 0], robot[:, 0])
        other = np.stack([truth[int(b)][i, 1:3] for b, i in zip(robot[:, 1], row, strict=True)])
        rel = other - me[row, 1:3]
        np.testing.assert_allclose(robot[:, 2], np.hypot(rel[:, 0], rel[:, 1]), atol=2e-6)
        bearing = np.arctan2(rel[:, 1], rel[:, 0]) - me[row, 3]
        err = np.angle(np.exp(1j * (bearing - robot[:, 3])))
        assert np.abs(err).max() < 2e-5
        assert np.all(robot[:, 2] <= sensor.max_range + 1e-6)
        assert np.all(np.abs(robot[:, 3]) <= sensor.fov / 2 + 1e-6)


def test_same_seed_same_bytes(tmp_path: Path) -> None:
    for name in ("a", "b"):
        lm.generate_landmark_world(tmp_path / name, seed=4, duration_s=15.0, robots=2)
    lm.generate_landmark_world(tmp_path / "c", seed=5, duration_s=15.0, robots=2)
    assert _files(tmp_path / "a") == _files(tmp_path / "b")
    assert (
        _files(tmp_path / "a")["Robot2_Odometry.dat"]
        != _files(tmp_path / "c")["Robot2_Odometry.dat"]
    )


def test_ekf_runs_each_robot_against_the_synthetic_truth(tmp_path: Path) -> None:
    lm.generate_landmark_world(tmp_path / "w", seed=1, landmarks=40, duration_s=90.0, robots=3)
    for k in (1, 2, 3):
        outcome = run_pipeline(
            tmp_path / "w", "ekf", tmp_path / f"r{k}", source_options={"robot": k}
        )
        ev = outcome.metrics["evaluation"]
        assert ev["ate"]["rmse"] < 0.15, (k, ev["ate"])
        assert ev["landmarks"]["rmse_m"] < 0.15, (k, ev["landmarks"])


def test_bad_robot_counts_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="robots"):
        lm.generate_landmark_world(tmp_path / "x", robots=lm.MAX_ROBOTS + 1)
    assert not (tmp_path / "x").exists()
    res = runner.invoke(app, ["synth", "landmarks", str(tmp_path / "y"), "--robots", "0"])
    assert res.exit_code == 2
    res = runner.invoke(app, ["synth", "landmarks", str(tmp_path / "y"), "--robots", "17"])
    assert res.exit_code == 2


def test_eight_robots_number_landmarks_after_the_robots(tmp_path: Path) -> None:
    lm.generate_landmark_world(tmp_path, seed=6, landmarks=25, duration_s=20.0, robots=8)
    world = lm.simulate_multi_robot_world(seed=6, robots=8, landmarks=25, duration_s=20.0)
    assert lm.landmark_subject0(8) == 9
    with MrclamSource(tmp_path, robot="all") as source:
        assert source.robots == list(range(1, 9))
        assert source.selection == list(range(1, 9))
        assert source.robot_subjects == frozenset(range(1, 9))
        assert source.landmark_subjects == frozenset(range(9, 34))
        assert source.unknown_barcodes == {}
        np.testing.assert_array_equal(source.observations.ids, world.robots[0].meas_ids + 9)
        assert source.robot_sightings == len(world.sightings[0].index)
        seen = set()
        for other in source.others:
            assert other.robot_sightings == len(world.sightings[other.robot - 1].index)
            seen |= set(other.sightings.ids.tolist())
        assert seen & {6, 7, 8}
        assert set(source.groundtruths()) == set(range(1, 9))
    meta = json.loads((tmp_path / "world.json").read_text())
    assert meta["subjects"]["landmarks"] == "9-33"


def test_cli_writes_an_mrclam_folder(tmp_path: Path) -> None:
    res = runner.invoke(
        app,
        ["synth", "landmarks", str(tmp_path / "w"), "--robots", "2", "--duration", "20"],
    )
    assert res.exit_code == 0, res.output
    assert (tmp_path / "w" / "Robot2_Measurement.dat").is_file()
    assert not (tmp_path / "w" / "odometry.csv").exists()
