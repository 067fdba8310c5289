"""Exact grid search time beside scipy's Dijkstra over the same graph, built in the same run.

Ours is `slamcli.planning.search.grid_search` (best of 3 calls, each building its own jump
tables; the first call of the process is printed too): JPS on uniform cost, A* with a
clearance-style extra cost. The reference is `scipy.sparse.csgraph.dijkstra` from the start,
stopped at our cost (`limit`), over `grid_graph` of the same grid; building that graph is timed
separately. Costs must agree to 1e-9 (relative, as the reference sums long paths edge by edge).

Maps: the Nav2 TurtleBot3 maps (pixel < 250 blocked: unknown counts as blocked), start/goal pairs
at the extremes of the largest free region; and 4000x4000 perfect mazes (seeded recursive
backtracker, scaled up so corridors are several cells wide) solved corner to corner.

Usage: python benchmarks/bench_plan.py [MAPS_DIR] [--size 4000] [--no-maze-reference]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

DEFAULT = Path(__file__).resolve().parents[2] / "shared/data/maps"
GOALS_S = {"map": 0.050, "map +extra": 1.0, "maze": 3.0}


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


def far_pairs(blocked: np.ndarray) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """Start/goal pairs at the extremes of the largest 4-connected free region."""
    from scipy.ndimage import label

    labels, _ = label(~blocked)
    cells = np.argwhere(labels == np.bincount(labels.ravel())[1:].argmax() + 1)

    def at(i: np.intp) -> tuple[int, int]:
        return int(cells[i, 0]), int(cells[i, 1])

    s, d = cells.sum(axis=1), cells[:, 0] - cells[:, 1]
    return [
        (at(cells[:, 0].argmin()), at(cells[:, 0].argmax())),
        (at(cells[:, 1].argmin()), at(cells[:, 1].argmax())),
        (at(s.argmin()), at(s.argmax())),
        (at(d.argmin()), at(d.argmax())),
    ]


def best_of(fn: Callable[[], Any], repeat: int = 3) -> tuple[float, float, Any]:
    """(first call s, best call s, last result)."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return times[0], min(times), out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("maps", nargs="?", type=Path, default=DEFAULT)
    parser.add_argument("--size", type=int, default=4000)
    parser.add_argument("--no-maze-reference", action="store_true")
    args = parser.parse_args()

    import cv2
    from scipy.sparse.csgraph import dijkstra

    from slamcli.planning.search import grid_graph, grid_search

    header = (
        f"{'map':<28}{'start -> goal':<26}{'method':<7}{'ours ms':>9}{'1st ms':>9}"
        f"{'expanded':>10}{'cost m':>12}{'dijkstra ms':>13}{'dij reached':>12}{'agree':>7}"
    )
    worst = dict.fromkeys(GOALS_S, 0.0)

    def run(label: str, kind: str, blocked, pairs, res, extra, graph_s, graph) -> None:
        w = blocked.shape[1]
        for start, goal in pairs:
            first, best, found = best_of(
                lambda s=start, g=goal: grid_search(
                    blocked, s, g, resolution_m=res, extra_cost=extra
                )
            )
            worst[kind] = max(worst[kind], best)
            ref_ms, settled, agree = "-", "-", "-"
            if graph is not None:
                t0 = time.perf_counter()
                dist = dijkstra(
                    graph, indices=start[0] * w + start[1], limit=found.cost_m * (1 + 1e-9)
                )
                ref_ms = f"{(time.perf_counter() - t0) * 1000:.1f}"
                ref = dist[goal[0] * w + goal[1]]
                settled = str(np.count_nonzero(np.isfinite(dist)))
                agree = "yes" if abs(ref - found.cost_m) <= 1e-9 * max(1.0, ref) else "NO"
            print(
                f"{label:<28}{f'{start}->{goal}':<26}{found.method:<7}{best * 1000:>9.1f}"
                f"{first * 1000:>9.1f}{found.expanded:>10}{found.cost_m:>12.3f}{ref_ms:>13}"
                f"{settled:>12}{agree:>7}"
            )
        if graph is not None:
            print(f"{'':<28}(grid_graph build for the reference: {graph_s * 1000:.0f} ms)")

    print(header)
    for path in sorted(args.maps.glob("*.pgm")):
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        blocked = image < 250
        res = 0.05
        yaml_path = path.with_suffix(".yaml")
        if yaml_path.exists():
            import yaml

            res = float(yaml.safe_load(yaml_path.read_text())["resolution"])
        pairs = far_pairs(blocked)
        t0 = time.perf_counter()
        graph = grid_graph(blocked, res)
        graph_s = time.perf_counter() - t0
        run(path.name, "map", blocked, pairs, res, None, graph_s, graph)
        # A* with a clearance-style cost: up to 3x extra within 10 cells of an obstacle.
        clearance = cv2.distanceTransform((~blocked).astype(np.uint8), cv2.DIST_L2, 5)
        extra = 3.0 * np.clip(1.0 - clearance / 10.0, 0.0, 1.0)
        t0 = time.perf_counter()
        graph = grid_graph(blocked, res, extra)
        graph_s = time.perf_counter() - t0
        run(path.name + " +extra", "map +extra", blocked, pairs[:2], res, extra, graph_s, graph)

    for corridor, wall in ((8, 2), (36, 4)):
        t0 = time.perf_counter()
        blocked, start, goal = maze(args.size, corridor, wall)
        label = f"maze {args.size} c{corridor}w{wall}"
        print(
            f"{label}: {np.count_nonzero(~blocked)} free cells, generated in "
            f"{time.perf_counter() - t0:.1f} s"
        )
        graph, graph_s = None, 0.0
        if not args.no_maze_reference:
            t0 = time.perf_counter()
            graph = grid_graph(blocked)
            graph_s = time.perf_counter() - t0
        run(label, "maze", blocked, [(start, goal)], 1.0, None, graph_s, graph)
        del graph

    for kind, goal in GOALS_S.items():
        verdict = "meets" if worst[kind] <= goal else "MISSES"
        print(f"slowest {kind} query: {worst[kind] * 1000:.1f} ms ({verdict} the goal <= {goal} s)")


if __name__ == "__main__":
    main()
