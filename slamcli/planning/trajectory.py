"""Time-parameterise a polyline for a differential-drive robot.

Model: the robot drives along the polyline; its heading blends linearly (in arc length) from
one segment's direction at the segment's midpoint to the next segment's direction at that
one's midpoint, so ``omega = v * dtheta/ds``. A corner sharper than ``sharp_turn_rad`` is taken
by stopping on it and turning in place at the maximum yaw rate. The speed profile is the usual
forward-backward pass: ``v <= max_speed``, ``|omega| <= max_yaw_rate`` (``v <= max_yaw_rate /
|dtheta/ds|``), and ``|dv/dt| <= max_accel`` along the path (v² is linear in arc length
between knots, so the acceleration is constant there). It starts at ``v0`` (0 by default) and
ends at rest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slamcli.config import check_settings, setting
from slamcli.planning.costmap import check_nonnegative, check_positive

SHARP_TURN_RAD = math.radians(60.0)
"""Corners turning more than this are taken by stopping and turning in place."""


@dataclass(frozen=True)
class Limits:
    """Kinematic limits of the robot along a path.

    Attributes:
        max_speed: the fastest the robot drives, m/s.
        max_yaw_rate: the fastest it turns, rad/s.
        max_accel: the largest speed change per second along the path, m/s².
    """

    max_speed: float = setting(0.5, unit="m/s", gt=0.0)
    max_yaw_rate: float = setting(1.0, unit="rad/s", gt=0.0)
    max_accel: float = setting(0.5, unit="m/s²", gt=0.0)

    def checked(self) -> Limits:
        """These limits, or a ConfigError naming the bad option."""
        return check_settings(self, _LIMIT_OPTIONS)


_LIMIT_OPTIONS = {
    "max_speed": "--max-speed",
    "max_yaw_rate": "--max-yaw-rate",
    "max_accel": "--max-accel",
}
"""The ``slamcli plan`` option that sets each of :class:`Limits`' fields."""


@dataclass(frozen=True)
class SpeedProfile:
    """Knots along a polyline with heading, speed and time; between knots:

    - a *move* (``s`` grows): heading linear in ``s``, ``v²`` linear in ``s``;
    - a *turn* (same ``s``): ``v = 0``, heading changes at the maximum yaw rate.

    Attributes:
        points: (P, 2) float64 polyline vertices, metres.
        vertex_s: (P,) arc length of each vertex, metres.
        s: (N,) arc length of each knot (non-decreasing), metres.
        theta: (N,) heading at each knot, radians (unwrapped).
        v: (N,) speed at each knot, m/s.
        t: (N,) time at each knot, s.
        max_yaw_rate: the yaw rate used for turns, rad/s.
    """

    points: NDArray[np.float64]
    vertex_s: NDArray[np.float64]
    s: NDArray[np.float64]
    theta: NDArray[np.float64]
    v: NDArray[np.float64]
    t: NDArray[np.float64]
    max_yaw_rate: float

    @property
    def duration_s(self) -> float:
        return float(self.t[-1])

    @property
    def length_m(self) -> float:
        return float(self.vertex_s[-1])

    def xy_at_s(self, s: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """(…, 2) positions on the polyline at arc lengths ``s`` (clamped to the ends)."""
        s = np.asarray(s, dtype=np.float64)
        return np.stack(
            (
                np.interp(s, self.vertex_s, self.points[:, 0]),
                np.interp(s, self.vertex_s, self.points[:, 1]),
            ),
            axis=-1,
        )

    def sample(self, times: NDArray[np.float64]) -> NDArray[np.float64]:
        """(K, 7) rows ``t, x, y, theta, v, omega, s`` at the given times (clamped to the ends).

        ``theta`` is wrapped to (-pi, pi].
        """
        tq = np.clip(np.asarray(times, dtype=np.float64), 0.0, self.t[-1])
        k = np.clip(np.searchsorted(self.t, tq, side="right") - 1, 0, len(self.t) - 2)
        t0, t1 = self.t[k], self.t[k + 1]
        s0, s1 = self.s[k], self.s[k + 1]
        v0, v1 = self.v[k], self.v[k + 1]
        th0, th1 = self.theta[k], self.theta[k + 1]
        tau = tq - t0
        dt = t1 - t0
        ds = s1 - s0
        move = ds > 0
        safe_dt = np.where(dt > 0, dt, 1.0)
        acc = np.where(move, (v1 - v0) / safe_dt, 0.0)
        v = np.where(move, v0 + acc * tau, 0.0)
        s = np.where(move, s0 + v0 * tau + 0.5 * acc * tau**2, s0)
        s = np.minimum(s, s1)
        slope = np.where(move, (th1 - th0) / np.where(move, ds, 1.0), 0.0)
        turn_rate = np.where(dt > 0, (th1 - th0) / safe_dt, 0.0)
        theta = np.where(move, th0 + slope * (s - s0), th0 + turn_rate * tau)
        omega = np.where(move, slope * v, turn_rate)
        xy = self.xy_at_s(s)
        wrapped = np.angle(np.exp(1j * theta))
        return np.column_stack((tq, xy, wrapped, v, omega, s))

    def sample_every(self, dt_s: float) -> NDArray[np.float64]:
        """:meth:`sample` at 0, dt, 2 dt, … and at the end time."""
        n = math.floor(self.t[-1] / dt_s + 1e-9)
        times = np.arange(n + 1) * dt_s
        if self.t[-1] - times[-1] > 1e-9:
            times = np.append(times, self.t[-1])
        return self.sample(times)


def time_parameterise(
    points: NDArray[np.float64],
    limits: Limits,
    *,
    v0: float = 0.0,
    step_m: float = 0.025,
    sharp_turn_rad: float = SHARP_TURN_RAD,
) -> SpeedProfile:
    """Speed profile along ``points`` (P, 2) metres under ``limits``; see the module docstring.

    ``step_m`` is the knot spacing (every segment gets an even number of knots, so its
    midpoint is one).
    """
    limits.checked()
    check_positive("step_m", step_m)
    check_nonnegative("v0", v0)
    pts = _drop_repeats(np.asarray(points, dtype=np.float64))
    seg = np.diff(pts, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    vertex_s = np.concatenate(([0.0], np.cumsum(seg_len)))
    if len(pts) < 2:
        zero = np.zeros(2)
        return SpeedProfile(pts[:1].repeat(2, 0), zero, zero, zero, zero, zero, limits.max_yaw_rate)
    phi = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
    turn = np.diff(phi)
    sharp = np.abs(turn) > sharp_turn_rad

    s_list: list[NDArray[np.float64]] = []
    th_list: list[NDArray[np.float64]] = []
    for i, length in enumerate(seg_len):
        n = max(2, 2 * math.ceil(length / (2 * step_m)))
        local = np.linspace(0.0, length, n + 1)
        half = local <= length / 2
        theta = np.full(n + 1, phi[i])
        # First half: blend from the previous segment's heading (met at its midpoint).
        if i > 0 and not sharp[i - 1]:
            span = (seg_len[i - 1] + length) / 2
            theta[half] = (
                phi[i - 1] + (phi[i] - phi[i - 1]) * (local[half] + seg_len[i - 1] / 2) / span
            )
        if i < len(seg_len) - 1 and not sharp[i]:
            span = (length + seg_len[i + 1]) / 2
            rest = ~half
            theta[rest] = phi[i] + (phi[i + 1] - phi[i]) * (local[rest] - length / 2) / span
        if i > 0 and not sharp[i - 1]:
            local, theta = local[1:], theta[1:]  # the vertex knot is already there
        s_list.append(vertex_s[i] + local)
        th_list.append(theta)
    s = np.concatenate(s_list)
    theta = np.concatenate(th_list)

    ds = np.diff(s)
    move = ds > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        curv = np.where(move, np.abs(np.diff(theta)) / np.where(move, ds, 1.0), np.inf)
        cap_iv = np.minimum(limits.max_speed, limits.max_yaw_rate / curv)
    cap_iv = np.where(move, cap_iv, 0.0)
    cap = np.minimum(np.concatenate(([np.inf], cap_iv)), np.concatenate((cap_iv, [np.inf])))
    v = _forward_backward(cap, ds, limits.max_accel, min(v0, limits.max_speed))

    dt = np.empty_like(ds)
    speed_sum = v[:-1] + v[1:]
    dt[move] = 2 * ds[move] / np.maximum(speed_sum[move], 1e-12)
    dt[~move] = np.abs(np.diff(theta)[~move]) / limits.max_yaw_rate
    t = np.concatenate(([0.0], np.cumsum(dt)))
    return SpeedProfile(pts, vertex_s, s, theta, v, t, limits.max_yaw_rate)


def _forward_backward(
    cap: NDArray[np.float64], ds: NDArray[np.float64], accel: float, v0: float
) -> NDArray[np.float64]:
    """Largest speeds under ``cap`` reachable from ``v0`` and stopping at the end."""
    v = cap.copy()
    v[0] = min(v[0], v0)
    v[-1] = 0.0
    two_a_ds = 2 * accel * ds
    for k in range(len(ds)):
        v[k + 1] = min(v[k + 1], math.sqrt(v[k] * v[k] + two_a_ds[k]))
    for k in range(len(ds) - 1, -1, -1):
        v[k] = min(v[k], math.sqrt(v[k + 1] * v[k + 1] + two_a_ds[k]))
    return v


def _drop_repeats(points: NDArray[np.float64]) -> NDArray[np.float64]:
    if len(points) < 2:
        return points
    keep = np.concatenate(([True], np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-12))
    return points[keep]
