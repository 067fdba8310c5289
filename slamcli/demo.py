"""The demo: the main jobs on the bundled sample data, end to end.

1. Dense RGB-D SLAM on ``sample_data/rgbd_room`` (trajectory, mesh as PLY and GLB, report),
   then an occupancy map built from that run (``map.yaml``/``map.pgm``/``map.png``);
2. a path planned across that map between two far-apart free places, smoothed, timed and
   followed by a simulated differential-drive robot;
3. EKF landmark SLAM on ``sample_data/landmarks``.

Each goes into its own folder under the demo's output: ``dense/``, ``plan/``, ``ekf/``.
"""

from __future__ import annotations

from dataclasses import dataclass
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
    """What the demo made: the dense run (with its map), the plan and the EKF run."""

    dense: RunOutcome
    map_files: list[Path]
    plan: Any
    plan_files: list[Path]
    map_file: Path
    start_xy: tuple[float, float]
    goal_xy: tuple[float, float]
    ekf: RunOutcome


def run_demo(
    out: str | Path,
    data: str | Path | None = None,
    landmarks: str | Path | None = None,
    force: bool = False,
    progress: ProgressFn | None = None,
) -> DemoOutcome:
    """Run the three jobs of the module docstring into ``out``."""
    from slamcli.mapping.output import map_run
    from slamcli.planning.output import write_plan
    from slamcli.planning.planner import plan

    rgbd = _existing(data, default_sample(), "rgbd")
    world = _existing(landmarks, default_landmarks(), "landmarks")
    root = RunDir(out, force=force)
    dense = run_pipeline(
        rgbd,
        "dense",
        root.path / "dense",
        force=force,
        command="demo",
        glb=True,
        progress=progress,
    )
    built, map_files = map_run(dense.run_dir, force=True)
    start, goal = far_apart_free_places(built.grid, ROBOT_RADIUS_M)
    result = plan(built.grid, start, goal, robot_radius_m=ROBOT_RADIUS_M)
    map_file = dense.run_dir / "map.yaml"
    plan_files = write_plan(result, RunDir(root.path / "plan", force=force), map_file)
    ekf = run_pipeline(world, "ekf", root.path / "ekf", force=force, command="demo")
    return DemoOutcome(dense, map_files, result, plan_files, map_file, start, goal, ekf)


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
