"""``slamcli demo``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary, exit_if_data_lost


def register(app: typer.Typer) -> None:
    app.command("demo", rich_help_panel="Start here")(demo)


@boundary
def demo(
    out: Annotated[Path, typer.Option("--out", "-o", help="Run folder to write.")] = Path(
        "runs/demo"
    ),
    data: Annotated[
        Path | None,
        typer.Option(help="RGB-D folder to use instead of the bundled sample_data/rgbd_room."),
    ] = None,
    force: Annotated[bool, typer.Option(help="Overwrite a non-empty --out folder.")] = False,
) -> None:
    """Run the main job on the bundled sample data and show what it wrote.

    Runs dense RGB-D SLAM on the sample RGB-D sequence (tracking, TSDF fusion, loop
    closure), scores the trajectory against ground truth (ATE, RPE) and writes
    trajectory.tum, keyframes.tum, mesh.ply, mesh.glb, points.ply, report.png and run.json
    into --out. Exits with 3 when frames had to be skipped.

    Example: [bold]slamcli demo --out runs/demo --force[/]
    """
    from slamcli.demo import run_demo

    with render.progress("tracking", None) as progress:
        outcome = run_demo(out, data=data, force=force, progress=progress)
    render.run_summary(outcome)
    exit_if_data_lost(outcome, outcome.input_path)
