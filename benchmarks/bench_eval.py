"""Speed and accuracy of trajectory reading and evaluation on the evo reference trajectories.

Usage: python benchmarks/bench_eval.py [TRAJECTORY_FOLDER] [--repeats N]

For each pair it prints: the time to read both files with ``read_poses`` beside a bare
``np.loadtxt`` of the same files (the floor for parsing text, measured in the same run), the
time of ``evaluate`` (association, alignment, ATE, RPE with delta 1 frame), and the ATE rmse
beside evo 1.38's figure for the same files and alignment (``evo_ape ... --align`` and, for
sim3, ``--correct_scale``; reproduced to 1e-6 in tests/test_cli_eval.py).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from slamcli.evaluation import evaluate
from slamcli.formats.trajectory import PoseTable, read_poses

T = TypeVar("T")

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data" / "trajectories"

# (gt, est, format, alignment, evo 1.38 ATE rmse)
PAIRS = [
    ("fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt", "tum", "se3", 0.008118977562045396),
    (
        "freiburg1_xyz-groundtruth.txt",
        "freiburg1_xyz-rgbdslam.txt",
        "tum",
        "se3",
        0.013470088849733695,
    ),
    (
        "freiburg1_xyz-groundtruth.txt",
        "freiburg1_xyz-ORB_kf_mono.txt",
        "tum",
        "sim3",
        0.00975458189868511,
    ),
    ("KITTI_00_gt.txt", "KITTI_00_ORB.txt", "kitti", "se3", 1.303449714565045),
    ("V102_groundtruth.csv", "V102.txt", "euroc", "se3", 0.09172711520685733),
    ("V101_gt.txt", "V101_openvins.txt", "tum", "se3", 0.05210196108597879),
]


def _best(repeats: int, fn: Callable[..., T], *args: Any, **kwargs: Any) -> tuple[float, T]:
    """Fastest of ``repeats`` runs of ``fn(*args, **kwargs)``, in seconds, and its result."""
    best = float("inf")
    for _ in range(max(repeats, 1)):
        start = time.perf_counter()
        out = fn(*args, **kwargs)
        best = min(best, time.perf_counter() - start)
    return best, out


def _read_pair(gt: Path, est: Path, gt_fmt: str, est_fmt: str) -> tuple[PoseTable, PoseTable]:
    return read_poses(gt, gt_fmt), read_poses(est, est_fmt)


def _loadtxt_pair(gt: Path, est: Path) -> tuple[np.ndarray, np.ndarray]:
    def load(path: Path) -> np.ndarray:
        return np.loadtxt(path, delimiter="," if path.suffix == ".csv" else None, comments="#")

    return load(gt), load(est)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", nargs="?", type=Path, default=DEFAULT)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    d: Path = args.folder
    head = f"{'pair':<52}{'read ms':>9}{'loadtxt ms':>12}{'eval ms':>9}{'ATE rmse':>12}{'evo':>12}"
    print(head)
    for gt_name, est_name, fmt, mode, evo_rmse in PAIRS:
        gt_fmt, est_fmt = ("euroc", "tum") if fmt == "euroc" else (fmt, fmt)
        gt_path, est_path = d / gt_name, d / est_name
        t_read, (gt, est) = _best(args.repeats, _read_pair, gt_path, est_path, gt_fmt, est_fmt)
        t_bare, _ = _best(args.repeats, _loadtxt_pair, gt_path, est_path)
        t_eval, res = _best(
            args.repeats, evaluate, gt, est, align=mode, by_index=fmt == "kitti", rpe_delta=1
        )
        rmse = res.ate.rmse
        name = f"{gt_name} / {est_name} ({mode})"
        print(
            f"{name:<52}{t_read * 1e3:>9.1f}{t_bare * 1e3:>12.1f}{t_eval * 1e3:>9.1f}"
            f"{rmse:>12.6f}{evo_rmse:>12.6f}"
        )


if __name__ == "__main__":
    main()
