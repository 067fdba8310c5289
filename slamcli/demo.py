"""The demo: the main job on the bundled sample data, end to end."""

from __future__ import annotations

from pathlib import Path

from slamcli.errors import InputError
from slamcli.run import RunOutcome, run_pipeline
from slamcli.types import ProgressFn

SAMPLE_ROOT = Path(__file__).resolve().parents[1] / "sample_data"
"""sample_data/ of a source checkout (an installed wheel does not carry it)."""


def default_sample() -> Path:
    """The bundled RGB-D sample sequence."""
    return SAMPLE_ROOT / "rgbd_room"


def run_demo(
    out: str | Path,
    data: str | Path | None = None,
    force: bool = False,
    progress: ProgressFn | None = None,
) -> RunOutcome:
    """Dense RGB-D SLAM on the sample sequence, scored against its ground truth.

    Writes the run folder ``out``: trajectory.tum, keyframes.tum, mesh.ply, mesh.glb,
    points.ply, report.png and run.json.
    """
    path = Path(data) if data is not None else default_sample()
    if not path.exists():
        raise InputError(
            f"{path}: sample data not found",
            hint="make one with 'slamcli synth rgbd DIR' and pass it with --data DIR",
        )
    return run_pipeline(
        path, "dense", out, force=force, command="demo", glb=True, progress=progress
    )
