"""Shared fixtures: paths to the real data in ../shared/data, and the commands and generated
inputs that several tests read, made once per test session (``reference_run``, ``shared_run``,
``shared_artefact``; see ``reference_runs.py``)."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

SHARED_DATA = Path(
    os.environ.get("SLAMCLI_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")
)


def shared_path(*parts: str) -> Path:
    """A path inside ../shared/data; skips the test (fails it under CI) when it is absent."""
    p = SHARED_DATA.joinpath(*parts)
    if not p.exists():
        msg = f"real data not found at {p} (set SLAMCLI_SHARED_DATA to the shared/data folder)"
        if os.environ.get("CI"):
            pytest.fail(msg)
        pytest.skip(msg)
    return p


@pytest.fixture
def tum_excerpt() -> Path:
    return shared_path("tum", "rgbd_dataset_freiburg1_rpy_excerpt")


@pytest.fixture
def trajectories_dir() -> Path:
    return shared_path("trajectories")


@pytest.fixture(scope="session")
def shared_root(tmp_path_factory: pytest.TempPathFactory, worker_id: str) -> Path:
    """The session's folder of shared runs and artefacts, the same for every test process."""
    base = tmp_path_factory.getbasetemp()
    # Under pytest-xdist each process has its own base folder inside the session's.
    return (base if worker_id == "master" else base.parent) / "reference-runs"


@pytest.fixture(scope="session")
def reference_run(shared_root: Path) -> Any:
    """``reference_run(name)``: the run folder of a reference run (``reference_runs.RUNS``),
    made once per test session, whichever test process asks first."""
    from reference_runs import run_once

    def get(name: str) -> Path:
        return run_once(name, shared_root)

    return get


@pytest.fixture(scope="session")
def shared_run(shared_root: Path) -> Any:
    """``shared_run(*argv, cwd=None, suffix="")``: ``slamcli ARGV`` run once per test session,
    whichever test process asks first, as a ``reference_runs.SharedRun`` (its ``--out`` folder,
    exit code and output). Commands that differ only in ``--out`` and ``--force`` are one run,
    and a reference run is the same run as the same command here. Read ``out``; to change it,
    copy it first (``reference_runs.copy_out``)."""
    from reference_runs import run_shared

    def get(*argv: str | Path, cwd: Path | None = None, suffix: str = "") -> Any:
        return run_shared(argv, shared_root, cwd=cwd, suffix=suffix)

    return get


@pytest.fixture(scope="session")
def shared_artefact(shared_root: Path) -> Any:
    """``shared_artefact(key, make)``: the folder ``make(folder)`` fills, made once per test
    session whichever test process asks first (a generated input several tests read)."""
    from reference_runs import make_once

    def get(key: str, make: Callable[[Path], object]) -> Path:
        return make_once(key, shared_root, make)

    return get


def _implausible_loops(root: Path) -> list[str]:
    """Loops accepted in any run.json under ``root`` whose scale is outside [0.5, 2]. A merge
    is not counted: it joins a map started after tracking was lost, whose scale is its own."""
    import json

    found = []
    for path in sorted(root.rglob("run.json")):
        try:
            info = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        metrics = info.get("metrics") if isinstance(info, dict) else None
        records = metrics.get("loop_closures") if isinstance(metrics, dict) else None
        for r in records if isinstance(records, list) else []:
            scale = r.get("scale") if isinstance(r, dict) else None
            accepted = r.get("accepted") and r.get("type") == "loop"
            if accepted and scale is not None and not 0.5 <= scale <= 2.0:
                found.append(f"{path}: loop {r.get('frames')} accepted with scale {scale}")
    return found


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Every run the suite made (in every test process's folders) is checked: no accepted
    loop needed a scale outside [0.5, 2]. A loop that does is no drift correction, and a
    suite that passes with one has passed on a run it should have doubted."""
    if hasattr(session.config, "workerinput"):
        return  # the controlling process checks the workers' folders too
    factory = getattr(session.config, "_tmp_path_factory", None)
    if factory is None:
        return
    bad = _implausible_loops(factory.getbasetemp())
    if bad:
        reporter = session.config.pluginmanager.get_plugin("terminalreporter")
        if reporter is not None:
            reporter.write_line("loops accepted with an implausible scale:", red=True)
            for line in bad:
                reporter.write_line(f"  {line}", red=True)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED
