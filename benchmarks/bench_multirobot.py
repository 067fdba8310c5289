"""Scaling of the joint `slamcli run graph --robot all` with the number of robots.

1. Synthetic worlds (`slamcli synth landmarks --robots N`, seeded) with 1, 2, 4, 8 and 16 robots
   driving ``--duration`` s each among ``--landmarks`` landmarks. For each N the joint graph
   run (`run_pipeline(..., "graph", robot="all")`, reading, solving, evaluation and the run
   folder) with ``solver=isam2`` and ``solver=batch``: wall time, peak RSS of the process that
   ran it, graph size (factors and variables) and the ATE of all robots under one common SE(2)
   alignment. N = 1 is the single-robot folder of the same field (robot 1's start), scored
   by its own SE(2) ATE. Batch runs above ``--batch-max`` robots are left out.
2. The reference for running past one machine, for the largest N: every robot as its own job
   (`run ekf --robot K`, what `slamcli batch` hands to Dask), then `slamcli merge` of the run
   folders. Reported: the sum of the job times (one core), the longest job (one core per
   robot), the merge time, the merge's peak RSS and its common-frame ATE.

Every run happens in a fresh child process, so that peak RSS (``ru_maxrss``) is its own.

Usage: python benchmarks/bench_multirobot.py [--robots 1,2,4,8,16] [--duration 60]
       [--landmarks 40] [--seed 1] [--batch-max 16]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any


def _peak_rss_mb() -> float:
    """Peak resident set size of this process, MiB (``ru_maxrss`` is KiB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def child_world(
    out: str, robots: int, duration: float, landmarks: int, seed: int
) -> dict[str, Any]:
    from slamcli.synth.landmarks import generate_landmark_world

    generate_landmark_world(
        out, seed=seed, landmarks=landmarks, duration_s=duration, robots=robots, force=True
    )
    return {}


def child_graph(world: str, out: str, robots: int, solver: str) -> dict[str, Any]:
    from slamcli.pipelines.graph import GraphConfig
    from slamcli.run import run_pipeline

    options = {"robot": "all"} if robots > 1 else {}
    start = time.perf_counter()
    outcome = run_pipeline(
        world, "graph", out, config=GraphConfig(solver=solver), source_options=options, force=True
    )
    wall = time.perf_counter() - start
    counts = outcome.counts
    factors = sum(v for k, v in counts.items() if k.startswith("factors_"))
    variables = counts["keyposes"] + counts["landmarks"] + counts.get("landmarks_tentative", 0)
    if robots > 1:
        ate = float(outcome.metrics["robots"]["ate_common"]["rmse"])
        placed = int(counts.get("robots_placed", 0)) + 1
    else:
        ate = float(outcome.metrics["evaluation"]["ate"]["rmse"])
        placed = 1
    return {
        "wall_s": wall,
        "rss_mb": _peak_rss_mb(),
        "factors": factors,
        "variables": variables,
        "ate_common_m": ate,
        "placed": placed,
    }


def child_ekf(world: str, out: str, robot: int) -> dict[str, Any]:
    from slamcli.run import run_pipeline

    start = time.perf_counter()
    outcome = run_pipeline(world, "ekf", out, source_options={"robot": robot}, force=True)
    return {
        "wall_s": time.perf_counter() - start,
        "rss_mb": _peak_rss_mb(),
        "ate_m": float(outcome.metrics["evaluation"]["ate"]["rmse"]),
    }


def child_merge(runs: list[str], out: str) -> dict[str, Any]:
    from slamcli.graphs.merge import merge_runs

    start = time.perf_counter()
    result = merge_runs(runs, out, force=True)
    wall = time.perf_counter() - start
    ev = result.evaluation or {}
    return {
        "wall_s": wall,
        "rss_mb": _peak_rss_mb(),
        "ate_common_m": ev.get("all", {}).get("rmse"),
        "unconnected": int((~result.connected).sum()),
    }


CHILDREN = {"world": child_world, "graph": child_graph, "ekf": child_ekf, "merge": child_merge}


def run_child(kind: str, *args: Any) -> dict[str, Any]:
    """Run one measurement in a fresh interpreter; its result comes back as JSON."""
    cmd = [sys.executable, __file__, "--child", kind, json.dumps(args)]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"{kind} {args} failed:\n{proc.stderr[-3000:]}")
    return dict(json.loads(proc.stdout.strip().splitlines()[-1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", default="1,2,4,8,16")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--landmarks", type=int, default=40)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--batch-max", type=int, default=16)
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        kind, payload = args.child
        print(json.dumps(CHILDREN[kind](*json.loads(payload))))
        return

    counts = [int(n) for n in args.robots.split(",")]
    print(
        f"joint `run graph --robot all`, {args.duration:g} s per robot, {args.landmarks} "
        f"landmarks, seed {args.seed}; each run in its own process"
    )
    header = (
        f"{'robots':>6} {'solver':>6} {'wall s':>8} {'peak RSS MB':>11} {'factors':>8} "
        f"{'variables':>9} {'ATE common m':>12} {'placed':>6}"
    )
    print(header)
    print("-" * len(header))
    with tempfile.TemporaryDirectory(prefix="bench_multirobot_") as tmp:
        root = Path(tmp)
        for n in counts:
            world = str(root / f"world{n}")
            run_child("world", world, n, args.duration, args.landmarks, args.seed)
            for solver in ("isam2", "batch"):
                if solver == "batch" and n > args.batch_max:
                    print(f"{n:>6} {solver:>6} {'(left out: --batch-max)':>40}")
                    continue
                r = run_child("graph", world, str(root / f"g{n}_{solver}"), n, solver)
                print(
                    f"{n:>6} {solver:>6} {r['wall_s']:>8.2f} {r['rss_mb']:>11.0f} "
                    f"{r['factors']:>8} {r['variables']:>9} {r['ate_common_m']:>12.4f} "
                    f"{r['placed']:>3}/{n:<2}",
                    flush=True,
                )
        n = max(counts)
        if n < 2:
            return
        world = str(root / f"world{n}")
        jobs = [run_child("ekf", world, str(root / f"e{n}_{k}"), k) for k in range(1, n + 1)]
        merged = run_child(
            "merge", [str(root / f"e{n}_{k}") for k in range(1, n + 1)], str(root / "merged")
        )
        walls = [j["wall_s"] for j in jobs]
        print()
        print(f"{n} robots as separate `run ekf --robot K` jobs, then `slamcli merge`:")
        print(f"  jobs: sum {sum(walls):.2f} s (one core), longest {max(walls):.2f} s")
        print(f"  jobs: peak RSS up to {max(j['rss_mb'] for j in jobs):.0f} MB each")
        print(f"  jobs: own-alignment ATE mean {sum(j['ate_m'] for j in jobs) / n:.4f} m")
        ate = merged["ate_common_m"]
        print(
            f"  merge: {merged['wall_s']:.2f} s, peak RSS {merged['rss_mb']:.0f} MB, "
            f"ATE common {ate:.4f} m, {merged['unconnected']} unconnected"
            if ate is not None
            else f"  merge: {merged['wall_s']:.2f} s, no ATE"
        )
        print(
            f"  one core: {sum(walls) + merged['wall_s']:.2f} s; one core per robot: "
            f"{max(walls) + merged['wall_s']:.2f} s"
        )


if __name__ == "__main__":
    main()
