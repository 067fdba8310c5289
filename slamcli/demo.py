"""The demo: the main jobs on the bundled sample data, end to end.

1. Dense RGB-D SLAM on ``sample_data/rgbd_room`` (trajectory, mesh as PLY and GLB, report),
   then an occupancy map built from that run (``map.yaml``/``map.pgm``/``map.png``);
2. a path planned across that map between two far-apart free places, smoothed, timed and
   followed by a simulated differential-drive robot;
3. EKF landmark SLAM on ``sample_data/landmarks``;
4. feature-based visual SLAM on the same RGB-D sequence (trajectory, keyframes, coloured
   points, pose graph), to set beside the dense run.

Each goes into its own folder under the demo's output: ``dense/``, ``plan/``, ``ekf/``,
``visual/``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from slamcli.errors import InputError
from slamcli.run import RunOutcome, run_pipeline
from slamcli.rundir import RunDir
from slamcli.types import OccupancyGrid, ProgressFn

SAMPLE_ROOT = Path(__file__).resolve().parents[1] / "sample_data"
"""sample_data/ of a source checkout (an installed wheel does not carry it)."""

ROBOT_RADIUS_M = 0.15
"""Radius of the robot the demo plans for: small, the sample room is about 4 m across."""


def default_sample() -> Path:
    """The bundled RGB-D sample sequence."""
    return SAMPLE_ROOT / "rgbd_room"


def default_landmarks() -> Path:
    """The bundled landmark world."""
    return SAMPLE_ROOT / "landmarks"


@dataclass
class DemoOutcome:
    """What the demo made: the dense run (with its map), the plan, the EKF and visual runs."""

    dense: RunOutcome
    map_files: list[Path]
    plan: Any
    plan_files: list[Path]
    map_file: Path
    start_xy: tuple[float, float]
    goal_xy: tuple[float, float]
    ekf: RunOutcome
    visual: RunOutcome


def run_demo(
    out: str | Path,
    data: str | Path | None = None,
    landmarks: str | Path | None = None,
    force: bool = False,
    progress: ProgressFn | None = None,
) -> DemoOutcome:
    """Run the four jobs of the module docstring into ``out``."""
    from slamcli.mapping.output import map_run
    from slamcli.planning.output import write_plan
    from slamcli.planning.planner import plan

    rgbd = _existing(data, default_sample(), "rgbd")
    world = _existing(landmarks, default_landmarks(), "landmarks")
    # The jobs go into one staged folder: a failed or interrupted demo leaves an earlier
    # demo folder whole, never a new dense run beside an old plan.
    with RunDir(out, force=force) as root:
        dense = run_pipeline(
            rgbd, "dense", root.staged("dense"), command="demo", glb=True, progress=progress
        )
        built, map_files = map_run(dense.run_dir, force=True)
        start, goal = far_apart_free_places(built.grid, ROBOT_RADIUS_M)
        result = plan(built.grid, start, goal, robot_radius_m=ROBOT_RADIUS_M)
        map_file = dense.run_dir / "map.yaml"
        with RunDir(root.staged("plan")) as plan_dir:
            plan_files = write_plan(result, plan_dir, map_file)
        ekf = run_pipeline(world, "ekf", root.staged("ekf"), command="demo")
        visual = run_pipeline(rgbd, "visual", root.staged("visual"), command="demo")
        root.relocate_records()
    return DemoOutcome(
        _final_run(root, dense),
        [root.final(p) for p in map_files],
        result,
        [root.final(p) for p in plan_files],
        root.final(map_file),
        start,
        goal,
        _final_run(root, ekf),
        _final_run(root, visual),
    )


def _final_run(root: RunDir, outcome: RunOutcome) -> RunOutcome:
    """``outcome`` with its paths moved from ``root``'s staging folder to the final one."""
    return replace(
        outcome,
        run_dir=root.final(outcome.run_dir),
        outputs=[root.final(p) for p in outcome.outputs],
    )


def far_apart_free_places(
    grid: OccupancyGrid, robot_radius_m: float
) -> tuple[tuple[float, float], tuple[float, float]]:
    """Two cell centres of the largest free region (after inflation), far apart: the cell
    farthest from the region's centre, and the cell farthest from that one."""
    from scipy import ndimage

    from slamcli.formats.occupancy import cell_to_world
    from slamcli.planning.costmap import build_costmap

    blocked = build_costmap(grid, robot_radius_m=robot_radius_m).blocked
    labels, count = ndimage.label(~blocked)
    if count == 0:
        raise InputError("the map has no free space for the demo's robot")
    sizes = np.bincount(labels.ravel())[1:]
    cells = np.argwhere(labels == 1 + int(np.argmax(sizes))).astype(np.float64)
    a = cells[np.argmax(np.hypot(*(cells - cells.mean(axis=0)).T))]
    b = cells[np.argmax(np.hypot(*(cells - a).T))]
    xy = cell_to_world(grid, np.stack([a, b]).astype(np.int64))
    return (float(xy[0, 0]), float(xy[0, 1])), (float(xy[1, 0]), float(xy[1, 1]))


def _existing(given: str | Path | None, default: Path, kind: str) -> Path:
    path = Path(given) if given is not None else default
    if not path.exists():
        raise InputError(
            f"{path}: sample data not found",
            hint=f"make one with 'slamcli synth {kind} DIR' and pass it to the demo",
        )
    return path
