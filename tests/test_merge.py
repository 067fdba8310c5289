"""``slamcli merge``: EKF maps of separate runs joined into one frame."""

from __future__ import annotations

import json
import math
import shlex
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import typer
from conftest import shared_path
from typer.testing import CliRunner

from slamcli.cli.merge import HELP, register
from slamcli.errors import ConfigError, InputError
from slamcli.formats.landmark_map import write_landmarks_csv
from slamcli.formats.trajectory import write_tum
from slamcli.geometry import planar_to_se3
from slamcli.graphs.merge import MergeConfig, load_runs, merge, merge_runs
from slamcli.run import run_pipeline
from slamcli.synth.landmarks import generate_landmark_world
from slamcli.types import LandmarkMap, Trajectory

runner = CliRunner()


def _app() -> typer.Typer:
    app = typer.Typer()
    register(app)

    @app.command("noop")
    def noop() -> None:
        """A second command, so that typer keeps ``merge`` as a sub-command."""

    return app


def _rot(yaw: float) -> np.ndarray:
    return np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])


FIELD = np.random.default_rng(11).uniform(-10, 10, (30, 2))


def _fake_run(
    folder: Path,
    world_from_run: tuple[float, float, float],
    ids: np.ndarray,
    *,
    robot: int,
    known_ids: bool = True,
    seed: int = 0,
    field: np.ndarray = FIELD,
) -> Path:
    """A run folder whose landmarks are ``field[ids]`` seen in a frame at ``world_from_run``."""
    rng = np.random.default_rng(seed)
    x, y, yaw = world_from_run
    local = (field[ids] - [x, y]) @ _rot(yaw) + rng.normal(0, 0.03, (len(ids), 2))
    cov = np.broadcast_to(np.eye(2) * 0.03**2, (len(ids), 2, 2)).copy()
    order = rng.permutation(len(ids))
    out_ids = ids if known_ids else np.arange(len(ids)) + 100 * robot
    folder.mkdir(parents=True)
    write_landmarks_csv(
        folder / "landmarks.csv", LandmarkMap(out_ids[order], local[order], cov[order])
    )
    t = np.linspace(0, 1, 20)
    path = np.column_stack([3 * np.cos(6 * t), 3 * np.sin(6 * t), 6 * t + np.pi / 2])
    stamps = (1_000_000_000 * (1 + np.arange(20))).astype(np.int64)
    write_tum(folder / "trajectory.tum", Trajectory(stamps, planar_to_se3(path)))
    record = {
        "pipeline": "ekf",
        "config": {"source": {"robot": robot}},
        "metrics": {"association": "known" if known_ids else "nn"},
    }
    (folder / "run.json").write_text(json.dumps(record))
    return folder


TRUE = [(0.0, 0.0, 0.0), (3.0, -2.0, 0.7), (-4.0, 5.0, -2.2)]
# A chain: run 1 overlaps runs 0 and 2, runs 0 and 2 share nothing.
SEEN = [np.arange(0, 14), np.arange(8, 24), np.arange(18, 30)]


def _relative(pose: tuple[float, float, float]) -> np.ndarray:
    """world_from_run in run 0's frame (run 0's true pose is the identity)."""
    return np.array(pose)


def _chain(tmp_path: Path, known_ids: bool) -> list[Path]:
    return [
        _fake_run(tmp_path / f"run{k}", TRUE[k], SEEN[k], robot=k + 1, known_ids=known_ids, seed=k)
        for k in range(3)
    ]


@pytest.mark.parametrize("known_ids", [True, False], ids=["ids", "constellation"])
def test_known_transforms_are_recovered_through_a_chain(tmp_path: Path, known_ids: bool) -> None:
    result = merge(load_runs(_chain(tmp_path, known_ids)))
    assert result.connected.all()
    for k in range(3):
        got = result.world_from_run[k]
        np.testing.assert_allclose(got[:2], TRUE[k][:2], atol=0.05)
        assert abs(math.remainder(got[2] - TRUE[k][2], 2 * math.pi)) < math.radians(0.5)
    by_pair = {(f.a, f.b): f for f in result.pairs}
    assert by_pair[(0, 1)].connected and by_pair[(1, 2)].connected
    assert not by_pair[(0, 2)].connected
    assert by_pair[(0, 1)].method == ("ids" if known_ids else "constellation")
    assert len(by_pair[(0, 1)].pairs) == 6 and len(by_pair[(1, 2)].pairs) == 6
    assert len(result.landmarks) == 30
    if known_ids:
        np.testing.assert_array_equal(np.sort(result.landmarks.ids), np.arange(30))
        order = np.argsort(result.landmarks.ids)
        np.testing.assert_allclose(result.landmarks.xy[order], FIELD, atol=0.2)
    assert np.nanmax(result.residual_rms_m) < 0.1


def test_the_ransac_matching_is_seeded(tmp_path: Path) -> None:
    runs = load_runs(_chain(tmp_path, known_ids=False))
    config = MergeConfig(max_hypotheses=50, seed=3)
    a, b = merge(runs, config), merge(runs, config)
    np.testing.assert_array_equal(a.world_from_run, b.world_from_run)


def test_a_run_sharing_no_landmarks_is_left_out(tmp_path: Path) -> None:
    paths = _chain(tmp_path, known_ids=True)
    elsewhere = np.random.default_rng(5).uniform(40, 60, (12, 2))
    paths.append(
        _fake_run(
            tmp_path / "lone",
            (1.0, 1.0, 0.3),
            np.arange(12) + 50,
            robot=7,
            field=np.vstack([FIELD, np.zeros((20, 2)), elsewhere]),
        )
    )
    res = runner.invoke(_app(), ["merge", *map(str, paths), "--out", str(tmp_path / "m")])
    assert res.exit_code == 3, res.output
    assert "lone" in res.stderr and "left out" in res.stderr
    record = json.loads((tmp_path / "m" / "run.json").read_text())
    assert record["unconnected"] == ["robot7"]
    assert [r["connected"] for r in record["runs"]] == [True, True, True, False]
    written = sorted(p.name for p in (tmp_path / "m").glob("trajectory_*.tum"))
    assert written == ["trajectory_robot1.tum", "trajectory_robot2.tum", "trajectory_robot3.tum"]


def test_bad_inputs_name_the_folder(tmp_path: Path) -> None:
    good = _fake_run(tmp_path / "good", TRUE[0], SEEN[0], robot=1)
    plain = tmp_path / "plain"
    plain.mkdir()
    with pytest.raises(InputError, match="plain: not a run folder"):
        load_runs([good, plain])
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "run.json").write_text(json.dumps({"pipeline": "dense"}))
    with pytest.raises(
        InputError, match=r"bare: a run folder of the dense pipeline without landmarks"
    ):
        load_runs([good, bare])
    with pytest.raises(InputError, match="at least two"):
        load_runs([good])
    res = runner.invoke(_app(), ["merge", str(good), str(bare), "--out", str(tmp_path / "m")])
    assert res.exit_code == 1
    assert "bare" in res.stderr
    assert not (tmp_path / "m").exists()


@pytest.mark.parametrize(
    ("setting", "pattern"),
    [
        ({"match": "nearest"}, r'^--match: expected one of "auto", "ids", "constellation"'),
        ({"inlier_m": 0.0}, r"^--inlier-m: expected a number > 0 \(m\), got 0\.0$"),
        ({"sigma_floor_m": math.nan}, r"^sigma_floor_m: expected a number > 0 \(m\), got nan$"),
        ({"min_common_ids": 1}, r"^min_common_ids: expected an integer >= 2, got 1$"),
        ({"min_inliers": 2}, r"^min_inliers: expected an integer >= 3, got 2$"),
        ({"max_hypotheses": 0}, r"^max_hypotheses: expected an integer >= 1, got 0$"),
    ],
)
def test_bad_settings_name_the_option_and_range(setting: dict[str, object], pattern: str) -> None:
    with pytest.raises(ConfigError, match=pattern):
        MergeConfig(**setting).check()  # type: ignore[arg-type]


def test_help_example_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    examples = [" ".join(line.split()) for line in HELP.split("[bold]")[1:]]
    assert len(examples) == 1
    command = shlex.split(examples[0].split("[/]")[0])
    assert command[:2] == ["slamcli", "merge"]
    monkeypatch.chdir(tmp_path)
    generate_landmark_world("runs/world3", seed=1, duration_s=30.0, robots=3)
    for k in (1, 2, 3):
        run_pipeline("runs/world3", "ekf", f"runs/world3_r{k}", source_options={"robot": k})
    res = runner.invoke(_app(), command[1:])
    assert res.exit_code == 0, res.output
    record = json.loads(Path("runs/merged/run.json").read_text())
    assert record["unconnected"] == []
    ev = record["metrics"]["evaluation"]
    assert set(ev["per_run"]) == {"robot1", "robot2", "robot3"}
    assert ev["all"]["rmse"] < 0.15
    assert {"rmse", "mean", "median", "max"} <= ev["all"].keys()
    for run in ev["per_run"].values():
        assert run["matched"] > 100 and run["ate"]["rmse"] < run["ate_unaligned"]["rmse"]
    assert ev["mean_of_rmse_m"] == np.mean([v["ate"]["rmse"] for v in ev["per_run"].values()])
    assert ev["alignment"].keys() == {"x_m", "y_m", "yaw_deg"}
    for name in ("landmarks.csv", "report.png", "trajectory_robot3.tum"):
        assert Path("runs/merged", name).is_file()


@pytest.mark.slow
def test_mrclam_five_robots_merge_into_one_frame(tmp_path: Path, shared_run: Any) -> None:
    data = shared_path("landmarks", "MRCLAM_Dataset6")
    runs = []
    for robot in range(1, 6):
        # Once per session: test_ekf scores the same runs.
        run = shared_run("run", "ekf", data, "--robot", str(robot))
        assert run.exit_code == 0, run.output
        runs.append(run.out)
    result = merge_runs(runs, tmp_path / "merged")
    assert result.connected.all()
    assert all(f.connected and f.method == "ids" for f in result.pairs)
    ev = result.evaluation
    assert set(ev["per_run"]) == {f"robot{k}" for k in range(1, 6)}
    assert ev["all"]["mean"] <= 0.20
    assert ev["mean_of_rmse_m"] <= 0.20
    assert max(v["ate"]["rmse"] for v in ev["per_run"].values()) <= 0.25
