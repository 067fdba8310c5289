"""``slamcli map build RUN_DIR`` and ``slamcli map show MAP``: occupancy maps from runs."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary

map_app = typer.Typer(
    help="Build occupancy maps from run folders and look at them.", no_args_is_help=True
)

BUILD_HELP = """Build a 2-D occupancy map from a run folder (a dense RGB-D run or an EKF run).

[bold]Dense runs.[/] The run's input log (run.json names it; --input when it moved) is read \
again and every depth frame with a pose in trajectory.tum is back-projected (every 4th pixel). \
Up comes from the accelerometer when the log has one (else the cameras' mean -y axis); the \
floor is the lowest large plane within 30 degrees of up found by RANSAC in points.ply (else \
mesh.ply, else the depth points). Points whose height above the floor lies in --height-band \
(default 0.1,1.5 m: a ground robot's body) are obstacles; every ray is carved free over its \
part below the band's top. The map's x axis is the world's x projected onto the floor.

[bold]EKF runs[/] (with landmarks.csv). Each landmark is an obstacle of --landmark-radius; \
every measurement ray is carved free up to the landmark's edge, and the robot's footprint \
(--robot-radius) along its path is free.

[bold]Cells.[/] Log-odds per frame: +0.85 for a hit, -0.4 for a cell a ray crosses, clamped \
to [-2, 3.5]; untouched cells stay unknown. map.yaml + map.pgm are a trinary map_server map \
(occupied >= 0.65, free <= 0.196, else unknown), ready for 'slamcli plan'.

Writes map.yaml, map.pgm, map.png (preview with the path) and map.json (figures) into the \
run folder (added to its run.json), or into --out.

Exit codes: 0 ok; 1 a folder that is not a run, an input that moved, no floor found, a bad \
option, or map files present without --force.

Example (after the 'slamcli run dense' example): \
[bold]slamcli map build runs/room_dense --resolution 0.05 --height-band 0.05,1.2[/]
"""


def register(app: typer.Typer) -> None:
    app.add_typer(map_app, name="map", rich_help_panel="Maps and paths")


@map_app.command("build", help=BUILD_HELP)
@boundary
def build(
    run_dir: Annotated[
        Path, typer.Argument(help="A run folder written by 'slamcli run'.", show_default=False)
    ],
    resolution: Annotated[float, typer.Option("--resolution", help="Cell size (m).")] = 0.05,
    height_band: Annotated[
        str,
        typer.Option(
            "--height-band",
            metavar="ZMIN,ZMAX",
            help="Heights above the floor (m) that are obstacles (dense runs).",
        ),
    ] = "0.1,1.5",
    input: Annotated[
        Path | None,
        typer.Option("--input", help="The run's input log, when it has moved.", show_default=False),
    ] = None,
    landmark_radius: Annotated[
        float, typer.Option("--landmark-radius", help="Obstacle radius of a landmark (m).")
    ] = 0.2,
    robot_radius: Annotated[
        float, typer.Option("--robot-radius", help="Footprint carved free along the path (m).")
    ] = 0.2,
    frame_step: Annotated[
        int, typer.Option("--frame-step", help="Use every n-th depth frame.")
    ] = 1,
    pixel_step: Annotated[
        int, typer.Option("--pixel-step", help="Use every n-th depth pixel (both axes).")
    ] = 4,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out", "-o", help="Folder to write (default: the run folder).", show_default=False
        ),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace existing map files.")] = False,
) -> None:
    from slamcli.mapping import MapSettings, build_map, map_run, parse_height_band, write_map
    from slamcli.rundir import RunDir

    settings = MapSettings(
        resolution_m=resolution,
        height_band_m=parse_height_band(height_band),
        pixel_step=pixel_step,
        frame_step=frame_step,
        landmark_radius_m=landmark_radius,
        robot_radius_m=robot_radius,
    ).checked()
    with render.progress("map") as progress:
        if out is None or out.resolve() == run_dir.resolve():
            built, written = map_run(
                run_dir, settings=settings, input_path=input, force=force, progress=progress
            )
        else:
            with RunDir(out, force=force) as target:
                built = build_map(run_dir, settings=settings, input_path=input, progress=progress)
                written = [target.final(p) for p in write_map(target.staging, built)]
    _summary(built.report)
    render.written(written)


def _summary(report: dict[str, Any]) -> None:
    cells, (w, h), (wm, hm) = report["cells"], report["size_cells"], report["size_m"]
    items: dict[str, Any] = {
        "run": report["run"],
        "size": f"{w} x {h} cells ({wm:g} x {hm:g} m) at {report['resolution_m']:g} m",
        "cells": f"{cells['free']} free, {cells['occupied']} occupied, {cells['unknown']} unknown",
    }
    if report["kind"] == "depth":
        floor, frames = report["floor"], report["frames"]
        items["up"] = report["up"]["method"]
        items["floor"] = (
            f"{floor['inliers']} of {floor['points']} points ({floor['points_from']}), "
            f"{floor['angle_to_up_deg']:.2f} deg from up"
        )
        items["frames"] = f"{frames['used']} used of {frames['read']}"
    else:
        items["landmarks"] = report["landmarks"]
    items["time"] = f"{report['time_s']:.2f} s"
    render.key_values("Map", items)


@map_app.command("show")
@boundary
def show(
    map: Annotated[
        Path,
        typer.Argument(
            help="A .yaml (map_server) or .npz map, or a run folder with map.yaml.",
            show_default=False,
        ),
    ],
) -> None:
    """Print a map's size, resolution, origin (yaw included), the area it covers in the world
    and its free / occupied / unknown cell counts.

    Examples:

    [bold]slamcli map show ../shared/data/maps/turtlebot3_world.yaml[/]

    [bold]slamcli map show runs/room_dense[/] (after the 'slamcli map build' example)
    """
    render.key_values("Map", map_items(describe_map(map)))


def describe_map(path: Path) -> dict[str, Any]:
    """A map's file, size in cells, resolution (m), origin (x m, y m, yaw rad), world extent
    (``extent_m``: the x and y ranges in metres of its area, the yaw's rotation included) and
    free / occupied / unknown cell counts, JSON-able (``map show``, ``info``)."""
    from slamcli.mapping import cell_counts
    from slamcli.planning.costmap import map_bounds
    from slamcli.planning.planner import load_map

    grid, file = load_map(path)
    h, w = grid.prob.shape
    xmin, xmax, ymin, ymax = map_bounds(grid)
    return {
        "file": str(file),
        "width": int(w),
        "height": int(h),
        "resolution_m": float(grid.resolution_m),
        "origin_xy_yaw": [float(v) for v in grid.origin_xy_yaw],
        "extent_m": {"x": [xmin, xmax], "y": [ymin, ymax]},
        **{k: int(v) for k, v in cell_counts(grid).items()},
    }


def map_items(d: dict[str, Any]) -> dict[str, Any]:
    """:func:`describe_map`'s figures as the lines ``map show`` prints."""
    w, h, res = d["width"], d["height"], d["resolution_m"]
    x, y, yaw = d["origin_xy_yaw"]
    (x0, x1), (y0, y1) = d["extent_m"]["x"], d["extent_m"]["y"]
    return {
        "file": d["file"],
        "size": f"{w} x {h} cells ({w * res:g} x {h * res:g} m)",
        "resolution": f"{res:g} m",
        "origin": f"({x:g}, {y:g}) m, yaw {yaw:g} rad",
        "extent": f"x {x0:g} .. {x1:g} m, y {y0:g} .. {y1:g} m",
        "free": d["free"],
        "occupied": d["occupied"],
        "unknown": d["unknown"],
    }
