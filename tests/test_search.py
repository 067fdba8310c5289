"""Exact grid search: JPS, A* and the distance field against scipy's Dijkstra on the same graph.

The reference is :func:`scipy.sparse.csgraph.dijkstra` over :func:`grid_graph` (built with
numpy, independent of the compiled search), on random grids, the Nav2 maps and the shared
building floors (inflated for a 0.2 m robot, uniform cost and with the clearance cost).
"""

from __future__ import annotations

import itertools
import math

import cv2
import numpy as np
import pytest
from conftest import shared_path
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.ndimage import label
from scipy.sparse.csgraph import dijkstra

from slamcli.errors import ConfigError, MapError, NoPathError
from slamcli.planning.costmap import build_costmap
from slamcli.planning.planner import load_map
from slamcli.planning.search import SearchResult, grid_distances, grid_graph, grid_search


def _walk_cost(
    blocked: np.ndarray, cells: np.ndarray, resolution_m: float, extra: np.ndarray | None
) -> float:
    """Checks that ``cells`` is a walk in the graph (module doc of search.py); its cost."""
    assert cells.ndim == 2 and cells.shape[1] == 2 and cells.dtype == np.int64
    assert not blocked[cells[:, 0], cells[:, 1]].any(), "the path enters a blocked cell"
    total = 0.0
    for (r0, c0), (r1, c1) in itertools.pairwise(cells.tolist()):
        dr, dc = r1 - r0, c1 - c0
        assert max(abs(dr), abs(dc)) == 1, f"({r0}, {c0}) -> ({r1}, {c1}) is not a move"
        if dr and dc:
            assert not (blocked[r0 + dr, c0] and blocked[r0, c0 + dc]), "squeezes between two"
            length = resolution_m * math.sqrt(2.0)
        else:
            length = resolution_m
        total += length * (1.0 + (0.0 if extra is None else extra[r1, c1]))
    return total


def _check(
    result: SearchResult,
    blocked: np.ndarray,
    start: tuple[int, int],
    goal: tuple[int, int],
    reference: float,
    resolution_m: float = 1.0,
    extra: np.ndarray | None = None,
) -> None:
    assert tuple(result.cells[0]) == start and tuple(result.cells[-1]) == goal
    assert result.cost_m == pytest.approx(reference, abs=1e-9, rel=0)
    walked = _walk_cost(blocked, result.cells, resolution_m, extra)
    assert walked == pytest.approx(result.cost_m, abs=1e-9, rel=0)


def _random_grid(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    density = rng.uniform(0.0, 0.6)
    if rng.random() < 0.4:
        # Blocky obstacles (rooms, corridors, long walls) as well as salt-and-pepper noise.
        k = int(rng.integers(2, 6))
        coarse = rng.random((h // k + 1, w // k + 1)) < density
        return np.kron(coarse, np.ones((k, k), dtype=bool))[:h, :w] | (rng.random((h, w)) < 0.05)
    return rng.random((h, w)) < density


def test_random_grids_match_dijkstra() -> None:
    rng = np.random.default_rng(20240611)
    checked = {"jps": 0, "astar": 0, "none": 0}
    for _ in range(200):
        h, w = (int(v) for v in rng.integers(5, 61, size=2))
        blocked = _random_grid(rng, h, w)
        free = np.argwhere(~blocked)
        if len(free) < 2:
            continue
        res = float(rng.choice([1.0, 0.05, 0.37]))
        extra = rng.random((h, w)) * rng.choice([0.5, 4.0]) if rng.random() < 0.4 else None
        start = tuple(int(v) for v in free[rng.integers(len(free))])
        dist = dijkstra(grid_graph(blocked, res, extra), indices=start[0] * w + start[1])
        for goal in free[rng.integers(len(free), size=6)]:
            goal = tuple(int(v) for v in goal)
            reference = dist[goal[0] * w + goal[1]]
            methods = ("astar",) if extra is not None else ("jps", "astar")
            if not np.isfinite(reference):
                for method in methods:
                    with pytest.raises(NoPathError, match="cells reached from the start"):
                        grid_search(
                            blocked, start, goal, resolution_m=res, extra_cost=extra, method=method
                        )
                checked["none"] += 1
                continue
            found = {}
            for method in methods:
                found[method] = grid_search(
                    blocked, start, goal, resolution_m=res, extra_cost=extra, method=method
                )
                assert found[method].method == method
                _check(found[method], blocked, start, goal, reference, res, extra)
                checked[method] += 1
            if "jps" in found:
                assert found["jps"].cost_m == pytest.approx(found["astar"].cost_m, abs=1e-9)
    # The seed gives a good mix; make sure it stays that way.
    assert checked["jps"] > 300 and checked["astar"] > 600 and checked["none"] > 20


@settings(max_examples=150, deadline=None)
@given(
    rows=st.lists(st.lists(st.booleans(), min_size=6, max_size=6), min_size=1, max_size=12).map(
        lambda r: np.array(r, dtype=bool)
    ),
    picks=st.tuples(st.integers(0, 10**6), st.integers(0, 10**6)),
)
def test_jps_cost_equals_dijkstra_property(rows: np.ndarray, picks: tuple[int, int]) -> None:
    blocked = rows
    free = np.argwhere(~blocked)
    if len(free) == 0:
        return
    start = tuple(int(v) for v in free[picks[0] % len(free)])
    goal = tuple(int(v) for v in free[picks[1] % len(free)])
    w = blocked.shape[1]
    reference = dijkstra(grid_graph(blocked), indices=start[0] * w + start[1])[
        goal[0] * w + goal[1]
    ]
    if not np.isfinite(reference):
        with pytest.raises(NoPathError):
            grid_search(blocked, start, goal)
        return
    _check(grid_search(blocked, start, goal), blocked, start, goal, reference)


def test_graph_diagonal_rule() -> None:
    # A diagonal move may cut past one blocked cell but not squeeze between two.
    one = np.array([[False, True], [False, False]])
    for method in ("jps", "astar"):
        found = grid_search(one, (0, 0), (1, 1), method=method)
        assert found.cost_m == pytest.approx(math.sqrt(2.0))
        assert found.cells.tolist() == [[0, 0], [1, 1]]
    two = np.array([[False, True], [True, False]])
    for method in ("jps", "astar"):
        with pytest.raises(NoPathError, match=r"\(1 cells reached from the start\)"):
            grid_search(two, (0, 0), (1, 1), method=method)
    graph = grid_graph(two).toarray()
    assert graph[0, 3] == 0 and graph[3, 0] == 0
    assert grid_graph(one).toarray()[0, 3] == pytest.approx(math.sqrt(2.0))


def test_extra_cost_is_charged_on_the_cell_entered() -> None:
    blocked = np.zeros((1, 3), dtype=bool)
    extra = np.array([[5.0, 1.0, 0.5]])
    found = grid_search(blocked, (0, 0), (0, 2), resolution_m=0.5, extra_cost=extra)
    assert found.method == "astar"
    assert found.cost_m == pytest.approx(0.5 * 2.0 + 0.5 * 1.5)


def test_goal_inside_a_jump() -> None:
    # Open grid: the goal lies on a straight ray, on a diagonal, or where a diagonal crosses its
    # row or column, far from any wall or jump point.
    blocked = np.zeros((41, 41), dtype=bool)
    for goal in ((20, 35), (20, 3), (33, 20), (5, 5), (30, 30), (8, 27), (39, 26), (21, 2)):
        dr, dc = abs(goal[0] - 20), abs(goal[1] - 20)
        octile = min(dr, dc) * math.sqrt(2.0) + abs(dr - dc)
        for method in ("jps", "astar"):
            found = grid_search(blocked, (20, 20), goal, method=method)
            _check(found, blocked, (20, 20), goal, octile)


def test_start_equals_goal() -> None:
    blocked = np.zeros((4, 4), dtype=bool)
    for method in ("auto", "jps", "astar"):
        found = grid_search(blocked, (2, 1), (2, 1), method=method)
        assert found.cells.tolist() == [[2, 1]]
        assert found.cost_m == 0.0


def test_unreachable_goal_reports_the_reached_count() -> None:
    blocked = np.zeros((10, 10), dtype=bool)
    blocked[:, 4] = True  # a wall splits the map into 10x4 and 10x5 free cells
    for method in ("jps", "astar"):
        with pytest.raises(NoPathError, match=r"40 cells reached from the start"):
            grid_search(blocked, (0, 0), (9, 9), method=method)
        with pytest.raises(NoPathError, match=r"50 cells reached from the start"):
            grid_search(blocked, (9, 9), (0, 0), method=method)


def test_bad_queries_raise_map_error() -> None:
    blocked = np.zeros((5, 6), dtype=bool)
    blocked[2, 3] = True
    with pytest.raises(MapError, match=r"start cell \(5, 0\) is outside the 5x6 grid"):
        grid_search(blocked, (5, 0), (0, 0))
    with pytest.raises(MapError, match=r"goal cell \(0, -1\) is outside"):
        grid_search(blocked, (0, 0), (0, -1))
    with pytest.raises(MapError, match=r"goal cell \(2, 3\) is blocked"):
        grid_search(blocked, (0, 0), (2, 3))
    with pytest.raises(MapError, match="extra_cost"):
        grid_search(blocked, (0, 0), (4, 5), extra_cost=-np.ones((5, 6)))
    with pytest.raises(MapError, match="extra_cost has shape"):
        grid_search(blocked, (0, 0), (4, 5), extra_cost=np.ones((6, 5)))
    with pytest.raises(ConfigError, match="uniform costs"):
        grid_search(blocked, (0, 0), (4, 5), extra_cost=np.ones((5, 6)), method="jps")
    with pytest.raises(ConfigError, match="unknown search method"):
        grid_search(blocked, (0, 0), (4, 5), method="bfs")


def test_deterministic() -> None:
    rng = np.random.default_rng(3)
    blocked = rng.random((80, 80)) < 0.3
    labels, _ = label(~blocked)
    cells = np.argwhere(labels == np.bincount(labels.ravel())[1:].argmax() + 1)
    start, goal = tuple(cells[0]), tuple(cells[-1])
    for method in ("jps", "astar"):
        a = grid_search(blocked, start, goal, method=method)
        b = grid_search(blocked.copy(), start, goal, method=method)
        assert np.array_equal(a.cells, b.cells) and a.expanded == b.expanded


@pytest.mark.parametrize("name", ["turtlebot3_world.pgm", "tb3_sandbox.pgm"])
def test_nav2_maps_match_dijkstra(name: str) -> None:
    image = cv2.imread(str(shared_path("maps", name)), cv2.IMREAD_UNCHANGED)
    blocked = image < 250  # 0 occupied, 205 unknown (blocked too), 254 free
    labels, _ = label(~blocked)
    largest = np.bincount(labels.ravel())[1:].argmax() + 1
    cells = np.argwhere(labels == largest)
    # Far-apart pairs: the extreme cells of the largest free region.
    top, bottom = cells[cells[:, 0].argmin()], cells[cells[:, 0].argmax()]
    left, right = cells[cells[:, 1].argmin()], cells[cells[:, 1].argmax()]
    w = blocked.shape[1]
    graph = grid_graph(blocked, 0.05)
    for a, b in ((top, bottom), (left, right), (top, right)):
        start, goal = (int(a[0]), int(a[1])), (int(b[0]), int(b[1]))
        reference = dijkstra(graph, indices=start[0] * w + start[1])[goal[0] * w + goal[1]]
        assert reference > 3.0  # metres: the pairs are far apart
        for method in ("jps", "astar"):
            found = grid_search(blocked, start, goal, resolution_m=0.05, method=method)
            _check(found, blocked, start, goal, reference, 0.05)
        assert grid_search(blocked, start, goal, resolution_m=0.05).method == "jps"


def _largest_region(blocked: np.ndarray) -> np.ndarray:
    """(N, 2) cells of the largest 4-connected free region."""
    labels, _ = label(~blocked)
    return np.argwhere(labels == np.bincount(labels.ravel())[1:].argmax() + 1)


def _distances_to(
    blocked: np.ndarray, goal: tuple[int, int], res: float, extra: np.ndarray | None
) -> np.ndarray:
    """scipy's Dijkstra over the reversed graph: (H, W) cost from every cell to ``goal``."""
    w = blocked.shape[1]
    reverse = grid_graph(blocked, res, extra).T.tocsr()
    return dijkstra(reverse, indices=goal[0] * w + goal[1]).reshape(blocked.shape)


@pytest.mark.parametrize("name", ["stata_basement", "building_31"])
def test_building_floors_match_dijkstra(name: str) -> None:
    grid, _ = load_map(shared_path("maps", f"{name}.yaml"))
    costmap = build_costmap(grid, 0.2, clearance_weight=1.0)
    blocked, res = costmap.blocked, costmap.resolution_m
    assert costmap.extra_cost is not None and costmap.extra_cost.max() > 0.5
    cells = _largest_region(blocked)
    rng = np.random.default_rng(7)
    goal = tuple(int(v) for v in cells[rng.integers(len(cells))])
    # Starts: of 64 random cells each time, the farthest from the goal.
    starts = []
    for _ in range(3):
        pick = cells[rng.integers(len(cells), size=64)]
        far = pick[np.hypot(*(pick - goal).T).argmax()]
        starts.append((int(far[0]), int(far[1])))
    for extra in (None, costmap.extra_cost):
        reference = _distances_to(blocked, goal, res, extra)
        field = grid_distances(blocked, goal, resolution_m=res, extra_cost=extra)
        assert np.array_equal(np.isinf(field), np.isinf(reference))
        finite = np.isfinite(reference)
        assert np.abs(field[finite] - reference[finite]).max() < 1e-6
        methods = ("jps", "astar") if extra is None else ("astar",)
        for start in starts:
            assert reference[start] > 20.0  # metres: the pairs are far apart
            for method in methods:
                found = grid_search(
                    blocked, start, goal, resolution_m=res, extra_cost=extra, method=method
                )
                assert found.method == method
                assert tuple(found.cells[0]) == start and tuple(found.cells[-1]) == goal
                assert found.cost_m == pytest.approx(reference[start], abs=1e-6, rel=0)
                walked = _walk_cost(blocked, found.cells, res, extra)
                assert walked == pytest.approx(found.cost_m, abs=1e-6, rel=0)


def test_distances_match_dijkstra_on_random_grids() -> None:
    rng = np.random.default_rng(99)
    checked = 0
    for _ in range(60):
        h, w = (int(v) for v in rng.integers(3, 41, size=2))
        blocked = _random_grid(rng, h, w)
        free = np.argwhere(~blocked)
        if len(free) == 0:
            continue
        res = float(rng.choice([1.0, 0.05]))
        extra = rng.random((h, w)) * 3.0 if rng.random() < 0.5 else None
        goal = tuple(int(v) for v in free[rng.integers(len(free))])
        field = grid_distances(blocked, goal, resolution_m=res, extra_cost=extra)
        reference = _distances_to(blocked, goal, res, extra)
        assert field.shape == blocked.shape and field.dtype == np.float64
        assert field[goal] == 0.0
        assert np.all(np.isinf(field[blocked]))
        assert np.array_equal(np.isinf(field), np.isinf(reference))
        finite = np.isfinite(reference)
        np.testing.assert_allclose(field[finite], reference[finite], rtol=0, atol=1e-9)
        # The field is the cost of a search ending at the goal, from any reachable cell.
        for cell in free[rng.integers(len(free), size=3)]:
            cell = (int(cell[0]), int(cell[1]))
            if np.isfinite(field[cell]):
                found = grid_search(blocked, cell, goal, resolution_m=res, extra_cost=extra)
                assert found.cost_m == pytest.approx(field[cell], abs=1e-9, rel=0)
                checked += 1
    assert checked > 100


def test_distances_measure_paths_to_the_goal() -> None:
    # Extra cost is paid on the cells entered, so the field is not symmetric.
    blocked = np.zeros((1, 3), dtype=bool)
    extra = np.array([[5.0, 1.0, 0.5]])
    to_east = grid_distances(blocked, (0, 2), resolution_m=0.5, extra_cost=extra)
    np.testing.assert_allclose(to_east[0], [0.5 * 2.0 + 0.5 * 1.5, 0.5 * 1.5, 0.0])
    to_west = grid_distances(blocked, (0, 0), resolution_m=0.5, extra_cost=extra)
    np.testing.assert_allclose(to_west[0], [0.0, 0.5 * 6.0, 0.5 * 2.0 + 0.5 * 6.0])
    # Blocked cells and cells cut off from the goal are inf; a diagonal may not squeeze
    # between two blocked cells.
    two = np.array([[False, True], [True, False]])
    field = grid_distances(two, (0, 0))
    assert field[0, 0] == 0.0 and np.all(np.isinf(field.ravel()[1:]))
    one = np.array([[False, True], [False, False]])
    np.testing.assert_allclose(grid_distances(one, (0, 0)), [[0.0, np.inf], [1.0, math.sqrt(2.0)]])


def test_distances_bad_queries_raise_map_error() -> None:
    blocked = np.zeros((5, 6), dtype=bool)
    blocked[2, 3] = True
    with pytest.raises(MapError, match=r"goal cell \(5, 0\) is outside the 5x6 grid"):
        grid_distances(blocked, (5, 0))
    with pytest.raises(MapError, match=r"goal cell \(2, 3\) is blocked"):
        grid_distances(blocked, (2, 3))
    with pytest.raises(MapError, match="extra_cost must be finite"):
        grid_distances(blocked, (0, 0), extra_cost=np.full((5, 6), np.nan))
    with pytest.raises(MapError, match="resolution_m"):
        grid_distances(blocked, (0, 0), resolution_m=0.0)


def test_deterministic_on_a_building_floor() -> None:
    grid, _ = load_map(shared_path("maps", "building_31.yaml"))
    costmap = build_costmap(grid, 0.2, clearance_weight=1.0)
    cells = _largest_region(costmap.blocked)
    start, goal = tuple(cells[0]), tuple(cells[-1])
    res = costmap.resolution_m
    for extra, method in ((None, "jps"), (None, "astar"), (costmap.extra_cost, "astar")):
        runs = [
            grid_search(
                costmap.blocked.copy(),
                start,
                goal,
                resolution_m=res,
                extra_cost=extra,
                method=method,
            )
            for _ in range(2)
        ]
        assert np.array_equal(runs[0].cells, runs[1].cells)
        assert (runs[0].cost_m, runs[0].expanded, runs[0].reached) == (
            runs[1].cost_m,
            runs[1].expanded,
            runs[1].reached,
        )
    a = grid_distances(costmap.blocked, goal, resolution_m=res, extra_cost=costmap.extra_cost)
    b = grid_distances(costmap.blocked, goal, resolution_m=res, extra_cost=costmap.extra_cost)
    assert np.array_equal(a, b)
