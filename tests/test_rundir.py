"""Run directories: refusing to clobber, atomic writes, run.json contents."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from slamcli import __version__
from slamcli.atomic import atomic_path
from slamcli.errors import ExportError, InputError
from slamcli.rundir import RUN_SCHEMA_VERSION, RunDir, Timings, hash_input


def test_refuses_non_empty_folder_without_force(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "old.txt").write_text("keep me")
    with pytest.raises(ExportError, match="not empty") as info:
        RunDir(out)
    assert "--force" in (info.value.hint or "")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_force_replaces_the_whole_folder_once_the_new_one_is_complete(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "old.txt").write_text("earlier run")
    with RunDir(out, force=True) as run:
        run.write_text("new.txt", "x")
        assert (out / "old.txt").read_text() == "earlier run"
        assert not (out / "new.txt").exists()
    assert sorted(p.name for p in out.iterdir()) == ["new.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_refuses_a_file_as_output_folder(tmp_path: Path) -> None:
    f = tmp_path / "file"
    f.write_text("")
    with pytest.raises(ExportError, match="not a folder"):
        RunDir(f)


def test_failed_write_leaves_the_earlier_file_untouched(tmp_path: Path) -> None:
    dest = tmp_path / "trajectory.tum"
    dest.write_text("earlier result\n")
    with pytest.raises(RuntimeError), atomic_path(dest) as tmp:
        tmp.write_text("half a resu")
        raise RuntimeError("interrupted")
    assert dest.read_text() == "earlier result\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["trajectory.tum"]


def test_atomic_temp_file_keeps_the_suffix(tmp_path: Path) -> None:
    with atomic_path(tmp_path / "plot.png") as tmp:
        assert tmp.suffix == ".png"
        assert tmp.parent == tmp_path
        tmp.write_bytes(b"png")
    assert (tmp_path / "plot.png").read_bytes() == b"png"


def test_run_json_records_inputs_outputs_and_timings(tmp_path: Path) -> None:
    data = tmp_path / "input.txt"
    data.write_bytes(b"0123456789")
    with RunDir(tmp_path / "run") as run:
        run.write_text("trajectory.tum", "1.0 0 0 0 0 0 0 1\n")
        timings = Timings()
        with timings.stage("read"):
            pass
        run.write_run_json(
            command="test",
            inputs=[hash_input(data)],
            config={"a": 1},
            seeds={"numpy": 7},
            timings=timings,
            counts={"frames": 3},
            metrics={"ate_rmse_m": 0.1},
        )
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["schema_version"] == RUN_SCHEMA_VERSION
    assert record["slamcli_version"] == __version__
    assert record["outputs"] == ["trajectory.tum", "run.json"]
    assert record["inputs"][0]["bytes"] == 10
    assert record["inputs"][0]["hash"] == "sha256:" + hashlib.sha256(b"0123456789").hexdigest()
    assert record["seeds"] == {"numpy": 7}
    assert record["counts"] == {"frames": 3}
    assert set(record["timings_s"]) == {"read"}
    assert "numpy" in record["packages"]


def test_hash_of_a_folder_depends_on_names_and_contents(tmp_path: Path) -> None:
    a = tmp_path / "a"
    a.mkdir()
    (a / "x.txt").write_text("1")
    first = hash_input(a)
    (a / "x.txt").write_text("2")
    second = hash_input(a)
    assert first["files"] == 1 and first["kind"] == "folder"
    assert first["hash"] != second["hash"]
    with pytest.raises(InputError, match="no such file"):
        hash_input(tmp_path / "missing")


def test_outputs_get_ordinary_permissions(tmp_path: Path) -> None:
    import os

    mask = os.umask(0o022)
    os.umask(mask)
    with RunDir(tmp_path / "run") as run:
        path = run.write_text("a.txt", "x")
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask
    assert path.parent.stat().st_mode & 0o777 == 0o777 & ~mask
