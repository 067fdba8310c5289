"""Exact grid search time beside pyastar2d and python-tcod's A*, and costs against Dijkstra.

Ours is `slamcli.planning.search.grid_search` (method "auto": JPS on uniform cost, A* with the
clearance cost; best of 3 calls). Beside it, on the same grid in the same run:

- pyastar2d (C++ A*): `astar_path(weights, start, goal, allow_diagonal=True)` with float32
  weights 1 + extra cost, np.inf on blocked cells;
- python-tcod: `tcod.path.path2d` (A* for one start and one goal) on an int32 cost array,
  round(100 * (1 + extra cost)), 0 on blocked cells, cardinal 70, diagonal 99.

Both use graphs of their own (pyastar2d prices a diagonal like a straight move and squeezes
between two blocked corners; tcod cuts corners and rounds the costs), so their path costs are
printed, measured with our cost model, but only ours is checked: against
`scipy.sparse.csgraph.dijkstra` over `grid_graph` of the same grid, from the start, stopped
just past our cost (`limit`); agree = within 1e-6 m. Each tool gets its input array prebuilt;
the timings cover the calls only.

Maps: the shared building floors (stata_basement, building_31) and the Nav2 TurtleBot3 maps,
read with their yaml files and inflated for a 0.2 m robot (`build_costmap`, blocked cells;
unknown space blocked); each uniform and with the clearance cost of `clearance_weight=1`;
seeded random far-apart start/goal pairs in the largest free region. Then 4000x4000 perfect
mazes (seeded recursive backtracker, corridors several cells wide), uniform cost, corner to
corner plus seeded random far pairs.

The first section measures numba's share of a command's wall time in fresh processes: the
import of numba and the first call of each kernel, with an empty cache (compiling) and again
with that cache filled.

The last section plans for car-like robots (`slamcli.planning.car.plan_car`, Hybrid-A*): a
4.5 x 1.9 m car with a 5 m turn radius in the synthetic yard of `tests/planning_data.py`
(backing into a bay, and a far open goal without reversing), and a 0.9 x 0.6 m robot with a 1.2 m
radius between seeded far-apart poses on the building floors. Beside each: OMPL's RRT* and BIT*
on its Reeds-Shepp (or Dubins) state space with our exact footprint test, each given the larger
of our time and 1 s, then OMPL's simplifier; the ratio is our length over OMPL's best.

Then the car-like planner's centring and steering, on the docs' Stata example and seeded
far-apart poses on both floors: today's shortest path (`--cost-penalty 0 --full-lock-distance
0`, the planner before the centring cost) beside the defaults, each with its length, the
clearance ratio along it (median and 10th percentile, measured by `tests/planning_data.py`
independently of the planner's cost field), the largest curvature rate measured from the poses,
the search's states and the warm wall time of `plan_car`. Beside them, OMPL's RRT* and BIT* on
the Reeds-Shepp space optimising the same centring cost (`StateCostIntegralObjective` with 1 +
the cell's cost), given at least 2 s, against ours with `--reverse-penalty 1` (OMPL cannot
price reversing), both priced by one function. Last, Nav2 Smac Hybrid-A*'s documented
behaviour beside ours.

Usage: python benchmarks/bench_plan.py [MAPS_DIR] [--size 4000] [--pairs 4] [--seed 0]
       [--no-maze-reference] [--no-startup] [--no-maze] [--no-car] [--no-centring]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

DEFAULT = Path(__file__).resolve().parents[2] / "shared/data/maps"
MAPS = ("stata_basement", "building_31", "tb3_sandbox", "turtlebot3_world")
BUILDINGS = ("stata_basement", "building_31")
ROBOT_RADIUS_M = 0.2
AGREE_M = 1e-6

# Timed in a fresh process: import numba, then the first call of each kernel.
STARTUP = """
import json, time
t0 = time.perf_counter()
import numba
t1 = time.perf_counter()
import numpy as np
from slamcli.planning.search import grid_distances, grid_search
blocked = np.zeros((40, 40), dtype=bool)
blocked[20, 5:35] = True
extra = np.full((40, 40), 0.5)
out = {"import numba": t1 - t0}
for name, call in (
    ("first call jps", lambda: grid_search(blocked, (0, 0), (39, 39), method="jps")),
    ("first call astar", lambda: grid_search(blocked, (0, 0), (39, 39), extra_cost=extra)),
    ("first call grid_distances", lambda: grid_distances(blocked, (39, 39), extra_cost=extra)),
    ("second call jps", lambda: grid_search(blocked, (0, 0), (39, 39), method="jps")),
):
    t = time.perf_counter()
    call()
    out[name] = time.perf_counter() - t
print(json.dumps(out))
"""


def startup() -> None:
    """Prints numba's import and first-call times, cold (empty cache) then warm."""
    import os

    print("numba start-up, each in a fresh process (first jps call also pays numba's own")
    print("one-time set-up on the first compiled call of the process):")
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        for label in ("cold (empty cache)", "warm (cache filled)"):
            t0 = time.perf_counter()
            proc = subprocess.run(
                [sys.executable, "-c", STARTUP], env=env, capture_output=True, text=True, check=True
            )
            wall = time.perf_counter() - t0
            times = json.loads(proc.stdout)
            parts = "  ".join(f"{k} {v * 1000:.0f} ms" for k, v in times.items())
            print(f"  {label:<20} {parts}  (process {wall:.1f} s)")


def maze(size: int, corridor: int, wall: int, seed: int = 0) -> tuple[np.ndarray, tuple, tuple]:
    """(size, size) bool blocked grid of a perfect maze, and the centres of its corner cells."""
    n = (size - wall) // (corridor + wall)
    rng = np.random.default_rng(seed)
    # Cells at odd (row, col) of a (2n+1)^2 grid; a passage opens the wall cell between two.
    open_ = np.zeros((2 * n + 1, 2 * n + 1), dtype=bool)
    open_[1::2, 1::2] = True
    seen = np.zeros((n, n), dtype=bool)
    seen[0, 0] = True
    stack = [(0, 0)]
    while stack:
        r, c = stack[-1]
        nbrs = [
            (r + dr, c + dc)
            for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1))
            if 0 <= r + dr < n and 0 <= c + dc < n and not seen[r + dr, c + dc]
        ]
        if not nbrs:
            stack.pop()
            continue
        nr, nc = nbrs[rng.integers(len(nbrs))]
        open_[r + nr + 1, c + nc + 1] = True
        seen[nr, nc] = True
        stack.append((nr, nc))
    widths = np.where(np.arange(2 * n + 1) % 2 == 1, corridor, wall)
    blocked = np.ones((size, size), dtype=bool)
    m = int(widths.sum())
    blocked[:m, :m] = ~np.repeat(np.repeat(open_, widths, axis=0), widths, axis=1)
    half = wall + corridor // 2
    far = wall + (n - 1) * (corridor + wall) + corridor // 2
    return blocked, (half, half), (far, far)


def far_pairs(
    blocked: np.ndarray, count: int, seed: int, candidates: int = 64
) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """Seeded start/goal pairs in the largest 4-connected free region: of ``candidates``
    random pairs, each time the one farthest apart (straight-line)."""
    from scipy.ndimage import label

    labels, _ = label(~blocked)
    cells = np.argwhere(labels == np.bincount(labels.ravel())[1:].argmax() + 1)
    rng = np.random.default_rng(seed)
    pairs = []
    for _ in range(count):
        pick = cells[rng.integers(len(cells), size=(candidates, 2))]
        far = np.hypot(*(pick[:, 0] - pick[:, 1]).T).argmax()
        a, b = pick[far]
        pairs.append(((int(a[0]), int(a[1])), (int(b[0]), int(b[1]))))
    return pairs


def best_of(fn: Callable[[], Any], repeat: int = 3) -> tuple[float, Any]:
    """(best call s, last result)."""
    best, out = math.inf, None
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - start)
    return best, out


def walk_cost(cells: np.ndarray, res: float, extra: np.ndarray | None) -> float:
    """Cost (m) of a cell path under our cost model (length times 1 + extra of the cell entered);
    nan for an empty path."""
    cells = np.asarray(cells, dtype=np.int64)
    if len(cells) == 0:
        return math.nan
    step = np.diff(cells, axis=0)
    length = np.where(np.all(step != 0, axis=1), math.sqrt(2.0), 1.0) * res
    if extra is not None:
        length *= 1.0 + extra[cells[1:, 0], cells[1:, 1]]
    return float(length.sum())


HEADER = (
    f"{'map':<26}{'cost':<7}{'start -> goal':<27}{'method':<7}{'ours ms':>9}{'expanded':>10}"
    f"{'cost m':>12}{'vs dijkstra':>13}{'pyastar ms':>11}{'ours/py':>9}{'py cost':>12}"
    f"{'tcod ms':>9}{'tcod cost':>12}"
)


class Table:
    """Runs the queries of one grid and prints one row each; keeps the times for the summary."""

    def __init__(self) -> None:
        self.rows: list[dict[str, Any]] = []

    def grid(
        self,
        name: str,
        label: str,
        blocked: np.ndarray,
        pairs: list[tuple[tuple[int, int], tuple[int, int]]],
        res: float,
        extra: np.ndarray | None,
        reference: bool,
    ) -> None:
        import pyastar2d
        import tcod.path
        from scipy.sparse.csgraph import dijkstra

        from slamcli.planning.search import grid_graph, grid_search

        factor = np.ones(blocked.shape) if extra is None else 1.0 + extra
        weights = np.where(blocked, np.inf, factor).astype(np.float32)
        tcod_cost = np.where(blocked, 0, np.rint(100 * factor)).astype(np.int32)
        graph = grid_graph(blocked, res, extra) if reference else None
        w = blocked.shape[1]
        kind = "clear" if extra is not None else "unif"
        for start, goal in pairs:
            ours_s, found = best_of(
                lambda s=start, g=goal: grid_search(
                    blocked, s, g, resolution_m=res, extra_cost=extra
                )
            )
            check = "-"
            if graph is not None:
                dist = dijkstra(graph, indices=start[0] * w + start[1], limit=found.cost_m + 1e-3)
                diff = abs(float(dist[goal[0] * w + goal[1]]) - found.cost_m)
                check = f"{'ok' if diff <= AGREE_M else 'NO'} {diff:.0e}"
            py_s, py_path = best_of(
                lambda s=start, g=goal: pyastar2d.astar_path(weights, s, g, allow_diagonal=True)
            )
            tc_s, tc_path = best_of(
                lambda s=start, g=goal: tcod.path.path2d(
                    tcod_cost, start_points=[s], end_points=[g], cardinal=70, diagonal=99
                )
            )
            py_cost = walk_cost(py_path if py_path is not None else [], res, extra)
            tc_cost = walk_cost(tc_path, res, extra)
            row = {"name": name, "map": label, "kind": kind, "ours": ours_s, "py": py_s}
            self.rows.append({**row, "tcod": tc_s})
            print(
                f"{label:<26}{kind:<7}{f'{start}->{goal}':<27}{found.method:<7}"
                f"{ours_s * 1000:>9.1f}{found.expanded:>10}{found.cost_m:>12.3f}{check:>13}"
                f"{py_s * 1000:>11.1f}{ours_s / py_s:>9.2f}{py_cost:>12.3f}"
                f"{tc_s * 1000:>9.1f}{tc_cost:>12.3f}",
                flush=True,
            )

    def summary(self) -> None:
        """Per map and cost mode: summed times and the ratio to pyastar2d."""
        print()
        print(
            f"{'map':<26}{'cost':<7}{'queries':>8}{'ours ms':>10}{'pyastar ms':>12}"
            f"{'tcod ms':>10}{'ours/py':>9}{'worst':>8}"
        )
        groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
        for row in self.rows:
            groups.setdefault((row["map"], row["kind"]), []).append(row)
        for (label, kind), rows in groups.items():
            ours = sum(r["ours"] for r in rows)
            py = sum(r["py"] for r in rows)
            tc = sum(r["tcod"] for r in rows)
            worst = max(r["ours"] / r["py"] for r in rows)
            print(
                f"{label:<26}{kind:<7}{len(rows):>8}{ours * 1000:>10.1f}{py * 1000:>12.1f}"
                f"{tc * 1000:>10.1f}{ours / py:>9.2f}{worst:>8.2f}"
            )
        building = [r for r in self.rows if r["name"] in BUILDINGS]
        for kind in ("unif", "clear"):
            rows = [r for r in building if r["kind"] == kind]
            if rows:
                ours = sum(r["ours"] for r in rows)
                py = sum(r["py"] for r in rows)
                verdict = "meets" if ours <= py else "MISSES"
                print(
                    f"building floors, {kind}: ours {ours * 1000:.1f} ms vs pyastar2d "
                    f"{py * 1000:.1f} ms in total ({verdict} the goal ours <= pyastar2d)"
                )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("maps", nargs="?", type=Path, default=DEFAULT)
    parser.add_argument("--size", type=int, default=4000)
    parser.add_argument("--pairs", type=int, default=4, help="random start/goal pairs per map")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-maze-reference", action="store_true")
    parser.add_argument("--no-maze", action="store_true")
    parser.add_argument("--no-startup", action="store_true")
    parser.add_argument("--no-car", action="store_true")
    parser.add_argument("--no-centring", action="store_true")
    args = parser.parse_args()

    if not args.no_startup:
        startup()
        print()

    from slamcli.planning.costmap import build_costmap
    from slamcli.planning.planner import load_map
    from slamcli.planning.search import grid_search

    # This process's own numba cost, then every row below is compiled code.
    t0 = time.perf_counter()
    import numba  # noqa: F401

    t1 = time.perf_counter()
    tiny = np.zeros((8, 8), dtype=bool)
    grid_search(tiny, (0, 0), (7, 7))
    grid_search(tiny, (0, 0), (7, 7), extra_cost=np.zeros((8, 8)))
    t2 = time.perf_counter()
    print(
        f"this process: import numba {(t1 - t0) * 1000:.0f} ms, first calls (load cached "
        f"kernels) {(t2 - t1) * 1000:.0f} ms"
    )
    print(HEADER)
    table = Table()
    for name in MAPS:
        yaml_path = args.maps / f"{name}.yaml"
        if not yaml_path.exists():
            print(f"{name}: {yaml_path} not found, skipped")
            continue
        grid, _ = load_map(yaml_path)
        costmap = build_costmap(grid, ROBOT_RADIUS_M, clearance_weight=1.0)
        blocked = costmap.blocked
        pairs = far_pairs(blocked, args.pairs, args.seed)
        res = costmap.resolution_m
        h, w = blocked.shape
        label = f"{name} {h}x{w}"
        table.grid(name, label, blocked, pairs, res, None, reference=True)
        table.grid(name, label, blocked, pairs, res, costmap.extra_cost, reference=True)

    if not args.no_maze:
        for corridor, wall in ((8, 2), (36, 4)):
            t0 = time.perf_counter()
            blocked, start, goal = maze(args.size, corridor, wall)
            label = f"maze {args.size} c{corridor}w{wall}"
            print(
                f"{label}: {np.count_nonzero(~blocked)} free cells, generated in "
                f"{time.perf_counter() - t0:.1f} s"
            )
            pairs = [(start, goal), *far_pairs(blocked, 2, args.seed)]
            table.grid(
                "maze", label, blocked, pairs, 1.0, None, reference=not args.no_maze_reference
            )
    table.summary()
    if not args.no_car:
        print()
        car(args.maps, args.seed)
    if not args.no_centring:
        print()
        car_centring(args.maps, args.seed)


def car(maps: Path, seed: int) -> None:
    """The car-like table of the module doc."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from planning_data import (  # type: ignore[import-not-found]
        BAY_GOAL,
        SMALL_CAR,
        SMALL_RADIUS_M,
        YARD_CAR,
        YARD_RADIUS_M,
        YARD_START,
        far_poses,
        ompl_car_length,
        yard,
    )

    from slamcli.planning.car import CarSettings, car_blocked, plan_car
    from slamcli.planning.car_motion import CarLimits
    from slamcli.planning.planner import load_map

    cases = []
    grid = yard()
    cases.append(("yard, into the bay", grid, YARD_CAR, YARD_RADIUS_M, YARD_START, BAY_GOAL, True))
    cases.append(
        ("yard, forward only", grid, YARD_CAR, YARD_RADIUS_M, YARD_START, (55.0, 30.0, 0.0), False)
    )
    for name in ("stata_basement", "building_31"):
        grid, _ = load_map(maps / f"{name}.yaml")
        for k, (a, b) in enumerate(far_poses(grid, car_blocked(grid, "blocked"), 0.8, 2, seed)):
            cases.append((f"{name} #{k}", grid, SMALL_CAR, SMALL_RADIUS_M, a, b, True))
    print(
        "ours: reversing costs 2x (the default, as Smac); len=: --reverse-penalty 1, the shortest"
        " path, OMPL's objective"
    )
    print(
        f"{'car-like case':24s} {'ours m':>8s} {'gears':>5s} {'ours ms':>8s} {'len= m':>8s} "
        f"{'RRT* m':>8s} {'BIT* m':>8s} {'budget s':>8s} {'ours/best':>9s} {'len=/best':>9s} "
        f"{'clear m':>8s} {'max k':>7s}"
    )
    for label, grid, fp, radius, a, b, reverse in cases:
        limits = CarLimits(
            max_speed=1.0,
            wheelbase_m=0.6 * float(np.ptp(fp.vertices[:, 0])),
            min_turn_radius_m=radius,
        )
        settings = CarSettings(fp, radius, reverse=reverse)
        plan_car(grid, a, b, settings, limits)  # compiled kernels loaded
        t0 = time.perf_counter()
        result = plan_car(grid, a, b, settings, limits)
        ours = time.perf_counter() - t0
        shortest = plan_car(
            grid, a, b, CarSettings(fp, radius, reverse=reverse, reverse_weight=1.0), limits
        )
        budget = max(1.0, ours)
        ref = ompl_car_length(
            grid, result.blocked, fp, radius, a, b, reverse=reverse, time_s=budget
        )

        def fmt(v: float | None) -> str:
            return f"{v:8.2f}" if v is not None else f"{'none':>8s}"

        best = ref["best"]
        ratio = f"{result.length_m / best:9.3f}" if best else f"{'-':>9s}"
        ratio1 = f"{shortest.length_m / best:9.3f}" if best else f"{'-':>9s}"
        print(
            f"{label:24s} {result.length_m:8.2f} {result.reversals:5d} {ours * 1000:8.0f} "
            f"{shortest.length_m:8.2f} {fmt(ref['RRTstar'])} {fmt(ref['BITstar'])} {budget:8.1f} "
            f"{ratio} {ratio1} {result.min_clearance_m:8.3f} {result.max_curvature * radius:7.3f}"
        )
    print("max k: the path's largest curvature times R (at most 1); goal: ours/best <= 1.1")


NAV2_SMAC = (
    (
        "cost of a cell",
        "costmap inflation: exp decay from the inscribed radius",
        "(1 - d/m)², m = largest d within --inflation-radius",
    ),
    ("cost weight", "cost_penalty 2.0 (cost / 252)", "--cost-penalty 8"),
    (
        "keeps to the middle",
        "where inflation reaches across the corridor",
        "by construction (0 on the middle line, as far as 1.5 m sees)",
    ),
    ("reversing", "reverse_penalty 2.0", "--reverse-penalty 2"),
    (
        "obstacle heuristic",
        "2-D Dijkstra over the costmap, cost included",
        "the same, exact 8-connected, cost included",
    ),
    ("distance heuristic", "precomputed Reeds-Shepp lookup table", "Reeds-Shepp length, computed"),
    ("analytic expansion", "every few nodes, cost-blind", "near the goal only when costed"),
    (
        "smoother",
        "gradient smoother: w_smooth, w_data; curvature not rate-limited",
        "curvature ramps at --full-lock-distance, anchored every 3 m, poses checked",
    ),
    ("collision check", "footprint on the costmap", "exact footprint polygon on the cells"),
    (
        "time limit",
        "max_planning_time 5 s: fails past it",
        "--max-planning-time 5 s: a greedy search, then an error",
    ),
)


def car_centring(maps: Path, seed: int) -> None:
    """The centring and steering table of the module doc."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from planning_data import (  # type: ignore[import-not-found]
        SMALL_CAR,
        SMALL_RADIUS_M,
        clearance_ratios,
        far_poses,
        ompl_car_length,
        path_cost,
    )

    from slamcli.planning.car import CarSettings, car_blocked, plan_car
    from slamcli.planning.car_motion import CarLimits
    from slamcli.planning.costmap import centring_cost, clearance_ratio
    from slamcli.planning.planner import load_map

    limits = CarLimits(max_speed=1.0, wheelbase_m=0.54, min_turn_radius_m=SMALL_RADIUS_M)
    grids = {}
    cases = [("docs' Stata example", "stata_basement", (24.4, -2.4, 0.7), (-54.5, 5.7, -1.94))]
    for name in BUILDINGS:
        grids[name] = load_map(maps / f"{name}.yaml")[0]
        blocked = car_blocked(grids[name], "blocked")
        for k, (a, b) in enumerate(far_poses(grids[name], blocked, 0.8, 3, seed)):
            cases.append((f"{name} #{k}", name, a, b))

    def run(grid: Any, a: tuple, b: tuple, settings: Any) -> tuple[Any, float]:
        plan_car(grid, a, b, settings, limits)  # warm
        t = time.perf_counter()
        result = plan_car(grid, a, b, settings, limits)
        return result, time.perf_counter() - t

    print(
        f"car-like centring (seed {seed}; 0.9 x 0.6 m, R 1.2 m; rate limit "
        f"{1 / (SMALL_RADIUS_M * 0.5):.2f} 1/m² = full lock over 0.5 m): today = "
        "--cost-penalty 0 --full-lock-distance 0"
    )
    print(
        f"{'query':22s} {'today m':>8s} {'med':>5s} {'p10':>5s} {'rate':>7s} {'states':>7s} "
        f"{'ms':>5s} | {'ours m':>7s} {'x':>5s} {'med':>5s} {'p10':>5s} {'rate':>5s} "
        f"{'states':>7s} {'ms':>5s}  warnings"
    )
    worst_ms = 0.0
    for label, name, a, b in cases:
        grid = grids[name]
        today, t_today = run(
            grid,
            a,
            b,
            CarSettings(SMALL_CAR, SMALL_RADIUS_M, cost_penalty=0.0, full_lock_distance_m=None),
        )
        ours, t_ours = run(grid, a, b, CarSettings(SMALL_CAR, SMALL_RADIUS_M))
        worst_ms = max(worst_ms, t_ours * 1000)
        r0 = clearance_ratios(grid, today.blocked, today.poses)
        r1 = clearance_ratios(grid, ours.blocked, ours.poses)
        print(
            f"{label:22s} {today.length_m:8.1f} {np.median(r0):5.2f} {np.percentile(r0, 10):5.2f} "
            f"{today.max_curvature_rate:7.1f} {today.expanded:7d} {t_today * 1000:5.0f} | "
            f"{ours.length_m:7.1f} {ours.length_m / today.length_m:5.2f} {np.median(r1):5.2f} "
            f"{np.percentile(r1, 10):5.2f} {ours.max_curvature_rate:5.2f} {ours.expanded:7d} "
            f"{t_ours * 1000:5.0f}  {len(ours.warnings)}"
        )
    print(f"worst warm plan_car time with the defaults: {worst_ms:.0f} ms")

    print()
    print("the same centring cost, OMPL on the Reeds-Shepp space (cost = sum ds (1 + 8 c)):")
    print(
        f"{'query':22s} {'ours':>8s} {'RRT*':>8s} {'BIT*':>8s} {'budget s':>8s} {'ours/best':>9s}"
    )
    for label, name, a, b in cases[:3]:
        grid = grids[name]
        settings = CarSettings(SMALL_CAR, SMALL_RADIUS_M, reverse_weight=1.0)
        ours, t_ours = run(grid, a, b, settings)
        blocked = ours.blocked
        cost = 8.0 * centring_cost(clearance_ratio(blocked, grid.resolution_m, 1.5))
        mine = path_cost(grid, cost, ours.poses)
        budget = max(2.0, t_ours)
        ref = ompl_car_length(
            grid, blocked, SMALL_CAR, SMALL_RADIUS_M, a, b, time_s=budget, cost=cost
        )

        def fmt(v: float | None) -> str:
            return f"{v:8.1f}" if v is not None else f"{'none':>8s}"

        best = ref["best"]
        ratio = f"{mine / best:9.3f}" if best else f"{'-':>9s}"
        print(
            f"{label:22s} {mine:8.1f} {fmt(ref['RRTstar'])} {fmt(ref['BITstar'])} "
            f"{budget:8.1f} {ratio}"
        )

    print()
    print("Nav2 Smac Hybrid-A* (its documentation's defaults) beside ours:")
    for what, smac, mine_text in NAV2_SMAC:
        print(f"  {what:20s} Smac: {smac}")
        print(f"  {'':20s} ours: {mine_text}")


if __name__ == "__main__":
    main()
