"""``slamcli info`` on inputs that are not logs: maps, trajectory files and g2o pose graphs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import shared_path
from typer.testing import CliRunner

from slamcli.cli.app import app

runner = CliRunner()


def _info(*args: str) -> str:
    res = runner.invoke(app, ["info", *args])
    assert res.exit_code == 0, res.output
    return res.stdout


def test_map_as_text_and_json() -> None:
    path = shared_path("maps", "turtlebot3_world.yaml")
    assert "384 x 384 cells" in _info(str(path))
    d = json.loads(_info(str(path), "--json"))
    assert d["kind"] == "map"
    assert (d["width"], d["height"], d["resolution_m"]) == (384, 384, 0.05)
    assert d["free"] + d["occupied"] + d["unknown"] == 384 * 384


def test_trajectory_files() -> None:
    tum = json.loads(
        _info(str(shared_path("trajectories", "freiburg1_xyz-groundtruth.txt")), "--json")
    )
    assert tum["kind"] == "trajectory" and tum["format"] == "tum"
    assert tum["poses"] == 3000
    assert tum["span_s"] == pytest.approx(30.09, abs=0.01)
    assert tum["rate_hz"] == pytest.approx(99.7, abs=0.1)
    assert 5 < tum["path_length_m"] < 15
    kitti = _info(str(shared_path("trajectories", "KITTI_00_gt.txt")))
    assert "kitti" in kitti and "4541" in kitti and "not timed" in kitti


def test_pose_graph() -> None:
    d = json.loads(_info(str(shared_path("pose_graphs", "intel.g2o")), "--json"))
    assert d["kind"] == "pose graph" and d["dimension"] == "2-D"
    assert (d["vertices"], d["edges"], d["loop_closure_edges"]) == (1728, 2512, 785)
    assert "loop closures" in _info(str(shared_path("pose_graphs", "sphere2500.g2o")))


def test_malformed_pose_graph_names_the_line(tmp_path: Path) -> None:
    f = tmp_path / "bad.g2o"
    f.write_text("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0\n")
    res = runner.invoke(app, ["info", str(f)])
    assert res.exit_code == 1
    assert "bad.g2o:2: EDGE_SE2 has 2 id(s) and 9 values" in res.output


def test_unrecognised_input_hint_names_what_else_info_reads(tmp_path: Path) -> None:
    res = runner.invoke(app, ["info", str(tmp_path)])
    assert res.exit_code == 1
    assert "not a recognised input" in res.stderr
    hint = next(line for line in res.stderr.splitlines() if line.startswith("hint:"))
    assert "known formats:" in hint and "tum" in hint
    assert "maps" in hint and ".g2o" in hint and ".kitti" in hint
