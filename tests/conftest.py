"""Shared fixtures: paths to the real data in ../shared/data and small generated inputs."""

from __future__ import annotations

import os
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
def reference_run(tmp_path_factory: pytest.TempPathFactory, worker_id: str) -> Any:
    """``reference_run(name)``: the run folder of a reference run (``reference_runs.RUNS``),
    made once per test session, whichever test process asks first."""
    from reference_runs import run_once

    base = tmp_path_factory.getbasetemp()
    # Under pytest-xdist each process has its own base folder inside the session's.
    root = (base if worker_id == "master" else base.parent) / "reference-runs"

    def get(name: str) -> Path:
        return run_once(name, root)

    return get
