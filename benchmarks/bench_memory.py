"""Peak memory and ms/frame of `slamcli run dense` beside the import floor, measured in one run.

Each run is a child process; its peak resident set size comes from ``os.wait4`` (the kernel's
``ru_maxrss`` of that child alone). The reference is a bare ``python -c "import open3d, cv2"``
child: the floor no run can go below. ms/frame and ATE come from the run's own run.json
(``metrics.ms_per_frame.total``, ``metrics.evaluation.ate.rmse``), with the voxel blocks the
volume used and the capacity it ended with.

Usage: python benchmarks/bench_memory.py [--set KEY=VALUE ...]
       (--set block_count=19776 reproduces the old up-front budget of the sample's camera)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data" / "rgbd_room"
TUM = ROOT.parent / "shared" / "data" / "tum" / "rgbd_dataset_freiburg1_rpy_excerpt"
GOAL_MB = 1000.0
"""Peak RSS the sample runs (30 frames and the first 10) must stay under."""


def peak_rss_mb(cmd: list[str]) -> float:
    """Run ``cmd`` to completion; its peak resident set size in MB (10**6 bytes).

    Raises:
        subprocess.CalledProcessError: the command failed.
    """
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    # wait4 reports this child's own rusage; RUSAGE_CHILDREN would give the maximum over every
    # child waited for so far.
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    stderr = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    if proc.returncode != 0:
        raise subprocess.CalledProcessError(proc.returncode, cmd, stderr=stderr)
    return usage.ru_maxrss * 1024 / 1e6  # Linux reports kB


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()

    cases: list[tuple[str, Path, int | None]] = [
        ("sample, first 10 frames", SAMPLE, 10),
        ("sample, 30 frames", SAMPLE, None),
    ]
    if TUM.exists():
        cases.append(("TUM fr1/rpy excerpt, 150 frames", TUM, None))
    else:
        print(f"(skipping the TUM excerpt: {TUM} not found)")

    floor = peak_rss_mb([sys.executable, "-c", "import open3d, cv2"])
    sets = [arg for s in args.sets for arg in ("--set", s)]
    print(
        f"{'input':<34}{'peak RSS MB':>12}{'over floor':>12}{'ms/frame':>10}"
        f"{'ATE rmse m':>12}{'blocks used/capacity':>22}"
    )
    print(f"{'python -c import open3d, cv2':<34}{floor:>12.0f}{0:>12.0f}{'-':>10}{'-':>12}")
    worst_sample = 0.0
    with tempfile.TemporaryDirectory(prefix="bench_memory_") as tmp:
        for i, (label, path, max_frames) in enumerate(cases):
            out = Path(tmp) / f"run{i}"
            cmd = [sys.executable, "-m", "slamcli", "run", "dense", str(path), "--out", str(out)]
            if max_frames is not None:
                cmd += ["--max-frames", str(max_frames)]
            peak = peak_rss_mb(cmd + sets)
            record = json.loads((out / "run.json").read_text())
            counts, metrics = record["counts"], record["metrics"]
            ate = metrics.get("evaluation", {}).get("ate", {}).get("rmse")
            ate_text = "-" if ate is None else f"{ate:.4f}"
            blocks = f"{counts['voxel_blocks']}/{counts['voxel_block_budget']}"
            ms = metrics["ms_per_frame"]["total"]
            print(
                f"{label:<34}{peak:>12.0f}{peak - floor:>12.0f}{ms:>10.1f}{ate_text:>12}"
                f"{blocks:>22}"
            )
            if path == SAMPLE:
                worst_sample = max(worst_sample, peak)
    verdict = "meets" if worst_sample < GOAL_MB else "MISSES"
    print(f"sample runs peak at {worst_sample:.0f} MB ({verdict} the goal < {GOAL_MB:.0f} MB)")


if __name__ == "__main__":
    main()
