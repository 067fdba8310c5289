"""Time a car-like path that may change gear, and simulate a bicycle-model car following it.

A car path (from a Hybrid-A* planner) is three arrays over its N poses:

- ``poses (N, 3)``: x, y (m) and yaw (rad), the car's heading, also when it reverses;
- ``direction (N,) int8``: the gear of the motion *leaving* each pose, +1 forward, -1 reverse;
- ``curvature (N,) float64``: the signed curvature (1/m) of the motion leaving each pose, the
  steering's ``tan(steer) / wheelbase``: the yaw changes by ``curvature`` per metre of *signed*
  travel (negative in reverse), so ``omega = v * curvature`` with ``v`` signed.

The last entries of ``direction`` and ``curvature`` describe no motion and are not used. A pose
where the gear flips is a *cusp*: the car stops there. The path is cut at the cusps into
*pieces*, each driven in one gear from rest to rest.

:func:`time_parameterise_car` gives every pose a speed and a time. Between two poses the car
moves along the chord with constant acceleration (``v²`` linear in arc length), which makes
``|dv/dt| <= max_accel`` exact; each segment keeps the curvature of its first pose, so a speed
under ``sqrt(max_lateral_accel / |k|)`` and ``max_yaw_rate / |k|`` at both its ends keeps the
lateral acceleration and the yaw rate within their limits all along it.

:func:`simulate_bicycle` drives a kinematic bicycle (rear-axle reference point) along the
profile, piece by piece, steering by pure pursuit around the path's curvature, in a compiled
loop (numba).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.config import check_settings, setting
from slamcli.errors import ConfigError, InputError
from slamcli.planning.tracker import TrackerSettings, TrackingResult

__all__ = [
    "BicycleTrackingResult",
    "CarLimits",
    "CarProfile",
    "simulate_bicycle",
    "time_parameterise_car",
]

_SAME_POSITION_M = 1e-9
"""Consecutive poses closer than this are one pose."""

_AT_END_M = 1e-6
"""A car this close to (or past) the end of a piece, in arc length, is at its end."""

_CURVATURE_SLACK = 1e-6
"""Relative excess over ``1 / min_turn_radius_m`` accepted in a path's curvature (rounding)."""


@dataclass(frozen=True)
class CarLimits:
    """Kinematic limits and geometry of a car-like robot.

    Attributes:
        max_speed: the fastest the car drives forwards, m/s.
        max_reverse_speed: the fastest it drives backwards, m/s; None (the default) means half
            of ``max_speed``, and is replaced by that value when the limits are made.
        max_accel: the largest speed change per second along the path, m/s².
        max_lateral_accel: the largest ``v² |curvature|``, m/s².
        max_yaw_rate: the fastest the heading turns, rad/s.
        wheelbase_m: distance from the rear axle (the reference point) to the front axle, m.
        min_turn_radius_m: the tightest turn of the rear axle's centre, m; the steering angle
            is limited to ``atan(wheelbase_m / min_turn_radius_m)``.
    """

    max_speed: float = setting(1.0, unit="m/s", gt=0.0)
    max_reverse_speed: float | None = setting(None, unit="m/s", gt=0.0)
    max_accel: float = setting(0.5, unit="m/s²", gt=0.0)
    max_lateral_accel: float = setting(0.5, unit="m/s²", gt=0.0)
    max_yaw_rate: float = setting(1.0, unit="rad/s", gt=0.0)
    wheelbase_m: float = setting(0.5, unit="m", gt=0.0)
    min_turn_radius_m: float = setting(1.0, unit="m", gt=0.0)

    def __post_init__(self) -> None:
        speed = self.max_speed
        if self.max_reverse_speed is None and isinstance(speed, (int, float)):
            object.__setattr__(self, "max_reverse_speed", 0.5 * float(speed))

    def checked(self, names: Mapping[str, str] | None = None) -> CarLimits:
        """These limits, or a ConfigError naming the bad option (a field name, or what
        ``names`` calls it, e.g. ``{"max_speed": "--max-speed"}``)."""
        return check_settings(self, names)

    @property
    def max_steer_rad(self) -> float:
        """The largest steering angle, ``atan(wheelbase / min_turn_radius)``, radians."""
        return math.atan(self.wheelbase_m / self.min_turn_radius_m)

    def speed_limit(self, gear: int) -> float:
        """The top speed (m/s, >= 0) in ``gear`` (+1 forward, -1 reverse)."""
        rev = self.max_reverse_speed
        return float(self.max_speed if gear > 0 or rev is None else rev)


@dataclass(frozen=True)
class CarProfile:
    """A car path with a speed and a time at each of its K knots.

    The knots are the path's poses, without repeated positions (the motion leaving a repeated
    position is the one of its last copy), plus the midpoint of any piece made of one segment
    (so the car can speed up and slow down on it). Between knots the car moves along the
    chord, ``v²`` linear in arc length, at the first knot's curvature.

    Attributes:
        xy: (K, 2) positions, metres.
        yaw: (K,) heading, radians, unwrapped (continuous).
        s: (K,) arc length from the start, metres, absolute (it grows in reverse too).
        t: (K,) time, seconds.
        v: (K,) signed speed, m/s: negative in reverse, 0 at the start, the cusps and the end.
        curvature: (K,) signed curvature of the motion leaving each knot, 1/m.
        direction: (K,) int8 gear of the motion leaving each knot (+1 / -1); the last knot
            repeats the gear it was reached in.
    """

    xy: NDArray[np.float64]
    yaw: NDArray[np.float64]
    s: NDArray[np.float64]
    t: NDArray[np.float64]
    v: NDArray[np.float64]
    curvature: NDArray[np.float64]
    direction: NDArray[np.int8]

    @property
    def duration_s(self) -> float:
        """Time from the start to the stop at the goal, seconds."""
        return float(self.t[-1])

    @property
    def length_m(self) -> float:
        """Path length, metres, reversing included."""
        return float(self.s[-1])

    @property
    def cusps(self) -> NDArray[np.int64]:
        """(C,) knot indices where the gear changes (the car stops there)."""
        d = self.direction[:-1].astype(np.int64)
        return np.flatnonzero(d[1:] != d[:-1]) + 1

    @property
    def reversals(self) -> int:
        """Number of gear changes."""
        return len(self.cusps)

    @property
    def piece_bounds(self) -> NDArray[np.int64]:
        """(P + 1,) knot indices: piece p runs from knot ``b[p]`` to knot ``b[p + 1]``."""
        return np.concatenate(([0], self.cusps, [len(self.s) - 1])).astype(np.int64)

    def sample(self, times: ArrayLike) -> NDArray[np.float64]:
        """(M, 6) rows ``t, x, y, theta, v, omega`` (s, m, m, rad, m/s signed, rad/s) at the
        given times, clamped to [0, duration]; ``theta`` is wrapped to (-pi, pi] and
        ``omega = v * curvature``."""
        tq = np.clip(np.asarray(times, dtype=np.float64).reshape(-1), 0.0, self.t[-1])
        k = np.clip(np.searchsorted(self.t, tq, side="right") - 1, 0, len(self.t) - 2)
        ds = self.s[k + 1] - self.s[k]
        sp0 = np.abs(self.v[k])
        sp1 = np.abs(self.v[k + 1])
        acc = (sp1**2 - sp0**2) / (2.0 * ds)
        tau = tq - self.t[k]
        dist = np.clip(sp0 * tau + 0.5 * acc * tau**2, 0.0, ds)
        speed = np.clip(sp0 + acc * tau, 0.0, None)
        u = dist / ds
        xy = self.xy[k] + u[:, None] * (self.xy[k + 1] - self.xy[k])
        theta = self.yaw[k] + u * (self.yaw[k + 1] - self.yaw[k])
        v = self.direction[k] * speed
        omega = v * self.curvature[k]
        return np.column_stack((tq, xy, np.angle(np.exp(1j * theta)), v, omega))

    def sample_every(self, dt_s: float) -> NDArray[np.float64]:
        """:meth:`sample` at 0, dt, 2 dt, ... and at the end time; (M, 6)."""
        if not (math.isfinite(dt_s) and dt_s > 0):
            raise ConfigError(
                f"dt_s: expected a number > 0 (s), got {dt_s!r}",
                hint="sample the trajectory every 0.02 to 0.1 s",
            )
        n = math.floor(self.duration_s / dt_s + 1e-9)
        times = np.arange(n + 1) * dt_s
        if self.duration_s - times[-1] > 1e-9:
            times = np.append(times, self.duration_s)
        return self.sample(times)


def time_parameterise_car(
    poses: ArrayLike, direction: ArrayLike, curvature: ArrayLike, limits: CarLimits
) -> CarProfile:
    """Speeds and times along a car path (see the module docstring for the arrays).

    Along each piece (between cusps) the speed is the largest one that starts and ends at
    rest and keeps, at every knot, ``|v| <= max_speed`` (``max_reverse_speed`` in reverse),
    ``v² |k| <= max_lateral_accel`` and ``|v k| <= max_yaw_rate`` for the curvature of both
    segments meeting there, with ``|dv/dt| <= max_accel`` between knots: a forward pass
    (speeding up) and a backward pass (braking) over arc length.

    Raises:
        ConfigError: a bad limit.
        InputError: arrays of the wrong shape, non-finite values, a gear other than +1/-1, a
            curvature above ``1 / min_turn_radius_m``, or a path without length.
    """
    limits = limits.checked()
    xy, yaw, gear, kappa = _check_path(poses, direction, curvature, limits)
    xy, yaw, gear, kappa = _drop_repeats(xy, yaw, gear, kappa)
    xy, yaw, gear, kappa = _split_lone_segments(xy, yaw, gear, kappa)
    seg_len = np.hypot(*np.diff(xy, axis=0).T)
    s = np.concatenate(([0.0], np.cumsum(seg_len)))

    seg_gear = gear[:-1]
    seg_k = np.abs(kappa[:-1])
    with np.errstate(divide="ignore"):
        seg_cap = np.minimum.reduce(
            [
                np.where(seg_gear > 0, limits.max_speed, limits.speed_limit(-1)),
                np.sqrt(limits.max_lateral_accel / seg_k),
                limits.max_yaw_rate / seg_k,
            ]
        )
    cap = np.minimum(np.concatenate(([0.0], seg_cap)), np.concatenate((seg_cap, [0.0])))
    cap[_cusps(gear)] = 0.0
    speed = _forward_backward(cap, seg_len, limits.max_accel)
    dt = 2.0 * seg_len / (speed[:-1] + speed[1:])
    t = np.concatenate(([0.0], np.cumsum(dt)))
    gear_out = gear.copy()
    gear_out[-1] = gear[-2]
    v = gear_out * speed
    v[-1] = 0.0
    return CarProfile(xy, yaw, s, t, v, kappa, gear_out.astype(np.int8))


def _check_path(
    poses: ArrayLike, direction: ArrayLike, curvature: ArrayLike, limits: CarLimits
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """The path as (N, 2) xy, (N,) unwrapped yaw, (N,) int gear, (N,) curvature, or an
    InputError naming what is wrong."""
    p = np.asarray(poses, dtype=np.float64)
    d = np.asarray(direction)
    k = np.asarray(curvature, dtype=np.float64)
    hint = "pass poses (N, 3) x, y, yaw with direction (N,) of +1/-1 and curvature (N,)"
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2:
        raise InputError(f"car path: poses must be (N, 3) with N >= 2, got {p.shape}", hint=hint)
    n = len(p)
    if d.shape != (n,) or k.shape != (n,):
        raise InputError(
            f"car path: {n} poses need {n} directions and curvatures, got {d.shape} and {k.shape}",
            hint=hint,
        )
    if not (np.isfinite(p).all() and np.isfinite(k).all()):
        raise InputError("car path: poses and curvatures must be finite", hint=hint)
    bad = np.flatnonzero((d != 1) & (d != -1))
    if len(bad):
        raise InputError(
            f"car path: direction[{bad[0]}] = {d[bad[0]]!r}; only +1 (forward) and -1 "
            "(reverse) are gears",
            hint=hint,
        )
    k_max = 1.0 / limits.min_turn_radius_m
    over = np.flatnonzero(np.abs(k[:-1]) > k_max * (1.0 + _CURVATURE_SLACK))
    if len(over):
        i = int(over[0])
        raise InputError(
            f"car path: curvature[{i}] = {k[i]:.6g} 1/m is sharper than the car can turn "
            f"(1 / min_turn_radius_m = {k_max:.6g} 1/m)",
            hint="plan with a min turn radius at least the car's, or raise min_turn_radius_m "
            "to what the car can do",
        )
    return p[:, :2].copy(), np.unwrap(p[:, 2]), d.astype(np.int64), k.copy()


_Path = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]


def _drop_repeats(
    xy: NDArray[np.float64],
    yaw: NDArray[np.float64],
    gear: NDArray[np.int64],
    kappa: NDArray[np.float64],
) -> _Path:
    """The path without a pose whose leaving segment has no length (the later copy, which
    carries the motion that really leaves the position, is kept)."""
    step = np.hypot(*np.diff(xy, axis=0).T)
    keep = np.concatenate((step > _SAME_POSITION_M, [True]))
    if keep.sum() < 2:
        raise InputError(
            "car path: all poses are at one position; there is nothing to drive",
            hint="give a goal away from the start",
        )
    return xy[keep], yaw[keep], gear[keep], kappa[keep]


def _cusps(gear: NDArray[np.int64]) -> NDArray[np.int64]:
    """Knot indices where the gear of the leaving motion differs from the arriving one."""
    g = gear[:-1]
    return np.flatnonzero(g[1:] != g[:-1]) + 1


def _split_lone_segments(
    xy: NDArray[np.float64],
    yaw: NDArray[np.float64],
    gear: NDArray[np.int64],
    kappa: NDArray[np.float64],
) -> _Path:
    """The path with a knot added in the middle of every piece that has only one segment."""
    bounds = np.concatenate(([0], _cusps(gear), [len(xy) - 1]))
    lone = bounds[:-1][np.diff(bounds) == 1]
    if not len(lone):
        return xy, yaw, gear, kappa
    mid_xy = 0.5 * (xy[lone] + xy[lone + 1])
    mid_yaw = 0.5 * (yaw[lone] + yaw[lone + 1])
    at = lone + 1
    return (
        np.insert(xy, at, mid_xy, axis=0),
        np.insert(yaw, at, mid_yaw),
        np.insert(gear, at, gear[lone]),
        np.insert(kappa, at, kappa[lone]),
    )


def _forward_backward(
    cap: NDArray[np.float64], ds: NDArray[np.float64], accel: float
) -> NDArray[np.float64]:
    """(K,) largest speeds under ``cap`` with ``|v_{k+1}² - v_k²| <= 2 accel ds_k``."""
    v = cap.tolist()
    two_a_ds = (2.0 * accel * ds).tolist()
    for k in range(len(two_a_ds)):
        v[k + 1] = min(v[k + 1], math.sqrt(v[k] * v[k] + two_a_ds[k]))
    for k in range(len(two_a_ds) - 1, -1, -1):
        v[k] = min(v[k], math.sqrt(v[k + 1] * v[k + 1] + two_a_ds[k]))
    return np.asarray(v, dtype=np.float64)


@dataclass
class BicycleTrackingResult(TrackingResult):
    """A :class:`~slamcli.planning.tracker.TrackingResult` with the car's steering and gear.

    ``states`` rows are ``t, x, y, theta, v, omega`` with ``v`` signed (negative in reverse)
    and ``omega = v * tan(steer) / wheelbase``; ``events`` holds one ``{"t_s", "x", "y",
    "kind": "reverse" | "forward", "obstacle": None}`` per gear change and ``paths`` one
    ``(start time, (P, 2) polyline)`` per piece.

    Attributes:
        steer_rad: (K,) steering angle held from each state on, radians (+ left).
        gear: (K,) int8 gear (+1 / -1) of the piece being followed.
    """

    steer_rad: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    gear: NDArray[np.int8] = field(default_factory=lambda: np.zeros(0, dtype=np.int8))


def simulate_bicycle(
    profile: CarProfile,
    limits: CarLimits,
    settings: TrackerSettings | None = None,
    *,
    max_steer_rate: float | None = None,
) -> BicycleTrackingResult:
    """Drive a kinematic bicycle along ``profile`` from its start (at rest, on the first pose,
    wheels at the first curvature) and stop at its end.

    Model (rear-axle reference point, steering ``delta``): ``x' = v cos(theta)``,
    ``y' = v sin(theta)``, ``theta' = v tan(delta) / wheelbase``, integrated exactly over each
    ``settings.dt_s`` step for the mean speed and the steering held. Every step:

    - progress = the nearest point of the current piece (searched near the last one); past
      the piece's end, on the straight line on along the direction of travel;
    - steering: pure pursuit of the point ``look = max(lookahead_min_m, lookahead_gain_s |v|)``
      further along the piece, around the path's own curvature. The circle from the car
      through that point has curvature ``2 sin(alpha) / d`` (``alpha`` its bearing from the
      direction of travel, ``d`` its distance; in reverse the point lies behind the car, the
      rear axle drives the circle backwards and the steering takes the opposite sign). The
      command is the path's curvature at the car's progress plus that pursuit curvature
      minus the pursuit curvature of the same point from the path's own pose at the
      progress: on the path the car steers exactly the path's curvature, so it does not
      cut in where the curvature changes, and off the path it turns back like pure pursuit.
      Past the piece's end the path goes on along its last arc. ``|delta| <= atan(L /
      R_min)``. With ``max_steer_rate`` the wheels turn at most that fast, and the path's
      curvature is taken ahead by half the distance they need to turn to the curvature at
      the pursued point (at most ``look``), so they pass the middle of a change where the
      path does;
    - speed = the profile's speed at the time since the piece began, plus ``progress_gain``
      times how far the car lags it, at least ``creep_speed`` once the profile has stopped,
      at most: what still brakes to rest at the piece's end, the car's speed, lateral
      acceleration and yaw-rate limits for the steering held, and, while the wheels lag the
      command by more than one step's turn, ``lookahead_min_m`` covered in the time they
      need to catch up. It changes by at most ``max_accel * dt``;
    - once stopped within ``goal_tolerance_m`` of the piece's end, the car changes gear and
      follows the next piece; at the last piece's end it has reached the goal. At rest, it
      pulls off only once the wheels have turned to the pure-pursuit angle.

    The simulation gives up ``timeout_margin_s`` after the profile's duration, or when the
    car has stopped at a piece's end farther than the tolerance from it.

    Raises:
        ConfigError: a bad limit or setting.
    """
    cfg = settings or TrackerSettings()
    limits = limits.checked()
    _check_tracker(cfg)
    if max_steer_rate is not None and not (math.isfinite(max_steer_rate) and max_steer_rate > 0):
        raise ConfigError(
            f"max_steer_rate: expected a number > 0 (rad/s) or None, got {max_steer_rate!r}",
            hint="leave it unset for steering that turns instantly",
        )
    bounds = profile.piece_bounds
    first = bounds[:-1].copy()
    last = bounds[1:].copy()
    steer_max = limits.max_steer_rad
    steer0 = max(-steer_max, min(steer_max, math.atan(limits.wheelbase_m * profile.curvature[0])))
    t_limit = profile.duration_s + cfg.timeout_margin_s
    n_max = math.ceil(t_limit / cfg.dt_s) + 2
    states = np.zeros((n_max, 6))
    cross = np.zeros(n_max)
    steer = np.zeros(n_max)
    gear = np.zeros(n_max, dtype=np.int8)
    switch_step = np.zeros(len(first), dtype=np.int64)
    n, reached, t_goal, n_switch = _follow(
        np.ascontiguousarray(profile.xy[:, 0]),
        np.ascontiguousarray(profile.xy[:, 1]),
        profile.yaw,
        profile.s,
        profile.t,
        np.abs(profile.v),
        profile.direction.astype(np.int64),
        profile.curvature,
        first,
        last,
        limits.wheelbase_m,
        steer_max,
        math.inf if max_steer_rate is None else float(max_steer_rate),
        limits.max_accel,
        limits.max_speed,
        limits.speed_limit(-1),
        limits.max_lateral_accel,
        limits.max_yaw_rate,
        cfg.dt_s,
        cfg.lookahead_min_m,
        cfg.lookahead_gain_s,
        cfg.progress_gain,
        cfg.creep_speed,
        cfg.goal_tolerance_m,
        t_limit,
        steer0,
        states,
        cross,
        steer,
        gear,
        switch_step,
    )
    result = BicycleTrackingResult(
        states=states[:n].copy(),
        cross_track_m=cross[:n].copy(),
        reached_goal=bool(reached),
        time_to_goal_s=float(t_goal) if reached else None,
        steer_rad=steer[:n].copy(),
        gear=gear[:n].copy(),
    )
    result.paths.append((0.0, profile.xy[first[0] : last[0] + 1]))
    for p in range(1, n_switch + 1):
        row = result.states[switch_step[p]]
        result.paths.append((float(row[0]), profile.xy[first[p] : last[p] + 1]))
        kind = "forward" if profile.direction[first[p]] > 0 else "reverse"
        result.events.append(
            {
                "t_s": round(float(row[0]), 3),
                "x": float(row[1]),
                "y": float(row[2]),
                "kind": kind,
                "obstacle": None,
            }
        )
    return result


def _check_tracker(cfg: TrackerSettings) -> None:
    """ConfigError naming the first tracker setting the bicycle follower cannot use."""
    for name in ("dt_s", "lookahead_min_m", "goal_tolerance_m"):
        value = getattr(cfg, name)
        if not (math.isfinite(value) and value > 0):
            raise ConfigError(
                f"tracker {name}: expected a number > 0, got {value!r}",
                hint=f"the default is {getattr(TrackerSettings(), name)}",
            )
    for name in ("lookahead_gain_s", "progress_gain", "creep_speed", "timeout_margin_s"):
        value = getattr(cfg, name)
        if not (math.isfinite(value) and value >= 0):
            raise ConfigError(
                f"tracker {name}: expected a number >= 0, got {value!r}",
                hint=f"the default is {getattr(TrackerSettings(), name)}",
            )


@numba.njit(cache=True, nogil=True)
def _project(
    px: NDArray[np.float64],
    py: NDArray[np.float64],
    yaw: NDArray[np.float64],
    s: NDArray[np.float64],
    first: int,
    last: int,
    g: int,
    x: float,
    y: float,
    s_lo: float,
    s_hi: float,
    hint: int,
) -> tuple[float, float, int]:
    """(arc length, distance, segment) of the point of piece ``first..last`` nearest (x, y)
    among the segments overlapping [s_lo, s_hi]; past the piece's end, the straight line on
    along the direction of travel ``g`` counts as path."""
    j = min(max(hint, first), last - 1)
    while j > first and s[j] > s_lo:
        j -= 1
    best_s = s[j]
    best_d = math.inf
    best_j = j
    while j < last and s[j] <= s_hi:
        ax, ay = px[j], py[j]
        dx, dy = px[j + 1] - ax, py[j + 1] - ay
        l2 = dx * dx + dy * dy
        u = ((x - ax) * dx + (y - ay) * dy) / l2
        u = min(max(u, 0.0), 1.0)
        ex, ey = ax + u * dx - x, ay + u * dy - y
        d = math.sqrt(ex * ex + ey * ey)
        if d < best_d:
            best_d, best_s, best_j = d, s[j] + u * (s[j + 1] - s[j]), j
        j += 1
    if best_j == last - 1 and best_s >= s[last]:
        mx, my = g * math.cos(yaw[last]), g * math.sin(yaw[last])
        rx, ry = x - px[last], y - py[last]
        ahead = rx * mx + ry * my
        if ahead > 0.0:
            best_s = s[last] + ahead
            best_d = abs(rx * my - ry * mx)
    return best_s, best_d, best_j


@numba.njit(cache=True, nogil=True)
def _pose_at(
    px: NDArray[np.float64],
    py: NDArray[np.float64],
    yaw: NDArray[np.float64],
    s: NDArray[np.float64],
    last: int,
    g: int,
    k_end: float,
    sq: float,
    hint: int,
) -> tuple[float, float, float]:
    """(x, y, yaw) of the piece ending at ``last`` at arc length ``sq`` (>= s[hint]); past the
    end, on the arc of curvature ``k_end`` driven on in gear ``g``."""
    if sq >= s[last]:
        sigma = g * (sq - s[last])
        th0 = yaw[last]
        th1 = th0 + k_end * sigma
        if abs(k_end * sigma) < 1e-9:
            return px[last] + sigma * math.cos(th0), py[last] + sigma * math.sin(th0), th1
        return (
            px[last] + (math.sin(th1) - math.sin(th0)) / k_end,
            py[last] - (math.cos(th1) - math.cos(th0)) / k_end,
            th1,
        )
    j = hint
    while j < last - 1 and s[j + 1] <= sq:
        j += 1
    u = (sq - s[j]) / (s[j + 1] - s[j])
    u = min(max(u, 0.0), 1.0)
    return (
        px[j] + u * (px[j + 1] - px[j]),
        py[j] + u * (py[j + 1] - py[j]),
        yaw[j] + u * (yaw[j + 1] - yaw[j]),
    )


@numba.njit(cache=True, nogil=True)
def _curvature_at(
    s: NDArray[np.float64],
    kap: NDArray[np.float64],
    last: int,
    k_end: float,
    sq: float,
    hint: int,
) -> float:
    """The path's curvature at arc length ``sq`` (>= s[hint]) of the piece ending at
    ``last``; ``k_end`` past its end."""
    if sq >= s[last]:
        return k_end
    j = hint
    while j < last - 1 and s[j + 1] <= sq:
        j += 1
    return kap[j]


@numba.njit(cache=True, nogil=True)
def _pursuit_curvature(x: float, y: float, th: float, g: int, tx: float, ty: float) -> float:
    """Signed curvature (``tan(delta) / L``) of the circle from pose (x, y, th), driven in gear
    ``g``, through the point (tx, ty): ``g 2 sin(alpha) / d`` with ``alpha`` the bearing of
    the point from the direction of travel and ``d`` its distance."""
    dx, dy = tx - x, ty - y
    d2 = dx * dx + dy * dy
    if d2 < 1e-18:
        return 0.0
    hx, hy = g * math.cos(th), g * math.sin(th)
    return g * 2.0 * (hx * dy - hy * dx) / d2


@numba.njit(cache=True, nogil=True)
def _reference(
    s: NDArray[np.float64],
    t: NDArray[np.float64],
    speed: NDArray[np.float64],
    last: int,
    tq: float,
    hint: int,
) -> tuple[float, float, int]:
    """(arc length, speed, knot) of the profile at time ``tq`` (>= t[hint]), clamped to the
    knot ``last``."""
    if tq >= t[last]:
        return s[last], 0.0, last
    k = hint
    while k < last - 1 and t[k + 1] <= tq:
        k += 1
    ds = s[k + 1] - s[k]
    acc = (speed[k + 1] ** 2 - speed[k] ** 2) / (2.0 * ds)
    tau = tq - t[k]
    dist = min(max(speed[k] * tau + 0.5 * acc * tau * tau, 0.0), ds)
    return s[k] + dist, max(speed[k] + acc * tau, 0.0), k


@numba.njit(cache=True, nogil=True)
def _follow(
    px: NDArray[np.float64],
    py: NDArray[np.float64],
    yaw: NDArray[np.float64],
    s: NDArray[np.float64],
    t: NDArray[np.float64],
    speed: NDArray[np.float64],
    gear: NDArray[np.int64],
    kap: NDArray[np.float64],
    first: NDArray[np.int64],
    last: NDArray[np.int64],
    wheelbase: float,
    steer_max: float,
    steer_rate: float,
    accel: float,
    v_forward: float,
    v_reverse: float,
    lat_accel: float,
    yaw_rate: float,
    dt: float,
    look_min: float,
    look_gain: float,
    progress_gain: float,
    creep: float,
    tol: float,
    t_limit: float,
    steer0: float,
    out_states: NDArray[np.float64],
    out_cross: NDArray[np.float64],
    out_steer: NDArray[np.float64],
    out_gear: NDArray[np.int8],
    out_switch: NDArray[np.int64],
) -> tuple[int, bool, float, int]:
    """The simulation loop of :func:`simulate_bicycle`; fills the ``out_*`` rows and returns
    (rows, reached the goal, time it did, gear changes)."""
    n_pieces = len(first)
    piece = 0
    i0, i1 = first[0], last[0]
    g = gear[i0]
    x, y, th = px[i0], py[i0], yaw[i0]
    v = 0.0
    delta = steer0
    s_rob = s[i0]
    seg = i0
    ref_k = i0
    t_piece = 0.0
    n_switch = 0
    window = max(1.0, 3.0 * look_min)
    n_max = len(out_cross)
    n = 0
    while n < n_max:
        t_now = n * dt
        s_rob, err, seg = _project(
            px, py, yaw, s, i0, i1, g, x, y, s_rob - 0.1, s_rob + window, seg
        )
        d_end = math.hypot(x - px[i1], y - py[i1])
        remaining = s[i1] - s_rob
        while v == 0.0 and d_end <= tol and remaining <= tol and piece < n_pieces - 1:
            piece += 1
            n_switch += 1
            out_switch[n_switch] = n
            i0, i1 = first[piece], last[piece]
            g = gear[i0]
            seg, ref_k, t_piece = i0, i0, t_now
            s_rob, err, seg = _project(
                px, py, yaw, s, i0, i1, g, x, y, s[i0] - 0.1, s[i0] + window, i0
            )
            d_end = math.hypot(x - px[i1], y - py[i1])
            remaining = s[i1] - s_rob
        out_states[n, 0] = t_now
        out_states[n, 1] = x
        out_states[n, 2] = y
        out_states[n, 3] = th - 2.0 * math.pi * math.floor((th + math.pi) / (2.0 * math.pi))
        out_states[n, 4] = v
        out_cross[n] = err
        out_gear[n] = g
        out_steer[n] = delta
        n += 1
        if piece == n_pieces - 1 and v == 0.0 and d_end <= tol and remaining <= tol:
            return n, True, t_now, n_switch
        if t_now > t_limit:
            return n, False, 0.0, n_switch

        # Steering: the path's curvature plus the pure-pursuit correction (see the docstring
        # of simulate_bicycle).
        look = max(look_min, look_gain * abs(v))
        k_end = kap[i1 - 1]
        tx, ty, _ = _pose_at(px, py, yaw, s, i1, g, k_end, s_rob + look, seg)
        qx, qy, qth = _pose_at(px, py, yaw, s, i1, g, k_end, s_rob, seg)
        k_path = _curvature_at(s, kap, i1, k_end, s_rob, seg)
        if steer_rate < math.inf:
            # Slow wheels turn early, so that they pass the middle of a curvature change
            # where the path does.
            k_look = _curvature_at(s, kap, i1, k_end, s_rob + look, seg)
            turn = abs(math.atan(wheelbase * k_look) - delta) / steer_rate
            k_path = _curvature_at(s, kap, i1, k_end, s_rob + min(0.5 * abs(v) * turn, look), seg)
        kappa = (
            k_path
            + _pursuit_curvature(x, y, th, g, tx, ty)
            - _pursuit_curvature(qx, qy, qth, g, tx, ty)
        )
        delta_des = min(max(math.atan(wheelbase * kappa), -steer_max), steer_max)
        step = steer_rate * dt
        lag = abs(delta_des - delta)
        delta = min(max(delta_des, delta - step), delta + step)
        k_cmd = math.tan(delta) / wheelbase

        s_ref, v_ref, ref_k = _reference(s, t, speed, i1, t_now - t_piece + t[i0], ref_k)
        v_des = v_ref + progress_gain * (s_ref - s_rob)
        if v_ref == 0.0 and s_ref >= s[i1]:
            v_des = max(v_des, creep)
        # The fastest speed for the next step from which braking at max_accel (exactly
        # integrated at the mean speed of each step) still stops within the piece:
        # v'²/(2a) + (v + v') dt / 2 <= remaining.
        b = accel * dt
        disc = b * b - 4.0 * (b * abs(v) - 2.0 * accel * max(remaining, 0.0))
        v_des = min(v_des, 0.5 * (math.sqrt(disc) - b) if disc > 0.0 else 0.0)
        at_end = remaining <= _AT_END_M
        if at_end or (d_end <= 0.5 * tol and remaining <= tol):
            v_des = 0.0
        if v == 0.0 and at_end and d_end > tol:
            return n, False, 0.0, n_switch
        cap = v_forward if g > 0 else v_reverse
        if lag > step:
            # Slow wheels: cover at most look_min while they turn to the commanded angle.
            cap = min(cap, look_min * steer_rate / lag)
        if k_cmd != 0.0:
            cap = min(cap, math.sqrt(lat_accel / abs(k_cmd)), yaw_rate / abs(k_cmd))
        v_des = min(max(v_des, 0.0), cap)
        sp = abs(v)
        if sp == 0.0 and delta != delta_des:
            # At rest (a start or a cusp) the wheels turn before the car pulls off.
            v_des = 0.0
        sp_new = max(min(max(v_des, sp - accel * dt), sp + accel * dt), 0.0)
        out_states[n - 1, 5] = v * k_cmd
        out_steer[n - 1] = delta

        # Exact arc of the rear axle over the step: mean speed, steering held.
        v_new = g * sp_new
        w = 0.5 * (v + v_new) * k_cmd
        a = 0.5 * w * dt
        chord = 0.5 * (v + v_new) * dt * (math.sin(a) / a if a != 0.0 else 1.0)
        x += chord * math.cos(th + a)
        y += chord * math.sin(th + a)
        th += w * dt
        v = v_new
    return n, False, 0.0, n_switch
