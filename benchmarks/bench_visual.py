"""ms/frame and accuracy of `slamcli run visual` beside a bare read-and-ORB loop, for RGB-D
(a TUM folder) and stereo (a KITTI folder), and the whole command on a long sequence.

The reference is the least any ORB-based tracker must do per frame: read the frame's PNGs with
OpenCV (colour and depth; left and right) and run ``cv2.ORB.create(n).detectAndCompute`` on the
grey image (on both images of a stereo pair, with the stereo feature count), over the same
frames, in the same process, after a short warm-up run of each (imports and the page cache are
not per-frame costs). Ours is the whole ``run_pipeline`` call (reading,
ORB spread over the pyramid, tracking, local mapping and bundle adjustment, loop closure, the
final global adjustment and pose re-estimation, writing the run folder), once with the default
``threads = 2`` and once with ``threads = 1``, to show what the second core gives. The goals:
at most 2x the bare loop with two threads, at most 3x with one; for stereo also no slower than
ORB-SLAM3's stereo tracking on the same KITTI frames (2,000 features), measured at 68-77 ms per
frame with reading.

The last table is what a user waits for: ``slamcli run visual`` as a command (a new process:
start-up, imports, reading, the run, the report) on a ``slamcli synth rgbd`` sequence of
``--long`` frames (600 by default, rendered into a temporary folder first), against the bare
loop over the same frames (in this process, warm). The goal: at most 2.5x.

Every figure depends on the machine: the first line names it.

Usage: python benchmarks/bench_visual.py [--input TUM_FOLDER] [--stereo KITTI_FOLDER]
[--frames N] [--repeat R] [--long N]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

DEFAULT = Path(__file__).resolve().parents[2] / "shared/data/tum/rgbd_dataset_freiburg1_rpy_excerpt"
STEREO = Path(__file__).resolve().parents[2] / "shared/data/stereo/kitti_excerpt_1"
GOAL = 2.0
GOAL_ONE_THREAD = 3.0
GOAL_COMMAND = 2.5
ORB_SLAM3_MS = (68.0, 77.0)


def machine() -> str:
    """The CPU model, the cores this process may use, and the load at the start."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return f"{model}, {cores} cores, load average {load:.2f} at start (figures are noisy above 1)"


def _listed(folder: Path, name: str) -> list[tuple[float, Path]]:
    rows = []
    for line in (folder / name).read_text().splitlines():
        parts = line.split()
        if len(parts) >= 2 and not line.startswith("#"):
            rows.append((float(parts[0]), folder / parts[1]))
    return rows


def frame_files(folder: Path, frames: int, max_dt: float = 0.02) -> list[tuple[Path, Path]]:
    """(colour, depth) files of the first ``frames`` frames, paired by nearest stamp (the
    bare loop reads the same images the pipeline gets; pairing is not timed)."""
    import numpy as np

    colour = _listed(folder, "rgb.txt")
    depth = _listed(folder, "depth.txt")
    depth_stamps = np.array([s for s, _ in depth])
    pairs = []
    for stamp, path in colour:
        k = int(np.argmin(np.abs(depth_stamps - stamp)))
        if abs(depth_stamps[k] - stamp) < max_dt:
            pairs.append((path, depth[k][1]))
        if len(pairs) == frames:
            break
    return pairs


def bare_loop(files: list[tuple[Path, Path]], features: int) -> float:
    """Seconds to read each frame's images and extract ORB from the grey colour image."""
    import cv2

    orb = cv2.ORB.create(features)
    start = time.perf_counter()
    for colour, depth in files:
        bgr = cv2.imread(str(colour), cv2.IMREAD_COLOR)
        cv2.imread(str(depth), cv2.IMREAD_UNCHANGED)
        orb.detectAndCompute(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), None)
    return time.perf_counter() - start


def stereo_files(folder: Path, frames: int) -> list[tuple[Path, Path]]:
    """(left, right) files of the first ``frames`` pairs of a KITTI folder."""
    for left, right in (("image_0", "image_1"), ("image_l", "image_r")):
        if (folder / left).is_dir():
            names = sorted(p.name for p in (folder / left).glob("*.png"))[:frames]
            return [(folder / left / n, folder / right / n) for n in names]
    raise SystemExit(f"{folder}: no image_0/ or image_l/ folder")


def bare_stereo(files: list[tuple[Path, Path]], features: int) -> float:
    """Seconds to read each pair's two grey images and extract ORB from both."""
    import cv2

    orb = cv2.ORB.create(features)
    start = time.perf_counter()
    for left, right in files:
        for path in (left, right):
            orb.detectAndCompute(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), None)
    return time.perf_counter() - start


def ours(folder: Path, frames: int, threads: int) -> tuple[float, dict[str, Any]]:
    """Seconds of the whole ``run_pipeline`` call, and its run.json."""
    from slamcli.pipelines.visual import VisualConfig
    from slamcli.run import run_pipeline

    with tempfile.TemporaryDirectory(prefix="bench_visual_") as tmp:
        start = time.perf_counter()
        outcome = run_pipeline(
            folder,
            "visual",
            Path(tmp) / "run",
            config=VisualConfig(threads=threads),
            max_frames=frames,
        )
        seconds = time.perf_counter() - start
        info = json.loads((outcome.run_dir / "run.json").read_text())
    return seconds, info


def table(
    name: str, n: int, bare: str, ref_s: float, runs: dict[int, tuple[float, dict[str, Any]]]
) -> None:
    """Print one input's rows: the bare loop, ours with two threads and with one, and the
    per-stage times."""
    print(f"\n{name}: {n} frames, same process")
    print(f"{'variant':<48}{'ms/frame':>10}{'x bare':>8}{'ATE rmse m':>12}")
    print(f"{bare:<48}{ref_s / n * 1e3:>10.1f}{1:>8.2f}{'-':>12}")
    for threads, (seconds, info) in runs.items():
        label = f"slamcli run visual, threads={threads} (whole run)"
        ev = info["metrics"].get("evaluation")
        ate = f"{ev['ate']['rmse']:.4f}" if ev else "-"
        print(f"{label:<48}{seconds / n * 1e3:>10.1f}{seconds / ref_s:>8.2f}{ate:>12}")
    infos = [info for _, info in runs.values()]
    stages = sorted(set().union(*(i["metrics"]["ms_per_frame"] for i in infos)))
    print(f"{'per-stage ms/frame':<24}" + "".join(f"{f'threads={t}':>12}" for t in runs))
    for stage in stages:
        cells = "".join(f"{i['metrics']['ms_per_frame'].get(stage, 0.0):>12.1f}" for i in infos)
        print(f"  {stage:<22}{cells}")
    ratio = runs[2][0] / ref_s
    verdict = "meets" if ratio <= GOAL else "MISSES"
    print(f"ours (threads=2) / bare loop: {ratio:.2f}x ({verdict} the goal <= {GOAL:.1f}x)")
    ratio = runs[1][0] / ref_s
    verdict = "meets" if ratio <= GOAL_ONE_THREAD else "MISSES"
    print(
        f"ours (threads=1) / bare loop: {ratio:.2f}x ({verdict} the goal <= {GOAL_ONE_THREAD:.1f}x)"
    )
    print(f"threads=1 / threads=2: {runs[1][0] / runs[2][0]:.2f}x")


def command(n: int) -> None:
    """``slamcli run visual`` on a rendered sequence of ``n`` frames, as a command, against
    the bare loop over the same frames."""
    from slamcli.pipelines.visual import VisualConfig

    features = VisualConfig().max_features
    with tempfile.TemporaryDirectory(prefix="bench_visual_long_") as tmp:
        seq = Path(tmp) / "seq"
        subprocess.run(
            [
                sys.executable,
                "-m",
                "slamcli",
                "synth",
                "rgbd",
                str(seq),
                "--frames",
                str(n),
                "--noise",
            ],
            check=True,
            capture_output=True,
        )
        files = frame_files(seq, n)
        bare_loop(files[:5], features)
        ref_s = bare_loop(files, features)
        start = time.perf_counter()
        done = subprocess.run(
            [
                sys.executable,
                "-m",
                "slamcli",
                "run",
                "visual",
                str(seq),
                "--out",
                str(Path(tmp) / "run"),
            ],
            capture_output=True,
            text=True,
        )
        seconds = time.perf_counter() - start
        if done.returncode != 0:
            raise SystemExit(f"slamcli run visual failed:\n{done.stderr}")
        info = json.loads((Path(tmp) / "run" / "run.json").read_text())
    ate = info["metrics"]["evaluation"]["ate"]["rmse"]
    print(f"\nthe whole command: synth rgbd, {len(files)} frames (640x480, noise)")
    print(f"{'variant':<48}{'s':>10}{'x bare':>8}{'ATE rmse m':>12}")
    print(f"{'bare loop (warm, in this process)':<48}{ref_s:>10.2f}{1:>8.2f}{'-':>12}")
    label = "slamcli run visual (a new process)"
    print(f"{label:<48}{seconds:>10.2f}{seconds / ref_s:>8.2f}{ate:>12.4f}")
    ratio = seconds / ref_s
    verdict = "meets" if ratio <= GOAL_COMMAND else "MISSES"
    print(f"the command / bare loop: {ratio:.2f}x ({verdict} the goal <= {GOAL_COMMAND:.1f}x)")


def measure(
    folder: Path, n: int, repeat: int, bare: Any, files: list[Any], features: int
) -> tuple[float, dict[int, tuple[float, dict[str, Any]]]]:
    """Best-of-``repeat`` seconds of the bare loop and of our two variants."""
    bare(files[:5], features)  # warm the page cache and OpenCV
    # Load what a run imports once per process (pycolmap, GTSAM, matplotlib for the report),
    # as the bare loop's warm-up loads OpenCV: those seconds are not per frame.
    ours(folder, 12, 1)
    ref_s = min(bare(files, features) for _ in range(repeat))
    runs = {}
    for threads in (2, 1):
        results = [ours(folder, n, threads) for _ in range(repeat)]
        runs[threads] = min(results, key=lambda r: r[0])
    return ref_s, runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--input", type=Path, default=DEFAULT, help="a TUM RGB-D folder")
    parser.add_argument("--stereo", type=Path, default=STEREO, help="a KITTI stereo folder")
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--repeat", type=int, default=1, help="best of R for each variant")
    parser.add_argument(
        "--long", type=int, default=600, help="frames of the rendered sequence (0: skip it)"
    )
    args = parser.parse_args()
    print(machine())

    from slamcli.pipelines.visual import VisualConfig

    cfg = VisualConfig()
    files = frame_files(args.input, args.frames)
    ref_s, runs = measure(args.input, len(files), args.repeat, bare_loop, files, cfg.max_features)
    bare = f"bare loop: imread x2 + ORB({cfg.max_features})"
    table(f"RGB-D, {args.input.name}", len(files), bare, ref_s, runs)

    pairs = stereo_files(args.stereo, args.frames)
    n = len(pairs)
    ref_s, runs = measure(args.stereo, n, args.repeat, bare_stereo, pairs, cfg.stereo_max_features)
    bare = f"bare loop: imread x2 + ORB({cfg.stereo_max_features}) x2"
    table(f"stereo, {args.stereo.name}", n, bare, ref_s, runs)
    ms = runs[2][0] / n * 1e3
    lo, hi = ORB_SLAM3_MS
    verdict = "no slower than" if ms <= lo else "SLOWER than"
    print(f"stereo, threads=2: {ms:.1f} ms/frame, {verdict} ORB-SLAM3's {lo:.0f}-{hi:.0f} ms")
    if args.long:
        command(args.long)


if __name__ == "__main__":
    main()
