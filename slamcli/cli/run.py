"""``slamcli run PIPELINE INPUT --out DIR``: one pipeline over one log, into a run folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary, exit_if_data_lost
from slamcli.cli.source_options import (
    DEFAULTS,
    CameraInfoTopic,
    CameraOpt,
    Cx,
    Cy,
    DepthFactor,
    DepthTopic,
    DtOffset,
    Fx,
    Fy,
    GtFrame,
    GtTopic,
    MaxDt,
    OdomTopic,
    RgbTopic,
    SourceOptions,
    Strict,
    Undistort,
)

run_app = typer.Typer(
    help="Run a SLAM pipeline over a log and write a run folder (trajectory, report, run.json).",
    no_args_is_help=True,
)


def register(app: typer.Typer) -> None:
    app.add_typer(run_app, name="run", rich_help_panel="Run")


Out = Annotated[Path, typer.Option("--out", "-o", help="Run folder to write.", show_default=False)]
Force = Annotated[bool, typer.Option("--force", help="Overwrite a non-empty --out folder.")]
MaxFrames = Annotated[
    int | None,
    typer.Option("--max-frames", min=1, help="Stop after this many frames.", show_default=False),
]
Mcap = Annotated[
    bool,
    typer.Option("--mcap", help="Also write result.mcap (open it in Foxglove)."),
]


@run_app.command("odometry")
@boundary
def odometry(
    input: Annotated[
        Path, typer.Argument(help="A TUM RGB-D folder or an MCAP log.", show_default=False)
    ],
    out: Out,
    force: Force = False,
    max_frames: MaxFrames = None,
    mcap: Mcap = False,
    max_dt: MaxDt = DEFAULTS.max_dt,
    dt_offset: DtOffset = DEFAULTS.dt_offset,
    depth_factor: DepthFactor = None,
    camera: CameraOpt = None,
    fx: Fx = None,
    fy: Fy = None,
    cx: Cx = None,
    cy: Cy = None,
    undistort: Undistort = False,
    strict: Strict = False,
    rgb_topic: RgbTopic = None,
    depth_topic: DepthTopic = None,
    camera_info_topic: CameraInfoTopic = None,
    gt_topic: GtTopic = None,
    gt_frame: GtFrame = None,
    odom_topic: OdomTopic = None,
) -> None:
    """Frame-to-frame RGB-D odometry: the simplest tracker, and the baseline for the others.

    Registers each frame to the previous one (Open3D's multi-scale photometric + geometric
    kernel, seeded by a constant-velocity prior). Writes trajectory.tum, report.png and
    run.json (with ATE/RPE when the input has ground truth). Exits with 3 when frames had to
    be skipped.

    Example: [bold]slamcli run odometry rgbd_dataset_freiburg1_xyz --out runs/xyz[/]
    """
    opts = SourceOptions.pick(locals())
    _run("odometry", input, out, force, max_frames, mcap, opts)


def _run(
    pipeline: str,
    input: Path,
    out: Path,
    force: bool,
    max_frames: int | None,
    mcap: bool,
    opts: SourceOptions,
) -> None:
    from slamcli.run import run_pipeline

    with render.progress(f"{pipeline}") as progress:
        outcome = run_pipeline(
            input,
            pipeline,
            out,
            force=force,
            source_options=opts.open_kwargs(),
            max_frames=max_frames,
            command=f"run {pipeline}",
            mcap=mcap,
            progress=progress,
        )
    render.run_summary(outcome)
    exit_if_data_lost(outcome, input)
