"""``slamcli run graph``: factor-graph landmark SLAM, one robot and several, on the shared data."""

from __future__ import annotations

import json
import shlex
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import ConfigError
from slamcli.formats.landmarks import MrclamSource
from slamcli.pipelines import PIPELINES
from slamcli.pipelines.graph import GraphConfig
from slamcli.run import run_pipeline
from tests.conftest import shared_path

runner = CliRunner()


def _ate(run: Path) -> float:
    return float(json.loads((run / "run.json").read_text())["metrics"]["evaluation"]["ate"]["rmse"])


def test_help_example_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    repo = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(repo)
    args = shlex.split(PIPELINES["graph"].example)[1:]
    out = tmp_path / "example"
    args[args.index("--out") + 1] = str(out)
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert {"trajectory.tum", "landmarks.csv", "report.png", "run.json"} <= {
        p.name for p in out.iterdir()
    }
    assert _ate(out) < 0.1


def test_single_robot_beats_the_ekf_and_is_deterministic(tmp_path: Path) -> None:
    folder = shared_path("landmarks", "MRCLAM_Dataset6")
    a = run_pipeline(folder, "graph", tmp_path / "a", source_options={"robot": 1})
    b = run_pipeline(folder, "graph", tmp_path / "b", source_options={"robot": 1})
    # The EKF's smoothed path scores 0.153 m on robot 1 (README).
    assert _ate(tmp_path / "a") < 0.13
    assert a.counts["landmarks"] == 15
    assert (tmp_path / "a" / "trajectory.tum").read_bytes() == (
        tmp_path / "b" / "trajectory.tum"
    ).read_bytes()
    assert b.counts == a.counts


def test_batch_solver_matches_isam2_accuracy(tmp_path: Path) -> None:
    folder = shared_path("landmarks", "MRCLAM_Dataset6")
    run_pipeline(
        folder,
        "graph",
        tmp_path / "batch",
        config=GraphConfig(solver="batch"),
        source_options={"robot": 4},
    )
    assert _ate(tmp_path / "batch") < 0.16


def test_victoria_park_without_ids(tmp_path: Path) -> None:
    path = shared_path("landmarks", "victoria_park.txt")
    out = run_pipeline(
        path, "graph", tmp_path / "vp", source_options={"ignore_ids": True}, max_frames=3000
    )
    assert out.metrics["association"] == "nn"
    assert 10 <= out.counts["landmarks"] <= 200
    assert out.counts["updates"] > 0.8 * out.counts["observations"]


@pytest.mark.parametrize(
    ("robot", "match"),
    [("0", "no robot 0"), ("1,9", "no robot 9"), ("1,1", "twice"), ("one", "not a robot")],
)
def test_bad_robot_selection_is_a_config_error(robot: str, match: str) -> None:
    folder = shared_path("landmarks", "MRCLAM_Dataset6")
    with pytest.raises(ConfigError, match=match):
        MrclamSource(folder, robot=robot)


def test_bad_robot_on_the_command_line(tmp_path: Path) -> None:
    folder = shared_path("landmarks", "MRCLAM_Dataset6")
    result = runner.invoke(
        app, ["run", "graph", str(folder), "--robot", "1,7", "--out", str(tmp_path / "r")]
    )
    assert result.exit_code == 1
    assert "no robot 7" in result.output


def test_joint_five_robots_in_one_frame(tmp_path: Path) -> None:
    folder = shared_path("landmarks", "MRCLAM_Dataset6")
    out = run_pipeline(folder, "graph", tmp_path / "all", source_options={"robot": "all"})
    robots = out.metrics["robots"]["per_robot"]
    common = [robots[str(r)]["ate_common"]["rmse"] for r in range(1, 6)]
    assert max(common) <= 0.15
    assert float(np.mean(common)) <= 0.10
    for r in range(1, 6):
        assert (tmp_path / "all" / f"trajectory_robot{r}.tum").is_file()
    assert out.counts["robots_placed"] == 4
    assert out.counts["factors_robot"] > 0
