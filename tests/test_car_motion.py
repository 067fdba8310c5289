"""Speed profiles with gear changes and the bicycle-model follower, on car paths built
analytically here (straight lines and arcs driven forwards or backwards)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slamcli.errors import ConfigError, InputError
from slamcli.planning.car_motion import (
    CarLimits,
    CarProfile,
    simulate_bicycle,
    time_parameterise_car,
)
from slamcli.planning.tracker import TrackerSettings

LIMITS = CarLimits(
    max_speed=1.0,
    max_reverse_speed=0.5,
    max_accel=0.5,
    max_lateral_accel=0.5,
    max_yaw_rate=0.6,
    wheelbase_m=0.5,
    min_turn_radius_m=1.0,
)
"""Chosen so that different limits bind: the top speed on straights and wide arcs, the yaw
rate on arcs of radius 1 m (0.6 < sqrt(0.5)), the lateral acceleration at 1.5 m."""

SPACING_M = 0.05

Part = tuple[float, float, int]
"""(length m, curvature 1/m, gear +1/-1) of a constant-curvature part of a path."""


def drive(
    parts: list[Part], start: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
    """Poses at most SPACING_M apart along ``parts`` (exact arcs), with the gear and curvature
    of the motion leaving each pose, and the position of every gear change."""
    x, y, th = start
    poses = [(x, y, th)]
    gears: list[int] = []
    curv: list[float] = []
    cusps = []
    for i, (length, k, g) in enumerate(parts):
        if i and g != parts[i - 1][2]:
            cusps.append(np.array([x, y]))
        n = max(1, math.ceil(length / SPACING_M))
        x0, y0, t0 = x, y, th
        for j in range(1, n + 1):
            sigma = g * length * j / n
            if k == 0.0:
                x, y, th = x0 + sigma * math.cos(t0), y0 + sigma * math.sin(t0), t0
            else:
                th = t0 + k * sigma
                x = x0 + (math.sin(th) - math.sin(t0)) / k
                y = y0 - (math.cos(th) - math.cos(t0)) / k
            poses.append((x, y, th))
            gears.append(g)
            curv.append(k)
    gears.append(gears[-1])
    curv.append(curv[-1])
    return np.array(poses), np.array(gears, dtype=np.int8), np.array(curv), cusps


PATHS: dict[str, list[Part]] = {
    "straight": [(8.0, 0.0, 1)],
    "arc_wide": [(0.75 * 2 * math.pi * 2.5, 1 / 2.5, 1)],
    "arc_tight": [(math.pi * 1.0, -1.0, 1)],
    "s_curve": [(2.0, 0.0, 1), (2.0, 1 / 1.5, 1), (2.0, -1 / 1.5, 1), (2.0, 0.0, 1)],
    "reversal": [(math.pi, 0.5, 1), (3.0, 0.0, -1)],
    "three_point": [(2.0, 0.0, 1), (1.5, 1.0, 1), (2.0, -1.0, -1), (2.5, 0.0, 1)],
}


@pytest.fixture(scope="module")
def profiles() -> dict[str, CarProfile]:
    return {name: time_parameterise_car(*drive(parts)[:3], LIMITS) for name, parts in PATHS.items()}


@pytest.mark.parametrize("name", PATHS)
def test_profile_respects_every_limit(profiles: dict[str, CarProfile], name: str) -> None:
    """Checked on the sampled trajectory: speed per gear, acceleration, lateral acceleration
    and yaw rate, from the reported omega and from finite differences of the heading."""
    rows = profiles[name].sample_every(0.005)
    t, theta, v, omega = rows[:, 0], np.unwrap(rows[:, 3]), rows[:, 4], rows[:, 5]
    eps = 1e-9
    assert v.max() <= LIMITS.max_speed + eps
    assert -v.min() <= 0.5 + eps
    dt = np.diff(t)
    assert np.all(np.abs(np.diff(v)) / dt <= LIMITS.max_accel * (1 + 1e-6))
    assert np.all(np.abs(omega) <= LIMITS.max_yaw_rate + eps)
    assert np.all(np.abs(v * omega) <= LIMITS.max_lateral_accel + eps)
    # The heading's finite differences: a chord turns by slightly more per metre than the arc.
    yaw_rate = np.diff(theta) / dt
    v_mid = np.abs(v[1:] + v[:-1]) / 2
    assert np.all(np.abs(yaw_rate) <= LIMITS.max_yaw_rate * (1 + 1e-3))
    assert np.all(v_mid * np.abs(yaw_rate) <= LIMITS.max_lateral_accel * (1 + 1e-3))


@pytest.mark.parametrize("name", PATHS)
def test_profile_distance_and_duration(profiles: dict[str, CarProfile], name: str) -> None:
    """The speed integrated over the sampled time covers the path, and the duration equals
    the integral of ds / |v| along it (v² linear in s between knots, midpoint rule)."""
    prof = profiles[name]
    poses = drive(PATHS[name])[0]
    length = float(np.hypot(*np.diff(poses[:, :2], axis=0).T).sum())
    assert prof.length_m == pytest.approx(length, rel=1e-12)
    rows = prof.sample_every(0.002)
    assert np.trapezoid(np.abs(rows[:, 4]), rows[:, 0]) == pytest.approx(length, rel=1e-4)

    sub = (np.arange(400) + 0.5) / 400
    sp = np.abs(prof.v)
    v2 = sp[:-1, None] ** 2 + sub[None, :] * (sp[1:, None] ** 2 - sp[:-1, None] ** 2)
    ds = np.diff(prof.s)[:, None] / 400
    integral = float((ds / np.sqrt(v2)).sum())
    assert prof.duration_s == pytest.approx(integral, rel=3e-3)


@pytest.mark.parametrize(
    ("parts", "top"),
    [
        (PATHS["straight"], 1.0),
        (PATHS["arc_wide"], 1.0),
        (PATHS["arc_tight"], 0.6),  # yaw rate: 0.6 rad/s * 1 m
        ([(3.0, 1 / 1.5, 1)], math.sqrt(0.5 * 1.5)),  # lateral acceleration
        ([(3.0, 0.0, -1)], 0.5),  # reverse top speed
    ],
)
def test_profile_is_as_fast_as_the_limits_allow(parts: list[Part], top: float) -> None:
    """On a constant-curvature piece the fastest motion from rest to rest is accelerate,
    cruise at the top speed the limits allow, brake: the profile takes no less time, and at
    most about one segment more per speed change."""
    poses, gear, curv, _ = drive(parts)
    prof = time_parameterise_car(poses, gear, curv, LIMITS)
    length, a = prof.length_m, LIMITS.max_accel
    assert length > top**2 / a
    best = length / top + top / a
    assert best - 1e-9 <= prof.duration_s <= best + 2 * SPACING_M / top
    assert np.abs(prof.v).max() == pytest.approx(top, rel=1e-9)
    assert np.all(np.sign(prof.v[1:-1]) == parts[0][2])


@pytest.mark.parametrize("name", ["reversal", "three_point"])
def test_profile_stops_at_every_cusp(profiles: dict[str, CarProfile], name: str) -> None:
    prof = profiles[name]
    cusps = drive(PATHS[name])[3]
    assert prof.reversals == len(cusps)
    np.testing.assert_allclose(prof.xy[prof.cusps], cusps, atol=1e-12)
    assert prof.v[0] == 0.0 and prof.v[-1] == 0.0
    assert np.all(prof.v[prof.cusps] == 0.0)
    moving = np.ones(len(prof.v), dtype=bool)
    moving[prof.piece_bounds] = False
    assert np.all(np.abs(prof.v[moving]) > 0)
    assert np.all(np.sign(prof.v[moving]) == prof.direction[moving])
    # Sampled: the speed passes through zero at each cusp time, and changes sign only there.
    rows = prof.sample(prof.t[prof.cusps])
    np.testing.assert_array_equal(rows[:, 4], 0.0)
    np.testing.assert_allclose(rows[:, 1:3], cusps, atol=1e-9)
    v = prof.sample_every(0.01)[:, 4]
    signs = np.sign(v[v != 0.0])
    assert np.count_nonzero(np.diff(signs)) == len(cusps)


def test_sample_every_spans_the_profile(profiles: dict[str, CarProfile]) -> None:
    prof = profiles["reversal"]
    rows = prof.sample_every(0.1)
    assert rows.shape[1] == 6
    assert rows[0, 0] == 0.0 and rows[-1, 0] == pytest.approx(prof.duration_s)
    np.testing.assert_allclose(rows[0, 1:3], prof.xy[0], atol=1e-12)
    np.testing.assert_allclose(rows[-1, 1:3], prof.xy[-1], atol=1e-9)
    np.testing.assert_allclose(np.diff(rows[:-1, 0]), 0.1, atol=1e-9)
    with pytest.raises(ConfigError, match="dt_s"):
        prof.sample_every(0.0)


def test_repeated_cusp_pose_and_one_segment_piece() -> None:
    """A cusp pose given twice (end of one primitive, start of the next) is one knot; a piece
    of a single segment still starts and ends at rest."""
    poses, gear, curv, _ = drive([(1.0, 0.0, 1), (1.0, 0.5, -1)])
    i = 20  # the cusp
    poses2 = np.insert(poses, i + 1, poses[i], axis=0)
    gear2 = np.insert(gear, i + 1, gear[i])
    curv2 = np.insert(curv, i + 1, curv[i])
    gear2[i] = 1
    prof = time_parameterise_car(poses2, gear2, curv2, LIMITS)
    assert len(prof.s) == len(poses)
    np.testing.assert_array_equal(prof.cusps, [i])
    assert np.all(np.isfinite(prof.t)) and np.all(np.diff(prof.t) > 0)

    poses, gear, curv, _ = drive([(1.0, 0.0, 1), (0.04, 0.0, -1), (1.0, 0.5, 1)])
    prof = time_parameterise_car(poses, gear, curv, LIMITS)
    assert prof.reversals == 2
    a, b = prof.cusps
    assert b - a == 2  # the midpoint knot
    assert prof.v[a + 1] < 0 and prof.v[a] == prof.v[b] == 0.0
    assert np.all(np.isfinite(prof.t)) and np.all(np.diff(prof.t) > 0)


# The follower ----------------------------------------------------------------------------

SHORT_LOOKAHEAD = TrackerSettings(lookahead_gain_s=0.5)


@pytest.mark.parametrize("settings", [TrackerSettings(), SHORT_LOOKAHEAD], ids=["1s", "0.5s"])
@pytest.mark.parametrize("name", PATHS)
def test_bicycle_follows_each_path(
    profiles: dict[str, CarProfile], name: str, settings: TrackerSettings
) -> None:
    """Reaches the goal at rest, stays within 5 cm of the path (plain pure pursuit with a 1 s
    lookahead cuts the S-curve's inflection by 0.1 m), never steers beyond the limit, and
    keeps the car's speed and acceleration limits."""
    prof = profiles[name]
    res = simulate_bicycle(prof, LIMITS, settings)
    states = res.states
    assert res.reached_goal and res.time_to_goal_s is not None
    assert res.time_to_goal_s == pytest.approx(states[-1, 0])
    assert res.time_to_goal_s < prof.duration_s + 2.0
    assert math.hypot(*(states[-1, 1:3] - prof.xy[-1])) <= settings.goal_tolerance_m
    assert states[-1, 4] == 0.0
    assert res.cross_track_max_m < 0.05
    steer_max = math.atan(LIMITS.wheelbase_m / LIMITS.min_turn_radius_m)
    assert np.abs(res.steer_rad).max() <= steer_max + 1e-12
    np.testing.assert_allclose(
        states[:, 5], states[:, 4] * np.tan(res.steer_rad) / LIMITS.wheelbase_m, atol=1e-12
    )
    assert np.all(np.abs(np.diff(states[:, 4])) <= LIMITS.max_accel * settings.dt_s + 1e-12)
    assert np.all(np.abs(states[:, 4]) <= np.where(res.gear > 0, 1.0, 0.5) + 1e-12)


def test_states_obey_the_bicycle_model(profiles: dict[str, CarProfile]) -> None:
    """Each step is the exact arc of the rear axle for the mean speed and the steering held."""
    res = simulate_bicycle(profiles["three_point"], LIMITS, SHORT_LOOKAHEAD)
    s = res.states
    v_mean = 0.5 * (s[:-1, 4] + s[1:, 4])
    w = v_mean * np.tan(res.steer_rad[:-1]) / LIMITS.wheelbase_m
    dt = np.diff(s[:, 0])
    theta = np.unwrap(s[:, 3])
    np.testing.assert_allclose(np.diff(theta), w * dt, atol=1e-9)
    a = w * dt / 2
    chord = v_mean * dt * np.sinc(a / np.pi)
    np.testing.assert_allclose(np.diff(s[:, 1]), chord * np.cos(theta[:-1] + a), atol=1e-9)
    np.testing.assert_allclose(np.diff(s[:, 2]), chord * np.sin(theta[:-1] + a), atol=1e-9)


@pytest.mark.parametrize("name", ["reversal", "three_point"])
def test_bicycle_reverses_where_the_path_reverses(
    profiles: dict[str, CarProfile], name: str
) -> None:
    prof = profiles[name]
    cusps = drive(PATHS[name])[3]
    res = simulate_bicycle(prof, LIMITS, SHORT_LOOKAHEAD)
    gear = res.gear.astype(int)
    piece_gears = prof.direction[prof.piece_bounds[:-1]].astype(int)
    runs = [gear[0], *gear[1:][np.diff(gear) != 0]]
    assert runs == piece_gears.tolist()
    assert [e["kind"] for e in res.events] == [
        "forward" if g > 0 else "reverse" for g in piece_gears[1:]
    ]
    changes = np.flatnonzero(np.diff(gear) != 0) + 1
    tol = SHORT_LOOKAHEAD.goal_tolerance_m
    for k, cusp in zip(changes, cusps, strict=True):
        assert res.states[k, 4] == 0.0  # stopped to change gear
        assert math.hypot(*(res.states[k, 1:3] - cusp)) <= tol
    v = res.states[:, 4]
    assert np.all(v[gear > 0] >= 0.0) and np.all(v[gear < 0] <= 0.0)
    assert (v < -0.1).any()
    assert len(res.paths) == len(cusps) + 1


def test_steering_rate_limit(profiles: dict[str, CarProfile]) -> None:
    """Wheels turning at most 1 rad/s: the limit holds, and the car still follows the
    curvature steps (straight to full lock, full lock left to right at a cusp) closely."""
    rate = 1.0
    for name in ("three_point", "s_curve", "reversal"):
        res = simulate_bicycle(profiles[name], LIMITS, max_steer_rate=rate)
        assert res.reached_goal
        assert np.abs(np.diff(res.steer_rad)).max() <= rate * 0.02 + 1e-12
        assert res.cross_track_max_m < 0.05


def test_follower_is_deterministic(profiles: dict[str, CarProfile]) -> None:
    a = simulate_bicycle(profiles["three_point"], LIMITS)
    b = simulate_bicycle(profiles["three_point"], LIMITS)
    np.testing.assert_array_equal(a.states, b.states)
    np.testing.assert_array_equal(a.cross_track_m, b.cross_track_m)
    np.testing.assert_array_equal(a.steer_rad, b.steer_rad)
    assert a.events == b.events


# Errors ---------------------------------------------------------------------------------


def test_car_limits_are_checked() -> None:
    assert CarLimits(max_speed=2.0).max_reverse_speed == 1.0
    with pytest.raises(ConfigError, match="max_lateral_accel"):
        CarLimits(max_lateral_accel=0.0).checked()
    with pytest.raises(ConfigError, match="--wheelbase"):
        CarLimits(wheelbase_m=-1.0).checked({"wheelbase_m": "--wheelbase"})
    poses, gear, curv, _ = drive(PATHS["straight"])
    with pytest.raises(ConfigError, match="min_turn_radius_m"):
        time_parameterise_car(poses, gear, curv, CarLimits(min_turn_radius_m=math.nan))
    prof = time_parameterise_car(poses, gear, curv, LIMITS)
    with pytest.raises(ConfigError, match="max_steer_rate"):
        simulate_bicycle(prof, LIMITS, max_steer_rate=0.0)
    with pytest.raises(ConfigError, match="dt_s"):
        simulate_bicycle(prof, LIMITS, TrackerSettings(dt_s=0.0))


def test_bad_paths_are_input_errors() -> None:
    poses, gear, curv, _ = drive(PATHS["arc_tight"])
    with pytest.raises(InputError, match=r"curvature\[0\].*min_turn_radius_m"):
        time_parameterise_car(poses, gear, curv * 1.01, LIMITS)
    bad_gear = gear.copy()
    bad_gear[3] = 0
    with pytest.raises(InputError, match=r"direction\[3\]"):
        time_parameterise_car(poses, bad_gear, curv, LIMITS)
    with pytest.raises(InputError, match="directions and curvatures"):
        time_parameterise_car(poses, gear[:-1], curv, LIMITS)
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        time_parameterise_car(poses[:, :2], gear, curv, LIMITS)
    with pytest.raises(InputError, match="finite"):
        time_parameterise_car(np.where(poses == poses[2], np.nan, poses), gear, curv, LIMITS)
    still = np.repeat(poses[:1], 5, axis=0)
    with pytest.raises(InputError, match="one position"):
        time_parameterise_car(still, gear[:5], curv[:5], LIMITS)
