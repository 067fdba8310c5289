"""``slamcli plan MAP --start x,y --goal x,y``: a collision-free, smoothed, timed path."""

from __future__ import annotations

import math
import time
from enum import Enum
from pathlib import Path
from typing import Annotated, Any

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary
from slamcli.errors import ConfigError

_LOADED = time.perf_counter()
"""When the CLI loaded this module: the command's start where the process's is not known."""

PLAN_HELP = """Plan a path on an occupancy map, smooth it, time it and simulate a robot driving it.

MAP is a map_server .yaml map, a slamcli .npz grid, or a run folder with map.yaml (written by \
'slamcli map build'). Coordinates are metres in the map frame.

[bold]Free space.[/] A cell is occupied when its probability is >= 0.65 (map_server's \
occupied_thresh default); unknown cells are blocked (--unknown blocked, the default) or free \
(--unknown free). A cell is blocked when its centre lies within --robot-radius of an occupied \
cell's centre; a centre exactly at the radius counts as blocked. The grid search is exact on \
the 8-connected free cells. The map's origin yaw is honoured.

[bold]Clearance.[/] --clearance-weight w > 0 adds w * exp(-3/m * (d - radius)) per metre \
driven through a cell d metres from the nearest obstacle (0 beyond 1 m), like Nav2's inflation \
layer; 0 (the default) gives the shortest path.

[bold]Smoothing and timing.[/] The grid path is shortcut by line of sight and its corners are \
rounded; no segment touches a blocked cell. It is timed under --max-speed, --max-yaw-rate and \
--max-accel (turning in place at corners over 60 degrees), sampled every 0.1 s, and a unicycle \
robot follows it with pure pursuit.

[bold]Dynamic obstacles.[/] --obstacles FILE is a CSV with the header \
x,y,radius,appear_s,vanish_s (vanish_s empty or inf: it stays). The robot replans when one \
appears on its path within 1.5 m ahead, and waits when no way leads around it.

Writes into --out (default ./plan): path.csv, path_smooth.csv (x,y), trajectory.csv and \
tracked.csv (t,x,y,theta,v,omega), plan.json (with the time of each stage) and plan.png.

Exit codes: 0 ok; 1 a bad map, start or goal outside the map or not in free space (the \
message names the nearest free cell), no path (with the number of cells reached), a bad \
option, or --out not empty without --force.

Examples:

[bold]slamcli plan ../shared/data/maps/turtlebot3_world.yaml --start -2,-0.5 --goal 2,0.5 \
--out plan[/]

[bold]slamcli plan runs/landmarks --start -6,-5.9 --goal 4,5.9 --robot-radius 0.3 \
--clearance-weight 1 --out runs/landmarks_plan[/] (after the 'slamcli run ekf' example)
"""


class UnknownSpace(str, Enum):
    """What unknown cells are to the robot."""

    blocked = "blocked"
    free = "free"


def register(app: typer.Typer) -> None:
    app.command("plan", help=PLAN_HELP, rich_help_panel="Maps and paths")(plan)


def parse_xy(option: str, text: str) -> tuple[float, float]:
    """``"x,y"`` (metres) -> two finite floats; ConfigError naming the option."""
    parts = [p.strip() for p in text.split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != 2 or not all(math.isfinite(v) for v in values):
        raise ConfigError(
            f"{option}: expected two numbers x,y in metres, got {text!r}",
            hint=f"for example {option} -1.5,2.0",
        )
    return values[0], values[1]


@boundary
def plan(
    map: Annotated[
        Path,
        typer.Argument(
            help="A .yaml (map_server) or .npz map, or a run folder with map.yaml.",
            show_default=False,
        ),
    ],
    start: Annotated[
        str, typer.Option("--start", metavar="X,Y", help="Start x,y in metres.", show_default=False)
    ],
    goal: Annotated[
        str, typer.Option("--goal", metavar="X,Y", help="Goal x,y in metres.", show_default=False)
    ],
    robot_radius: Annotated[
        float, typer.Option("--robot-radius", help="Robot radius (m) for the inflated zone.")
    ] = 0.2,
    unknown: Annotated[
        UnknownSpace | None,
        typer.Option(
            "--unknown",
            help="Unknown cells are obstacles (blocked, the default) or free space (free).",
            show_default=False,
        ),
    ] = None,
    allow_unknown: Annotated[
        bool, typer.Option("--allow-unknown", hidden=True, help="Deprecated: --unknown free.")
    ] = False,
    clearance_weight: Annotated[
        float,
        typer.Option("--clearance-weight", help="Weight of the clearance cost; 0 = shortest."),
    ] = 0.0,
    max_speed: Annotated[float, typer.Option("--max-speed", help="Maximum speed (m/s).")] = 0.5,
    max_yaw_rate: Annotated[
        float, typer.Option("--max-yaw-rate", help="Maximum yaw rate (rad/s).")
    ] = 1.0,
    max_accel: Annotated[
        float, typer.Option("--max-accel", help="Maximum acceleration along the path (m/s²).")
    ] = 0.5,
    obstacles: Annotated[
        Path | None,
        typer.Option(
            "--obstacles",
            help="CSV of dynamic obstacles: x,y,radius,appear_s,vanish_s.",
            show_default=False,
        ),
    ] = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder to write.")] = Path("plan"),
    force: Annotated[bool, typer.Option("--force", help="Overwrite a non-empty --out.")] = False,
) -> None:
    """Plan a path on an occupancy map, smooth it, time it and simulate a robot driving it."""
    from slamcli.planning.obstacles import read_obstacles
    from slamcli.planning.output import process_start, write_plan
    from slamcli.planning.planner import load_map
    from slamcli.planning.planner import plan as run_plan
    from slamcli.planning.trajectory import Limits
    from slamcli.rundir import RunDir

    process = process_start()
    started = _LOADED if process is None else process
    start_xy = parse_xy("--start", start)
    goal_xy = parse_xy("--goal", goal)
    policy = unknown_policy(unknown, allow_unknown)
    limits = Limits(max_speed, max_yaw_rate, max_accel).checked()
    with RunDir(out, force=force) as run:
        dynamic = read_obstacles(obstacles) if obstacles is not None else []
        t0 = time.perf_counter()
        grid, map_file = load_map(map)
        read_ms = round((time.perf_counter() - t0) * 1000.0, 3)
        result = run_plan(
            grid,
            start_xy,
            goal_xy,
            robot_radius_m=robot_radius,
            unknown_policy=policy,
            clearance_weight=clearance_weight,
            limits=limits,
            obstacles=dynamic,
        )
        written = write_plan(
            result, run, map_file, timings_ms={"read_map": read_ms}, started=started
        )

    rows = plan_summary(result, map_file, start_xy, goal_xy, len(dynamic))
    render.key_values("Plan", rows)
    render.written(written)
    if not result.tracking.reached_goal:
        render.warn("the simulated robot did not reach the goal within the time limit")


def unknown_policy(unknown: UnknownSpace | None, allow_unknown: bool) -> str:
    """The unknown-space policy from --unknown and the deprecated --allow-unknown."""
    if not allow_unknown:
        return (unknown or UnknownSpace.blocked).value
    if unknown is UnknownSpace.blocked:
        raise ConfigError(
            "--allow-unknown contradicts --unknown blocked",
            hint="pass only --unknown free or --unknown blocked",
        )
    render.warn("--allow-unknown is deprecated; use --unknown free")
    return UnknownSpace.free.value


def plan_summary(
    result: Any,
    map_file: Path,
    start_xy: tuple[float, float],
    goal_xy: tuple[float, float],
    dynamic: int = 0,
) -> dict[str, str]:
    """The key figures of a plan, as printed by ``slamcli plan`` and the demo."""
    tr = result.tracking
    clearance = result.min_clearance_m
    rows = {
        "map": str(map_file),
        "start -> goal": f"({start_xy[0]:g}, {start_xy[1]:g}) -> "
        f"({goal_xy[0]:g}, {goal_xy[1]:g}) m",
        "grid cost": f"{result.grid_cost_m:.3f} m ({len(result.search.cells)} cells, "
        f"{result.search.expanded} expanded, {result.search.method})",
        "smoothed length": f"{result.length_m:.3f} m ({len(result.smooth_xy)} points)",
        "min clearance": "no obstacles" if math.isinf(clearance) else f"{clearance:.3f} m",
        "plan time": f"{result.plan_ms:.0f} ms",
        "trajectory": f"{result.profile.duration_s:.1f} s",
        "time to goal": "not reached"
        if tr.time_to_goal_s is None
        else f"{tr.time_to_goal_s:.1f} s",
        "cross-track error": f"RMS {tr.cross_track_rms_m:.3f} m, max {tr.cross_track_max_m:.3f} m",
    }
    if dynamic:
        rows["dynamic obstacles"] = f"{dynamic}: {tr.replans} replans, {tr.waits} waits"
    return rows
