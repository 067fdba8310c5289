"""Write a car-like plan's files into a run folder: CSVs, plan.json and plan.png.

- ``path.csv`` ``x,y,yaw,direction,curvature,steering``: the final path (m, rad, +1 forward /
  -1 reverse for the motion leaving each pose, 1/m, and the front wheel's steering angle
  ``atan(wheelbase · curvature)`` in rad, left positive), at most half a map cell apart;
- ``path_search.csv`` ``x,y,yaw``: the search's lattice poses before smoothing;
- ``trajectory.csv`` ``t,x,y,theta,v,omega``: the path timed every ``dt_s`` (v < 0 reversing);
- ``tracked.csv`` ``t,x,y,theta,v,omega``: the simulated bicycle-model robot;
- ``plan.json``: the figures and settings (keys in :func:`car_plan_record`);
- ``plan.png``: the map, the path coloured by gear, footprints along it, start and goal.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from slamcli.planning.car import CarPlanResult
from slamcli.planning.output import PLAN_SCHEMA_VERSION, _csv, _map_record, write_timed
from slamcli.rundir import RunDir

CAR_OUTPUT_FILES = (
    "path.csv",
    "path_search.csv",
    "trajectory.csv",
    "tracked.csv",
    "plan.json",
    "plan.png",
)


def car_plan_record(result: CarPlanResult, map_file: str | Path | None = None) -> dict[str, Any]:
    """plan.json's content for ``--motion ackermann``.

    Keys: ``schema_version``, ``slamcli_version``, ``motion`` ("ackermann"), ``map`` (as for
    the round robot), ``start``/``goal`` ([x, y, yaw] m, rad), ``footprint`` (vertices, m),
    ``settings``, ``limits``, ``length_m``, ``reversals`` (gear changes), ``min_clearance_m``
    (footprint to the nearest blocked cell over every pose, capped at 2 m),
    ``clearance_ratio`` (``median`` and ``p10``, the 10th percentile, over the poses: 1 on the
    middle line of the free space, 0 at a wall),
    ``max_curvature_per_m`` and ``curvature_limit_per_m`` (1 / min turn radius),
    ``max_curvature_rate_per_m2`` (measured from the poses, within each gear) and
    ``curvature_rate_limit_per_m2`` (None with ``--full-lock-distance 0``),
    ``goal_error_m``/``goal_error_deg`` (last pose to the goal), ``expanded``, ``timings_ms``,
    ``trajectory_s``, ``time_to_goal_s``, ``goal_reached``, ``warnings`` (a search cut short by
    the time budget), ``tracking``.
    """
    from slamcli import __version__

    s = result.settings
    tr = result.tracking
    err_m, err_rad = result.goal_error
    return {
        "schema_version": PLAN_SCHEMA_VERSION,
        "slamcli_version": __version__,
        "motion": "ackermann",
        "map": _map_record(result.grid, map_file),
        "start": list(result.start),
        "goal": list(result.goal),
        "footprint": s.footprint.vertices.tolist(),
        "settings": {
            "min_turn_radius_m": s.min_turn_radius_m,
            "reverse": s.reverse,
            "unknown": s.unknown,
            "bin_m": s.bin_m,
            "step_m": s.step_m,
            "n_steer": s.n_steer,
            "reverse_weight": s.reverse_weight,
            "switch_penalty_m": s.switch_penalty_m,
            "max_expanded": s.max_expanded,
            "cost_penalty": s.cost_penalty,
            "inflation_radius_m": s.inflation_radius_m,
            "max_planning_time_s": s.max_planning_time_s,
            "full_lock_distance_m": s.full_lock_distance_m,
        },
        "limits": {k: getattr(result.limits, k) for k in result.limits.__dataclass_fields__},
        "length_m": result.length_m,
        "reversals": result.reversals,
        "min_clearance_m": result.min_clearance_m,
        "clearance_ratio": {
            "median": result.clearance_ratio[0],
            "p10": result.clearance_ratio[1],
        },
        "max_curvature_per_m": result.max_curvature,
        "curvature_limit_per_m": 1.0 / s.min_turn_radius_m,
        "max_curvature_rate_per_m2": result.max_curvature_rate,
        "curvature_rate_limit_per_m2": result.curvature_rate_limit,
        "goal_error_m": err_m,
        "goal_error_deg": math.degrees(err_rad),
        "expanded": result.expanded,
        "timings_ms": result.timings_ms,
        "trajectory_s": result.profile.duration_s,
        "time_to_goal_s": tr.time_to_goal_s,
        "goal_reached": tr.reached_goal,
        "warnings": list(result.warnings),
        "tracking": {
            "cross_track_max_m": tr.cross_track_max_m,
            "cross_track_rms_m": tr.cross_track_rms_m,
        },
    }


def write_car_plan(
    result: CarPlanResult,
    run: RunDir,
    map_file: str | Path | None = None,
    *,
    timings_ms: dict[str, float] | None = None,
    started: float | None = None,
) -> list[Path]:
    """Write every file of the module docstring into ``run``; returns their paths.

    plan.json's ``timings_ms`` holds ``timings_ms`` (the caller's stages, such as
    ``read_map``), the plan's own stages, ``plot``, ``write`` and, when ``started`` (a
    ``time.perf_counter()`` value) is given, ``total``: plan.json is written last.
    """
    from slamcli.planning.car_plot import plot_car_plan

    steering = np.arctan(result.limits.wheelbase_m * result.curvature)
    path = np.column_stack(
        (result.poses, result.direction.astype(np.float64), result.curvature, steering)
    )
    csvs = {
        "path.csv": _csv("x,y,yaw,direction,curvature,steering", path),
        "path_search.csv": _csv("x,y,yaw", result.search_poses),
        "trajectory.csv": _csv("t,x,y,theta,v,omega", result.trajectory),
        "tracked.csv": _csv("t,x,y,theta,v,omega", result.tracking.states),
    }
    write_timed(
        run,
        csvs,
        lambda tmp: plot_car_plan(tmp, result),
        lambda: car_plan_record(result, map_file),
        {**(timings_ms or {}), **result.timings_ms},
        started,
    )
    return [run.path / name for name in CAR_OUTPUT_FILES]
