"""Write a plan's files into a run folder: CSVs, plan.json and plan.png.

Files (all written through :class:`slamcli.rundir.RunDir`, which the caller commits):

- ``path.csv`` ``x,y``: the grid path, cell centres in metres, start cell to goal cell;
- ``path_smooth.csv`` ``x,y``: the smoothed path, start point to goal point;
- ``trajectory.csv`` ``t,x,y,theta,v,omega``: the smoothed path timed every ``dt_s`` (s, m, m,
  rad in (-pi, pi], m/s, rad/s);
- ``tracked.csv`` ``t,x,y,theta,v,omega``: the simulated robot following it (every tracker
  step), replans included;
- ``plan.json``: the figures and settings (keys in :func:`plan_record`);
- ``plan.png``: the map, the inflated zone, the paths, start, goal and dynamic obstacles.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.planning.planner import PlanResult
from slamcli.rundir import RunDir, hash_input

PLAN_SCHEMA_VERSION = 1
"""Version of plan.json's layout."""

OUTPUT_FILES = (
    "path.csv",
    "path_smooth.csv",
    "trajectory.csv",
    "tracked.csv",
    "plan.json",
    "plan.png",
)


def _csv(columns: str, rows: NDArray[np.float64]) -> str:
    """``columns`` as a header line, then one line per row, every value ``%.6f``, comma
    separated (the text ``numpy.savetxt`` writes, at a fraction of its cost)."""
    table = np.atleast_2d(np.asarray(rows, dtype=np.float64))
    if table.size == 0:
        return columns + "\n"
    line = ",".join(["%.6f"] * table.shape[1]) + "\n"
    return columns + "\n" + (line * len(table)) % tuple(table.ravel().tolist())


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def plan_record(result: PlanResult, map_file: str | Path | None = None) -> dict[str, Any]:
    """plan.json's content.

    Keys: ``schema_version``, ``slamcli_version``, ``map`` (``path``, ``sha256``, ``bytes``,
    ``image`` {path, sha256, bytes} for a map_server YAML, ``resolution_m``,
    ``origin_xy_yaw``, ``shape_hw``), ``start``, ``goal`` ([x, y] m), ``start_cell``,
    ``goal_cell`` ([row, col]), ``robot_radius_m``, ``settings``, ``grid_cost_m`` (the search's
    cost exactly), ``grid_cells``, ``length_m`` (smoothed path), ``min_clearance_m`` (smoothed
    path to the nearest occupied cell centre; null without obstacles), ``expanded``,
    ``reached``, ``search_method``, ``plan_ms``, ``timings_ms`` (the plan's stages here;
    :func:`write_plan` adds the rest), ``trajectory_s`` (planned
    duration), ``time_to_goal_s`` (simulated; null if not reached), ``goal_reached``,
    ``tracking`` {cross_track_max_m, cross_track_rms_m}, ``replans``, ``waits``, ``events``
    [{t_s, x, y, kind (replan / wait / resume), obstacle}], ``obstacles``.
    """
    from slamcli import __version__

    grid = result.costmap.grid
    tr = result.tracking
    record: dict[str, Any] = {
        "schema_version": PLAN_SCHEMA_VERSION,
        "slamcli_version": __version__,
        "map": _map_record(grid, map_file),
        "start": list(result.start_xy),
        "goal": list(result.goal_xy),
        "start_cell": list(result.start_cell),
        "goal_cell": list(result.goal_cell),
        "robot_radius_m": result.costmap.robot_radius_m,
        "settings": result.settings,
        "grid_cost_m": result.grid_cost_m,
        "grid_cells": len(result.search.cells),
        "length_m": result.length_m,
        "min_clearance_m": _finite(result.min_clearance_m),
        "expanded": result.search.expanded,
        "reached": result.search.reached,
        "search_method": result.search.method,
        "plan_ms": result.plan_ms,
        "timings_ms": result.timings_ms,
        "trajectory_s": result.profile.duration_s,
        "time_to_goal_s": tr.time_to_goal_s,
        "goal_reached": tr.reached_goal,
        "tracking": {
            "cross_track_max_m": tr.cross_track_max_m,
            "cross_track_rms_m": tr.cross_track_rms_m,
        },
        "replans": tr.replans,
        "waits": tr.waits,
        "events": tr.events,
        "obstacles": [o.as_dict() for o in result.obstacles],
    }
    return record


def _map_record(grid: Any, map_file: str | Path | None) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if map_file is not None:
        info = hash_input(map_file)
        out.update(path=info["path"], sha256=info["hash"].split(":", 1)[1], bytes=info["bytes"])
        source = getattr(grid, "source_format", None)
        if isinstance(source, dict) and source.get("image"):
            image = Path(str(source["image"]))
            image = image if image.is_absolute() else Path(map_file).parent / image
            if image.is_file():
                img = hash_input(image)
                out["image"] = {
                    "path": img["path"],
                    "sha256": img["hash"].split(":", 1)[1],
                    "bytes": img["bytes"],
                }
    h, w = np.asarray(grid.prob).shape
    out.update(
        resolution_m=float(grid.resolution_m),
        origin_xy_yaw=[float(v) for v in grid.origin_xy_yaw],
        shape_hw=[int(h), int(w)],
    )
    return out


def write_plan(
    result: PlanResult,
    run: RunDir,
    map_file: str | Path | None = None,
    *,
    timings_ms: dict[str, float] | None = None,
    started: float | None = None,
) -> list[Path]:
    """Write every file of the module docstring into ``run``; returns their paths.

    plan.json's ``timings_ms`` holds ``timings_ms`` (the caller's stages before planning, such
    as ``read_map``), the plan's own stages, ``plot`` (plan.png) and ``write`` (the CSVs and
    the hashes of the inputs), in ms; and ``total``, the wall time since ``started`` (a
    ``time.perf_counter()`` value, e.g. the command's start), when given. plan.json is written
    last, so these cover every other file.
    """
    from slamcli.planning.plot import plot_plan

    csvs = {
        "path.csv": _csv("x,y", result.grid_xy),
        "path_smooth.csv": _csv("x,y", result.smooth_xy),
        "trajectory.csv": _csv("t,x,y,theta,v,omega", result.trajectory),
        "tracked.csv": _csv("t,x,y,theta,v,omega", result.tracking.states),
    }
    timings = {**(timings_ms or {}), **result.timings_ms}
    write_timed(
        run,
        csvs,
        lambda tmp: plot_plan(tmp, result),
        lambda: plan_record(result, map_file),
        timings,
        started,
    )
    return [run.path / name for name in OUTPUT_FILES]


def write_timed(
    run: RunDir,
    csvs: dict[str, str],
    plot: Callable[[Path], object],
    record: Callable[[], dict[str, Any]],
    timings_ms: dict[str, float],
    started: float | None,
) -> None:
    """Write the CSV texts, plan.png (``plot(path)``) and, last, plan.json (``record()``) with
    ``timings_ms`` completed by ``plot`` (plan.png), ``write`` (the CSVs and the record) and,
    when ``started`` (a ``time.perf_counter()`` value) is given, ``total``."""
    t0 = time.perf_counter()
    for name, text in csvs.items():
        run.write_text(name, text)
    t1 = time.perf_counter()
    with run.atomic("plan.png") as tmp:
        plot(tmp)
    t2 = time.perf_counter()
    content = record()
    t3 = time.perf_counter()
    timings = dict(timings_ms)
    timings["plot"] = _ms(t2 - t1)
    timings["write"] = _ms((t1 - t0) + (t3 - t2))
    if started is not None:
        timings["total"] = _ms(t3 - started)
    content["timings_ms"] = timings
    run.write_json("plan.json", content)


def _ms(seconds: float) -> float:
    return round(seconds * 1000.0, 3)


def process_start() -> float | None:
    """When this process started, as a ``time.perf_counter()`` value (resolution: one clock
    tick, 10 ms on Linux); None where the kernel does not say (no ``/proc``)."""
    try:
        stat = Path("/proc/self/stat").read_text()
        # Fields after the command name in parentheses; field 22 (starttime) is the 20th.
        ticks = int(stat[stat.rindex(")") + 2 :].split()[19])
        since_boot = time.clock_gettime(time.CLOCK_BOOTTIME)
        age = since_boot - ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, AttributeError):
        return None
    return time.perf_counter() - max(age, 0.0)
