"""slamcli.convert.convert: one call chooses what to write from the input and OUT's suffix."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.cli.convert import HELP
from slamcli.convert import ConvertResult, convert
from slamcli.errors import ConfigError, InputError
from slamcli.formats.mcap import write as mw
from slamcli.formats.trajectory import read_trajectory, write_tum
from slamcli.types import Trajectory

REPO = Path(__file__).resolve().parents[1]
LANDMARKS = REPO / "sample_data" / "landmarks"
ROOM = REPO / "sample_data" / "rgbd_room"
runner = CliRunner()


def _run_folder(folder: Path, pipeline: str = "dense") -> Path:
    folder.mkdir(parents=True)
    stamps = 1_600_000_000_000_000_000 + np.arange(4, dtype=np.int64) * 50_000_000
    poses = np.tile(np.eye(4), (4, 1, 1))
    poses[:, 0, 3] = np.arange(4)
    write_tum(folder / "trajectory.tum", Trajectory(stamps, poses))
    record = {"command": f"run {pipeline}", "config": {pipeline: {}, "source": {}}}
    (folder / "run.json").write_text(json.dumps(record), encoding="utf-8")
    return folder


def test_a_run_folder_becomes_a_result_log(tmp_path: Path) -> None:
    run = _run_folder(tmp_path / "run")
    result = convert(run, tmp_path / "result.mcap")
    assert isinstance(result, ConvertResult) and result.kind == "run"
    assert result.summary is not None
    assert result.summary.topics[mw.TOPIC_RESULT_POSE] == ("foxglove.PoseInFrame", 4)
    with pytest.raises(ConfigError, match="--flavor ros2 is for RGB-D inputs, not run folders"):
        convert(run, tmp_path / "other.mcap", flavor="ros2")


def test_a_landmark_folder_becomes_a_landmark_log(tmp_path: Path) -> None:
    result = convert(LANDMARKS, tmp_path / "lm.mcap", flavor="foxglove")
    assert result.kind == "landmarks" and result.summary is not None
    assert {mw.TOPIC_ODOM, mw.TOPIC_LANDMARKS} <= set(result.summary.topics)
    with pytest.raises(ConfigError, match="--compress-images is for RGB-D inputs"):
        convert(LANDMARKS, tmp_path / "x.mcap", compress_images="jpeg")


def test_a_source_becomes_an_rgbd_log(tmp_path: Path) -> None:
    result = convert(ROOM, tmp_path / "room.mcap", max_frames=2)
    assert result.kind == "source" and result.summary is not None
    assert result.summary.frames == 2 and result.skipped == 0


def test_a_pose_topic_becomes_a_trajectory(tmp_path: Path) -> None:
    log = convert(LANDMARKS, tmp_path / "lm.mcap").out
    out = tmp_path / "gt.tum"
    result = convert(log, out, source_options={"gt_topic": mw.TOPIC_GROUND_TRUTH})
    assert result.kind == "trajectory" and result.summary is None
    assert result.poses == len(read_trajectory(out, "tum")) > 0
    assert result.poses_from == mw.TOPIC_GROUND_TRUTH
    with pytest.raises(ConfigError, match="export a trajectory"):
        convert(log, tmp_path / "x.mcap", source_options={"gt_topic": "/ground_truth"})


def test_a_folder_of_runs_names_its_runs(tmp_path: Path) -> None:
    demo = tmp_path / "demo"
    _run_folder(demo / "dense")
    _run_folder(demo / "ekf", "ekf")
    with pytest.raises(InputError, match=r"holds 2 runs \(dense, ekf\)"):
        convert(demo, demo / "result.mcap")
    res = runner.invoke(app, ["convert", str(demo), str(demo / "result.mcap")])
    assert res.exit_code == 1 and "dense, ekf" in res.output
    assert not (demo / "result.mcap").exists()


def test_the_help_example_for_run_folders_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The --help example converts a run of 'slamcli demo --out runs/demo'."""
    (example,) = re.findall(r"\[bold\](slamcli convert runs/demo\S*[^[]*)\[/\]", HELP)
    args = shlex.split(example)[1:]
    monkeypatch.chdir(tmp_path)
    _run_folder(Path(args[1]))
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert Path(args[2]).is_file()
