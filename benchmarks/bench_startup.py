"""Start-up time of `slamcli --help` against a bare `python -c pass`, measured in one run.

Usage: python benchmarks/bench_startup.py [REPEATS]
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import time


def _time(cmd: list[str], repeats: int) -> float:
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        samples.append(time.perf_counter() - start)
    return statistics.median(samples)


def main() -> None:
    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    bare = _time([sys.executable, "-c", "pass"], repeats)
    ours = _time([sys.executable, "-m", "slamcli", "--help"], repeats)
    print(f"{'command':<28}{'median ms':>12}")
    print(f"{'python -c pass':<28}{bare * 1000:>12.1f}")
    print(f"{'slamcli --help':<28}{ours * 1000:>12.1f}")
    print(f"overhead of slamcli --help over bare python: {(ours - bare) * 1000:.1f} ms")


if __name__ == "__main__":
    main()
