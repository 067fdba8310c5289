"""A run folder is all or nothing: interrupted runs leave nothing, or the earlier folder intact.

The SIGINT test starts real ``slamcli run ekf`` processes and interrupts them at chosen moments:
when the staging folder appears (the run is starting), when its first file appears (the run is
writing) and at fixed delays after the staging folder appeared (the run is computing). The
--force variants run over an earlier complete folder, which must come out byte-identical unless
the new run completed.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from slamcli.errors import ExportError
from slamcli.rundir import RunDir

ROOT = Path(__file__).resolve().parents[1]
LANDMARKS = ROOT / "sample_data" / "landmarks"
OLD_RECORD = {"schema_version": 1, "outputs": ["trajectory.tum", "report.png", "run.json"]}


def _staging(parent: Path, name: str) -> list[Path]:
    return [p for p in parent.iterdir() if p.name.startswith(f".{name}.staging-")]


def _hidden(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if p.name.startswith("."))


def _write_old_run(out: Path) -> bytes:
    """A complete earlier run folder; returns its run.json bytes."""
    out.mkdir()
    (out / "trajectory.tum").write_text("1.0 0 0 0 0 0 0 1\n")
    (out / "report.png").write_bytes(b"old png")
    data = (json.dumps(OLD_RECORD, indent=2) + "\n").encode()
    (out / "run.json").write_bytes(data)
    return data


def _assert_complete(out: Path) -> None:
    record = json.loads((out / "run.json").read_text())
    listed = set(record["outputs"])
    present = {p.name for p in out.iterdir()}
    assert listed == present, f"run.json lists {sorted(listed)}, folder has {sorted(present)}"


# --- RunDir in-process ------------------------------------------------------------------------


def test_nothing_appears_until_commit(tmp_path: Path) -> None:
    out = tmp_path / "run"
    with RunDir(out) as run:
        path = run.write_text("a.txt", "x")
        assert path == out / "a.txt"
        assert not out.exists()
        assert run.staging.parent == tmp_path and run.staging.name.startswith(".run.staging-")
        assert (run.staging / "a.txt").read_text() == "x"
    assert (out / "a.txt").read_text() == "x"
    assert _hidden(tmp_path) == []


@pytest.mark.parametrize("error", [RuntimeError("boom"), KeyboardInterrupt()])
def test_failure_leaves_the_earlier_folder_untouched(tmp_path: Path, error: BaseException) -> None:
    out = tmp_path / "run"
    old = _write_old_run(out)
    with pytest.raises(type(error)), RunDir(out, force=True) as run:
        run.write_text("trajectory.tum", "new")
        run.write_text("run.json", "{}")
        raise error
    assert (out / "run.json").read_bytes() == old
    assert (out / "trajectory.tum").read_text() == "1.0 0 0 0 0 0 0 1\n"
    assert _hidden(tmp_path) == []


def test_failure_in_a_new_nested_out_leaves_no_folders(tmp_path: Path) -> None:
    out = tmp_path / "a" / "b" / "run"
    with pytest.raises(RuntimeError), RunDir(out) as run:
        run.write_text("x.txt", "x")
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_failed_swap_puts_the_old_folder_back(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "run"
    old = _write_old_run(out)
    run = RunDir(out, force=True)
    run.write_text("run.json", "{}")
    real = Path.replace

    def replace(self: Path, target: Path) -> Path:
        if self == run.staging:
            raise OSError(28, "No space left on device", str(self))
        return real(self, target)

    monkeypatch.setattr(Path, "replace", replace)
    with pytest.raises(ExportError, match="No space left"):
        run.commit()
    assert (out / "run.json").read_bytes() == old
    assert _hidden(tmp_path) == []


def test_stale_staging_of_a_killed_process_is_removed(tmp_path: Path) -> None:
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        text=True,
        capture_output=True,
        check=True,
    )
    pid = int(dead.stdout)
    stale = tmp_path / f".run.staging-{pid}-abc123"
    stale.mkdir()
    (stale / "trajectory.tum").write_text("half")
    other = tmp_path / f".other.staging-{pid}-abc123"
    other.mkdir()
    with RunDir(tmp_path / "run") as run:
        run.write_text("a.txt", "x")
    assert _hidden(tmp_path) == [other.name]


def test_an_old_folder_set_aside_by_a_killed_commit_comes_back(tmp_path: Path) -> None:
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        text=True,
        capture_output=True,
        check=True,
    )
    aside = tmp_path / f".run.old-{int(dead.stdout)}-xyz"
    old = _write_old_run(aside)
    with pytest.raises(ExportError, match="not empty"):
        RunDir(tmp_path / "run")
    assert (tmp_path / "run" / "run.json").read_bytes() == old


def test_refuses_to_replace_the_working_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "precious.txt").write_text("x")
    monkeypatch.chdir(tmp_path)
    for out in (".", str(tmp_path), ".."):
        with pytest.raises(ExportError, match="working directory"):
            RunDir(out, force=True)
    assert (tmp_path / "precious.txt").exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.chdir(empty)
    with pytest.raises(ExportError, match="working directory"):
        RunDir(".")
    assert _hidden(tmp_path) == [] and _hidden(empty) == []


# --- real processes, real SIGINT --------------------------------------------------------------


@dataclass
class Case:
    name: str
    force: bool
    trigger: str  # "staging", "writing" or seconds after the staging folder appears


CASES = [
    Case("fresh-at-staging", False, "staging"),
    Case("fresh-while-writing", False, "writing"),
    Case("force-at-staging", True, "staging"),
    Case("force-while-writing", True, "writing"),
    Case("fresh-0.5s-into-work", False, "0.5"),
    Case("force-1.5s-into-work", True, "1.5"),
]


def _due(case: Case, parent: Path, name: str) -> Callable[[], bool]:
    def staged_files() -> list[str]:
        names: list[str] = []
        for folder in _staging(parent, name):
            with contextlib.suppress(FileNotFoundError):
                names += [p.name for p in folder.iterdir() if not p.name.startswith(".slamcli-")]
        return names

    if case.trigger == "staging":
        return lambda: bool(_staging(parent, name))
    if case.trigger == "writing":
        return lambda: bool(staged_files())
    delay = float(case.trigger)
    seen: list[float] = []

    def after_staging() -> bool:
        if not seen and _staging(parent, name):
            seen.append(time.monotonic())
        return bool(seen) and time.monotonic() - seen[0] >= delay

    return after_staging


@pytest.mark.skipif(os.name != "posix", reason="SIGINT delivery as on POSIX")
def test_sigint_leaves_nothing_or_the_old_folder_or_a_complete_one(tmp_path: Path) -> None:
    from slamcli.synth.landmarks import generate_landmark_world

    # A 30 s world instead of the 120 s sample: the same files, an EKF run a quarter as long.
    world = tmp_path / "world"
    generate_landmark_world(world, duration_s=30.0)
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200"}
    procs = []
    for case in CASES:
        parent = tmp_path / case.name
        parent.mkdir()
        out = parent / "out"
        old = _write_old_run(out) if case.force else None
        args = [sys.executable, "-m", "slamcli", "run", "ekf", str(world), "--out", str(out)]
        if case.force:
            args.append("--force")
        proc = subprocess.Popen(
            args, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        procs.append((case, proc, parent, out, old, _due(case, parent, "out"), [False]))

    deadline = time.monotonic() + 120
    while any(proc.poll() is None and not sent[0] for _, proc, *_rest, sent in procs):
        assert time.monotonic() < deadline, "runs did not reach their interrupt points"
        for _case, proc, _parent, _out, _old, due, sent in procs:
            if not sent[0] and proc.poll() is None and due():
                proc.send_signal(signal.SIGINT)
                sent[0] = True
        time.sleep(0.005)

    for case, proc, parent, out, old, _due_fn, sent in procs:
        output, _ = proc.communicate(timeout=120)
        # Every trigger fires once the staging folder exists, inside the CLI's error boundary.
        assert proc.returncode in (0, 130), f"{case.name}: exit {proc.returncode}\n{output}"
        assert "Traceback" not in output, f"{case.name}:\n{output}"
        assert _hidden(parent) == [], f"{case.name}: left {_hidden(parent)}"
        if proc.returncode == 0:
            _assert_complete(out)
            assert old is None or (out / "run.json").read_bytes() != old
        elif old is not None:
            assert (out / "run.json").read_bytes() == old, case.name
            assert sorted(p.name for p in out.iterdir()) == sorted(OLD_RECORD["outputs"])
        else:
            assert not out.exists(), f"{case.name}: {sorted(p.name for p in out.iterdir())}"
        assert sent[0] or proc.returncode == 0
    shutil.rmtree(tmp_path, ignore_errors=True)


def test_records_name_final_paths_not_the_staging_folder(tmp_path: Path) -> None:
    with RunDir(tmp_path / "demo") as root:
        staged = root.staged("plan")
        staged.mkdir()
        record = {
            "map": {"path": str(root.staging.resolve() / "dense" / "map.yaml"), "bytes": 3},
            "runs": [str(root.staging / "dense"), "elsewhere"],
            "n": 1,
        }
        (staged / "plan.json").write_text(json.dumps(record))
        root.relocate_records()
    fixed = json.loads((tmp_path / "demo" / "plan" / "plan.json").read_text())
    assert fixed["map"]["path"] == str((tmp_path / "demo").resolve() / "dense" / "map.yaml")
    assert fixed["runs"] == [str(tmp_path / "demo" / "dense"), "elsewhere"]
    assert fixed["n"] == 1 and fixed["map"]["bytes"] == 3


def test_a_symlinked_out_is_replaced_where_it_points(tmp_path: Path) -> None:
    disk = tmp_path / "disk"
    disk.mkdir()
    real = disk / "run"
    _write_old_run(real)
    link = tmp_path / "run"
    link.symlink_to(real)
    with RunDir(link, force=True) as run:
        path = run.write_text("new.txt", "x")
    assert path == link / "new.txt"
    assert link.is_symlink()
    assert sorted(p.name for p in real.iterdir()) == ["new.txt"]
    assert _hidden(tmp_path) == [] and _hidden(disk) == []
