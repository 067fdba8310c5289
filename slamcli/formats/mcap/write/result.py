"""SLAM results written as an MCAP log a user drags into Foxglove: the trajectory, the occupancy
map, the point cloud and the mesh (a GLB model inside a ``foxglove.SceneUpdate``)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ExportError
from slamcli.formats.mcap.write.foxglove import (
    IDENTITY_POSE,
    b64,
    fox_pose,
    fox_time,
    put_json,
    write_pose_and_tf,
)
from slamcli.formats.mcap.write.layer import (
    RESULT_CAMERA_FRAME,
    TOPIC_RESULT_MAP,
    TOPIC_RESULT_MESH,
    TOPIC_RESULT_POINTS,
    TOPIC_RESULT_POSE,
    WORLD_FRAME,
    McapWriteSummary,
    open_log,
)
from slamcli.formats.mesh import mesh_to_glb
from slamcli.formats.run_folder import RESULT_KINDS, RUN_FILES, read_run
from slamcli.types import OccupancyGrid, SlamResult, TriangleMesh

# Foxglove's NumericType enum values (PackedElementField.type).
_UINT8, _INT8, _FLOAT32 = 1, 2, 7

# Foxglove turns glTF's Y-up into its Z-up by rotating every model +90° about x; a model pose
# of -90° about x undoes that, so the GLB keeps the mesh's own coordinates.
_GLTF_TO_WORLD_XYZW = (-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5))


def write_result_log(
    out: str | Path, result: SlamResult, *, force: bool = False
) -> McapWriteSummary:
    """Write a SLAM result as an MCAP log that opens in Foxglove (JSON, official schemas).

    Topics: ``/slamcli/pose`` (``foxglove.PoseInFrame`` per pose, in ``world``) and ``/tf``
    (``foxglove.FrameTransform`` world -> ``camera``) from the trajectory; ``/slamcli/map``
    (``foxglove.Grid``), ``/slamcli/points`` (``foxglove.PointCloud``) and ``/slamcli/mesh``
    (``foxglove.SceneUpdate`` with the mesh as a GLB model, vertex colours kept), each once at
    the trajectory's first stamp (0 without a trajectory). The run calls this at its end for
    ``--mcap``; :func:`write_result_mcap` does the same from a run folder's files.

    The grid's cells carry ``occupancy`` (int8: 0-100 percent, -1 unknown, as
    ``nav_msgs/OccupancyGrid``) and ``red``/``green``/``blue``/``alpha`` (uint8: free white,
    occupied black, unknown grey) so Foxglove shows it like a map server would.

    Raises:
        ExportError: nothing to write, ``out`` exists without ``force``, or a write failed.
    """
    out = Path(out)
    traj = result.trajectory
    if traj is None and result.grid is None and result.points is None and result.mesh is None:
        raise ExportError(
            f"{out}: nothing to write; the result has no trajectory, map, points or mesh"
        )
    t0 = int(traj.stamps_ns[0]) if traj is not None and len(traj) else 0
    with open_log(out, "", force) as mcap_log:
        if result.grid is not None:
            put_json(mcap_log, TOPIC_RESULT_MAP, "Grid", t0, grid_message(result.grid, t0))
        if result.points is not None:
            msg = point_cloud_message(result.points, result.point_colors, t0)
            put_json(mcap_log, TOPIC_RESULT_POINTS, "PointCloud", t0, msg)
        if result.mesh is not None:
            put_json(mcap_log, TOPIC_RESULT_MESH, "SceneUpdate", t0, mesh_message(result.mesh, t0))
        if traj is not None:
            for stamp, pose in zip(traj.stamps_ns.tolist(), traj.world_from_body, strict=True):
                write_pose_and_tf(mcap_log, TOPIC_RESULT_POSE, RESULT_CAMERA_FRAME, stamp, pose)
        topics = mcap_log.topics()
    return McapWriteSummary(out, topics)


def grid_message(grid: OccupancyGrid, stamp_ns: int) -> dict[str, Any]:
    """A ``foxglove.Grid`` (JSON) of an occupancy grid; row 0 is the lowest y, as in the grid."""
    prob = np.asarray(grid.prob, dtype=np.float32)
    if prob.ndim != 2 or prob.size == 0:
        raise ExportError(f"occupancy grid must be a non-empty (H, W) array, got {prob.shape}")
    h, w = prob.shape
    unknown = np.isnan(prob)
    p = np.clip(np.where(unknown, 0.0, prob), 0.0, 1.0)
    cells = np.empty((h, w, 5), dtype=np.uint8)
    cells[..., 0] = np.where(unknown, -1, np.rint(p * 100.0)).astype(np.int8).view(np.uint8)
    cells[..., 1:4] = np.where(unknown, 205, np.rint((1.0 - p) * 255.0)).astype(np.uint8)[..., None]
    cells[..., 4] = 255
    x, y, yaw = (float(v) for v in grid.origin_xy_yaw)
    res = float(grid.resolution_m)
    fields = [
        {"name": "occupancy", "offset": 0, "type": _INT8},
        {"name": "red", "offset": 1, "type": _UINT8},
        {"name": "green", "offset": 2, "type": _UINT8},
        {"name": "blue", "offset": 3, "type": _UINT8},
        {"name": "alpha", "offset": 4, "type": _UINT8},
    ]
    return {
        "timestamp": fox_time(stamp_ns),
        "frame_id": WORLD_FRAME,
        "pose": fox_pose((x, y, 0.0), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))),
        "column_count": w,
        "cell_size": {"x": res, "y": res},
        "row_stride": w * 5,
        "cell_stride": 5,
        "fields": fields,
        "data": b64(cells.tobytes()),
    }


def point_cloud_message(
    points: NDArray[np.floating[Any]], colors: NDArray[np.uint8] | None, stamp_ns: int
) -> dict[str, Any]:
    """A ``foxglove.PointCloud`` (JSON): float32 x, y, z (m) and, with colours, uint8 RGBA."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    layout = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    fields = [{"name": n, "offset": 4 * i, "type": _FLOAT32} for i, n in enumerate("xyz")]
    if colors is not None:
        rgb = np.asarray(colors, dtype=np.uint8).reshape(len(pts), -1)
        layout += [("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1")]
        fields += [
            {"name": n, "offset": 12 + i, "type": _UINT8}
            for i, n in enumerate(("red", "green", "blue", "alpha"))
        ]
    packed = np.zeros(len(pts), dtype=np.dtype(layout))
    for i, axis in enumerate("xyz"):
        packed[axis] = pts[:, i]
    if colors is not None:
        packed["red"], packed["green"], packed["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
        packed["alpha"] = rgb[:, 3] if rgb.shape[1] > 3 else 255
    return {
        "timestamp": fox_time(stamp_ns),
        "frame_id": WORLD_FRAME,
        "pose": IDENTITY_POSE,
        "point_stride": packed.dtype.itemsize,
        "fields": fields,
        "data": b64(packed.tobytes()),
    }


def mesh_message(mesh: TriangleMesh, stamp_ns: int) -> dict[str, Any]:
    """A ``foxglove.SceneUpdate`` (JSON) with one entity holding the mesh as a GLB model."""
    model = {
        "pose": fox_pose((0.0, 0.0, 0.0), _GLTF_TO_WORLD_XYZW),
        "scale": {"x": 1.0, "y": 1.0, "z": 1.0},
        "color": {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0},
        "override_color": False,
        "url": "",
        "media_type": "model/gltf-binary",
        "data": b64(mesh_to_glb(mesh)),
    }
    entity = {
        "timestamp": fox_time(stamp_ns),
        "frame_id": WORLD_FRAME,
        "id": "mesh",
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [],
        "arrows": [],
        "cubes": [],
        "spheres": [],
        "cylinders": [],
        "lines": [],
        "triangles": [],
        "texts": [],
        "models": [model],
    }
    return {"deletions": [], "entities": [entity]}


def write_result_mcap(
    run_dir: str | Path, out: str | Path | None = None, *, force: bool = False
) -> Path:
    """Write ``result.mcap`` (or ``out``) for a run folder; see :func:`write_result_log`.

    Raises:
        InputError: not a run folder, or an unreadable result file.
        ExportError: the folder holds none of the files of
            :data:`~slamcli.formats.run_folder.RESULT_KINDS`, ``out`` exists without
            ``force``, or the write failed.
    """
    run = read_run(run_dir)
    if not any(run.has(kind) for kind in RESULT_KINDS):
        names = ", ".join(RUN_FILES[kind] for kind in RESULT_KINDS)
        raise ExportError(f"{run.path}: nothing to write; the run folder has none of {names}")
    dest = Path(out) if out is not None else run.path / "result.mcap"
    return write_result_log(dest, run.result(), force=force).path
