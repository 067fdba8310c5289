"""Hybrid-A*: kinematically feasible paths for a car-like robot on an occupancy grid.

The search (Dolgov et al. 2010, and Nav2's Smac Hybrid-A*) runs in the map's grid frame (cells;
headings relative to the grid's u axis), over continuous poses ``(u, v, yaw)``:

- **Lattice.** A node is expanded by driving a fixed arc length ``step`` with each of
  ``n_steer`` curvatures evenly spread over ``[-1/R, 1/R]``, forwards and (when reversing is
  allowed) backwards. Poses are kept continuous; a bin of ``bin`` cells by ``bin`` cells by
  ``2 pi / n_headings`` decides which poses count as the same state (the cheaper one is kept).
- **Collisions.** Every primitive is checked with the exact footprint test of
  :mod:`slamcli.planning.footprint` at poses spaced so that no point of the footprint moves more
  than half a cell between two checks.
- **Cost.** Arc length, times ``reverse_weight`` when reversing, plus ``switch_penalty`` per gear
  change.
- **Heuristic.** The larger of the exact 8-connected grid distance to the goal around the
  obstacles (holonomic, :func:`slamcli.planning.search.grid_distances` on the cells the
  footprint's inscribed circle cannot enter) and the Reeds-Shepp (or, forward only, Dubins)
  length to the goal ignoring obstacles.
- **Analytic expansion.** From expanded nodes (every node near the goal, more rarely far from
  it) the shortest Reeds-Shepp/Dubins curve to the goal is tried; the first collision-free one
  that reverses at most :data:`TAIL_REVERSE_RADII` turn radii and makes no shuffle (a run of
  one gear shorter than half a step between two gear changes) ends the search, so the goal pose
  is reached exactly.

:func:`shortcut_path` then replaces runs of primitives by shorter analytic curves when these are
collision-free and keep at least the clearance the search path had (up to ``margin``): every
piece stays made of arcs of radius R and straight lines, so the curvature never exceeds 1/R.
"""

from __future__ import annotations

import heapq
import math
import threading
import time
from dataclasses import dataclass

import numba
import numpy as np
from numba import types
from numba.typed import Dict
from numpy.typing import NDArray

from slamcli.planning.curves import dubins_length, dubins_segments, rs_length, rs_segments
from slamcli.planning.footprint import FootprintChecker, pose_free_uv

FootprintTest = tuple[
    NDArray[np.uint8],
    NDArray[np.float64],
    NDArray[np.float64],
    float,
    float,
    NDArray[np.float64],
]
"""What the kernels need of a footprint test (:func:`footprint_test`)."""

__all__ = [
    "LatticeResult",
    "lattice_search",
    "sample_pieces",
    "segment_curvatures",
    "shortcut_path",
]

SEARCHING, FOUND, EXHAUSTED, LIMIT, TIMEOUT = 0, 1, 2, 3, 4
"""Outcomes of :func:`_search_kernel`."""

TAIL_REVERSE_RADII = 3.0
"""An analytic curve to the goal may reverse at most this many turn radii in all."""

_S, _L, _R = 0, 1, -1
"""Segment kinds of :mod:`slamcli.planning.curves`: the sign of the curvature."""


@dataclass(frozen=True)
class LatticeResult:
    """What :func:`lattice_search` found, in grid coordinates (cells, radians).

    Attributes:
        status: FOUND, EXHAUSTED (every reachable state expanded), LIMIT (expansion cap hit)
            or TIMEOUT (the deadline passed).
        nodes: (K, 3) poses of the lattice path from the start, the last one where the
            analytic curve to the goal begins.
        curvature: (K,) curvature (1/cells) of the primitive that reached each node (0 for the
            start).
        direction: (K,) +1/-1 gear of the primitive that reached each node (0 for the start).
        tail_kinds, tail_lengths: the analytic curve from the last node to the goal (segment
            kinds :data:`_S`/:data:`_L`/:data:`_R`, signed lengths in cells).
        expanded: nodes expanded.
    """

    status: int
    nodes: NDArray[np.float64]
    curvature: NDArray[np.float64]
    direction: NDArray[np.int8]
    tail_kinds: NDArray[np.int64]
    tail_lengths: NDArray[np.float64]
    expanded: int


@numba.njit(cache=True, nogil=True)
def _advance(x: float, y: float, t: float, kappa: float, ds: float) -> tuple[float, float, float]:
    """The pose after driving ``ds`` (signed; < 0 backwards) at constant curvature ``kappa``."""
    if abs(kappa) < 1e-12:
        return x + ds * math.cos(t), y + ds * math.sin(t), t
    t1 = t + kappa * ds
    return (
        x + (math.sin(t1) - math.sin(t)) / kappa,
        y - (math.cos(t1) - math.cos(t)) / kappa,
        t1,
    )


@numba.njit(cache=True, nogil=True)
def _pose_free(fp: FootprintTest, u: float, v: float, t: float) -> bool:
    """The exact footprint test at a grid pose, after a quick accept: every covering circle's
    centre lies in a cell farther than its radius from any blocked cell (or the map's edge)."""
    blocked, dist, verts, r_in, r_out, circles = fp
    c, s = math.cos(t), math.sin(t)
    h, w = dist.shape
    for k in range(circles.shape[0]):
        cu = u + c * circles[k, 0] - s * circles[k, 1]
        cv = v + s * circles[k, 0] + c * circles[k, 1]
        if cu < 0.0 or cv < 0.0 or cu >= w or cv >= h or dist[int(cv), int(cu)] <= circles[k, 2]:
            return pose_free_uv(blocked, dist, u, v, t, verts, r_in, r_out)
    return True


@numba.njit(cache=True, nogil=True)
def _piece_free(
    fp: FootprintTest,
    x: float,
    y: float,
    t: float,
    kappa: float,
    ds: float,
    spacing: float,
) -> bool:
    """Whether the footprint is free at every check pose of one constant-curvature piece
    (its end included, its start not): poses are spaced so that no footprint point moves more
    than ``spacing`` cells between two of them."""
    dist, r_out = fp[1], fp[4]
    h, w = dist.shape
    sweep = abs(ds) * (1.0 + r_out * abs(kappa))
    n = max(1, math.ceil(sweep / spacing))
    arc = abs(ds) / n
    k = 1
    while k <= n:
        px, py, pt = _advance(x, y, t, kappa, ds * k / n)
        room = dist[int(py), int(px)] - r_out if 0.0 <= px < w and 0.0 <= py < h else -1.0
        if room > 0.0:
            # Every footprint within arc length s of here lies within r_out + s of this
            # reference point, so the next poses closer than ``room`` along the piece are free.
            k += math.ceil(room / arc) if arc > 0.0 else n
            continue
        if not _pose_free(fp, px, py, pt):
            return False
        k += 1
    return True


@numba.njit(cache=True, nogil=True)
def _curve_free(
    fp: FootprintTest,
    x: float,
    y: float,
    t: float,
    kinds: NDArray[np.int8],
    lengths: NDArray[np.float64],
    radius: float,
    spacing: float,
) -> bool:
    """Whether the footprint stays free along an analytic curve (segment kinds and signed
    lengths as :func:`slamcli.planning.curves.rs_segments` gives them)."""
    for i in range(kinds.shape[0]):
        kappa = kinds[i] / radius
        if lengths[i] == 0.0:
            continue
        if not _piece_free(fp, x, y, t, kappa, lengths[i], spacing):
            return False
        x, y, t = _advance(x, y, t, kappa, lengths[i])
    return True


@numba.njit(cache=True, nogil=True)
def _gear_runs(lengths: NDArray[np.float64], min_piece: float) -> tuple[int, int, int, bool]:
    """(first gear, last gear, gear changes, no short run) of signed segment lengths: a run
    of one gear between two gear changes shorter than ``min_piece`` is a short run (a
    needless shuffle); the first and last runs may be short."""
    first = 0
    last = 0
    switches = 0
    run = 0.0
    ok = True
    for i in range(lengths.shape[0]):
        if lengths[i] == 0.0:
            continue
        g = 1 if lengths[i] > 0 else -1
        if first == 0:
            first = g
        elif g != last:
            if switches > 0 and run < min_piece:
                ok = False
            switches += 1
            run = 0.0
        last = g
        run += abs(lengths[i])
    return first, last, switches, ok


@numba.njit(cache=True, nogil=True)
def _bin_key(x: float, y: float, t: float, bin_size: float, nx: int, n_headings: int) -> int:
    """The lattice bin of a pose: ``bin_size`` cells square, ``2 pi / n_headings`` wide."""
    heading = math.floor((t % (2.0 * math.pi)) / (2.0 * math.pi / n_headings)) % n_headings
    return (math.floor(y / bin_size) * nx + math.floor(x / bin_size)) * n_headings + heading


@numba.njit(cache=True, nogil=True)
def _segments(
    x0: float, y0: float, t0: float, x1: float, y1: float, t1: float, radius: float, reverse: bool
) -> tuple[NDArray[np.int8], NDArray[np.float64]]:
    """The shortest Reeds-Shepp (or, forward only, Dubins) curve's segments."""
    if reverse:
        return rs_segments(x0, y0, t0, x1, y1, t1, radius)
    return dubins_segments(x0, y0, t0, x1, y1, t1, radius)


@numba.njit(cache=True, nogil=True)
def _wrap(t: float) -> float:
    return (t + math.pi) % (2.0 * math.pi) - math.pi


@numba.njit(cache=True, nogil=True)
def _search_kernel(
    fp: FootprintTest,
    holo: NDArray[np.float64],
    cost: NDArray[np.float64],
    costed: bool,
    start: NDArray[np.float64],
    goal: NDArray[np.float64],
    radius: float,
    step: float,
    n_steer: int,
    reverse: bool,
    bin_size: float,
    n_headings: int,
    reverse_weight: float,
    switch_penalty: float,
    max_expanded: int,
    spacing: float,
    stop: NDArray[np.uint8],
    greed: float,
):
    h, w = holo.shape
    cap = 1 << 16
    xs = np.empty(cap)
    ys = np.empty(cap)
    ts = np.empty(cap)
    gs = np.empty(cap)
    parent = np.empty(cap, dtype=np.int64)
    kap = np.empty(cap)
    gear = np.empty(cap, dtype=np.int8)
    best = Dict.empty(key_type=types.int64, value_type=types.float64)
    closed = Dict.empty(key_type=types.int64, value_type=types.boolean)
    nx = int(w / bin_size) + 2

    curvatures = np.empty(n_steer)
    for i in range(n_steer):
        curvatures[i] = (-1.0 + 2.0 * i / (n_steer - 1)) / radius if n_steer > 1 else 0.0
    gears = np.array([1, -1], dtype=np.int8) if reverse else np.array([1], dtype=np.int8)
    kinds = np.zeros(0, dtype=np.int8)
    lengths = np.zeros(0)

    xs[0], ys[0], ts[0], gs[0] = start[0], start[1], start[2], 0.0
    parent[0], kap[0], gear[0] = -1, 0.0, 0
    n_nodes = 1
    heap = [(0.0, 0.0, 0)]
    expanded = 0
    gx, gy, gt = goal[0], goal[1], goal[2]
    while heap:
        _, _, i = heapq.heappop(heap)
        x, y, t = xs[i], ys[i], ts[i]
        key = _bin_key(x, y, t, bin_size, nx, n_headings)
        if key in closed:
            continue
        closed[key] = True
        expanded += 1
        if expanded > max_expanded:
            return LIMIT, i, n_nodes, xs, ys, ts, parent, kap, gear, kinds, lengths, expanded
        if expanded % 1024 == 0 and stop[0]:
            return TIMEOUT, i, n_nodes, xs, ys, ts, parent, kap, gear, kinds, lengths, expanded
        r = min(max(int(y), 0), h - 1)
        c = min(max(int(x), 0), w - 1)
        hol = holo[r, c]
        # Analytic expansion: always near the goal, every few nodes further away. With a
        # clearance cost, only near the goal: the curve would cut across the cost.
        if costed:
            shoot = math.hypot(x - goal[0], y - goal[1]) <= 2.0 * radius
        else:
            every = max(1, int(hol / (2.0 * radius)))
            shoot = expanded % every == 0 or hol <= 2.0 * radius
        if shoot:
            kinds, lengths = _segments(x, y, t, gx, gy, gt, radius, reverse)
            first, _, _, tidy = _gear_runs(lengths, 0.5 * step)
            # The piece into this node and the curve's first run must not make a shuffle.
            if first != gear[i] and gear[i] != 0 and lengths.shape[0] > 0:
                tidy = tidy and abs(lengths[0]) >= 0.5 * step
            # Nor may the curve back up further than a manoeuvre needs (the lattice, which
            # pays for reversing, takes the long ways).
            backwards = 0.0
            for k in range(lengths.shape[0]):
                backwards -= min(lengths[k], 0.0)
            tidy = tidy and backwards <= TAIL_REVERSE_RADII * radius
            if tidy and _curve_free(fp, x, y, t, kinds, lengths, radius, spacing):
                return (
                    FOUND,
                    i,
                    n_nodes,
                    xs,
                    ys,
                    ts,
                    parent,
                    kap,
                    gear,
                    kinds,
                    lengths,
                    expanded,
                )
        for gi in range(gears.shape[0]):
            d = gears[gi]
            for si in range(n_steer):
                kappa = curvatures[si]
                ds = step * d
                if not _piece_free(fp, x, y, t, kappa, ds, spacing):
                    continue
                nx_, ny_, nt_ = _advance(x, y, t, kappa, ds)
                nt_ = _wrap(nt_)
                rr = int(ny_)
                cc = int(nx_)
                if rr < 0 or cc < 0 or rr >= h or cc >= w:
                    continue
                hol_n = holo[rr, cc]
                if not math.isfinite(hol_n):
                    continue
                nkey = _bin_key(nx_, ny_, nt_, bin_size, nx, n_headings)
                if nkey in closed:
                    continue
                g = gs[i] + step * (reverse_weight if d < 0 else 1.0)
                if costed:
                    g += step * (reverse_weight if d < 0 else 1.0) * cost[rr, cc]
                if gear[i] != 0 and gear[i] != d:
                    g += switch_penalty
                if nkey in best and best[nkey] <= g:
                    continue
                best[nkey] = g
                if n_nodes == xs.shape[0]:
                    cap = 2 * xs.shape[0]
                    xs = _grow(xs, cap)
                    ys = _grow(ys, cap)
                    ts = _grow(ts, cap)
                    gs = _grow(gs, cap)
                    kap = _grow(kap, cap)
                    parent = _grow_i(parent, cap)
                    gear = _grow_b(gear, cap)
                j = n_nodes
                n_nodes += 1
                xs[j], ys[j], ts[j], gs[j] = nx_, ny_, nt_, g
                parent[j], kap[j], gear[j] = i, kappa, d
                if reverse:
                    nonholo = rs_length(nx_, ny_, nt_, gx, gy, gt, radius)
                else:
                    nonholo = dubins_length(nx_, ny_, nt_, gx, gy, gt, radius)
                f = g + greed * max(hol_n, nonholo)
                heapq.heappush(heap, (f, -g, j))
    return EXHAUSTED, -1, n_nodes, xs, ys, ts, parent, kap, gear, kinds, lengths, expanded


@numba.njit(cache=True)
def _grow(a: NDArray[np.float64], cap: int) -> NDArray[np.float64]:
    out = np.empty(cap)
    out[: a.shape[0]] = a
    return out


@numba.njit(cache=True)
def _grow_i(a: NDArray[np.int64], cap: int) -> NDArray[np.int64]:
    out = np.empty(cap, dtype=np.int64)
    out[: a.shape[0]] = a
    return out


@numba.njit(cache=True)
def _grow_b(a: NDArray[np.int8], cap: int) -> NDArray[np.int8]:
    out = np.empty(cap, dtype=np.int8)
    out[: a.shape[0]] = a
    return out


def lattice_search(
    checker: FootprintChecker,
    holonomic: NDArray[np.float64],
    start: tuple[float, float, float],
    goal: tuple[float, float, float],
    *,
    cost: NDArray[np.float64] | None = None,
    radius: float,
    step: float,
    bin_size: float,
    n_steer: int = 5,
    n_headings: int = 72,
    reverse: bool = True,
    reverse_weight: float = 1.0,
    switch_penalty: float = 0.0,
    max_expanded: int = 2_000_000,
    spacing: float = 0.5,
    deadline: float = math.inf,
    greed: float = 1.0,
) -> LatticeResult:
    """Run the search of the module doc; all lengths in cells, poses ``(u, v, yaw)``.

    ``checker`` tests the footprint; ``holonomic`` (H, W) is the grid distance of every cell to
    the goal (inf where unreachable), with ``cost`` included when one is given; ``cost`` (H, W)
    is the clearance cost: a primitive ending in cell c costs ``(1 + cost[c])`` per cell of
    arc length. The search stops with TIMEOUT once ``time.perf_counter()`` passes ``deadline``
    (a timer thread raises a flag that the search, which runs without the GIL, reads every
    1024 expansions). ``greed`` > 1 weighs the heuristic by it (weighted A*):
    a path is found after far fewer expansions, at most ``greed`` times as costly.
    """
    costed = cost is not None
    stop = np.zeros(1, dtype=np.uint8)
    timer = None
    if math.isfinite(deadline):
        timer = threading.Timer(max(0.0, deadline - time.perf_counter()), stop.fill, (1,))
        timer.daemon = True
        timer.start()
    try:
        out = _search_kernel(
            footprint_test(checker),
            np.ascontiguousarray(holonomic, dtype=np.float64),
            np.ascontiguousarray(cost if costed else np.zeros((1, 1)), dtype=np.float64),
            costed,
            np.asarray(start, dtype=np.float64),
            np.asarray(goal, dtype=np.float64),
            float(radius),
            float(step),
            int(n_steer),
            bool(reverse),
            float(bin_size),
            int(n_headings),
            float(reverse_weight),
            float(switch_penalty),
            int(max_expanded),
            float(spacing),
            stop,
            float(greed),
        )
    finally:
        if timer is not None:
            timer.cancel()
    status, last, _, xs, ys, ts, parent, kap, gear, kinds, lengths, expanded = out
    chain: list[int] = []
    i = int(last)
    while i >= 0 and status == FOUND:
        chain.append(i)
        i = int(parent[i])
    chain.reverse()
    idx = np.asarray(chain, dtype=np.int64)
    return LatticeResult(
        status=int(status),
        nodes=np.stack((xs[idx], ys[idx], ts[idx]), axis=1),
        curvature=kap[idx].copy(),
        direction=gear[idx].astype(np.int8),
        tail_kinds=np.asarray(kinds, dtype=np.int64) if status == FOUND else np.zeros(0, np.int64),
        tail_lengths=np.asarray(lengths, dtype=np.float64) if status == FOUND else np.zeros(0),
        expanded=int(expanded),
    )


def segment_curvatures(kinds: NDArray[np.int64] | list[int], radius: float) -> NDArray[np.float64]:
    """Curvature (1/cells) of each analytic segment kind for turn radius ``radius`` (cells)."""
    return np.asarray(kinds, dtype=np.float64) / radius


def sample_pieces(
    start: tuple[float, float, float] | NDArray[np.float64],
    curvatures: NDArray[np.float64] | list[float],
    lengths: NDArray[np.float64] | list[float],
    step: float,
) -> tuple[NDArray[np.float64], NDArray[np.int8], NDArray[np.float64]]:
    """Poses along constant-curvature pieces from ``start`` (start excluded), at most ``step``
    apart and exactly at each piece's end, with the gear (+1/-1) and curvature of the piece
    each pose ends. ``lengths`` are signed (< 0 backwards)."""
    x, y, t = (float(v) for v in start)
    poses: list[tuple[float, float, float]] = []
    gears: list[int] = []
    curv: list[float] = []
    for kappa, length in zip(curvatures, lengths, strict=True):
        kappa, length = float(kappa), float(length)
        if length == 0.0:
            continue
        n = max(1, math.ceil(abs(length) / step))
        for k in range(1, n + 1):
            poses.append(_advance(x, y, t, kappa, length * k / n))
            gears.append(1 if length > 0 else -1)
            curv.append(kappa)
        x, y, t = poses[-1]
    return (
        np.asarray(poses, dtype=np.float64).reshape(-1, 3),
        np.asarray(gears, dtype=np.int8),
        np.asarray(curv, dtype=np.float64),
    )


@numba.njit(cache=True, nogil=True)
def _pieces_cost(
    cost: NDArray[np.float64],
    costed: bool,
    x: float,
    y: float,
    t: float,
    curvatures: NDArray[np.float64],
    lengths: NDArray[np.float64],
    reverse_weight: float,
    spacing: float,
) -> float:
    """The search's cost of constant-curvature pieces from ``(x, y, t)``: each stretch of at
    most ``spacing`` cells costs its length times ``1 + cost`` of the cell at its end, times
    ``reverse_weight`` when backwards (cells outside the map count as 1; without ``costed``
    every cell counts 0: the reverse-weighted length)."""
    h, w = cost.shape
    total = 0.0
    for i in range(lengths.shape[0]):
        length = lengths[i]
        if length == 0.0:
            continue
        n = max(1, math.ceil(abs(length) / spacing))
        weight = reverse_weight if length < 0.0 else 1.0
        for k in range(1, n + 1):
            px, py, _ = _advance(x, y, t, curvatures[i], length * k / n)
            c = 0.0
            if costed:
                c = cost[int(py), int(px)] if 0.0 <= px < w and 0.0 <= py < h else 1.0
            total += abs(length) / n * weight * (1.0 + c)
        x, y, t = _advance(x, y, t, curvatures[i], length)
    return total


@numba.njit(cache=True)
def _shortcut_kernel(
    fp: FootprintTest,
    fp_margin: FootprintTest,
    cost: NDArray[np.float64],
    costed: bool,
    reverse_weight: float,
    nodes: NDArray[np.float64],
    piece_len: NDArray[np.float64],
    piece_clear: NDArray[np.bool_],
    piece_gears: NDArray[np.int64],
    radius: float,
    reverse: bool,
    window: int,
    spacing: float,
    min_piece: float,
) -> NDArray[np.int64]:
    """Greedy shortcuts between lattice nodes: from each kept node, the farthest node within
    ``window`` whose analytic curve is cheaper than the path between them by
    :func:`_pieces_cost` (shorter, when neither a cost nor a reverse weight applies), changes
    gear no more often, makes no short shuffle, and is free (with the margin footprint where the
    replaced pieces were all free with it)."""
    k = nodes.shape[0]
    keep = np.zeros(k, dtype=np.int64)
    n_keep = 0
    i = 0
    keep[n_keep] = 0
    n_keep += 1
    cum = np.zeros(k)
    for a in range(1, k):
        cum[a] = cum[a - 1] + piece_len[a]
    while i < k - 1:
        nxt = i + 1
        for j in range(min(k - 1, i + window), i + 1, -1):
            kinds, lengths = _segments(
                nodes[i, 0],
                nodes[i, 1],
                nodes[i, 2],
                nodes[j, 0],
                nodes[j, 1],
                nodes[j, 2],
                radius,
                reverse,
            )
            if costed or reverse_weight != 1.0:
                kappas = np.empty(kinds.shape[0])
                for s in range(kinds.shape[0]):
                    kappas[s] = kinds[s] / radius
                total = _pieces_cost(
                    cost,
                    costed,
                    nodes[i, 0],
                    nodes[i, 1],
                    nodes[i, 2],
                    kappas,
                    lengths,
                    reverse_weight,
                    spacing,
                )
            else:
                total = 0.0
                for s in range(lengths.shape[0]):
                    total += abs(lengths[s])
            if total >= cum[j] - cum[i] - 1e-9:
                continue
            first, last, switches, tidy = _gear_runs(lengths, min_piece)
            if not tidy:
                continue
            before = piece_gears[i, 1]
            after = piece_gears[j + 1, 0] if j + 1 < k else 0
            new = switches + (before != 0 and first != before) + (after != 0 and last != after)
            old = (before != 0 and piece_gears[i + 1, 0] != before) + (
                after != 0 and piece_gears[j, 1] != after
            )
            for a in range(i + 1, j + 1):
                old += piece_gears[a, 2]
                if a < j and piece_gears[a, 1] != piece_gears[a + 1, 0]:
                    old += 1
            if new > old:
                continue
            all_clear = True
            for a in range(i + 1, j + 1):
                if not piece_clear[a]:
                    all_clear = False
                    break
            test = fp_margin if all_clear else fp
            ok = _curve_free(
                test, nodes[i, 0], nodes[i, 1], nodes[i, 2], kinds, lengths, radius, spacing
            )
            if ok:
                nxt = j
                break
        keep[n_keep] = nxt
        n_keep += 1
        i = nxt
    return keep[:n_keep]


def shortcut_path(
    checker: FootprintChecker,
    margin: FootprintChecker,
    nodes: NDArray[np.float64],
    piece_len: NDArray[np.float64],
    piece_clear: NDArray[np.bool_],
    piece_gears: NDArray[np.int64],
    *,
    radius: float,
    reverse: bool,
    min_piece: float,
    cost: NDArray[np.float64] | None = None,
    reverse_weight: float = 1.0,
    window: int = 60,
    spacing: float = 0.5,
) -> NDArray[np.int64]:
    """Indices of the nodes kept by the greedy analytic shortcuts (first and last included);
    consecutive kept nodes ``i < j`` with ``j > i + 1`` are joined by the shortest analytic
    curve, the others by their original piece. ``piece_len[a]``/``piece_clear[a]`` describe the
    piece that reaches node ``a`` (cells; free with the ``margin`` checker's larger footprint,
    which a shortcut replacing only such pieces must then be free with too); ``piece_gears[a]``
    its first gear, last gear and gear changes (row 0 zeros); ``min_piece`` the shortest run
    of one gear a shortcut may put between two gear changes (cells). With ``cost`` (the
    search's clearance cost) or a ``reverse_weight`` other than 1, ``piece_len`` holds each
    piece's cost (:func:`pieces_cost`) and a shortcut must be cheaper, not only shorter: a
    turn made to drive forwards is not undone by a shorter curve that backs up."""
    costed = cost is not None
    return np.asarray(
        _shortcut_kernel(
            footprint_test(checker),
            footprint_test(margin),
            np.ascontiguousarray(cost if costed else np.zeros((1, 1)), dtype=np.float64),
            costed,
            float(reverse_weight),
            np.ascontiguousarray(nodes, dtype=np.float64),
            np.ascontiguousarray(piece_len, dtype=np.float64),
            np.ascontiguousarray(piece_clear, dtype=np.bool_),
            np.ascontiguousarray(piece_gears, dtype=np.int64),
            float(radius),
            bool(reverse),
            int(window),
            float(spacing),
            float(min_piece),
        )
    )


def pieces_cost(
    cost: NDArray[np.float64] | None,
    start: tuple[float, float, float] | NDArray[np.float64],
    curvatures: NDArray[np.float64],
    lengths: NDArray[np.float64],
    reverse_weight: float,
    spacing: float = 0.5,
) -> float:
    """The search's cost (cells) of constant-curvature pieces from ``start`` (grid pose): arc
    length times ``1 + cost`` along it (no cost: 0), times ``reverse_weight`` when backwards."""
    x, y, t = (float(v) for v in start)
    return float(
        _pieces_cost(
            np.ascontiguousarray(np.zeros((1, 1)) if cost is None else cost, dtype=np.float64),
            cost is not None,
            x,
            y,
            t,
            np.ascontiguousarray(curvatures, dtype=np.float64),
            np.ascontiguousarray(lengths, dtype=np.float64),
            float(reverse_weight),
            float(spacing),
        )
    )


def covering_circles(verts: NDArray[np.float64]) -> NDArray[np.float64]:
    """(M, 3) circles ``x, y, r`` (body frame, the vertices' units) whose union covers the
    polygon: its bounding box cut along the longer side into near-square pieces, each covered
    by the circle through its corners."""
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    size = hi - lo
    long_axis = 0 if size[0] >= size[1] else 1
    n = max(1, math.ceil(size[long_axis] / max(size[1 - long_axis], 1e-12)))
    piece = size.copy()
    piece[long_axis] /= n
    out = np.empty((n, 3))
    for k in range(n):
        centre = lo + piece / 2
        centre[long_axis] += k * piece[long_axis]
        out[k] = (centre[0], centre[1], 0.5 * math.hypot(piece[0], piece[1]))
    return out


def footprint_test(checker: FootprintChecker) -> FootprintTest:
    """The compiled kernels' view of a checker: blocked cells, distance field, vertices,
    inradius, circumradius (cells) and covering circles."""
    return (
        checker.blocked_u8,
        np.ascontiguousarray(checker.dist, dtype=np.float64),
        np.ascontiguousarray(checker.verts_cells, dtype=np.float64),
        float(checker.r_in),
        float(checker.r_out),
        covering_circles(checker.verts_cells),
    )
