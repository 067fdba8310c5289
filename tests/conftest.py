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
