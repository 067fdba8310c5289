"""Simulate a unicycle robot following a planned path with pure pursuit, replanning around
dynamic obstacles.

Controller, every ``dt_s``:

- progress ``s`` = the nearest point of the path (searched near the last one);
- speed command = the reference speed at the current time plus ``progress_gain`` times how far
  the robot lags the reference's position, within [0, max_speed];
- pure pursuit: aim at the path point ``lookahead = max(lookahead_min_m, lookahead_gain_s * v)``
  ahead; curvature ``2 sin(alpha) / lookahead``; if the speed would need more than the maximum
  yaw rate, the speed is lowered instead; when the aim point lies more than
  ``rotate_threshold_rad`` off the heading, the robot brakes and turns in place;
- speed changes at most ``max_accel * dt`` per step, ``|omega| <= max_yaw_rate``.

Dynamic obstacles: each step the path from the robot's progress to ``detect_range_m`` ahead is
checked against the obstacles present, each grown by the robot radius. A hit triggers a replan
from the robot's position with the present obstacles blocked. When no path exists the robot
stops and waits until the set of present obstacles changes, then tries again; when nothing can
change any more (every blocking obstacle stays for ever), it is a :class:`NoPathError` naming
the obstacle.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import NoPathError
from slamcli.planning.obstacles import DynamicObstacle, first_hit
from slamcli.planning.trajectory import Limits, SpeedProfile

ReplanFn = Callable[[NDArray[np.float64], float, Sequence[DynamicObstacle]], SpeedProfile]
"""``replan(xy, v, present_obstacles) -> profile`` from the robot's position to the goal;
raises NoPathError when the obstacles leave no way."""


@dataclass(frozen=True)
class TrackerSettings:
    """Tuning of the simulated controller (see the module docstring)."""

    dt_s: float = 0.02
    lookahead_min_m: float = 0.25
    lookahead_gain_s: float = 1.0
    progress_gain: float = 1.0
    rotate_threshold_rad: float = math.radians(60.0)
    rotate_gain: float = 3.0
    creep_speed: float = 0.05
    goal_tolerance_m: float = 0.05
    detect_range_m: float = 1.5
    timeout_margin_s: float = 30.0


@dataclass
class TrackingResult:
    """What the simulated robot did.

    Attributes:
        states: (K, 6) float64 rows ``t, x, y, theta, v, omega`` (s, m, m, rad, m/s, rad/s).
        cross_track_m: (K,) distance from the robot to the path it was following, m.
        reached_goal: whether it came within the goal tolerance.
        time_to_goal_s: when it did (s), else None.
        replans: replans caused by an obstacle on the path ahead.
        waits: times it stopped because no path led around the obstacles present.
        events: one dict per replan / wait / resume: ``t_s, x, y, kind, obstacle``.
        paths: every path followed, as (start time s, (P, 2) polyline m), the first one included.
    """

    states: NDArray[np.float64]
    cross_track_m: NDArray[np.float64]
    reached_goal: bool
    time_to_goal_s: float | None
    replans: int = 0
    waits: int = 0
    events: list[dict[str, Any]] = field(default_factory=list)
    paths: list[tuple[float, NDArray[np.float64]]] = field(default_factory=list)

    @property
    def cross_track_max_m(self) -> float:
        return float(self.cross_track_m.max()) if len(self.cross_track_m) else 0.0

    @property
    def cross_track_rms_m(self) -> float:
        if not len(self.cross_track_m):
            return 0.0
        return float(np.sqrt(np.mean(self.cross_track_m**2)))


class _Track:
    """One speed profile as plain Python floats, for the per-step work of :func:`simulate`.

    Each method gives, bit for bit, what the profile's vectorised methods give for one value
    (``numpy.interp``, :meth:`SpeedProfile.sample`), without their per-call overhead.
    """

    def __init__(self, profile: SpeedProfile) -> None:
        self.profile = profile
        self.vs: list[float] = profile.vertex_s.tolist()
        self.px: list[float] = profile.points[:, 0].tolist()
        self.py: list[float] = profile.points[:, 1].tolist()
        self.t: list[float] = profile.t.tolist()
        self.s: list[float] = profile.s.tolist()
        self.v: list[float] = profile.v.tolist()
        self.length = self.vs[-1]
        self.duration = self.t[-1]
        self.end = (self.px[-1], self.py[-1])

    def xy_at(self, s: float) -> tuple[float, float]:
        """The path's point at arc length ``s`` (m), clamped to the ends (``numpy.interp``)."""
        vs = self.vs
        if s <= vs[0]:
            return self.px[0], self.py[0]
        if s >= vs[-1]:
            return self.px[-1], self.py[-1]
        j = bisect.bisect_right(vs, s) - 1
        if vs[j] == s:
            return self.px[j], self.py[j]
        span = vs[j + 1] - vs[j]
        ds = s - vs[j]
        x = (self.px[j + 1] - self.px[j]) / span * ds + self.px[j]
        y = (self.py[j + 1] - self.py[j]) / span * ds + self.py[j]
        return x, y

    def reference(self, t: float) -> tuple[float, float]:
        """(arc length m, speed m/s) of the timed reference at time ``t`` (s), clamped to the
        profile's span, as :meth:`SpeedProfile.sample` gives them."""
        ts = self.t
        tq = t if t > 0.0 else 0.0
        tq = tq if tq < self.duration else self.duration
        k = bisect.bisect_right(ts, tq) - 1
        k = len(ts) - 2 if k > len(ts) - 2 else (0 if k < 0 else k)
        s0, s1 = self.s[k], self.s[k + 1]
        if not s1 - s0 > 0:
            return s0, 0.0
        v0 = self.v[k]
        tau = tq - ts[k]
        dt = ts[k + 1] - ts[k]
        acc = (self.v[k + 1] - v0) / (dt if dt > 0 else 1.0)
        s = s0 + v0 * tau + 0.5 * acc * (tau * tau)
        return (s if s < s1 else s1), v0 + acc * tau

    def project(self, x: float, y: float, s_lo: float, s_hi: float) -> tuple[float, float]:
        """(arc length, distance) of the path's point nearest (x, y) with s in [s_lo, s_hi]."""
        vs, px, py = self.vs, self.px, self.py
        last = len(vs) - 1
        i0 = bisect.bisect_right(vs, s_lo) - 1
        i0 = last - 1 if i0 > last - 1 else (0 if i0 < 0 else i0)
        i1 = bisect.bisect_left(vs, s_hi)
        i1 = last if i1 > last else i1
        i1 = i0 + 1 if i1 < i0 + 1 else i1
        best_s, best_d = 0.0, math.inf
        for k in range(i0, i1):
            ax, ay = px[k], py[k]
            dx, dy = px[k + 1] - ax, py[k + 1] - ay
            l2 = dx * dx + dy * dy
            u = ((x - ax) * dx + (y - ay) * dy) / (l2 if l2 > 1e-300 else 1e-300)
            # numpy.clip's order of comparisons, so even the sign of a zero is the same.
            u = u if u > 0.0 else 0.0
            u = u if u < 1.0 else 1.0
            s = vs[k] + u * math.sqrt(l2)
            s = s if s > s_lo else s_lo
            s = s if s < s_hi else s_hi
            nx, ny = self.xy_at(s)
            ex, ey = nx - x, ny - y
            d = math.sqrt(ex * ex + ey * ey)
            if d < best_d:
                best_s, best_d = s, d
        return best_s, best_d


def simulate(
    profile: SpeedProfile,
    limits: Limits,
    *,
    robot_radius_m: float = 0.0,
    obstacles: Sequence[DynamicObstacle] = (),
    replan: ReplanFn | None = None,
    settings: TrackerSettings | None = None,
) -> TrackingResult:
    """Drive a unicycle from the path's start (at rest, facing along the path) to its end.

    The loop works on plain floats (:class:`_Track`, :func:`unicycle_step_scalar`); numpy
    comes in only to check dynamic obstacles and to replan.
    """
    cfg = settings or TrackerSettings()
    dt = cfg.dt_s
    track = _Track(profile)
    goal = track.end
    x, y = (float(c) for c in profile.points[0])
    theta = float(profile.theta[0])
    v = 0.0
    t = 0.0
    t_ref0 = 0.0
    s_robot = 0.0
    waiting: set[int] | None = None  # indices of the obstacles present when the wait began
    blocker: DynamicObstacle | None = None
    states: list[tuple[float, ...]] = []
    errors: list[float] = []
    result = TrackingResult(np.zeros((0, 6)), np.zeros(0), False, None)
    result.paths.append((0.0, profile.points))
    t_limit = profile.duration_s + cfg.timeout_margin_s
    last_change = max(
        [o.appear_s for o in obstacles]
        + [o.vanish_s for o in obstacles if math.isfinite(o.vanish_s)],
        default=0.0,
    )
    window = max(1.0, 3 * cfg.lookahead_min_m)
    two_pi = 2.0 * math.pi
    present_idx: set[int] = set()
    present: list[DynamicObstacle] = []

    def event(kind: str, ob: DynamicObstacle | None) -> None:
        result.events.append(
            {"t_s": round(t, 3), "x": x, "y": y, "kind": kind, "obstacle": ob.name if ob else None}
        )

    while True:
        if obstacles:
            present_idx = {i for i, o in enumerate(obstacles) if o.present(t)}
            present = [obstacles[i] for i in sorted(present_idx)]
        if waiting is not None and present_idx != waiting:
            waiting = None
            try:
                profile = _replan(replan, np.array([x, y]), v, present)
            except NoPathError:
                waiting = present_idx
            else:
                event("resume", blocker)
                track = _Track(profile)
                t_ref0, s_robot = t, 0.0
                result.paths.append((t, profile.points))
                t_limit = t + profile.duration_s + cfg.timeout_margin_s
        if waiting is not None and v == 0.0 and t >= last_change:
            assert blocker is not None
            raise NoPathError(
                f"no path around {blocker.label()}: it never vanishes "
                f"(robot stopped at ({x:.2f}, {y:.2f}) m, t = {t:.1f} s)",
                hint="give the obstacle a vanish_s, or move it off the only way to the goal",
            )

        back = s_robot - 0.1
        s_robot, err = track.project(x, y, 0.0 if back < 0.0 else back, s_robot + window)
        if waiting is None and present and replan is not None:
            ahead = np.linspace(s_robot, min(s_robot + cfg.detect_range_m, track.length), 64)
            hit = first_hit(profile.xy_at_s(ahead), present, robot_radius_m)
            if hit is not None:
                blocker = present[hit[1]]
                try:
                    profile = _replan(replan, np.array([x, y]), v, present)
                except NoPathError:
                    waiting = present_idx
                    result.waits += 1
                    event("wait", blocker)
                else:
                    result.replans += 1
                    event("replan", blocker)
                    track = _Track(profile)
                    t_ref0, s_robot = t, 0.0
                    result.paths.append((t, profile.points))
                    t_limit = t + profile.duration_s + cfg.timeout_margin_s
                    s_robot, err = track.project(x, y, 0.0, 1.0)
                goal = track.end

        errors.append(err)
        if waiting is None and math.hypot(x - goal[0], y - goal[1]) <= cfg.goal_tolerance_m:
            states.append((t, x, y, theta, v, 0.0))
            result.reached_goal = True
            result.time_to_goal_s = t
            break
        if waiting is None and t > t_limit:
            states.append((t, x, y, theta, v, 0.0))
            break

        if waiting is not None:
            v_cmd, omega = _brake(v, limits, dt), 0.0
        else:
            v_cmd, omega = _pursue(track, t - t_ref0, s_robot, x, y, theta, v, limits, cfg)
        states.append((t, x, y, theta, v, omega))
        # Exact unicycle motion over the step at the mean speed and constant omega.
        x, y, theta = unicycle_step_scalar(x, y, theta, 0.5 * (v + v_cmd), omega, dt)
        theta = math.remainder(theta, two_pi)
        v = v_cmd
        t = round(t + dt, 9)

    result.states = np.asarray(states, dtype=np.float64)
    result.cross_track_m = np.asarray(errors, dtype=np.float64)
    return result


def unicycle_step_scalar(
    x: float, y: float, yaw: float, v: float, omega: float, dt: float
) -> tuple[float, float, float]:
    """:func:`slamcli.geometry.planar.unicycle_step` for one pose, on plain floats: the same
    operations in the same order, so the same result bit for bit (m, m, rad)."""
    a = 0.5 * omega * dt
    ratio = math.sin(a) / a if a != 0.0 else 1.0
    chord = v * dt * ratio
    phi = yaw + a
    return x + chord * math.cos(phi), y + chord * math.sin(phi), yaw + omega * dt


def _replan(
    replan: ReplanFn | None,
    xy: NDArray[np.float64],
    v: float,
    present: Sequence[DynamicObstacle],
) -> SpeedProfile:
    if replan is None:
        raise NoPathError("replanning is not available")
    return replan(xy, v, present)


def _brake(v: float, limits: Limits, dt: float) -> float:
    slower = v - limits.max_accel * dt
    return 0.0 if slower < 0.0 else slower


def _clamp(value: float, lo: float, hi: float) -> float:
    """``max(lo, min(hi, value))`` without the calls (the same result, down to a zero's
    sign)."""
    value = value if value < hi else hi
    return value if value > lo else lo


def _clamp_up(value: float, lo: float, hi: float) -> float:
    """``min(max(value, lo), hi)`` without the calls (the same result, down to a zero's
    sign)."""
    value = lo if lo > value else value
    return hi if hi < value else value


def _pursue(
    track: _Track,
    t_ref: float,
    s_robot: float,
    x: float,
    y: float,
    theta: float,
    v: float,
    limits: Limits,
    cfg: TrackerSettings,
) -> tuple[float, float]:
    """(speed, yaw rate) commands for the next step, limits applied."""
    max_speed, max_yaw_rate = limits.max_speed, limits.max_yaw_rate
    s_ref, v_ref = track.reference(t_ref)
    dist_goal = math.hypot(x - track.end[0], y - track.end[1])
    v_des = v_ref + cfg.progress_gain * (s_ref - s_robot)
    if t_ref >= track.duration and cfg.creep_speed > v_des:
        # The reference has arrived; creep in, braking in time for the goal.
        v_des = cfg.creep_speed
    stop = math.sqrt(2 * limits.max_accel * dist_goal)
    v_des = stop if stop < v_des else v_des
    v_des = max_speed if max_speed < v_des else v_des
    v_des = 0.0 if v_des < 0.0 else v_des

    look = cfg.lookahead_gain_s * v
    look = look if look > cfg.lookahead_min_m else cfg.lookahead_min_m
    aim = s_robot + look
    tx, ty = track.xy_at(track.length if track.length < aim else aim)
    dx, dy = tx - x, ty - y
    if math.hypot(dx, dy) < 1e-9:
        alpha = 0.0
    else:
        alpha = math.atan2(dy, dx) - theta
        alpha = math.atan2(math.sin(alpha), math.cos(alpha))
    if abs(alpha) > cfg.rotate_threshold_rad:
        omega = _clamp(cfg.rotate_gain * alpha, -max_yaw_rate, max_yaw_rate)
        return _brake(v, limits, cfg.dt_s), omega
    reach = math.hypot(dx, dy)
    reach = reach if reach > 1e-9 else 1e-9
    curvature = 2.0 * math.sin(alpha) / reach
    if abs(curvature) * v_des > max_yaw_rate:
        v_des = max_yaw_rate / abs(curvature)
    step = limits.max_accel * cfg.dt_s
    v_new = _clamp_up(v_des, v - step, v + step)
    v_new = _clamp_up(v_new, 0.0, max_speed)
    omega = _clamp(curvature * v_new, -max_yaw_rate, max_yaw_rate)
    return v_new, omega
