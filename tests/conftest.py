"""Shared fixtures: paths to the real data in ../shared/data and small generated inputs."""

from __future__ import annotations

import os
from pathlib import Path

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
