"""``slamcli demo``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary
from slamcli.errors import DataLossError


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

    Inspects the sample RGB-D sequence, tracks the camera with RGB-D odometry, scores the
    trajectory against ground truth (ATE, RPE) and writes trajectory.tum, report.png and
    run.json into --out. Exits with 3 when frames had to be skipped.

    Example: [bold]slamcli demo --out runs/demo --force[/]
    """
    from slamcli.demo import run_demo

    with render.progress("tracking", None) as progress:
        outcome = run_demo(out, data=data, force=force, progress=progress)
    info, run = outcome.info, outcome.run
    render.key_values(
        "Input",
        {
            "data": outcome.data,
            "format": info.format,
            "RGB-D frames": info.frames,
            "ground-truth poses": info.groundtruth,
            "camera": info.camera_source,
        },
    )
    ev = run.metrics.get("evaluation")
    if ev:
        stats = [("ATE (m)", ev["ate"])]
        if "rpe" in ev:
            stats.append(("RPE translation (m/frame)", ev["rpe"]["trans"]))
            stats.append(("RPE rotation (deg/frame)", ev["rpe"]["rot_deg"]))
        render.table(
            f"Accuracy against ground truth ({ev['pairs']} poses, {ev['alignment']} alignment)",
            ["metric", "rmse", "mean", "max"],
            [[name, *(f"{s[k]:.4f}" for k in ("rmse", "mean", "max"))] for name, s in stats],
            right_align=["rmse", "mean", "max"],
        )
    render.written(run.outputs)
    skipped = run.counts.get("frames_skipped", 0)
    if skipped:
        raise DataLossError(
            f"{outcome.data}: {skipped} frame(s) skipped because an image was missing or "
            "unreadable; the results above exclude them",
            hint=f"'slamcli info {outcome.data} --deep' names every unreadable image",
        )
