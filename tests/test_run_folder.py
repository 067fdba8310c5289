"""read_run: what a run folder holds, which pipeline made it, and the errors for folders that
are not one run."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from slamcli.errors import FormatError, InputError
from slamcli.formats.run_folder import RunRecord, is_run_dir, read_run, sub_runs
from slamcli.formats.trajectory import write_tum
from slamcli.types import Trajectory

REPO = Path(__file__).resolve().parents[1]
LANDMARKS = REPO / "sample_data" / "landmarks"


def _trajectory() -> Trajectory:
    stamps = 1_600_000_000_000_000_000 + np.arange(3, dtype=np.int64) * 100_000_000
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 0, 3] = np.arange(3)
    return Trajectory(stamps, poses)


def _dense_run(folder: Path, record: dict | None = None) -> Path:
    """A dense run folder as 'slamcli run dense' writes it (mesh and points left out)."""
    folder.mkdir(parents=True)
    write_tum(folder / "trajectory.tum", _trajectory())
    write_tum(folder / "keyframes.tum", _trajectory())
    if record is None:
        record = {
            "command": "run dense",
            "inputs": [{"path": str(REPO / "sample_data" / "rgbd_room")}],
            "config": {"dense": {"voxel_m": 0.01}, "source": {"max_dt": 0.03}},
        }
    (folder / "run.json").write_text(json.dumps(record), encoding="utf-8")
    return folder


@pytest.fixture(scope="module")
def ekf_run(shared_run: Any) -> Path:
    """``slamcli run ekf`` on the sample landmark world, made once per session."""
    run = shared_run("run", "ekf", LANDMARKS)
    assert run.exit_code == 0, run.output
    return Path(run.out)


def test_a_dense_run_folder(tmp_path: Path) -> None:
    run = read_run(_dense_run(tmp_path / "dense"))
    assert isinstance(run, RunRecord)
    assert run.pipeline == "dense"
    assert set(run.files) == {"trajectory", "keyframes"}
    assert run.has("trajectory") and not run.has("landmarks")
    assert run.source_options == {"max_dt": 0.03}
    assert run.input_path() == REPO / "sample_data" / "rgbd_room"
    assert len(run.trajectory()) == 3
    result = run.result()
    assert result.trajectory is not None and result.mesh is None and result.grid is None
    with pytest.raises(InputError, match=r"dense pipeline without mesh\.ply"):
        run.mesh()


def test_an_ekf_run_folder(ekf_run: Path) -> None:
    run = read_run(ekf_run)
    assert run.pipeline == "ekf"
    assert {"trajectory", "landmarks"} <= set(run.files)
    assert not run.has("mesh")
    assert len(run.landmarks()) == 40
    assert run.input_path() == LANDMARKS


def test_the_pipeline_key_wins_over_command_and_config(tmp_path: Path) -> None:
    record = {"pipeline": "odometry", "command": "run dense", "config": {"dense": {}}}
    assert read_run(_dense_run(tmp_path / "a", record)).pipeline == "odometry"
    # 'slamcli demo' records its command as "demo": the config's one pipeline section says.
    record = {"command": "demo", "config": {"ekf": {}, "source": {}}}
    assert read_run(_dense_run(tmp_path / "b", record)).pipeline == "ekf"
    assert read_run(_dense_run(tmp_path / "c", {})).pipeline is None


def test_a_folder_without_run_json(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("hello")
    assert not is_run_dir(tmp_path)
    with pytest.raises(InputError, match=r"not a run folder \(no run\.json\)") as err:
        read_run(tmp_path)
    assert str(tmp_path) in err.value.msg
    with pytest.raises(InputError, match="no such run folder"):
        read_run(tmp_path / "missing")
    with pytest.raises(InputError, match="is a file"):
        read_run(tmp_path / "notes.txt")


@pytest.mark.parametrize(
    ("text", "match"),
    [("{ not json", r"run\.json:1: not valid JSON"), ("[1, 2]", "expected a JSON object")],
)
def test_a_broken_run_json(tmp_path: Path, text: str, match: str) -> None:
    (tmp_path / "run.json").write_text(text)
    with pytest.raises(FormatError, match=match) as err:
        read_run(tmp_path)
    assert err.value.path == tmp_path / "run.json"


def test_a_folder_of_runs_names_them(tmp_path: Path) -> None:
    """'slamcli demo --out runs/demo' writes dense/, plan/ and ekf/: two of them are runs."""
    _dense_run(tmp_path / "dense")
    _dense_run(tmp_path / "ekf", {"command": "demo", "config": {"ekf": {}}})
    (tmp_path / "plan").mkdir()
    (tmp_path / "plan" / "plan.json").write_text("{}")
    assert sub_runs(tmp_path) == ["dense", "ekf"]
    with pytest.raises(InputError, match=r"holds 2 runs \(dense, ekf\), not one run folder") as e:
        read_run(tmp_path)
    assert e.value.hint is not None and str(tmp_path / "dense") in e.value.hint
