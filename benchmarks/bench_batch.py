"""`slamcli batch` on one and on two workers, beside the same jobs run one by one with
`slamcli run`.

N independent EKF jobs over generated landmark worlds (each single-threaded, so two of them
fill the machine's two cores): the reference is N `slamcli run ekf` commands one after the other,
measured in the same run. Printed: each variant's wall time, the speed-up of two workers over
one (goal: at least 1.7x on 2 cores), and the batch's overhead per job against running
`slamcli run` directly (its own process per job, the records, the report). Best of ``--repeat``.

Usage: python benchmarks/bench_batch.py [--jobs-count 8] [--duration 60] [--repeat 2]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

GOAL = 1.7


def _slamcli(*args: str) -> None:
    subprocess.run(
        [sys.executable, "-m", "slamcli", *args],
        check=False,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs-count", type=int, default=8, help="independent jobs")
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of each world")
    parser.add_argument("--repeat", type=int, default=2, help="best of R for each variant")
    args = parser.parse_args()

    from slamcli.synth.landmarks import generate_landmark_world

    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        root = Path(tmp)
        worlds = []
        for i in range(args.jobs_count):
            world = root / f"world{i}"
            generate_landmark_world(world, seed=i, duration_s=args.duration)
            worlds.append(world)
        manifest = root / "bench.toml"
        manifest.write_text(
            "".join(
                f'[[job]]\nname = "ekf-{w.name}"\ninput = "{w.name}"\npipeline = "ekf"\n'
                'fail_if = ["ate.rmse > 1.0"]\n\n'
                for w in worlds
            )
        )
        _slamcli("run", "ekf", str(worlds[0]), "--out", str(root / "warm"), "--force")

        def direct() -> float:
            start = time.perf_counter()
            for w in worlds:
                _slamcli("run", "ekf", str(w), "--out", str(root / "direct" / w.name), "--force")
            return time.perf_counter() - start

        def batch(workers: int) -> float:
            out = root / f"batch{workers}"
            shutil.rmtree(out, ignore_errors=True)
            start = time.perf_counter()
            _slamcli("batch", str(manifest), "--out", str(out), "--jobs", str(workers))
            seconds = time.perf_counter() - start
            if not (out / "batch.json").exists():
                raise RuntimeError(f"the batch on {workers} worker(s) wrote no batch.json")
            return seconds

        t_direct = min(direct() for _ in range(args.repeat))
        t1 = min(batch(1) for _ in range(args.repeat))
        t2 = min(batch(2) for _ in range(args.repeat))

    n = args.jobs_count
    print(f"{n} EKF jobs over {args.duration:g} s landmark worlds, best of {args.repeat}")
    print(f"{'variant':<44}{'wall s':>10}{'s/job':>10}")
    print(f"{'slamcli run, one after the other':<44}{t_direct:>10.2f}{t_direct / n:>10.2f}")
    print(f"{'slamcli batch --jobs 1':<44}{t1:>10.2f}{t1 / n:>10.2f}")
    print(f"{'slamcli batch --jobs 2':<44}{t2:>10.2f}{t2 / n:>10.2f}")
    speedup = t1 / t2
    verdict = "meets" if speedup >= GOAL else "MISSES"
    print(f"\nspeed-up of 2 workers over 1: {speedup:.2f}x ({verdict} the goal >= {GOAL}x)")
    overhead = (t1 - t_direct) / n
    print(
        f"batch overhead per job against 'slamcli run' ({t_direct / n:.2f} s/job): "
        f"{overhead * 1e3:+.0f} ms ({overhead / (t_direct / n):+.1%})"
    )


if __name__ == "__main__":
    main()
