"""ms/frame and accuracy of `slamcli run dense` beside Open3D's own frame-to-model loop.

The reference is the loop of Open3D's dense SLAM example (`o3d.t.pipelines.slam.Model`:
track against the ray-cast model, integrate, ray-cast), run on the same frames, decoded by the
same reader, in the same process and with the same (single-threaded) Open3D. Ours is the whole
`run_pipeline` call: reading, tracking with everything the pipeline adds, loop closure, mesh
extraction and writing the run folder, with ``threads = 2`` (frames decoded ahead on a second
core) and ``threads = 1``, whose trajectories must be identical.

Usage: python benchmarks/bench_dense.py [TUM_FOLDER] [--frames N] [--voxel 0.01]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

DEFAULT = Path(__file__).resolve().parents[2] / "shared/data/tum/rgbd_dataset_freiburg1_rpy_excerpt"
GOAL = 1.25


def open3d_loop(frames: list[Any], voxel: float, depth_max: float) -> tuple[float, np.ndarray]:
    """Open3D's example loop; returns (seconds, (N,4,4) world_from_camera)."""
    from slamcli.backends import import_open3d

    o3d = import_open3d()
    o3c = o3d.core
    device = o3c.Device("CPU:0")
    cam = frames[0].camera
    intrinsic = o3c.Tensor(cam.K, o3c.float64)
    pose = o3c.Tensor(np.eye(4))
    model = o3d.t.pipelines.slam.Model(voxel, 16, 40000, pose, device)
    h, w = frames[0].depth_m.shape
    input_frame = o3d.t.pipelines.slam.Frame(h, w, intrinsic, device)
    raycast_frame = o3d.t.pipelines.slam.Frame(h, w, intrinsic, device)
    poses = []
    start = time.perf_counter()
    for i, f in enumerate(frames):
        input_frame.set_data_from_image("depth", o3d.t.geometry.Image(f.depth_m))
        colour = np.ascontiguousarray(f.rgb, dtype=np.float32) / 255.0
        input_frame.set_data_from_image("color", o3d.t.geometry.Image(colour))
        if i > 0:
            result = model.track_frame_to_model(input_frame, raycast_frame, 1.0, depth_max, 0.07)
            pose = pose @ result.transformation
        poses.append(pose.cpu().numpy())
        model.update_frame_pose(i, pose)
        model.integrate(input_frame, 1.0, depth_max, 8.0)
        model.synthesize_model_frame(raycast_frame, 1.0, 0.1, depth_max, 8.0, False)
    return time.perf_counter() - start, np.stack(poses)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", nargs="?", type=Path, default=DEFAULT)
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--voxel", type=float, default=0.01)
    parser.add_argument("--depth-max", type=float, default=3.0)
    args = parser.parse_args()

    from slamcli.evaluation import evaluate
    from slamcli.formats import open_source
    from slamcli.run import run_pipeline
    from slamcli.types import RgbdFrame, Trajectory

    with open_source(args.folder) as source:
        frames = [f for f in source.frames(("rgbd",)) if isinstance(f, RgbdFrame)]
        frames = frames[: args.frames]
        groundtruth = source.groundtruth()
    stamps = np.array([f.stamp_ns for f in frames], dtype=np.int64)

    from slamcli.pipelines.dense import DenseConfig

    ref_s, ref_poses = open3d_loop(frames, args.voxel, args.depth_max)
    n = len(frames)
    rows = [("Open3D t.pipelines.slam.Model loop", ref_s, Trajectory(stamps, ref_poses))]
    runs = {}
    for threads in (2, 1):
        with tempfile.TemporaryDirectory(prefix="bench_dense_") as tmp:
            start = time.perf_counter()
            outcome = run_pipeline(
                args.folder,
                "dense",
                Path(tmp) / "run",
                max_frames=args.frames,
                config=DenseConfig(threads=threads),
            )
            runs[threads] = (time.perf_counter() - start, outcome.result.trajectory)
        label = f"slamcli run dense, threads={threads}"
        rows.append((label, runs[threads][0], runs[threads][1]))
    ours_s = runs[2][0]
    print(f"{args.folder.name}: {n} frames, voxel {args.voxel} m (reference), same process")
    print(f"{'variant':<38}{'ms/frame':>10}{'ATE rmse m':>12}")
    for label, seconds, traj in rows:
        ate = "-"
        if groundtruth is not None and traj is not None:
            ate = f"{evaluate(groundtruth, traj, align='se3').ate.rmse:.4f}"
        print(f"{label:<38}{seconds / n * 1000:>10.1f}{ate:>12}")
    ratio = ours_s / ref_s
    verdict = "meets" if ratio <= GOAL else "MISSES"
    print(f"ours (threads=2) / reference time: {ratio:.2f}x ({verdict} the goal <= {GOAL:.2f}x)")
    (t2, a), (t1, b) = runs[2], runs[1]
    same = a is not None and b is not None and np.array_equal(a.world_from_body, b.world_from_body)
    print(f"threads=1 / threads=2: {t1 / t2:.2f}x; trajectories identical: {same}")


if __name__ == "__main__":
    main()
