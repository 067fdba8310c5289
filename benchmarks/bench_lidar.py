"""2-D lidar SLAM time per scan beside a plain scan-to-scan ICP, measured in the same run.

Ours is `slamcli.pipelines.lidar.LidarSlam` fed a laser log (default: the shared CSAIL log,
361 beams a scan), everything included: points, correlative search and refinement, submap
insertion, loop search and the pose-graph solves, and the map at the end. The scans come with
drifting odometry made from the log's corrected poses (2.5 % long, 0.015 rad per metre heading
bias, seeded noise; as the tests make it), so loop search works as hard as on real odometry.

The reference is Open3D's point-to-point ICP (`registration_icp`, C++) of each scan to the one
before, from the odometry's guess, with a 0.5 m correspondence distance and at most 30
iterations: the plain scan matcher a lidar SLAM front end replaces.

Memory: the bytes the pipeline holds at the end (submap grids, cached pyramids, per-scan
records) beside those after half the log: submaps, not scans, are kept.

Usage: python benchmarks/bench_lidar.py [LOG] [--repeat 1]
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve()
DEFAULT = HERE.parents[2] / "shared/data/lidar/carmen/csail-corrected.log.gz"
GOAL_MS = 25.0


def drifting(reference: np.ndarray, seed: int = 0) -> np.ndarray:
    from slamcli.geometry.planar import between_planar, compose_planar

    rng = np.random.default_rng(seed)
    out = [reference[0].copy()]
    for a, b in itertools.pairwise(reference):
        d = between_planar(a, b)
        dist = math.hypot(d[0], d[1])
        sigma = 0.01 + 0.01 * dist
        step = np.array(
            [
                1.025 * d[0] + rng.normal(0, sigma),
                1.025 * d[1] + rng.normal(0, sigma),
                d[2] + 0.015 * dist + rng.normal(0, 0.005 + 0.002 * abs(d[2])),
            ]
        )
        out.append(compose_planar(out[-1], step))
    return np.array(out)


def held_bytes(slam: object) -> int:
    """Bytes of the arrays the pipeline holds: submap grids and pyramids, node and scan records."""
    total = 0
    for sub in slam._submaps.all:  # type: ignore[attr-defined]
        total += sub.grid.log_odds.nbytes + sub.grid.seen.nbytes
        if sub._pyramid is not None:
            total += sum(level.nbytes for level in sub._pyramid.levels)
    total += 24 * 2 * len(slam._local) + 48 * len(slam._scans)  # type: ignore[attr-defined]
    return total


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("log", nargs="?", type=Path, default=DEFAULT)
    parser.add_argument("--repeat", type=int, default=1)
    args = parser.parse_args()
    if not args.log.exists():
        print(f"no log at {args.log}", file=sys.stderr)
        return 1

    import open3d as o3d

    from slamcli.formats.carmen import CarmenSource
    from slamcli.geometry.planar import between_planar, planar_to_se3, se3_to_planar
    from slamcli.pipelines.lidar import LidarSlam
    from slamcli.scans.points import scan_points
    from slamcli.types import OdometryFrame, ScanFrame

    with CarmenSource.open(args.log, odometry="none", groundtruth="log") as source:
        scans = [f for f in source.frames(("scan",)) if isinstance(f, ScanFrame)]
        reference = source.groundtruth()
    assert reference is not None
    odometry = drifting(se3_to_planar(reference.world_from_body))
    beams = len(scans[0].ranges_m)

    ours_ms, half_bytes, end_bytes = [], 0, 0
    for _ in range(args.repeat):
        slam = LidarSlam()
        start = time.perf_counter()
        for k, (scan, odo) in enumerate(zip(scans, odometry, strict=True)):
            slam.process(OdometryFrame(scan.stamp_ns, world_from_body=planar_to_se3(odo)))
            slam.process(scan)
            if k == len(scans) // 2:
                half_bytes = held_bytes(slam)
        slam.finish()
        ours_ms.append(1000 * (time.perf_counter() - start) / len(scans))
        end_bytes = held_bytes(slam)

    reg = o3d.pipelines.registration
    clouds = []
    for scan in scans:
        pts = scan_points(scan, 30.0)
        cloud = o3d.geometry.PointCloud(
            o3d.utility.Vector3dVector(np.column_stack([pts, np.zeros(len(pts))]))
        )
        clouds.append(cloud)
    icp_ms = []
    for _ in range(args.repeat):
        start = time.perf_counter()
        for k in range(1, len(scans)):
            guess = planar_to_se3(between_planar(odometry[k - 1], odometry[k])[None])[0]
            reg.registration_icp(
                clouds[k],
                clouds[k - 1],
                0.5,
                guess,
                reg.TransformationEstimationPointToPoint(),
                reg.ICPConvergenceCriteria(max_iteration=30),
            )
        icp_ms.append(1000 * (time.perf_counter() - start) / (len(scans) - 1))

    print(f"log: {args.log.name}, {len(scans)} scans of {beams} beams")
    print(f"{'':34}{'ms per scan':>12}")
    print(f"{'slamcli run lidar (everything)':34}{min(ours_ms):12.1f}   goal <= {GOAL_MS:.0f}")
    print(f"{'Open3D ICP, scan to scan':34}{min(icp_ms):12.1f}")
    print(f"ratio ours / ICP: {min(ours_ms) / min(icp_ms):.1f}x")
    print(
        f"held by the pipeline: {half_bytes / 2**20:.1f} MiB after half the log, "
        f"{end_bytes / 2**20:.1f} MiB at the end"
    )
    return 0 if min(ours_ms) <= GOAL_MS else 1


if __name__ == "__main__":
    raise SystemExit(main())
