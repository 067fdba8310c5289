"""The demo: the main job on the bundled sample data, end to end."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from slamcli.errors import InputError
from slamcli.formats.base import SourceInfo
from slamcli.run import RunOutcome, run_pipeline
from slamcli.types import ProgressFn

SAMPLE_ROOT = Path(__file__).resolve().parents[1] / "sample_data"
"""sample_data/ of a source checkout (an installed wheel does not carry it)."""


@dataclass
class DemoOutcome:
    data: Path
    info: SourceInfo
    run: RunOutcome


def default_sample() -> Path:
    """The bundled RGB-D sample sequence."""
    return SAMPLE_ROOT / "rgbd_room"


def run_demo(
    out: str | Path,
    data: str | Path | None = None,
    force: bool = False,
    progress: ProgressFn | None = None,
) -> DemoOutcome:
    """Inspect the sample sequence, track it with RGB-D odometry and score it against ground truth.

    Writes the run folder ``out`` (trajectory.tum, report.png, run.json).
    """
    from slamcli.formats import open_source

    path = Path(data) if data is not None else default_sample()
    if not path.exists():
        raise InputError(
            f"{path}: sample data not found",
            hint="make one with 'slamcli synth rgbd DIR' and pass it with --data DIR",
        )
    with open_source(path) as source:
        info = source.info()
    outcome = run_pipeline(path, "odometry", out, force=force, command="demo", progress=progress)
    return DemoOutcome(path, info, outcome)
