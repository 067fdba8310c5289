"""An output location that cannot be written fails at once, in one line, with no traceback.

Tests run as root, for whom permission bits do not stop writes, so an unwritable --out is made
by putting it under a regular file (NotADirectoryError for everyone), and permission / full-disk
failures are simulated by making the writability probe raise.
"""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from slamcli import atomic
from slamcli.cli.app import app
from slamcli.errors import ExportError, InputError, SlamcliError
from slamcli.rundir import RunDir
from slamcli.types import OccupancyGrid, Trajectory

ROOT = Path(__file__).resolve().parents[1]
RGBD = ROOT / "sample_data" / "rgbd_room"
LANDMARKS = ROOT / "sample_data" / "landmarks"

runner = CliRunner()


def _flat(text: str) -> str:
    """Output with rich's line wrapping undone."""
    return " ".join(text.split())


def _never(*_args: object, **_kwargs: object) -> None:
    raise AssertionError("work started before --out was checked")


@pytest.fixture
def blocker(tmp_path: Path) -> Path:
    """A regular file: any path under it cannot be created."""
    f = tmp_path / "somefile"
    f.write_text("not a folder\n")
    return f


@pytest.fixture
def no_work(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every command's expensive first step fails the test if it is reached."""
    import slamcli.formats
    import slamcli.formats.mesh
    import slamcli.mapping
    import slamcli.planning.planner
    import slamcli.synth.landmarks
    import slamcli.synth.rgbd

    monkeypatch.setattr(slamcli.formats, "open_source", _never)
    monkeypatch.setattr(slamcli.formats.mesh, "export_mesh", _never)
    monkeypatch.setattr(slamcli.mapping, "build_map", _never)
    monkeypatch.setattr(slamcli.planning.planner, "load_map", _never)
    monkeypatch.setattr(slamcli.synth.rgbd, "build_rgbd_world", _never)
    monkeypatch.setattr(slamcli.synth.landmarks, "simulate_landmark_world", _never)


def _map_file(tmp_path: Path) -> Path:
    from slamcli.formats.occupancy import write_map_npz

    return write_map_npz(tmp_path / "map.npz", OccupancyGrid(np.zeros((20, 20), np.float32), 0.1))


def _commands(tmp_path: Path, out: Path) -> dict[str, list[str]]:
    run_folder = tmp_path / "a_run"
    run_folder.mkdir(exist_ok=True)
    return {
        "run dense": ["run", "dense", str(RGBD), "--max-frames", "3", "--out", str(out)],
        "run ekf": ["run", "ekf", str(LANDMARKS), "--out", str(out)],
        "plan": [
            "plan",
            str(tmp_path / "map.npz"),
            "--start",
            "0.2,0.2",
            "--goal",
            "1.5,1.5",
            "--out",
            str(out),
        ],
        "convert": ["convert", str(LANDMARKS), str(out / "log.mcap")],
        "map build": ["map", "build", str(run_folder), "--out", str(out)],
        "synth rgbd": ["synth", "rgbd", str(out), "--frames", "2"],
        "synth landmarks": ["synth", "landmarks", str(out)],
        "mesh export": ["mesh", "export", str(run_folder), "--out", str(out / "mesh.ply")],
    }


COMMANDS = [
    "run dense",
    "run ekf",
    "plan",
    "convert",
    "map build",
    "synth rgbd",
    "synth landmarks",
    "mesh export",
]


def _no_leftovers(folder: Path) -> None:
    hidden = [p.name for p in folder.iterdir() if p.name.startswith(".")]
    assert hidden == [], f"staging or temporary files left behind: {hidden}"


@pytest.mark.parametrize("command", COMMANDS)
def test_out_under_a_file_fails_before_any_work(
    command: str, tmp_path: Path, blocker: Path, no_work: None
) -> None:
    _map_file(tmp_path)
    out = blocker / "out"
    res = runner.invoke(app, _commands(tmp_path, out)[command])
    text = _flat(res.output)
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)
    assert "error:" in text and str(blocker) in text
    assert "hint:" in text
    _no_leftovers(tmp_path)


def _probe_fails(exc: OSError, monkeypatch: pytest.MonkeyPatch) -> None:
    real = tempfile.mkstemp

    def mkstemp(*args: object, **kwargs: object) -> tuple[int, str]:
        if str(kwargs.get("prefix", "")).startswith(".slamcli-probe-"):
            raise exc
        return real(*args, **kwargs)  # type: ignore[call-overload,no-any-return]

    monkeypatch.setattr(atomic.tempfile, "mkstemp", mkstemp)


@pytest.mark.parametrize(
    ("error", "reason"),
    [
        (errno.EACCES, "Permission denied"),
        (errno.ENOSPC, "No space left on device"),
        (errno.EROFS, "Read-only file system"),
    ],
)
@pytest.mark.parametrize("command", COMMANDS)
def test_unwritable_out_names_the_path_and_the_reason(
    command: str,
    error: int,
    reason: str,
    tmp_path: Path,
    no_work: None,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    _map_file(tmp_path)
    out = tmp_path / "out"
    if command in ("convert", "mesh export"):
        out.mkdir()
    where = tmp_path / "readonly"
    _probe_fails(OSError(error, os.strerror(error), str(where)), monkeypatch)
    res = runner.invoke(app, _commands(tmp_path, out)[command])
    text = _flat(res.output)
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output
    assert f"{where}:" in text and reason in text
    _no_leftovers(tmp_path)
    if command not in ("convert", "mesh export"):
        assert not out.exists()


def test_boundary_turns_any_os_error_into_one_line(tmp_path: Path) -> None:
    import typer

    from slamcli.cli.common import boundary

    target = tmp_path / "deep" / "file.txt"

    @boundary
    def failing() -> None:
        raise PermissionError(errno.EACCES, "Permission denied", str(target))

    @boundary
    def full() -> None:
        raise OSError(errno.ENOSPC, "No space left on device", str(target))

    @boundary
    def anonymous() -> None:
        raise OSError("something odd")

    app_ = typer.Typer()
    app_.command("a")(failing)
    app_.command("b")(full)
    app_.command("c")(anonymous)
    for name, reason in (("a", "Permission denied"), ("b", "No space left on device")):
        res = runner.invoke(app_, [name])
        assert res.exit_code == 1
        assert "Traceback" not in res.output
        assert f"{target}: {reason}" in _flat(res.output)
    res = runner.invoke(app_, ["c"])
    assert res.exit_code == 1 and "something odd" in res.output


def test_os_error_raised_mid_run_reaches_the_user_as_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A failure the pre-check cannot foresee (the disk fills up during writing)."""
    import slamcli.formats.landmark_map

    def full(path: Path, *_args: object) -> Path:
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(slamcli.formats.landmark_map, "write_landmarks_csv", full)
    out = tmp_path / "run"
    res = runner.invoke(app, ["run", "ekf", str(LANDMARKS), "--out", str(out)])
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output
    assert "landmarks.csv: No space left on device" in _flat(res.output)
    assert not out.exists()
    _no_leftovers(tmp_path)


def test_run_dir_check_raises_export_error(tmp_path: Path, blocker: Path) -> None:
    with pytest.raises(ExportError, match="not a folder") as info:
        RunDir(blocker / "out")
    assert info.value.hint
    with pytest.raises(ExportError, match="not a folder"):
        atomic.check_writable_file(blocker / "x.ply")


def test_bad_trajectory_stamps_are_an_input_error() -> None:
    poses = np.tile(np.eye(4), (3, 1, 1))
    with pytest.raises(InputError, match="strictly increasing: pose 2"):
        Trajectory(np.array([1, 5, 5]), poses)
    with pytest.raises(SlamcliError, match="strictly increasing"):
        Trajectory(np.array([3, 2, 1]), poses)
    with pytest.raises(InputError, match=r"\(N,4,4\) poses"):
        Trajectory(np.array([1, 2]), poses)


@pytest.mark.parametrize("command", ["map show", "plan"])
def test_junk_npz_map_says_what_was_expected(command: str, tmp_path: Path) -> None:
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"\x80\x04junk that is no zip archive at all" * 10)
    args = (
        ["map", "show", str(junk)]
        if command == "map show"
        else [
            "plan",
            str(junk),
            "--start",
            "0,0",
            "--goal",
            "1,1",
            "--out",
            str(tmp_path / "p"),
        ]
    )
    res = runner.invoke(app, args)
    text = _flat(res.output)
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output
    assert str(junk) in text
    assert "slamcli occupancy grid" in text and "prob" in text and "resolution_m" in text
    assert "pickled" not in text
    assert not (tmp_path / "p").exists()
    _no_leftovers(tmp_path)


def test_map_build_into_its_run_folder_checks_the_folder_first(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import slamcli.mapping.output

    run_folder = tmp_path / "a_run"
    run_folder.mkdir()
    (run_folder / "run.json").write_text("{}")
    monkeypatch.setattr(slamcli.mapping.output, "build_map", _never)
    _probe_fails(OSError(errno.EROFS, os.strerror(errno.EROFS), str(run_folder)), monkeypatch)
    res = runner.invoke(app, ["map", "build", str(run_folder)])
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output
    assert f"{run_folder}: cannot write (Read-only file system)" in _flat(res.output)
    assert sorted(p.name for p in run_folder.iterdir()) == ["run.json"]


def test_os_error_hint_follows_the_reason(tmp_path: Path) -> None:
    from slamcli.cli.common import os_error

    p = str(tmp_path / "x")
    full = os_error(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), p))
    assert isinstance(full, ExportError) and "--out" in (full.hint or "")
    denied = os_error(PermissionError(errno.EACCES, os.strerror(errno.EACCES), p))
    assert isinstance(denied, InputError) and "permissions" in (denied.hint or "")
    missing = os_error(FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), p))
    assert isinstance(missing, InputError) and missing.hint is None
    assert missing.msg == f"{p}: {os.strerror(errno.ENOENT)}"
    moved = os_error(OSError(errno.EXDEV, os.strerror(errno.EXDEV), p, None, p + "2"))
    assert moved.msg.startswith(f"{p} -> {p}2: ")
