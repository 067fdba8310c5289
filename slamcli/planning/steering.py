"""Continuous steering: a car-like path whose curvature changes at a bounded rate.

The search and its shortcuts build paths of arcs and straight lines, so the curvature, and with
it the steering angle, jumps where two pieces meet: a real vehicle's steering cannot. Here each
run of one gear (the path between two gear changes) is given a curvature profile that changes
by at most ``rate`` per metre, the limit :func:`curvature_rate` derives from the distance over
which the steering may go from straight ahead to full lock:

1. **Ramps.** The run's curvature, sampled every ``ds`` metres of arc length, is averaged over a
   window of ``W = 2 kappa_max / (0.75 rate)`` metres (a box filter; the run's end values
   continue past its ends; :data:`RAMP_SHARE`). A jump of ``dk`` becomes a ramp of that
   length, centred on the jump: the rate is at most ``2 kappa_max / W``, three quarters of the
   limit (the anchors' corrections below take the rest), and the curvature never leaves
   ``[-kappa_max, kappa_max]`` (an average of values within it). A constant stretch far from any
   jump, and so a whole run of one curvature, is unchanged.
2. **Anchors.** Each ramp moves the path sideways by about ``dk W² / 24`` (3.5 cm for a full
   lock change over a 1.3 m window), and over a long run these add up. So the run is cut into
   stretches of about :data:`CHUNK_M` metres, and on each, Gauss-Newton on three smooth
   corrections of the profile (``sin²(pi s / L)`` times 1, ``s / L - 1/2`` and its square,
   over the stretch), which vanish at the stretch's ends, brings its end onto the input
   path's pose there to 1e-9 m. The path stays within the ramps' own displacement of the
   input, and the gear changes and the goal stay where the search put them. The curvature is
   clipped to ``kappa_max`` after each step, so where a ramp reaches full lock the others
   take up the correction.
3. **Checks.** The new run is kept only when its curvature stays within ``kappa_max``, its rate
   within ``rate`` (both from the integrated poses) and its footprint free at every pose (the
   exact test of :mod:`slamcli.planning.footprint`); otherwise the run keeps its arcs and
   lines, and the caller reports it.

A run that cannot keep both ends (a short stretch at full lock with a jump in it, where no
ramp fits) may end up to :data:`MAX_GEAR_SHIFT_M` and :data:`MAX_GEAR_TURN_DEG` from its gear
change, its last stretch ramped and not corrected; the next run starts where it ends. The goal
is always kept.

At a gear change the vehicle stops, and may turn its wheels while standing: the curvature of
one run's end and the next run's start are independent (as in Fraichard and Scheuer's
continuous-curvature paths with cusps, which also allow a standstill change).

Poses are ``(x, y, yaw)`` in metres and radians; each pose's curvature and gear are those of
the motion leaving it (the last pose repeats the last motion's).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

FULL_LOCK_DISTANCE_M = 0.5
"""Default shortest travel over which the steering goes from straight ahead to full lock."""

_NEWTON_STEPS = 20
RAMP_SHARE = 0.75
"""Share of the rate limit the ramps use; the corrections of the anchors get the rest."""
MAX_GEAR_SHIFT_M = 0.10
"""How far a gear change may move when the run before it cannot end exactly there."""
MAX_GEAR_TURN_DEG = 5.0
"""How far its heading may turn then."""
CHUNK_M = 3.0
"""Length of the stretches at whose ends the ramped path is brought back onto the input's
poses."""
_END_TOL_M = 1e-9
_RATE_TOL = 1.0 + 1e-6


def curvature_rate(min_turn_radius_m: float, full_lock_distance_m: float) -> float:
    """The curvature rate limit, 1/m², that reaching full lock (``1 / min_turn_radius_m``)
    over ``full_lock_distance_m`` of travel implies."""
    return 1.0 / (min_turn_radius_m * full_lock_distance_m)


@dataclass(frozen=True)
class SteeredPath:
    """A path with continuous steering within each gear run.

    Attributes:
        poses: (N, 3) world poses, at most ``ds`` apart.
        direction: (N,) int8 gear of the motion leaving each pose.
        curvature: (N,) 1/m of the motion leaving each pose.
        kept_runs: how many gear runs kept their arcs and lines because the smoothed run
            failed a check (curvature, rate or footprint).
        runs: how many gear runs the path has.
    """

    poses: F64
    direction: NDArray[np.int8]
    curvature: F64
    kept_runs: int
    runs: int


def pose_curvatures(poses: F64) -> tuple[F64, F64]:
    """The curvature (1/m, signed, of the arc between consecutive poses, from their chord and
    heading change: exact for arcs) and the arc lengths (m) between consecutive poses."""
    dyaw = np.angle(np.exp(1j * np.diff(poses[:, 2])))
    chord = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    arc = chord / np.sinc(dyaw / (2.0 * np.pi))
    with np.errstate(invalid="ignore", divide="ignore"):
        kappa = np.where(arc > 1e-12, dyaw / arc, 0.0)
    return kappa, arc


def steered_path(
    poses: F64,
    direction: NDArray[np.int8],
    curvature: F64,
    *,
    kappa_max: float,
    rate: float,
    ds: float,
    free: Callable[[F64], NDArray[np.bool_]],
) -> SteeredPath:
    """The path of the module doc from a path of arcs and lines (``poses`` with the
    ``direction`` and ``curvature`` of the motion leaving each), sampled every ``ds`` metres
    at most; ``free`` tests the footprint at (M, 3) poses."""
    n = len(poses)
    starts = [0, *(np.flatnonzero(np.diff(direction[:-1].astype(np.int64)) != 0) + 1), n - 1]
    pairs = [(a, b) for a, b in itertools.pairwise(starts) if b > a]
    kept = 0
    done: list[tuple[F64, F64, F64]] = []  # (start pose, poses, curvatures) per run

    def steer(i: int, start: F64, open_end: bool) -> tuple[F64, F64] | None:
        a, b = pairs[i]
        return _steer_run(
            poses[a : b + 1],
            curvature[a:b],
            float(direction[a]),
            kappa_max,
            rate,
            ds,
            free,
            start=start,
            open_end=open_end,
        )

    start = poses[0]
    for i, (a, b) in enumerate(pairs):
        open_end = i < len(pairs) - 1
        run = steer(i, start, open_end)
        if run is None and not np.array_equal(start, poses[a]):
            # The run before moved this gear change and this run cannot start there: the
            # run before is redone keeping the gear change where the search put it.
            before_start = done[-1][0]
            again = steer(i - 1, before_start, False)
            if again is None and not np.array_equal(before_start, poses[pairs[i - 1][0]]):
                return SteeredPath(poses, direction, curvature, len(pairs), len(pairs))
            pa, pb = pairs[i - 1]
            if again is None:
                kept += 1
                again = (poses[pa + 1 : pb + 1], curvature[pa:pb])
            done[-1] = (before_start, *again)
            start = poses[a]
            run = steer(i, start, open_end)
        if run is None:
            kept += 1
            run = (poses[a + 1 : b + 1], curvature[a:b])
        done.append((start, *run))
        start = run[0][-1]
    runs = len(pairs)
    out_p: list[F64] = [poses[:1], *(d[1] for d in done)]
    out_k: list[F64] = [d[2] for d in done]
    out_g: list[NDArray[np.int8]] = [
        np.full(len(d[2]), direction[a], dtype=np.int8)
        for d, (a, _) in zip(done, pairs, strict=True)
    ]
    g = np.concatenate(out_g)
    k = np.concatenate(out_k)
    return SteeredPath(
        poses=np.vstack(out_p),
        direction=np.concatenate((g, g[-1:])),
        curvature=np.concatenate((k, k[-1:])),
        kept_runs=kept,
        runs=runs,
    )


def _integrate(start: F64, kappa: F64, step: float) -> F64:
    """(M, 3) poses after each of ``len(kappa)`` arcs of signed length ``step`` (< 0 backwards)
    and curvature ``kappa`` from ``start``."""
    turn = kappa * step
    yaw = start[2] + np.concatenate(([0.0], np.cumsum(turn)))
    chord = step * np.sinc(turn / (2.0 * np.pi))
    heading = yaw[:-1] + turn / 2.0
    x = start[0] + np.cumsum(chord * np.cos(heading))
    y = start[1] + np.cumsum(chord * np.sin(heading))
    return np.column_stack((x, y, yaw[1:]))


def _steer_run(
    run: F64,
    kappa_in: F64,
    gear: float,
    kappa_max: float,
    rate: float,
    ds: float,
    free: Callable[[F64], NDArray[np.bool_]],
    *,
    start: F64 | None = None,
    open_end: bool = False,
) -> tuple[F64, F64] | None:
    """One gear run (its poses, first to last, and the curvature of each motion) with ramped
    curvature, from ``start`` (the run's first pose unless a gear change moved) and with its
    end pose kept; or None when a check fails. With ``open_end`` (the run ends at a gear
    change, not the goal) a run whose end cannot be kept may end up to
    :data:`MAX_GEAR_SHIFT_M` and :data:`MAX_GEAR_TURN_DEG` away from it, its last stretch
    ramped and not corrected."""
    _, arcs = pose_curvatures(run)
    length = float(arcs.sum())
    if length <= 0.0:
        return None
    m = max(1, math.ceil(length / ds))
    step = length / m
    # The input profile averaged over each new step: the heading at every step's end is the
    # input's own.
    edges = np.concatenate(([0.0], np.cumsum(arcs)))
    heading = np.concatenate(([0.0], np.cumsum(kappa_in * arcs)))
    target = np.diff(np.interp(np.arange(m + 1) * step, edges, heading)) / step
    width = max(1, math.ceil(2.0 * kappa_max / (RAMP_SHARE * rate) / step))
    if width > 1:
        padded = np.concatenate((np.full(width, target[0]), target, np.full(width, target[-1])))
        box = np.convolve(padded, np.ones(width) / width, mode="same")[width:-width]
    else:
        box = target.copy()
    # Every CHUNK_M or so, the ramped path is brought back onto the input's pose there, so it
    # never strays further than the ramps of one chunk move it.
    first = run[0] if start is None else start
    chunks = max(1, round(length / CHUNK_M))
    bounds = np.linspace(0, m, chunks + 1).round().astype(np.int64)
    out = None
    for open_last in (False, True) if open_end else (False,):
        out = _anchored(
            run, edges, kappa_in, box, bounds, first, gear, step, kappa_max, rate, open_last
        )
        if out is not None:
            break
    if out is None:
        return None
    kappa, steps, parts = out
    if open_end:
        end = parts[-1][-1]
        shift = math.hypot(end[0] - run[-1, 0], end[1] - run[-1, 1])
        turn = abs(_wrap(end[2] - run[-1, 2]))
        if shift > MAX_GEAR_SHIFT_M or math.degrees(turn) > MAX_GEAR_TURN_DEG:
            return None
    poses = np.vstack(parts)
    if np.abs(kappa).max() > kappa_max * (1.0 + 1e-9):
        return None
    spacing = np.abs(steps)
    if m > 1 and (np.abs(np.diff(kappa)) / spacing[1:]).max() > rate * _RATE_TOL:
        return None
    if not free(poses).all():
        return None
    return poses, kappa


def _anchored(
    run: F64,
    edges: F64,
    kappa_in: F64,
    box: F64,
    bounds: NDArray[np.int64],
    first: F64,
    gear: float,
    step: float,
    kappa_max: float,
    rate: float,
    open_last: bool,
) -> tuple[F64, F64, list[F64]] | None:
    """The ramped profile ``box`` corrected stretch by stretch (``bounds``, in steps) onto the
    input run's poses, from ``first``: the curvatures, the signed steps and each stretch's
    poses; with ``open_last`` the last stretch is left uncorrected. None when a stretch
    cannot be closed even joined with its neighbours."""
    m = len(box)
    chunks = len(bounds) - 1
    kappa = box.copy()
    steps = np.full(m, gear * step)
    # Accepted stretches: (first step, end step, start pose, poses).
    done: list[tuple[int, int, F64, F64]] = []
    j = 0
    k_min = 1
    while j < chunks:
        start = first if not done else done[-1][3][-1]
        part = None
        # A stretch mostly at full lock has little room for the correction: it is joined
        # with the next until the correction fits, and at the run's end with the one before.
        for k in range(max(j + 1, k_min), chunks + 1):
            i0, i1 = bounds[j], bounds[k]
            if open_last and i1 == m:
                # The last stretch ramped and left where it ends.
                free_end = _integrate(start, box[i0:i1], gear * step)
                part = (box[i0:i1].copy(), free_end, gear * step)
                end = free_end[-1]
                break
            end = run[-1] if i1 == m else _pose_at(run, edges, kappa_in, gear, i1 * step)
            kappa_before = box[0] if i0 == 0 else kappa[i0 - 1]
            part = _close(
                start, end, box[i0:i1], gear * step, kappa_max, rate * _RATE_TOL, kappa_before
            )
            if part is not None:
                break
        if part is None:
            if not done:
                return None
            # No end works from stretch j: the one before takes it on.
            k_min = j + 1
            i0 = done.pop()[0]
            j = int(np.flatnonzero(bounds == i0)[0])
            continue
        kappa[i0:i1], poses_part, steps[i0:i1] = part
        poses_part[-1] = end
        done.append((i0, i1, start, poses_part))
        j = k
    return kappa, steps, [d[3] for d in done]


def _pose_at(run: F64, edges: F64, kappa_in: F64, gear: float, s: float) -> F64:
    """The input run's pose ``s`` metres along it (its poses, their arc-length ``edges`` and
    the curvature of each motion)."""
    i = int(np.clip(np.searchsorted(edges, s, side="right") - 1, 0, len(kappa_in) - 1))
    return _integrate(run[i], np.array([kappa_in[i]]), gear * (s - edges[i]))[-1]


def _close(
    start: F64,
    end: F64,
    kappa: F64,
    step: float,
    kappa_max: float,
    max_rate: float,
    kappa_before: float,
) -> tuple[F64, F64, float] | None:
    """The profile ``kappa`` (arcs of signed length ``step`` from ``start``) corrected by
    Gauss-Newton, as the module doc says, so that it ends at ``end``: three smooth changes of
    the curvature and one of the stretch's length (the ramps cut corners, so the way along
    changes too, which no change of curvature mends). Returns the curvatures, the poses and
    the signed step, or None when it does not converge or the curvature changes by more than
    ``max_rate`` per metre (``kappa_before``: the curvature of the step before the first)."""
    m = len(kappa)
    u = (np.arange(m) + 0.5) / m
    window = np.sin(np.pi * u) ** 2
    basis = np.stack((window, window * (u - 0.5), window * ((u - 0.5) ** 2 - 1.0 / 12.0)))
    length = m * abs(step)
    # Unknowns in metres of the end's displacement: curvature ones scaled by length².
    basis = basis / length**2
    sign = 1.0 if step > 0 else -1.0
    for _ in range(_NEWTON_STEPS):
        poses = _integrate(start, kappa, step)
        err = np.array([end[0] - poses[-1, 0], end[1] - poses[-1, 1], _wrap(end[2] - poses[-1, 2])])
        if math.hypot(err[0], err[1]) < _END_TOL_M and abs(err[2]) < _END_TOL_M:
            if np.abs(np.diff(kappa, prepend=kappa_before)).max() > max_rate * abs(step):
                return None
            return kappa, poses, step
        # d(end)/d(kappa_i): the heading turns by step; the end swings about motion i.
        before = np.vstack((start[None, :], poses[:-1]))
        mid = (before + poses) / 2.0
        dx = poses[-1, 0] - mid[:, 0]
        dy = poses[-1, 1] - mid[:, 1]
        jac_k = np.stack((-dy * step, dx * step, np.full(m, step))) @ basis.T
        # d(end)/d(length), every step longer by 1/m: along each step's heading, and the rest
        # swung by its curvature.
        heading = before[:, 2] + kappa * step / 2.0
        jac_l = (
            sign
            * np.array(
                [
                    np.sum(np.cos(heading) - kappa * dy),
                    np.sum(np.sin(heading) + kappa * dx),
                    np.sum(kappa),
                ]
            )
            / m
        )
        jac = np.column_stack((jac_k, jac_l))
        delta, *_ = np.linalg.lstsq(jac, err, rcond=None)
        step += sign * delta[3] / m
        # Where the ramps already reach full lock the correction is clipped; the next step
        # puts what it could not do elsewhere along the stretch.
        kappa = np.clip(kappa + delta[:3] @ basis, -kappa_max, kappa_max)
    return None


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi
