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
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder to write.")] = Path("runs/demo"),
    data: Annotated[
        Path | None,
        typer.Option(help="RGB-D folder to use instead of the bundled sample_data/rgbd_room."),
    ] = None,
    landmarks: Annotated[
        Path | None,
        typer.Option(help="Landmark log to use instead of the bundled sample_data/landmarks."),
    ] = None,
    force: Annotated[bool, typer.Option(help="Overwrite a non-empty --out folder.")] = False,
) -> None:
    """Run the main jobs on the bundled sample data and show what they wrote.

    1. dense/: dense RGB-D SLAM on the sample RGB-D sequence (tracking, TSDF fusion, loop
    closure), scored against ground truth, with the mesh as PLY and GLB and an occupancy
    map (map.yaml, map.pgm, map.png) built from the run;
    2. plan/: a path across that map between two far-apart free places, smoothed, timed and
    followed by a simulated robot (path.csv, trajectory.csv, plan.json, plan.png);
    3. ekf/: EKF landmark SLAM on the sample landmark world, with landmarks.csv and a report;
    4. visual/: feature-based visual SLAM on the same RGB-D sequence (ORB features, local
    bundle adjustment, loop closure), with keyframes, coloured points and the pose graph.

    Exits with 3 when frames had to be skipped.

    Example: [bold]slamcli demo --out runs/demo --force[/]
    """
    from slamcli.cli.plan import plan_summary
    from slamcli.demo import run_demo

    with render.progress("demo", None) as progress:
        outcome = run_demo(out, data=data, landmarks=landmarks, force=force, progress=progress)
    render.heading("1. Dense RGB-D SLAM and an occupancy map")
    render.run_summary(outcome.dense)
    render.written(outcome.map_files)
    render.heading("2. A path across the map")
    render.key_values(
        "Plan", plan_summary(outcome.plan, outcome.map_file, outcome.start_xy, outcome.goal_xy)
    )
    render.written(outcome.plan_files)
    render.heading("3. EKF landmark SLAM")
    render.run_summary(outcome.ekf)
    render.heading("4. Visual SLAM (ORB features, bundle adjustment, loop closure)")
    render.run_summary(outcome.visual)
    exit_if_data_lost(outcome.dense)
    exit_if_data_lost(outcome.ekf)
    exit_if_data_lost(outcome.visual)
