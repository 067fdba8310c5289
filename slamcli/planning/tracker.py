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

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import NoPathError
from slamcli.geometry.planar import unicycle_step
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


def project(
    profile: SpeedProfile, xy: NDArray[np.float64], s_lo: float, s_hi: float
) -> tuple[float, float]:
    """(arc length, distance) of the point of the path nearest ``xy`` with s in [s_lo, s_hi]."""
    vs = profile.vertex_s
    i0 = min(max(int(np.searchsorted(vs, s_lo, side="right")) - 1, 0), len(vs) - 2)
    i1 = min(int(np.searchsorted(vs, s_hi, side="left")), len(vs) - 1)
    i1 = max(i1, i0 + 1)
    a = profile.points[i0:i1]
    b = profile.points[i0 + 1 : i1 + 1]
    d = b - a
    l2 = (d**2).sum(axis=1)
    u = np.clip(((xy - a) * d).sum(axis=1) / np.maximum(l2, 1e-300), 0.0, 1.0)
    s = vs[i0:i1] + u * np.sqrt(l2)
    s = np.clip(s, s_lo, s_hi)
    near = profile.xy_at_s(s)
    dist = np.linalg.norm(near - xy, axis=1)
    k = int(np.argmin(dist))
    return float(s[k]), float(dist[k])


def simulate(
    profile: SpeedProfile,
    limits: Limits,
    *,
    robot_radius_m: float = 0.0,
    obstacles: Sequence[DynamicObstacle] = (),
    replan: ReplanFn | None = None,
    settings: TrackerSettings | None = None,
) -> TrackingResult:
    """Drive a unicycle from the path's start (at rest, facing along the path) to its end."""
    cfg = settings or TrackerSettings()
    dt = cfg.dt_s
    goal = profile.points[-1].copy()
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

    def event(kind: str, ob: DynamicObstacle | None) -> None:
        result.events.append(
            {"t_s": round(t, 3), "x": x, "y": y, "kind": kind, "obstacle": ob.name if ob else None}
        )

    while True:
        present_idx = {i for i, o in enumerate(obstacles) if o.present(t)}
        present = [obstacles[i] for i in sorted(present_idx)]
        xy = np.array([x, y])
        if waiting is not None and present_idx != waiting:
            waiting = None
            try:
                profile = _replan(replan, xy, v, present)
            except NoPathError:
                waiting = present_idx
            else:
                event("resume", blocker)
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

        s_robot, err = project(
            profile, xy, max(s_robot - 0.1, 0.0), s_robot + max(1.0, 3 * cfg.lookahead_min_m)
        )
        if waiting is None and present and replan is not None:
            ahead = np.linspace(s_robot, min(s_robot + cfg.detect_range_m, profile.length_m), 64)
            hit = first_hit(profile.xy_at_s(ahead), present, robot_radius_m)
            if hit is not None:
                blocker = present[hit[1]]
                try:
                    profile = _replan(replan, xy, v, present)
                except NoPathError:
                    waiting = present_idx
                    result.waits += 1
                    event("wait", blocker)
                else:
                    result.replans += 1
                    event("replan", blocker)
                    t_ref0, s_robot = t, 0.0
                    result.paths.append((t, profile.points))
                    t_limit = t + profile.duration_s + cfg.timeout_margin_s
                    s_robot, err = project(profile, xy, 0.0, 1.0)
                goal = profile.points[-1].copy()

        states.append((t, x, y, theta, v, 0.0))
        errors.append(err)
        if waiting is None and math.hypot(x - goal[0], y - goal[1]) <= cfg.goal_tolerance_m:
            result.reached_goal = True
            result.time_to_goal_s = t
            break
        if waiting is None and t > t_limit:
            break

        if waiting is not None:
            v_cmd, omega = _brake(v, limits, dt), 0.0
        else:
            v_cmd, omega = _pursue(profile, t - t_ref0, s_robot, x, y, theta, v, limits, cfg)
        states[-1] = (*states[-1][:5], omega)
        # Exact unicycle motion over the step at the mean speed and constant omega.
        nx, ny, nth = unicycle_step(x, y, theta, 0.5 * (v + v_cmd), omega, dt)
        x, y, theta = float(nx), float(ny), math.remainder(float(nth), 2.0 * math.pi)
        v = v_cmd
        t = round(t + dt, 9)

    result.states = np.asarray(states, dtype=np.float64)
    result.cross_track_m = np.asarray(errors, dtype=np.float64)
    return result


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
    return max(v - limits.max_accel * dt, 0.0)


def _pursue(
    profile: SpeedProfile,
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
    ref = profile.sample(np.array([t_ref]))[0]
    s_ref, v_ref = float(ref[6]), float(ref[4])
    length = profile.length_m
    dist_goal = math.hypot(x - profile.points[-1, 0], y - profile.points[-1, 1])
    v_des = v_ref + cfg.progress_gain * (s_ref - s_robot)
    if t_ref >= profile.duration_s:
        # The reference has arrived; creep in, braking in time for the goal.
        v_des = max(v_des, cfg.creep_speed)
    v_des = min(v_des, math.sqrt(2 * limits.max_accel * dist_goal), limits.max_speed)
    v_des = max(v_des, 0.0)

    look = max(cfg.lookahead_min_m, cfg.lookahead_gain_s * v)
    target = profile.xy_at_s(min(s_robot + look, length))
    dx, dy = float(target[0]) - x, float(target[1]) - y
    if math.hypot(dx, dy) < 1e-9:
        alpha = 0.0
    else:
        alpha = math.atan2(dy, dx) - theta
        alpha = math.atan2(math.sin(alpha), math.cos(alpha))
    if abs(alpha) > cfg.rotate_threshold_rad:
        omega = max(-limits.max_yaw_rate, min(limits.max_yaw_rate, cfg.rotate_gain * alpha))
        return _brake(v, limits, cfg.dt_s), omega
    reach = max(math.hypot(dx, dy), 1e-9)
    curvature = 2.0 * math.sin(alpha) / reach
    if abs(curvature) * v_des > limits.max_yaw_rate:
        v_des = limits.max_yaw_rate / abs(curvature)
    step = limits.max_accel * cfg.dt_s
    v_new = min(max(v_des, v - step), v + step)
    v_new = min(max(v_new, 0.0), limits.max_speed)
    omega = curvature * v_new
    omega = max(-limits.max_yaw_rate, min(limits.max_yaw_rate, omega))
    return v_new, omega
