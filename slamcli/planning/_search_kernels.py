"""Compiled kernels of :mod:`slamcli.planning.search`: A*, jump point search and Dijkstra.

Every kernel works on a padded grid flattened row-major: ``free`` (Hp * Wp,) uint8, 1 for a
free cell, with a border of blocked cells all around, so a neighbour index never leaves the
array. Moves are numbered clockwise from north (0 N, 1 NE, 2 E, ... 7 NW; even = straight, odd =
diagonal); a diagonal is legal unless both orthogonal cells it passes between are blocked.
Costs are in cells (a straight move 1, a diagonal sqrt 2, times the factor of the cell entered);
the caller scales them to metres.

The open list is a binary heap in a flat float64 array of (f, g, cell) triples, ordered by f,
then larger g, then smaller cell index, so every result is deterministic. ``pos[cell]`` is the
slot of a cell's entry: a cheaper path to an open cell moves that entry up (decrease-key)
rather than adding a second one, which halves the heap work of A* on building maps.

This module imports numba: import it only where a search runs.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_SQRT2 = math.sqrt(2.0)
_OCT = _SQRT2 - 2.0
_DR = np.array([-1, -1, 0, 1, 1, 1, 0, -1], dtype=np.int64)
_DC = np.array([0, 1, 1, 1, 0, -1, -1, -1], dtype=np.int64)
_LEN = np.array([1.0, _SQRT2, 1.0, _SQRT2, 1.0, _SQRT2, 1.0, _SQRT2])

_NEW, _OPEN, _CLOSED = 0, 8, 16


@numba.njit(cache=True, nogil=True)
def _offsets(wp: int) -> np.ndarray:
    """Flat index step of each move on a grid of row length ``wp``."""
    return _DR * wp + _DC


@numba.njit(cache=True, nogil=True)
def _octile(dr: int, dc: int) -> float:
    """Octile distance (cells) of a (drow, dcol) offset."""
    ar = dr if dr >= 0 else -dr
    ac = dc if dc >= 0 else -dc
    return ar + ac + _OCT * (ar if ar < ac else ac)


@numba.njit(cache=True, nogil=True)
def _sift_up(heap: np.ndarray, pos: np.ndarray, j: int, f: float, g: float, i: int) -> None:
    """Moves entry (f, g, i) up from slot j of the heap to its place; keeps ``pos`` current."""
    while j > 0:
        p = (j - 1) >> 1
        pf = heap[3 * p]
        pg = heap[3 * p + 1]
        if f < pf or (f == pf and (g > pg or (g == pg and i < heap[3 * p + 2]))):
            heap[3 * j] = pf
            heap[3 * j + 1] = pg
            heap[3 * j + 2] = heap[3 * p + 2]
            pos[int(heap[3 * p + 2])] = j
            j = p
        else:
            break
    heap[3 * j] = f
    heap[3 * j + 1] = g
    heap[3 * j + 2] = i
    pos[i] = j


@numba.njit(cache=True, nogil=True)
def _pop(heap: np.ndarray, pos: np.ndarray, n: int) -> int:
    """Removes the first of the ``n`` heap entries; returns its cell."""
    top = int(heap[2])
    n -= 1
    if n == 0:
        return top
    f = heap[3 * n]
    g = heap[3 * n + 1]
    i = heap[3 * n + 2]
    j = 0
    while True:
        c = 2 * j + 1
        if c >= n:
            break
        if c + 1 < n:
            cf = heap[3 * c]
            rf = heap[3 * c + 3]
            cg = heap[3 * c + 1]
            rg = heap[3 * c + 4]
            if rf < cf or (
                rf == cf and (rg > cg or (rg == cg and heap[3 * c + 5] < heap[3 * c + 2]))
            ):
                c += 1
        cf = heap[3 * c]
        cg = heap[3 * c + 1]
        if cf < f or (cf == f and (cg > g or (cg == g and heap[3 * c + 2] < i))):
            heap[3 * j] = cf
            heap[3 * j + 1] = cg
            heap[3 * j + 2] = heap[3 * c + 2]
            pos[int(heap[3 * c + 2])] = j
            j = c
        else:
            break
    heap[3 * j] = f
    heap[3 * j + 1] = g
    heap[3 * j + 2] = i
    pos[int(i)] = j
    return top


@numba.njit(cache=True, nogil=True)
def _grow(heap: np.ndarray, n: int) -> np.ndarray:
    """A copy of the ``n``-entry heap with twice the room."""
    grown = np.empty(2 * heap.size + 24)
    grown[: 3 * n] = heap[: 3 * n]
    return grown


@numba.njit(cache=True, nogil=True)
def _cells(path: np.ndarray, wp: int, r0: int, c0: int) -> np.ndarray:
    """(K, 2) int64 (row, col) of padded flat indices, shifted by (r0 - 1, c0 - 1)."""
    out = np.empty((path.size, 2), np.int64)
    for k in range(path.size):
        r = path[k] // wp
        out[k, 0] = r - 1 + r0
        out[k, 1] = path[k] - r * wp - 1 + c0
    return out


@numba.njit(cache=True, nogil=True)
def astar(
    free: np.ndarray,
    extra: np.ndarray,
    weighted: bool,
    wp: int,
    src: int,
    dst: int,
    r0: int,
    c0: int,
) -> tuple[np.ndarray, float, int, int]:
    """A* with the octile heuristic from ``src`` to ``dst`` (padded flat indices).

    ``extra`` (H, W) float64 is the extra cost of the unpadded grid, whose cell (r0, c0) is
    padded cell (1, 1); read only when ``weighted``. Returns (cells (K, 2) int64 of the unpadded
    grid, cost in cells, expanded, reached); K is 0 when ``dst`` cannot be reached.
    """
    n = free.size
    offs = _offsets(wp)
    # Per cell: the move that reached it (bits 0-2), open (bit 3), closed (bit 4).
    node = np.zeros(n, np.uint8)
    g = np.empty(n, np.float64)
    pos = np.empty(n, np.int32)
    tr = dst // wp
    tc = dst - tr * wp
    sr = src // wp
    er = r0 - 1
    ec = c0 - 1
    heap = np.empty(3 * 1024)
    _sift_up(heap, pos, 0, _octile(tr - sr, tc - (src - sr * wp)), 0.0, src)
    size = 1
    g[src] = 0.0
    node[src] = _OPEN
    expanded = 0
    reached = 1
    while size > 0:
        x = _pop(heap, pos, size)
        size -= 1
        node[x] |= _CLOSED
        expanded += 1
        if x == dst:
            break
        if 3 * (size + 8) > heap.size:
            heap = _grow(heap, size)
        gx = g[x]
        xr = x // wp
        xc = x - xr * wp
        for k in range(8):
            y = x + offs[k]
            if free[y] == 0:
                continue
            state = node[y]
            if state & _CLOSED:
                continue
            if k & 1 and free[x + offs[k - 1]] == 0 and free[x + offs[(k + 1) & 7]] == 0:
                continue
            yr = xr + _DR[k]
            yc = xc + _DC[k]
            step = _LEN[k] * (1.0 + extra[yr + er, yc + ec]) if weighted else _LEN[k]
            ng = gx + step
            if state == 0:
                reached += 1
                j = size
                size += 1
            elif ng < g[y]:
                j = pos[y]
            else:
                continue
            g[y] = ng
            node[y] = _OPEN | k
            _sift_up(heap, pos, j, ng + _octile(tr - yr, tc - yc), ng, y)
    if not node[dst] & _CLOSED:
        return np.empty((0, 2), np.int64), math.inf, expanded, reached
    count = 1
    x = dst
    while x != src:
        x -= offs[node[x] & 7]
        count += 1
    path = np.empty(count, np.int64)
    x = dst
    for k in range(count - 1, -1, -1):
        path[k] = x
        if k:
            x -= offs[node[x] & 7]
    return _cells(path, wp, r0, c0), g[dst], expanded, reached


@numba.njit(cache=True, nogil=True)
def _jump_straight(free: np.ndarray, x: int, s: int, q: int, dst: int) -> tuple[int, int]:
    """Jumps from x by straight step s (q a perpendicular step): (stop, steps) or (-1, steps).

    Stops at the goal or at a cell y with a forced neighbour (y+s free, and y+q blocked with
    y+s+q free, or the same on the -q side); returns -1 when a wall comes first.
    """
    y = x
    k = 0
    while True:
        y += s
        if free[y] == 0:
            return -1, k
        k += 1
        if y == dst:
            return y, k
        if free[y + s] and (
            (free[y + q] == 0 and free[y + s + q]) or (free[y - q] == 0 and free[y + s - q])
        ):
            return y, k


@numba.njit(cache=True, nogil=True)
def _jump_diagonal(free: np.ndarray, x: int, d: int, sa: int, sb: int, dst: int) -> tuple[int, int]:
    """Jumps from x by diagonal step d = sa + sb: (stop, steps) or (-1, steps).

    Stops at the goal, at a cell with a forced neighbour, or at a cell from which a straight
    jump along sa or sb stops; returns -1 when the diagonal is blocked first.
    """
    y = x
    k = 0
    while True:
        if free[y + d] == 0 or (free[y + sa] == 0 and free[y + sb] == 0):
            return -1, k
        y += d
        k += 1
        if y == dst:
            return y, k
        if (free[y + sa] and free[y + sa - sb] and free[y - sb] == 0) or (
            free[y + sb] and free[y + sb - sa] and free[y - sa] == 0
        ):
            return y, k
        if _jump_straight(free, y, sa, sb, dst)[0] >= 0:
            return y, k
        if _jump_straight(free, y, sb, sa, dst)[0] >= 0:
            return y, k


@numba.njit(cache=True, nogil=True)
def jps(
    free: np.ndarray, succ: np.ndarray, wp: int, src: int, dst: int, r0: int, c0: int
) -> tuple[np.ndarray, float, int, int]:
    """Jump point search from ``src`` to ``dst`` (padded flat indices), uniform cost.

    ``succ`` (9, 256) uint8: bit k set when move k is a successor of a node entered by move d
    (8 for the start) whose neighbours are free as in the 8-bit mask. Returns (cells (K, 2)
    int64 shifted by (r0, c0), cost in cells, expanded, reached jump points); K is 0 when
    ``dst`` cannot be reached.
    """
    n = free.size
    offs = _offsets(wp)
    state = np.zeros(n, np.uint8)
    g = np.empty(n, np.float64)
    came = np.empty(n, np.uint8)
    parent = np.empty(n, np.int64)
    tr = dst // wp
    tc = dst - tr * wp
    sr = src // wp
    pos = np.empty(n, np.int32)
    heap = np.empty(3 * 256)
    _sift_up(heap, pos, 0, _octile(tr - sr, tc - (src - sr * wp)), 0.0, src)
    size = 1
    g[src] = 0.0
    state[src] = _OPEN
    came[src] = 8
    parent[src] = -1
    expanded = 0
    reached = 1
    while size > 0:
        x = _pop(heap, pos, size)
        size -= 1
        state[x] = _CLOSED
        expanded += 1
        if x == dst:
            break
        if 3 * (size + 8) > heap.size:
            heap = _grow(heap, size)
        gx = g[x]
        mask = 0
        for k in range(8):
            mask |= free[x + offs[k]] << k
        moves = succ[came[x], mask]
        xr = x // wp
        xc = x - xr * wp
        for k in range(8):
            if not (moves >> k) & 1:
                continue
            if k & 1:
                y, steps = _jump_diagonal(free, x, offs[k], offs[k - 1], offs[(k + 1) & 7], dst)
            else:
                y, steps = _jump_straight(free, x, offs[k], offs[(k + 2) & 7], dst)
            if y < 0 or state[y] == _CLOSED:
                continue
            ng = gx + steps * _LEN[k]
            if state[y] == _NEW:
                state[y] = _OPEN
                reached += 1
                j = size
                size += 1
            elif ng < g[y]:
                j = pos[y]
            else:
                continue
            g[y] = ng
            came[y] = k
            parent[y] = x
            h = _octile(tr - xr - steps * _DR[k], tc - xc - steps * _DC[k])
            _sift_up(heap, pos, j, ng + h, ng, y)
    if state[dst] != _CLOSED:
        return np.empty((0, 2), np.int64), math.inf, expanded, reached
    # Jump nodes lie on straight or diagonal lines: count, then fill the cells between them.
    count = 1
    x = dst
    while x != src:
        p = parent[x]
        count += (x - p) // offs[came[x]]
        x = p
    path = np.empty(count, np.int64)
    x = dst
    j = count - 1
    path[j] = x
    while x != src:
        step = offs[came[x]]
        p = parent[x]
        y = x
        while y != p:
            y -= step
            j -= 1
            path[j] = y
        x = p
    return _cells(path, wp, r0, c0), g[dst], expanded, reached


@numba.njit(cache=True, nogil=True)
def dijkstra_to(
    free: np.ndarray, extra: np.ndarray, weighted: bool, wp: int, dst: int, r0: int, c0: int
) -> np.ndarray:
    """(Hp * Wp,) float64: cost (cells) of the cheapest path from each padded cell to ``dst``.

    ``extra`` (H, W) as in :func:`astar`. A move into cell u costs its length times
    ``1 + extra`` of u (when ``weighted``), so the search runs backwards from ``dst``: settling u
    prices every move v -> u with u's factor. Unreachable and blocked cells stay inf.
    """
    n = free.size
    offs = _offsets(wp)
    dist = np.full(n, np.inf)
    dist[dst] = 0.0
    pos = np.empty(n, np.int32)
    heap = np.empty(3 * 1024)
    _sift_up(heap, pos, 0, 0.0, 0.0, dst)
    size = 1
    while size > 0:
        u = _pop(heap, pos, size)
        size -= 1
        if 3 * (size + 8) > heap.size:
            heap = _grow(heap, size)
        du = dist[u]
        fu = 1.0
        if weighted:
            ur = u // wp
            fu += extra[ur + r0 - 1, u - ur * wp + c0 - 1]
        for k in range(8):
            v = u + offs[k]
            if free[v] == 0:
                continue
            if k & 1 and free[u + offs[k - 1]] == 0 and free[u + offs[(k + 1) & 7]] == 0:
                continue
            # Settled cells never pass this test: their cost is at most du.
            nd = du + _LEN[k] * fu
            dv = dist[v]
            if nd < dv:
                if dv == np.inf:
                    j = size
                    size += 1
                else:
                    j = pos[v]
                dist[v] = nd
                _sift_up(heap, pos, j, nd, nd, v)
    return dist
