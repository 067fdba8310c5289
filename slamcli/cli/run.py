"""``slamcli run PIPELINE INPUT --out DIR``: one pipeline over one log, into a run folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

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
    IgnoreIds,
    LandmarkTopic,
    MaxDt,
    OdomTopic,
    RgbTopic,
    Robot,
    SourceOptions,
    Strict,
    Undistort,
)
from slamcli.pipelines import PIPELINES

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
BuildMap = Annotated[
    bool,
    typer.Option(
        "--map",
        help="Also build the occupancy map: map.yaml, map.pgm, map.png, map.json "
        "(as 'slamcli map build' with its defaults).",
    ),
]


ConfigFile = Annotated[
    Path | None,
    typer.Option(
        "--config",
        help="TOML file whose [PIPELINE] table overrides the defaults "
        "(see 'slamcli config dump PIPELINE').",
        show_default=False,
    ),
]
Sets = Annotated[
    list[str] | None,
    typer.Option(
        "--set",
        help="Override one setting, e.g. --set voxel_m=0.01 (repeatable; applied after --config).",
        show_default=False,
    ),
]

DOCS = {
    "odometry": """Frame-to-frame RGB-D odometry: the simplest tracker, the baseline for others.

    Registers each frame to the previous one (Open3D's multi-scale photometric + geometric
    kernel, seeded by a constant-velocity prior). Writes trajectory.tum, report.png and
    run.json (with ATE/RPE when the input has ground truth). Exits with 3 when frames had to
    be skipped.

    Example: [bold]slamcli run odometry rgbd_dataset_freiburg1_xyz --out runs/xyz[/]
    """,
    "dense": """Dense RGB-D SLAM: a coloured mesh and a trajectory from an RGB-D log.

    Tracks each frame against a ray-cast of the fused TSDF volume (seeded by ORB features and
    PnP), fuses trusted frames, closes loops between keyframes and re-integrates with the
    optimised poses. Writes trajectory.tum, keyframes.tum, mesh.ply, points.ply, report.png
    and run.json. Settings: 'slamcli config dump dense'. Exits with 3 when frames had to be
    skipped.

    Example: [bold]slamcli run dense rgbd_dataset_freiburg1_xyz --out runs/xyz --set voxel_m=0.01[/]
    """,
    "ekf": """EKF landmark SLAM: a planar trajectory and a landmark map from odometry and
    range-bearing observations.

    Reads an MRCLAM folder (--robot N), a Victoria Park file (GTSAM format), a
    'slamcli synth landmarks' folder or an MCAP log with odometry and landmark observations.
    Known correspondences when the log has landmark ids, nearest neighbour with chi-square
    gating (or JCBB) otherwise (--ignore-ids). Writes trajectory.tum (the path smoothed
    against the final map), trajectory_filtered.tum (the filter's own path), landmarks.csv
    (with covariances), report.png and run.json (ATE after SE(2) alignment, landmark RMSE,
    NEES/NIS when the log has ground truth). --map adds an occupancy map. Settings:
    'slamcli config dump ekf'.

    Example: [bold]slamcli run ekf MRCLAM_Dataset6 --robot 2 --out runs/mrclam2[/]
    """,
}


def _command(pipeline: str) -> Any:
    def command(
        input: Annotated[
            Path,
            typer.Argument(
                help="A TUM RGB-D folder, an MCAP log, an MRCLAM folder, a Victoria Park file "
                "or a 'slamcli synth landmarks' folder.",
                show_default=False,
            ),
        ],
        out: Out,
        force: Force = False,
        max_frames: MaxFrames = None,
        mcap: Mcap = False,
        map_: BuildMap = False,
        config: ConfigFile = None,
        set_: Sets = None,
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
        robot: Robot = None,
        ignore_ids: IgnoreIds = False,
        landmark_topic: LandmarkTopic = None,
    ) -> None:
        from slamcli.config import load_config
        from slamcli.pipelines import get_pipeline

        settings = load_config(get_pipeline(pipeline).config_class, pipeline, config, set_ or ())
        opts = SourceOptions.pick(locals())
        _run(pipeline, input, out, force, max_frames, mcap, opts, settings, map_)

    command.__doc__ = DOCS[pipeline]
    return boundary(command)


for _name in PIPELINES:
    run_app.command(_name)(_command(_name))


def _run(
    pipeline: str,
    input: Path,
    out: Path,
    force: bool,
    max_frames: int | None,
    mcap: bool,
    opts: SourceOptions,
    settings: Any,
    build_map: bool = False,
) -> None:
    from slamcli.run import run_pipeline

    with render.progress(f"{pipeline}") as progress:
        outcome = run_pipeline(
            input,
            pipeline,
            out,
            force=force,
            config=settings,
            source_options=opts.open_kwargs(),
            max_frames=max_frames,
            command=f"run {pipeline}",
            mcap=mcap,
            progress=progress,
        )
    if build_map:
        from slamcli.mapping import map_run

        with render.progress("map") as progress:
            _, written = map_run(outcome.run_dir, force=True, progress=progress)
        outcome.outputs[-1:-1] = written  # before run.json, as run.json lists them
    render.run_summary(outcome)
    exit_if_data_lost(outcome, input)
