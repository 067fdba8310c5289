"""Decode speed of TumRgbdSource.frames() against a bare cv2.imread loop over the same files.

Usage: python benchmarks/bench_tum_decode.py [TUM_FOLDER] [--repeats N]

Goal: frames/s of ``TumRgbdSource.frames()`` within 15 % of the bare loop (colour
``IMREAD_COLOR`` + depth ``IMREAD_UNCHANGED``), which is the floor any reader pays for PNG
decoding. Each variant runs ``--repeats`` times, interleaved, and the best run counts.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

DEFAULT = (
    Path(__file__).resolve().parents[2]
    / "shared"
    / "data"
    / "tum"
    / "rgbd_dataset_freiburg1_rpy_excerpt"
)
GOAL = 0.85


def bare_loop(files: list[tuple[str, str]]) -> float:
    """Seconds to imread every (colour, depth) pair."""
    import cv2

    t0 = time.perf_counter()
    for rgb, depth in files:
        cv2.imread(rgb, cv2.IMREAD_COLOR)
        cv2.imread(depth, cv2.IMREAD_UNCHANGED)
    return time.perf_counter() - t0


def ours(folder: Path) -> tuple[float, int]:
    """Seconds to open the folder and iterate every RGB-D frame, and the frame count."""
    from slamcli.formats.tum_rgbd import TumRgbdSource

    t0 = time.perf_counter()
    n = 0
    with TumRgbdSource.open(folder) as source:
        for _ in source.frames(("rgbd",)):
            n += 1
    return time.perf_counter() - t0, n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", nargs="?", type=Path, default=DEFAULT)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    import cv2

    from slamcli.formats.tum_rgbd import TumRgbdSource

    with TumRgbdSource.open(args.folder) as source:
        files = [
            (str(args.folder / r), str(args.folder / d)) for _, r, _, d in source.associations()
        ]
    bare_loop(files[:5])
    ours_best, bare_best, frames = float("inf"), float("inf"), 0
    for _ in range(args.repeats):
        bare_best = min(bare_best, bare_loop(files))
        seconds, frames = ours(args.folder)
        ours_best = min(ours_best, seconds)
    bare_fps = len(files) / bare_best
    ours_fps = frames / ours_best
    ratio = ours_fps / bare_fps
    print(
        f"folder: {args.folder}  frames: {frames}  opencv {cv2.__version__}  best of {args.repeats}"
    )
    print(f"{'variant':<36}{'frames/s':>10}{'ms/frame':>10}")
    print(f"{'bare cv2.imread (colour + depth)':<36}{bare_fps:>10.1f}{1000 / bare_fps:>10.2f}")
    print(f"{'TumRgbdSource.frames()':<36}{ours_fps:>10.1f}{1000 / ours_fps:>10.2f}")
    verdict = "meets" if ratio >= GOAL else "MISSES"
    print(f"ratio ours/bare: {ratio:.3f} ({verdict} the goal >= {GOAL:.2f})")


if __name__ == "__main__":
    main()
