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

[bold]Car-like robots.[/] --motion ackermann plans for a robot that cannot turn in place: \
--min-turn-radius R, --footprint (a polygon 'x1,y1;x2,y2;...' in the robot's frame, x forward, \
or a centred rectangle 'LENGTHxWIDTH'), headings in --start/--goal as x,y,yaw (yaw in radians, \
0 if left out), and --reverse/--no-reverse (--reverse-penalty: a metre backwards costs that \
many metres forwards; 1 gives the shortest path). The search is Hybrid-A* with Reeds-Shepp \
(Dubins without reversing) curves to the goal; the footprint is checked against the occupied \
(and, with --unknown blocked, unknown) cells at every pose, at most half a cell apart, not as \
an inflated circle. A centring cost keeps the path near the middle of the free space \
(--cost-penalty, default 8; --inflation-radius, how far around a point the middle is looked \
for; --cost-penalty 0 gives the shortest path). The path keeps its curvature within 1/R and \
ramps it at most 1/(R x --full-lock-distance) per metre (0.5 m from straight to full lock), \
stops at each gear change, is timed under --max-speed, --max-accel, --max-yaw-rate and \
--max-lateral-accel, and a bicycle-model robot (--wheelbase) follows it. --max-planning-time \
bounds the search. --robot-radius, --clearance-weight and --obstacles are for --motion diff \
only; --cost-penalty also centres the round robot's path (default 0 there).

Writes into --out (default ./plan): path.csv, path_smooth.csv (x,y), trajectory.csv and \
tracked.csv (t,x,y,theta,v,omega), plan.json (with the time of each stage) and plan.png. With \
--motion ackermann: path.csv (x,y,yaw,direction,curvature,steering; direction -1 when \
reversing), \
path_search.csv (the search's poses), trajectory.csv and tracked.csv (v < 0 reversing), \
plan.json (length, reversals, min clearance, max curvature, goal error, stage times) and \
plan.png.

Exit codes: 0 ok; 1 a bad map, start or goal outside the map or not in free space (the \
message names the nearest free cell), no path (with the number of cells reached), a bad \
option, or --out not empty without --force.

Examples:

[bold]slamcli plan ../shared/data/maps/turtlebot3_world.yaml --start -2,-0.5 --goal 2,0.5 \
--out plan[/]

[bold]slamcli plan runs/landmarks --start -6,-5.9 --goal 4,5.9 --robot-radius 0.3 \
--clearance-weight 1 --out runs/landmarks_plan[/] (after the 'slamcli run ekf' example)

[bold]slamcli plan ../shared/data/maps/building_31.yaml --motion ackermann --footprint 0.9x0.6 \
--min-turn-radius 1.2 --start 0,0,0 --goal 5.5,14,1.57 --out plan_car[/]

[bold]slamcli plan ../shared/data/maps/building_31.yaml --motion ackermann --footprint 0.9x0.6 \
--min-turn-radius 1.2 --start 0,0,0 --goal 5.5,14,1.57 --cost-penalty 0 --full-lock-distance 0 \
--out plan_car_shortest[/] (the shortest path, of arcs and straight lines)
"""


class Motion(str, Enum):
    """How the robot moves."""

    diff = "diff"
    ackermann = "ackermann"


class UnknownSpace(str, Enum):
    """What unknown cells are to the robot."""

    blocked = "blocked"
    free = "free"


def register(app: typer.Typer) -> None:
    app.command("plan", help=PLAN_HELP, rich_help_panel="Maps and paths")(plan)


def parse_pose(option: str, text: str) -> tuple[float, float, float | None]:
    """``"x,y"`` or ``"x,y,yaw"`` (metres, radians) -> finite floats, yaw None when left out;
    ConfigError naming the option."""
    parts = [p.strip() for p in text.split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) not in (2, 3) or not all(math.isfinite(v) for v in values):
        raise ConfigError(
            f"{option}: expected x,y or x,y,yaw (metres, radians), got {text!r}",
            hint=f"for example {option} -1.5,2.0 or {option} -1.5,2.0,1.57",
        )
    return values[0], values[1], (values[2] if len(values) == 3 else None)


def parse_footprint_option(text: str) -> Any:
    """--footprint: ``LENGTHxWIDTH`` (a rectangle centred on the robot) or a polygon
    ``x1,y1;x2,y2;...`` in metres."""
    from slamcli.planning.footprint import Footprint, parse_footprint

    size = text.lower().split("x")
    if len(size) == 2 and ";" not in text:
        try:
            length, width = float(size[0]), float(size[1])
        except ValueError:
            pass
        else:
            return Footprint.rectangle(length, width)
    return parse_footprint(text, "--footprint")


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
        str,
        typer.Option(
            "--start",
            metavar="X,Y[,YAW]",
            help="Start x,y in metres (and heading in radians, --motion ackermann).",
            show_default=False,
        ),
    ],
    goal: Annotated[
        str,
        typer.Option(
            "--goal",
            metavar="X,Y[,YAW]",
            help="Goal x,y in metres (and heading in radians, --motion ackermann).",
            show_default=False,
        ),
    ],
    motion: Annotated[
        Motion,
        typer.Option(
            "--motion",
            help="diff: turns in place (differential drive); ackermann: car-like.",
        ),
    ] = Motion.diff,
    robot_radius: Annotated[
        float, typer.Option("--robot-radius", help="Robot radius (m) for the inflated zone.")
    ] = 0.2,
    footprint: Annotated[
        str | None,
        typer.Option(
            "--footprint",
            metavar="LxW|x1,y1;x2,y2;...",
            help="Ackermann: the robot's outline, a centred LENGTHxWIDTH rectangle or a convex "
            "polygon in its frame (m, x forward).",
            show_default=False,
        ),
    ] = None,
    min_turn_radius: Annotated[
        float,
        typer.Option("--min-turn-radius", help="Ackermann: tightest turn radius (m)."),
    ] = 1.0,
    reverse: Annotated[
        bool,
        typer.Option("--reverse/--no-reverse", help="Ackermann: whether it may drive backwards."),
    ] = True,
    reverse_penalty: Annotated[
        float,
        typer.Option(
            "--reverse-penalty",
            help="Ackermann: cost of a metre driven backwards, in metres forwards (1 = "
            "shortest path; 2 as Nav2's Smac planner).",
        ),
    ] = 2.0,
    full_lock_distance: Annotated[
        float,
        typer.Option(
            "--full-lock-distance",
            help="Ackermann: the shortest travel (m) over which the steering may go from "
            "straight ahead to full lock; the curvature then changes by at most 1/(R x this) "
            "per metre. 0 keeps arcs and straight lines, whose steering jumps.",
        ),
    ] = 0.5,
    max_planning_time: Annotated[
        float,
        typer.Option(
            "--max-planning-time",
            help="Ackermann: the search's time budget (s; the free space and heuristic before "
            "it are not counted). When the full search runs out of 60 % of it, a greedy one "
            "looks for a path in the rest: found, it comes with a warning; not found, an error.",
        ),
    ] = 5.0,
    wheelbase: Annotated[
        float | None,
        typer.Option(
            "--wheelbase",
            help="Ackermann: wheelbase (m) of the simulated bicycle; default 0.6 x the "
            "footprint's length.",
            show_default=False,
        ),
    ] = None,
    max_lateral_accel: Annotated[
        float,
        typer.Option("--max-lateral-accel", help="Ackermann: maximum lateral accel. (m/s²)."),
    ] = 0.5,
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
    cost_penalty: Annotated[
        float | None,
        typer.Option(
            "--cost-penalty",
            help="Weight of the centring cost: a metre driven where it is c (0 on the middle "
            "line of the free space, 0.04 at 80 % of the way there, 1 at a wall) costs 1 + "
            "penalty x c metres. 0 = shortest path. Default 8 with --motion ackermann, 0 with "
            "diff.",
            show_default=False,
        ),
    ] = None,
    inflation_radius: Annotated[
        float,
        typer.Option(
            "--inflation-radius",
            help="How far (m) around a point the centring cost looks for the middle of the "
            "free space; wider space than twice this is not centred.",
        ),
    ] = 1.5,
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
    s_pose = parse_pose("--start", start)
    g_pose = parse_pose("--goal", goal)
    policy = unknown_policy(unknown, allow_unknown)
    if motion is Motion.ackermann:
        from slamcli.planning.car import COST_PENALTY

        if obstacles is not None or clearance_weight != 0.0:
            raise ConfigError(
                "--obstacles and --clearance-weight are for --motion diff",
                hint="leave them out with --motion ackermann",
            )
        _plan_car(
            map,
            s_pose,
            g_pose,
            footprint,
            min_turn_radius,
            reverse,
            reverse_penalty,
            (COST_PENALTY if cost_penalty is None else cost_penalty, inflation_radius),
            max_planning_time,
            full_lock_distance,
            policy,
            (max_speed, max_yaw_rate, max_accel, max_lateral_accel, wheelbase),
            out,
            force,
            started,
        )
        return
    for option, pose in (("--start", s_pose), ("--goal", g_pose)):
        if pose[2] is not None:
            raise ConfigError(
                f"{option}: a heading is used only with --motion ackermann",
                hint=f"give {option} as x,y, or add --motion ackermann",
            )
    start_xy, goal_xy = s_pose[:2], g_pose[:2]
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
            cost_penalty=0.0 if cost_penalty is None else cost_penalty,
            centring_radius_m=inflation_radius,
        )
        written = write_plan(
            result, run, map_file, timings_ms={"read_map": read_ms}, started=started
        )

    rows = plan_summary(result, map_file, start_xy, goal_xy, len(dynamic))
    render.key_values("Plan", rows)
    render.written(written)
    if not result.tracking.reached_goal:
        render.warn("the simulated robot did not reach the goal within the time limit")


def _plan_car(
    map_path: Path,
    s_pose: tuple[float, float, float | None],
    g_pose: tuple[float, float, float | None],
    footprint: str | None,
    min_turn_radius: float,
    reverse: bool,
    reverse_penalty: float,
    centring: tuple[float, float],
    max_planning_time: float,
    full_lock_distance: float,
    policy: str,
    limits_in: tuple[float, float, float, float, float | None],
    out: Path,
    force: bool,
    started: float,
) -> None:
    """``plan --motion ackermann``: plan, write and print a car-like path."""
    from slamcli.planning.car import CarSettings, plan_car
    from slamcli.planning.car_motion import CarLimits
    from slamcli.planning.car_output import write_car_plan
    from slamcli.planning.planner import load_map
    from slamcli.rundir import RunDir

    if footprint is None:
        raise ConfigError(
            "--motion ackermann needs --footprint",
            hint="give the outline as LENGTHxWIDTH (e.g. --footprint 0.9x0.6) or as a polygon "
            "'x1,y1;x2,y2;...' in metres, x forward",
        )
    fp = parse_footprint_option(footprint)
    settings = CarSettings(
        fp,
        min_turn_radius,
        reverse=reverse,
        unknown=policy,
        reverse_weight=reverse_penalty,
        cost_penalty=centring[0],
        inflation_radius_m=centring[1],
        max_planning_time_s=max_planning_time,
        full_lock_distance_m=full_lock_distance if full_lock_distance != 0.0 else None,
    ).checked()
    max_speed, max_yaw_rate, max_accel, max_lateral, wheelbase = limits_in
    length = float(fp.vertices[:, 0].max() - fp.vertices[:, 0].min())
    limits = CarLimits(
        max_speed=max_speed,
        max_accel=max_accel,
        max_lateral_accel=max_lateral,
        max_yaw_rate=max_yaw_rate,
        wheelbase_m=wheelbase if wheelbase is not None else 0.6 * length,
        min_turn_radius_m=min_turn_radius,
    ).checked(
        {
            "max_speed": "--max-speed",
            "max_accel": "--max-accel",
            "max_lateral_accel": "--max-lateral-accel",
            "max_yaw_rate": "--max-yaw-rate",
            "wheelbase_m": "--wheelbase",
            "min_turn_radius_m": "--min-turn-radius",
        }
    )
    start = (s_pose[0], s_pose[1], s_pose[2] or 0.0)
    goal = (g_pose[0], g_pose[1], g_pose[2] or 0.0)
    with RunDir(out, force=force) as run:
        t0 = time.perf_counter()
        grid, map_file = load_map(map_path)
        read_ms = round((time.perf_counter() - t0) * 1000.0, 3)
        result = plan_car(grid, start, goal, settings, limits)
        written = write_car_plan(
            result, run, map_file, timings_ms={"read_map": read_ms}, started=started
        )
    render.key_values("Plan", car_summary(result, map_file))
    render.written(written)
    for warning in result.warnings:
        render.warn(warning)
    if not result.tracking.reached_goal:
        render.warn("the simulated robot did not reach the goal within the time limit")


def car_summary(result: Any, map_file: Path) -> dict[str, str]:
    """The key figures of a car-like plan, as printed by ``slamcli plan --motion ackermann``."""
    tr = result.tracking
    err_m, err_rad = result.goal_error
    s, g = result.start, result.goal
    search_ms = result.timings_ms.get("search", 0.0)
    return {
        "map": str(map_file),
        "start -> goal": f"({s[0]:g}, {s[1]:g}, {s[2]:g} rad) -> ({g[0]:g}, {g[1]:g}, "
        f"{g[2]:g} rad)",
        "length": f"{result.length_m:.3f} m ({len(result.poses)} poses)",
        "gear changes": str(result.reversals),
        "min clearance": f"{result.min_clearance_m:.3f} m (footprint to the nearest blocked cell)",
        "centring": f"median {result.clearance_ratio[0]:.2f}, 10th percentile "
        f"{result.clearance_ratio[1]:.2f} (clearance ratio)",
        "max curvature": f"{result.max_curvature:.4f} 1/m (limit "
        f"{1.0 / result.settings.min_turn_radius_m:.4f})",
        "steering rate": f"{result.max_curvature_rate:.3f} 1/m² of curvature per metre "
        + (
            "(not limited)"
            if result.curvature_rate_limit is None
            else f"(limit {result.curvature_rate_limit:.3f})"
        ),
        "goal error": f"{err_m:.4f} m, {math.degrees(err_rad):.3f} deg",
        "search": f"{result.expanded} states in {search_ms:.0f} ms",
        "trajectory": f"{result.profile.duration_s:.1f} s",
        "time to goal": "not reached"
        if tr.time_to_goal_s is None
        else f"{tr.time_to_goal_s:.1f} s",
        "cross-track error": f"RMS {tr.cross_track_rms_m:.3f} m, max {tr.cross_track_max_m:.3f} m",
    }


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
