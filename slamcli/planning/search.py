"""Exact shortest paths on an 8-connected occupancy grid: jump point search, A* and Dijkstra.

The graph
---------
``blocked`` is an (H, W) bool array, row 0 first. The nodes are its unblocked cells (node
``r * W + c`` in :func:`grid_graph`; blocked cells are isolated nodes there). Every cell links to
its 8 neighbours:

* a straight move (N, E, S, W) into an unblocked cell has length ``resolution_m``;
* a diagonal move into an unblocked cell has length ``resolution_m * sqrt(2)`` and is allowed
  unless BOTH orthogonal cells it passes between are blocked: it may cut past one blocked
  corner, it may not squeeze between two;
* a move into cell c costs its length times ``1 + extra_cost[c]`` (``extra_cost`` (H, W) >= 0,
  default 0), so the octile distance times ``resolution_m`` stays an admissible and consistent
  heuristic.

A legal diagonal move always has an unblocked orthogonal cell beside it, so two cells are
connected in this graph exactly when they are 4-connected through unblocked cells. The graph is
symmetric for uniform cost only: with ``extra_cost`` a move and its reverse are priced by
different cells.

Methods
-------
The searches are compiled with numba (:mod:`slamcli.planning._search_kernels`, imported on the
first search, so importing this module stays cheap; the kernels are cached on disk, so only the
first run after an install compiles them). They run on the bounding box of the free cells,
padded with one blocked cell all around, and keep the open list in a binary heap indexed by
cell, so a cheaper path to an open cell moves its entry up instead of adding a second one.

``"astar"``: A* over cells with the octile heuristic; any ``extra_cost``.

``"jps"`` (uniform cost only): jump point search (Harabor & Grastien 2011) with forced-neighbour
rules derived for this graph, which (unlike the usual JPS grid) may cut one blocked corner:

* entering x by a straight move s from p, x+s+q (q a perpendicular step) is forced when x+q is
  blocked and x+s, x+s+q are free. Every other neighbour is reached from p without x at no
  greater cost: x+q by the diagonal p -> x+q (sqrt 2 < 2; legal because x is free), x-s+q
  directly, and x+s+q by p -> x+q -> x+s+q (same cost, diagonal first) when x+q is free;
* entering x by a diagonal move a+b (a, b straight), the natural successors are a, b and a+b;
  x+a-b is forced when x-b is blocked and x+a, x+a-b are free (likewise with a and b swapped).
  Otherwise x+a-b is reached from p by p -> p+a -> x+a-b (2 < 1 + sqrt 2), and x-a, x-b
  directly from p.

So every shortest path has an equally short one that moves diagonally first and turns only at
jump points: cells with a forced neighbour, plus, on a diagonal, cells from which a straight
jump along one of its two components stops. Jumps scan the grid cell by cell (compiled, so no
jump tables are built per query) and also stop at the goal. The tests compare both methods with
scipy's Dijkstra on thousands of random grids, the Nav2 maps and the shared building floors.

``"auto"``: ``"jps"`` when ``extra_cost`` is None, else ``"astar"`` (JPS needs uniform cost).
Chosen by measurement (``benchmarks/bench_plan.py``): on the building floors JPS answers far
queries in about 1-3 ms where A* settles 10^5 cells in 10-30 ms.

Ties in f are broken towards the larger g, then the smaller cell index: the result is
deterministic.

Distance fields
---------------
:func:`grid_distances` is Dijkstra from the goal over the reversed graph: the cost of the
cheapest path FROM every cell TO the goal, extra cost charged on the cells entered along that
path (the goal's own included, the starting cell's not). It is an exact heuristic for searches
that end at that goal.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, MapError, NoPathError

if TYPE_CHECKING:
    from scipy.sparse import csr_matrix

__all__ = ["SearchResult", "grid_distances", "grid_graph", "grid_search"]

_SQRT2 = math.sqrt(2.0)
# Directions clockwise from north as (drow, dcol); even = straight, odd = diagonal.
_DIRS = ((-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1))
_START = 8  # pseudo-direction of the start node: every legal move is a successor
_METHODS = ("auto", "jps", "astar")


@dataclass(frozen=True)
class SearchResult:
    """A shortest path.

    ``cells`` (K, 2) int64 (row, col) from start to goal inclusive; ``cost_m`` its cost (move
    lengths in metres, times ``1 + extra_cost`` of the cell entered); ``expanded`` nodes popped
    and processed; ``reached`` nodes given a finite cost (cells for A*, jump points for JPS);
    ``method`` ``"jps"`` or ``"astar"``.
    """

    cells: NDArray[np.int64]
    cost_m: float
    expanded: int
    reached: int
    method: str


def _legal(free: list[bool], k: int) -> bool:
    if k % 2 == 0:
        return free[k]
    return free[k] and (free[(k - 1) % 8] or free[(k + 1) % 8])


def _forced(free: list[bool], d: int) -> list[int]:
    """Forced neighbours of a cell entered by a move in direction d (neighbour bits ``free``)."""
    out = []
    if d % 2 == 0:
        for side, diag in (((d - 2) % 8, (d - 1) % 8), ((d + 2) % 8, (d + 1) % 8)):
            if not free[side] and free[diag] and free[d]:
                out.append(diag)
    else:
        for back, diag, along in (
            ((d - 3) % 8, (d - 2) % 8, (d - 1) % 8),
            ((d + 3) % 8, (d + 2) % 8, (d + 1) % 8),
        ):
            if not free[back] and free[diag] and free[along]:
                out.append(diag)
    return out


def _successor_table() -> list[list[tuple[int, ...]]]:
    """Legal successor directions per (direction entered by, 8-neighbour free mask)."""
    table: list[list[tuple[int, ...]]] = []
    for d in range(_START + 1):
        row = []
        for m in range(256):
            free = [bool((m >> k) & 1) for k in range(8)]
            if d == _START:
                cand = list(range(8))
            elif d % 2 == 0:
                cand = [d, *_forced(free, d)]
            else:
                cand = [(d - 1) % 8, d, (d + 1) % 8, *_forced(free, d)]
            row.append(tuple(k for k in cand if _legal(free, k)))
        table.append(row)
    return table


@functools.cache
def _successor_masks() -> NDArray[np.uint8]:
    """(9, 256) uint8: the successor directions of :func:`_successor_table` as bit masks."""
    table = np.zeros((_START + 1, 256), dtype=np.uint8)
    for d, row in enumerate(_successor_table()):
        for m, dirs in enumerate(row):
            table[d, m] = sum(1 << k for k in dirs)
    return table


def _check_grid(blocked: NDArray[np.bool_], resolution_m: float) -> NDArray[np.bool_]:
    grid = np.asarray(blocked)
    if grid.ndim != 2 or grid.size == 0:
        raise MapError(
            f"the occupancy grid must be a non-empty 2-D array, got shape {grid.shape}",
            hint="pass the (H, W) bool array of blocked cells",
        )
    if not (math.isfinite(resolution_m) and resolution_m > 0):
        raise MapError(
            f"resolution_m must be a positive number, got {resolution_m}",
            hint="pass the map's cell size in metres",
        )
    return grid.astype(bool, copy=False)


def _check_cell(grid: NDArray[np.bool_], name: str, cell: tuple[int, int]) -> tuple[int, int]:
    h, w = grid.shape
    r, c = int(cell[0]), int(cell[1])
    if not (0 <= r < h and 0 <= c < w):
        raise MapError(
            f"{name} cell ({r}, {c}) is outside the {h}x{w} grid",
            hint=f"pick a {name} with 0 <= row < {h} and 0 <= col < {w}",
        )
    if grid[r, c]:
        raise MapError(f"{name} cell ({r}, {c}) is blocked", hint=f"pick a {name} in a free cell")
    return r, c


def _check_extra(
    grid: NDArray[np.bool_], extra_cost: NDArray[np.float64] | None
) -> NDArray[np.float64] | None:
    if extra_cost is None:
        return None
    extra = np.asarray(extra_cost, dtype=np.float64)
    if extra.shape != grid.shape:
        raise MapError(
            f"extra_cost has shape {extra.shape}, the grid {grid.shape}",
            hint="pass one extra cost per grid cell",
        )
    # min() is NaN when any value is: one comparison catches NaN and negatives.
    lo, hi = float(extra.min()), float(extra.max())
    if not (lo >= 0 and hi < math.inf):
        raise MapError(
            f"extra_cost must be finite and >= 0 everywhere, got values in [{lo}, {hi}]",
            hint="clip the cost to [0, finite] and use blocked for impassable cells",
        )
    return extra


@dataclass(frozen=True)
class _Padded:
    """The bounding box of the free cells, padded with a blocked border, flattened.

    ``free`` (Hp * Wp,) uint8, 1 on free cells; grid cell (r0, c0) is padded cell (1, 1).
    """

    free: NDArray[np.uint8]
    shape: tuple[int, int]
    r0: int
    c0: int

    @property
    def wp(self) -> int:
        return self.shape[1]

    def index(self, cell: tuple[int, int]) -> int:
        """The padded flat index of grid cell (row, col)."""
        return (cell[0] - self.r0 + 1) * self.wp + cell[1] - self.c0 + 1


def _pad(grid: NDArray[np.bool_]) -> _Padded:
    """The padded box of the free cells of ``grid`` (which has at least one free cell)."""
    rows = np.flatnonzero(~grid.all(axis=1))
    cols = np.flatnonzero(~grid.all(axis=0))
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    free = np.zeros((r1 - r0 + 2, c1 - c0 + 2), dtype=np.uint8)
    np.logical_not(grid[r0:r1, c0:c1], out=free[1:-1, 1:-1].view(bool))
    return _Padded(free.ravel(), free.shape, r0, c0)


def _extra_arg(extra: NDArray[np.float64] | None) -> tuple[NDArray[np.float64], bool]:
    """The kernels' (extra cost array, weighted flag): a 1x1 placeholder when uniform."""
    if extra is None:
        return np.zeros((1, 1)), False
    return np.ascontiguousarray(extra), True


def load_kernels() -> None:
    """Load the compiled search (numba's one-time start-up and the cached kernels, or their
    compilation on the first run after an install) with a search on a tiny grid, so that a
    caller can time it apart from its searches."""
    tiny = np.zeros((3, 3), dtype=bool)
    grid_search(tiny, (0, 0), (2, 2))
    grid_search(tiny, (0, 0), (2, 2), extra_cost=np.zeros((3, 3)))


def grid_search(
    blocked: NDArray[np.bool_],
    start: tuple[int, int],
    goal: tuple[int, int],
    *,
    resolution_m: float = 1.0,
    extra_cost: NDArray[np.float64] | None = None,
    method: str = "auto",
) -> SearchResult:
    """The shortest path from ``start`` to ``goal`` (row, col) on the graph of the module doc.

    ``blocked`` (H, W) bool; ``resolution_m`` metres per cell; ``extra_cost`` (H, W) float >= 0
    or None; ``method`` ``"auto"``, ``"jps"`` (uniform cost only) or ``"astar"``. Deterministic.
    Raises :class:`MapError` when start or goal is outside the grid or blocked,
    :class:`NoPathError` when the goal cannot be reached, :class:`ConfigError` for an unknown
    method.
    """
    if method not in _METHODS:
        raise ConfigError(
            f"unknown search method {method!r}", hint=f"use one of {', '.join(_METHODS)}"
        )
    grid = _check_grid(blocked, resolution_m)
    s = _check_cell(grid, "start", start)
    t = _check_cell(grid, "goal", goal)
    extra = _check_extra(grid, extra_cost)
    if method == "auto":
        method = "jps" if extra is None else "astar"
    if method == "jps" and extra is not None:
        raise ConfigError(
            "method 'jps' needs uniform costs (extra_cost=None)",
            hint="use method='astar' or 'auto' with an extra cost",
        )
    if s == t:
        return SearchResult(np.array([s], dtype=np.int64), 0.0, 0, 1, method)
    from slamcli.planning import _search_kernels as kernels

    box = _pad(grid)
    src, dst = box.index(s), box.index(t)
    if method == "jps":
        cells, _, expanded, reached = kernels.jps(
            box.free, _successor_masks(), box.wp, src, dst, box.r0, box.c0
        )
        # The cost from the path's moves, so it does not depend on the order of the jumps.
        diag = np.count_nonzero(np.all(np.diff(cells, axis=0) != 0, axis=1))
        cost = resolution_m * ((len(cells) - 1 - diag) + _SQRT2 * diag)
    else:
        cells, cost_cells, expanded, reached = kernels.astar(
            box.free, *_extra_arg(extra), box.wp, src, dst, box.r0, box.c0
        )
        cost = resolution_m * cost_cells
    if len(cells):
        return SearchResult(cells, float(cost), int(expanded), int(reached), method)
    n = _component_size(grid, s)
    raise NoPathError(
        f"no path from {s} to {t}: the goal is not connected to the start "
        f"({n} cells reached from the start)",
        hint="pick a goal in the same free region, or check the map's occupancy threshold",
    )


def _component_size(grid: NDArray[np.bool_], cell: tuple[int, int]) -> int:
    """Free cells connected to ``cell`` (4-connectivity, the same components as the graph)."""
    from scipy import ndimage

    labels, _ = ndimage.label(~grid)
    return int(np.count_nonzero(labels == labels[cell]))


def grid_distances(
    blocked: NDArray[np.bool_],
    goal: tuple[int, int],
    *,
    resolution_m: float = 1.0,
    extra_cost: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """(H, W) float64: the cost (m) of the cheapest path from each cell TO ``goal`` (row, col).

    Same graph as :func:`grid_search` (see the module doc): with ``extra_cost`` a path pays
    ``1 + extra_cost`` of every cell it enters, the goal included, so ``out[c]`` equals
    ``grid_search(blocked, c, goal, ...).cost_m``. ``np.inf`` on blocked cells and on cells not
    connected to the goal; 0 at the goal. Raises :class:`MapError` when the goal is outside
    the grid or blocked, or ``extra_cost`` is malformed.
    """
    grid = _check_grid(blocked, resolution_m)
    t = _check_cell(grid, "goal", goal)
    extra = _check_extra(grid, extra_cost)
    from slamcli.planning import _search_kernels as kernels

    box = _pad(grid)
    dist = kernels.dijkstra_to(box.free, *_extra_arg(extra), box.wp, box.index(t), box.r0, box.c0)
    hp, wp = box.shape
    out = np.full(grid.shape, np.inf)
    inner = dist.reshape(hp, wp)[1:-1, 1:-1]
    np.multiply(inner, resolution_m, out=out[box.r0 : box.r0 + hp - 2, box.c0 : box.c0 + wp - 2])
    return out


def grid_graph(
    blocked: NDArray[np.bool_],
    resolution_m: float = 1.0,
    extra_cost: NDArray[np.float64] | None = None,
) -> csr_matrix:
    """The search graph as an (H*W, H*W) sparse matrix; node ``r * W + c``, weights in metres.

    Blocked cells are nodes without edges. Meant for independent checks with
    :func:`scipy.sparse.csgraph.dijkstra`.
    """
    from scipy.sparse import csr_matrix

    grid = np.asarray(blocked).astype(bool, copy=False)
    h, w = grid.shape
    free = np.zeros((h + 2, w + 2), dtype=bool)
    free[1:-1, 1:-1] = ~grid

    def nb(k: int) -> NDArray[np.bool_]:
        dr, dc = _DIRS[k]
        return free[1 + dr : h + 1 + dr, 1 + dc : w + 1 + dc].ravel()

    # Directions in order of node offset, so each row's column indices come out sorted.
    order = sorted(range(8), key=lambda k: _DIRS[k][0] * w + _DIRS[k][1])
    valid = np.empty((h * w, 8), dtype=bool)
    centre = ~grid.ravel()
    for j, k in enumerate(order):
        ok = centre & nb(k)
        if k % 2:
            ok &= nb((k - 1) % 8) | nb((k + 1) % 8)
        valid[:, j] = ok
    idx_type = np.int32 if h * w < 2**31 - w - 2 else np.int64
    indptr = np.zeros(h * w + 1, dtype=idx_type)
    np.cumsum(valid.sum(axis=1, dtype=idx_type), out=indptr[1:])
    edge = np.flatnonzero(valid)
    del valid
    which = (edge & 7).astype(np.uint8)
    node = edge >> 3
    offsets = np.array([_DIRS[k][0] * w + _DIRS[k][1] for k in order])
    indices = (node + offsets[which]).astype(idx_type)
    del edge, node
    lengths = resolution_m * np.array([_SQRT2 if k % 2 else 1.0 for k in order])
    data = lengths[which]
    if extra_cost is not None:
        data *= 1.0 + np.asarray(extra_cost, dtype=np.float64).ravel()[indices]
    return csr_matrix((data, indices, indptr), shape=(h * w, h * w))
