"""Message times of a CARMEN log: which are usable, and what replaces the others.

See :mod:`slamcli.formats.carmen` for the rules.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slamcli.formats.carmen.layout import I64

DEFAULT_STEP_S = 0.1
"""Spacing of replaced stamps when the log has too few usable times to measure its own."""

_DEFAULT_STEP_NS = round(DEFAULT_STEP_S * 1e9)
_MIN_STEP_SAMPLES = 3


@dataclass(frozen=True)
class Clock:
    """The repaired stamps of a log's frame-giving lines.

    Attributes:
        stamps_ns: (M,) int64 in file order; never decreasing, strictly increasing among the
            laser lines and among the ODOM lines.
        replaced: (M,) bool, the lines whose own time was not used.
        step_ns: the spacing used where no usable time follows (the log's typical one).
        trusted: False when the log's clock was ignored (fewer than half the scan times
            usable) and every line was stamped ``step_ns`` after the one before.
    """

    stamps_ns: I64
    replaced: NDArray[np.bool_]
    step_ns: int
    trusted: bool


def repair_stamps(laser: NDArray[np.bool_], ipc: I64, logger: I64) -> Clock:
    """The stamps of a log's frame-giving lines, in file order.

    Scan times are judged first, among themselves; odometry times are then usable only where
    they also fit between the usable scan times around them, so a scan keeps its own time
    when the ODOM lines before it run late.

    Args:
        laser: (M,) bool, laser lines (True) and ODOM lines (False).
        ipc, logger: (M,) int64 each line's ipc_time and logger_time in ns, -1 where there is
            none (zero, negative, not finite).
    """
    m = int(laser.size)
    lasers = np.flatnonzero(laser) if laser.any() else np.arange(m)
    first, first_ok = _usable(ipc[lasers].tolist(), logger[lasers].tolist())
    stamps, ok = [0] * m, [False] * m
    for j, i in enumerate(lasers.tolist()):
        stamps[i], ok[i] = first[j], first_ok[j]
    if 0 < lasers.size < m and sum(first_ok) * 2 >= lasers.size:
        _odometry_between(laser.tolist(), ipc.tolist(), logger.tolist(), stamps, ok)
    step = _typical_step(stamps, ok)
    if sum(first_ok) * 2 < lasers.size:
        base = 0
        if any(first_ok):
            j = first_ok.index(True)
            base = max(first[j] - int(lasers[j]) * step, 0)
        out = [base + i * step for i in range(m)]
        return Clock(np.asarray(out, np.int64), ~np.asarray(ok, bool), step, False)
    out = _fill(stamps, ok, step, laser.tolist())
    return Clock(np.asarray(out, np.int64), ~np.asarray(ok, bool), step, True)


def _usable(ipc: list[int], logger: list[int]) -> tuple[list[int], list[bool]]:
    """Each line's usable time (ipc_time first, else logger_time) in a sequence of one kind,
    and whether it has one."""
    m = len(ipc)
    following = _following(ipc, logger, [True] * m)
    stamps, ok = [0] * m, [False] * m
    last = -1
    for i in range(m):
        for value in (ipc[i], logger[i]):
            if value <= last or _jumps(value, last, following[i]):
                continue
            stamps[i], ok[i], last = value, True, value
            break
    return stamps, ok


def _odometry_between(
    laser: list[bool], ipc: list[int], logger: list[int], stamps: list[int], ok: list[bool]
) -> None:
    """Judge the ODOM lines' times in place, given the laser lines' (``stamps``, ``ok``)."""
    m = len(laser)
    following = _following(ipc, logger, [not x for x in laser])
    ceiling = [-1] * m
    nxt = -1
    for i in range(m - 1, -1, -1):
        ceiling[i] = nxt
        if laser[i] and ok[i]:
            nxt = stamps[i]
    last, last_odometry = -1, -1
    for i in range(m):
        if laser[i]:
            last = max(last, stamps[i]) if ok[i] else last
            continue
        for value in (ipc[i], logger[i]):
            if value < last or value <= last_odometry or value <= 0:
                continue
            if (0 <= ceiling[i] < value) or _jumps(value, last, following[i]):
                continue
            stamps[i], ok[i], last, last_odometry = value, True, value, value
            break


def _following(ipc: list[int], logger: list[int], counted: list[bool]) -> list[int]:
    """For each line, the time of the next counted line that has one (-1: none)."""
    m = len(ipc)
    out = [-1] * m
    nxt = -1
    for i in range(m - 1, -1, -1):
        out[i] = nxt
        if counted[i] and (ipc[i] > 0 or logger[i] > 0):
            nxt = ipc[i] if ipc[i] > 0 else logger[i]
    return out


def _jumps(value: int, last: int, after: int) -> bool:
    """A lone jump ahead: the next time falls back between the last usable time and this one."""
    return after >= 0 and last <= after < value


def _typical_step(stamps: list[int], ok: list[bool]) -> int:
    """Median time per line between consecutive usable times, ns; the default without enough."""
    steps: list[float] = []
    prev = -1
    for i, good in enumerate(ok):
        if not good:
            continue
        if prev >= 0 and stamps[i] > stamps[prev]:
            steps.append((stamps[i] - stamps[prev]) / (i - prev))
        prev = i
    if len(steps) < _MIN_STEP_SAMPLES:
        return _DEFAULT_STEP_NS
    return max(1, round(statistics.median(steps)))


def _fill(stamps: list[int], ok: list[bool], step: int, laser: list[bool]) -> list[int]:
    """Replace the stamps of lines without a usable time.

    A run of such lines goes between the usable times around it; where they leave no room
    (the same time on both sides) the ODOM time before it, or else the time after it, is
    replaced too (``ok`` loses it), so a scan keeps its time rather than an ODOM line.
    """
    m = len(stamps)
    out = list(stamps)
    i = 0
    while i < m:
        if ok[i]:
            i += 1
            continue
        b = i
        while b < m and not ok[b]:
            b += 1
        a = i - 1
        if b < m and not _room(out, a, b):
            if a >= 0 and ok[a] and laser[b] and not laser[a]:
                ok[a] = False
                i = a
            else:
                ok[b] = False
            continue
        for j in range(i, b):
            out[j] = _between(out, a, b, j, step, m)
        i = b
    return out


def _room(out: list[int], a: int, b: int) -> bool:
    """Whether the lines between a and b (a = -1: the start) fit strictly increasing stamps."""
    if a < 0:
        return out[b] >= b + 1
    return out[b] - out[a] >= b - a


def _between(out: list[int], a: int, b: int, j: int, step: int, m: int) -> int:
    if a >= 0 and b < m:
        return out[a] + (out[b] - out[a]) * (j - a) // (b - a)
    if a >= 0:
        return out[a] + (j - a) * step
    if b < m:
        if out[b] - b * step >= 0:
            return out[b] - (b - j) * step
        return out[b] * (j + 1) // (b + 1)
    return j * step
