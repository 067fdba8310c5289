"""Pairing two streams of stamps (colour and depth, odometry and observations) one to one.

Both the TUM RGB-D reader and the MCAP source pair stamps the way TUM's ``associate.py`` does;
this module holds that one rule so neither source has to import the other.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


def associate_stamps(
    first_ns: ArrayLike, second_ns: ArrayLike, max_dt_ns: int, offset_ns: int = 0
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Pair two stamp lists like TUM's ``associate.py`` in O(N log M + K log K), K candidates.

    Candidates are all ``(i, j)`` with ``|first[i] - (second[j] + offset)| < max_dt``; they are
    taken in order of increasing ``|Δt|`` (ties by first stamp, second stamp, then index),
    each index at most once.

    Args:
        first_ns: (N,) int64 nanoseconds (colour).
        second_ns: (M,) int64 nanoseconds (depth).
        max_dt_ns: strict upper bound on ``|Δt|`` in nanoseconds.
        offset_ns: added to ``second_ns`` before comparing.

    Returns:
        (P,) indices into ``first_ns`` and (P,) indices into ``second_ns``, ordered by the
        first list's stamp (then index).
    """
    a = np.asarray(first_ns, dtype=np.int64).reshape(-1)
    b = np.asarray(second_ns, dtype=np.int64).reshape(-1) + np.int64(offset_ns)
    empty = np.zeros(0, dtype=np.intp)
    if a.size == 0 or b.size == 0 or max_dt_ns <= 0:
        return empty, empty
    b_order = np.argsort(b, kind="stable")
    b_sorted = b[b_order]
    lo = np.searchsorted(b_sorted, a - max_dt_ns, side="right")
    hi = np.searchsorted(b_sorted, a + max_dt_ns, side="left")
    counts = np.maximum(hi - lo, 0)
    total = int(counts.sum())
    if total == 0:
        return empty, empty
    i = np.repeat(np.arange(a.size, dtype=np.intp), counts)
    group_start = np.repeat(np.cumsum(counts) - counts, counts)
    j = b_order[np.repeat(lo, counts) + (np.arange(total) - group_start)]
    dt = np.abs(a[i] - b[j])
    order = np.lexsort((j, i, b[j], a[i], dt))
    used_a = bytearray(a.size)
    used_b = bytearray(b.size)
    pairs: list[tuple[int, int]] = []
    # The greedy 1:1 pass is inherently sequential, but runs over the few candidates inside the
    # windows (about one or two per frame), not over all N x M pairs.
    for ii, jj in zip(i[order].tolist(), j[order].tolist(), strict=True):
        if not used_a[ii] and not used_b[jj]:
            used_a[ii] = used_b[jj] = 1
            pairs.append((ii, jj))
    out = np.asarray(pairs, dtype=np.intp)
    out = out[np.lexsort((out[:, 0], a[out[:, 0]]))]
    return out[:, 0], out[:, 1]


__all__ = ["associate_stamps"]
