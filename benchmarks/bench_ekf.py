"""Speed of `slamcli run ekf` on a whole MRCLAM log, and of one EKF update as the map grows.

1. The whole robot-1 log of MRCLAM_Dataset6: `run_pipeline` (reading, filtering, evaluation,
   writing the run folder) and the bare pipeline loop over `MrclamSource.frames()`, beside the
   log's own duration (goal: at least 150x faster than real time). Reading the log alone is the
   reference measured in the same run. Best of ``--repeat``.
2. One range-bearing update of `LandmarkEkf` at 100, 400 and 1600 landmarks (innovation +
   update, with and without a prediction before each one, so the lazy cross-covariance product
   `_settle` is included in one column), split into the gain part (A = P Hᵀ and K, O(n)) and
   the Joseph covariance correction (one rank-four n x n correction, O(n²)). The reference is
   the dense textbook update (full 2 x n H, K = P Hᵀ S⁻¹, (I - KH) P (I - KH)ᵀ + K R Kᵀ by
   numpy matmuls, O(n³)) on the same filter state.

numpy runs single-threaded (the thread variables are set before numpy is imported).

Usage: python benchmarks/bench_ekf.py [MRCLAM_FOLDER] [--robot 1] [--repeat 2] [--updates 200]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import itertools  # noqa: E402
import math  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from slamcli.ekf.filter import LandmarkEkf, joseph_correction, observe_jacobians  # noqa: E402
from slamcli.geometry.planar import wrap_angle  # noqa: E402

DEFAULT = Path(__file__).resolve().parents[2] / "shared/data/landmarks/MRCLAM_Dataset6"
GOAL = 150.0
SIZES = (100, 400, 1600)
R_COV = np.diag([0.1**2, math.radians(3.0) ** 2])
PSD = np.array([0.02, 0.004])


def best_of(repeat: int, fn: Callable[[], object]) -> float:
    best = math.inf
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


# -- 1. the whole log ---------------------------------------------------------------------------


def whole_log(folder: Path, robot: int, repeat: int) -> None:
    from slamcli.formats.landmarks import MrclamSource
    from slamcli.pipelines.ekf import EkfSlam
    from slamcli.run import run_pipeline

    with MrclamSource(folder, robot=robot) as source:
        frames = list(source.frames(EkfSlam.consumes))
        start_pose = source.start_pose()
    duration = (frames[-1].stamp_ns - frames[0].stamp_ns) * 1e-9

    def read_only() -> None:
        with MrclamSource(folder, robot=robot) as source:
            for _ in source.frames(EkfSlam.consumes):
                pass

    def bare_loop() -> None:
        with MrclamSource(folder, robot=robot) as source:
            pipe = EkfSlam()
            pipe.set_start(source.start_pose())
            for frame in source.frames(EkfSlam.consumes):
                pipe.process(frame)
            pipe.finish()

    def filter_only() -> None:
        pipe = EkfSlam()
        pipe.set_start(start_pose)
        for frame in frames:
            pipe.process(frame)
        pipe.finish()

    with tempfile.TemporaryDirectory(prefix="bench_ekf_") as tmp:
        out = Path(tmp) / "run"
        outcome: list[object] = []

        def whole() -> None:
            outcome[:] = [
                run_pipeline(folder, "ekf", out, source_options={"robot": robot}, force=True)
            ]

        rows = [
            ("read the log only (reference)", best_of(repeat, read_only)),
            ("pipeline on frames already read", best_of(repeat, filter_only)),
            ("bare loop over MrclamSource.frames()", best_of(repeat, bare_loop)),
            ("run_pipeline (whole run, writes)", best_of(repeat, whole)),
        ]
    metrics = outcome[0].metrics  # type: ignore[attr-defined]
    ate = metrics.get("evaluation", {}).get("ate", {}).get("rmse")
    print(
        f"{folder.name} robot {robot}: {len(frames)} frames, log duration {duration:.1f} s"
        + (f", ATE rmse {ate:.3f} m" if ate is not None else "")
        + f", best of {repeat}"
    )
    print(f"{'variant':<40}{'wall s':>9}{'x real time':>13}")
    for label, seconds in rows:
        print(f"{label:<40}{seconds:>9.3f}{duration / seconds:>13.0f}")
    for label, seconds in rows[2:]:
        factor = duration / seconds
        verdict = "meets" if factor >= GOAL else "MISSES"
        print(f"{label}: {factor:.0f}x real time ({verdict} the goal >= {GOAL:.0f}x)")


# -- 2. one update as the map grows -------------------------------------------------------------


def build_filter(n: int, seed: int) -> LandmarkEkf:
    rng = np.random.default_rng(seed)
    ekf = LandmarkEkf(np.zeros(3), np.diag([0.01, 0.01, 0.001]), capacity=n)
    for _ in range(n):
        z = np.array([rng.uniform(1.0, 30.0), rng.uniform(-math.pi, math.pi)])
        ekf.add_landmark(z, R_COV)
    # A few updates so that the covariance is full (every entry correlated).
    for _ in range(5):
        slot = int(rng.integers(n))
        zhat = ekf.predicted(slot)[0]
        ekf.update(ekf.innovation(slot, zhat + rng.normal(0, 0.02, 2), R_COV))
    return ekf


def time_updates(n: int, updates: int, predict: bool, seed: int) -> float:
    """Seconds per innovation + update (+ the prediction before it, when ``predict``)."""
    ekf = build_filter(n, seed)
    rng = np.random.default_rng(seed + 1)
    slots = rng.integers(n, size=updates)
    noise = rng.normal(0, 0.02, size=(updates, 2))
    total = 0.0
    for k in range(updates):
        slot = int(slots[k])
        zhat = ekf.predicted(slot)[0]
        z = zhat + noise[k]
        start = time.perf_counter()
        if predict:
            ekf.predict_velocity(0.3, 0.05, 0.1, PSD)
        ekf.update(ekf.innovation(slot, z, R_COV))
        total += time.perf_counter() - start
    return total / updates


def time_parts(n: int, updates: int, seed: int) -> tuple[float, float, float]:
    """Seconds per update of: the cross-term product after a prediction, the gain part, the
    covariance correction, spelled out as in `LandmarkEkf.update` on a copy of the state."""
    ekf = build_filter(n, seed)
    rng = np.random.default_rng(seed + 2)
    p = ekf.P.copy()
    # The correction runs on its own copy so that the gain keeps reading a covariance.
    scratch_p = p.copy()
    dim = p.shape[0]
    # The cross-term product writes into a scratch copy, so that P stays a covariance.
    scratch = p.copy()
    g = np.eye(3)
    g[0, 2], g[1, 2] = -0.01, 0.03
    settle = gain = correction = 0.0
    for _ in range(updates):
        slot = int(rng.integers(n))
        inn = ekf.innovation(slot, ekf.predicted(slot)[0] + rng.normal(0, 0.02, 2), R_COV)
        i = 3 + 2 * slot
        t0 = time.perf_counter()
        cross = g @ p[:3, 3:dim]
        scratch[:3, 3:dim] = cross
        scratch[3:dim, :3] = cross.T
        t1 = time.perf_counter()
        a = p[:, :3] @ inn.H[:, :3].T + p[:, i : i + 2] @ inn.H[:, 3:].T
        k = np.linalg.solve(inn.S, a.T).T
        _ = k @ inn.nu
        t2 = time.perf_counter()
        joseph_correction(scratch_p, k, a, inn.S)
        t3 = time.perf_counter()
        settle += t1 - t0
        gain += t2 - t1
        correction += t3 - t2
    return settle / updates, gain / updates, correction / updates


def dense_update(
    p: np.ndarray, x: np.ndarray, slot: int, z: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The textbook update with a full H and dense matrix products."""
    dim = len(x)
    i = 3 + 2 * slot
    zhat, hr, hl = observe_jacobians(x[:3], x[i : i + 2])
    h = np.zeros((2, dim))
    h[:, :3], h[:, i : i + 2] = hr, hl
    s = h @ p @ h.T + R_COV
    k = np.linalg.solve(s, h @ p).T
    nu = np.array([z[0] - zhat[0], wrap_angle(z[1] - zhat[1])])
    ikh = np.eye(dim) - k @ h
    return ikh @ p @ ikh.T + k @ R_COV @ k.T, x + k @ nu


def time_dense(n: int, updates: int, seed: int) -> float:
    ekf = build_filter(n, seed)
    rng = np.random.default_rng(seed + 3)
    p, x = ekf.P.copy(), ekf.x.copy()
    start = time.perf_counter()
    for _ in range(updates):
        slot = int(rng.integers(n))
        z = ekf.predicted(slot)[0] + rng.normal(0, 0.02, 2)
        p, x = dense_update(p, x, slot, z)
    return (time.perf_counter() - start) / updates


def growth(sizes: tuple[int, ...], updates: int, seed: int, dense_budget_s: float) -> None:
    print()
    print(
        "One range-bearing update vs landmark count (ms per update; "
        f"{updates} updates to random landmarks, fewer at 1600)"
    )
    rows: dict[int, dict[str, float]] = {}
    time_updates(sizes[0], 50, True, seed)  # warm-up: imports, caches, allocator
    for n in sizes:
        count = updates if n < 1600 else max(20, updates // 4)
        row = {
            "no predict": time_updates(n, count, False, seed),
            "predict+settle": time_updates(n, count, True, seed),
        }
        row["settle"], row["gain"], row["correction"] = time_parts(n, count, seed)
        rows[n] = row
    # The dense reference, as far as it fits the budget (its cost grows as n³).
    spent = 0.0
    last: tuple[int, float] | None = None
    for n in sizes:
        if last is not None:
            estimate = last[1] * (n / last[0]) ** 3 * 3
            if spent + estimate > dense_budget_s:
                print(
                    f"(dense reference at {n} landmarks skipped: about {estimate:.0f} s expected, "
                    f"over the {dense_budget_s:.0f} s budget)"
                )
                break
        count = 20 if n <= 100 else (5 if n <= 400 else 2)
        start = time.perf_counter()
        rows[n]["dense"] = time_dense(n, count, seed)
        spent += time.perf_counter() - start
        last = (n, rows[n]["dense"])
    cols = [
        ("no predict", "innov+update"),
        ("predict+settle", "pred+innov+upd"),
        ("settle", "settle O(n)"),
        ("gain", "gain A,K O(n)"),
        ("correction", "P corr O(n²)"),
        ("dense", "dense ref"),
    ]
    print(f"{'landmarks':>10}{'state':>7}" + "".join(f"{h:>16}" for _, h in cols))
    for n in sizes:
        cells = "".join(
            f"{rows[n][key] * 1e3:>16.3f}" if key in rows[n] else f"{'(skipped)':>16}"
            for key, _ in cols
        )
        print(f"{n:>10}{3 + 2 * n:>7}{cells}")
    print("growth factors (state size x4 per step: linear x4, quadratic x16, cubic x64)")
    for a, b in itertools.pairwise(sizes):
        cells = "".join(
            f"{rows[b][key] / rows[a][key]:>16.1f}"
            if key in rows[a] and key in rows[b]
            else f"{'-':>16}"
            for key, _ in cols
        )
        print(f"{f'{a}->{b}':>17}{cells}")
    for n in sizes:
        if "dense" in rows[n]:
            ratio = rows[n]["dense"] / rows[n]["no predict"]
            print(f"at {n} landmarks ours is {ratio:.0f}x faster than the dense textbook update")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", nargs="?", type=Path, default=DEFAULT)
    parser.add_argument("--robot", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--updates", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--dense-budget", type=float, default=5.0, help="seconds")
    args = parser.parse_args()

    print("numpy single-threaded: OMP/OPENBLAS/MKL_NUM_THREADS=1 set before importing numpy")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"{os.cpu_count()} CPUs, load average {load:.2f} at start (figures are noisy above 1)")
    if args.folder.exists():
        whole_log(args.folder, args.robot, args.repeat)
    else:
        print(f"{args.folder} not found: whole-log figures skipped")
    growth(SIZES, args.updates, args.seed, args.dense_budget)


if __name__ == "__main__":
    main()
