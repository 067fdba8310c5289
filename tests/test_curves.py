"""Reeds-Shepp and Dubins curves: lengths against OMPL, sampled geometry against the motion model.

The references are independent of the code under test: OMPL's ``ReedsSheppStateSpace`` and
``DubinsStateSpace`` (C++) for the lengths, and for the samples the closed-form motion of a car
on a circle, ``x(s) = x0 + (sin(yaw0 + k s) - sin(yaw0)) / k`` (the implementation places
chords at the mean heading instead).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numba
import numpy as np
import pytest

from slamcli.errors import ConfigError
from slamcli.planning.curves import (
    Curve,
    dubins_length,
    dubins_segments,
    rs_length,
    rs_segments,
    sample_curve,
    shortest_curve,
)

Pair = tuple[np.ndarray, np.ndarray, float]


def _frame(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fwd = np.array([math.cos(q[2]), math.sin(q[2])])
    return fwd, np.array([-fwd[1], fwd[0]])


def _random(rng: np.random.Generator, r: float) -> tuple[np.ndarray, np.ndarray]:
    # Yaws beyond [-pi, pi] too: the curves must not care how an angle is written.
    return rng.uniform([-10, -10, -7], [10, 10, 7]), rng.uniform([-10, -10, -7], [10, 10, 7])


def _near(rng: np.random.Generator, r: float) -> tuple[np.ndarray, np.ndarray]:
    q0 = rng.uniform([-10, -10, -math.pi], [10, 10, math.pi])
    return q0, q0 + rng.uniform(-2.5 * r, 2.5 * r, 3) * np.array([1.0, 1.0, 1.0 / r])


def _same(rng: np.random.Generator, r: float) -> tuple[np.ndarray, np.ndarray]:
    q0 = rng.uniform([-10, -10, -math.pi], [10, 10, math.pi])
    return q0, q0.copy()


def _rotate_in_place(rng: np.random.Generator, r: float) -> tuple[np.ndarray, np.ndarray]:
    q0 = rng.uniform([-10, -10, -math.pi], [10, 10, math.pi])
    return q0, q0 + np.array([0.0, 0.0, rng.uniform(-2 * math.pi, 2 * math.pi)])


def _straight_ahead(rng: np.random.Generator, r: float) -> tuple[np.ndarray, np.ndarray]:
    q0 = rng.uniform([-10, -10, -math.pi], [10, 10, math.pi])
    fwd, _ = _frame(q0)
    return q0, np.append(q0[:2] + rng.uniform(0.01, 20) * fwd, q0[2])


def _straight_behind(rng: np.random.Generator, r: float) -> tuple[np.ndarray, np.ndarray]:
    q0 = rng.uniform([-10, -10, -math.pi], [10, 10, math.pi])
    fwd, _ = _frame(q0)
    return q0, np.append(q0[:2] - rng.uniform(0.01, 20) * fwd, q0[2])


def _half_turn(rng: np.random.Generator, r: float) -> tuple[np.ndarray, np.ndarray]:
    # 180-degree turns: on the spot, one diameter to the side, or anywhere nearby.
    q0 = rng.uniform([-10, -10, -math.pi], [10, 10, math.pi])
    _, left = _frame(q0)
    side = rng.choice([0.0, 2.0 * r, -2.0 * r, rng.uniform(-5.0, 5.0)])
    return q0, np.append(q0[:2] + side * left, q0[2] + rng.choice([-math.pi, math.pi]))


def _on_circle(rng: np.random.Generator, r: float) -> tuple[np.ndarray, np.ndarray]:
    # The goal on one of the start's turning circles: a single arc, forwards or backwards.
    q0 = rng.uniform([-10, -10, -math.pi], [10, 10, math.pi])
    fwd, left = _frame(q0)
    turn = rng.uniform(-3.0, 3.0)
    side = rng.choice([-1.0, 1.0])
    step = r * (math.sin(turn) * fwd + side * (1.0 - math.cos(turn)) * left)
    return q0, np.append(q0[:2] + step, q0[2] + side * turn)


def _far(rng: np.random.Generator, r: float) -> tuple[np.ndarray, np.ndarray]:
    return rng.uniform([-1e3, -1e3, -math.pi], [1e3, 1e3, math.pi]), rng.uniform(
        [-1e3, -1e3, -math.pi], [1e3, 1e3, math.pi]
    )


def _very_close(rng: np.random.Generator, r: float) -> tuple[np.ndarray, np.ndarray]:
    q0 = rng.uniform([-10, -10, -math.pi], [10, 10, math.pi])
    return q0, q0 + np.append(rng.normal(0.0, 1e-4, 2), rng.normal(0.0, 1e-3))


FAMILIES: dict[str, Callable[[np.random.Generator, float], tuple[np.ndarray, np.ndarray]]] = {
    "random": _random,
    "near": _near,
    "same": _same,
    "rotate_in_place": _rotate_in_place,
    "straight_ahead": _straight_ahead,
    "straight_behind": _straight_behind,
    "half_turn": _half_turn,
    "on_circle": _on_circle,
    "far": _far,
    "very_close": _very_close,
}


def _pairs(family: str, n: int, seed: int) -> list[Pair]:
    rng = np.random.default_rng([seed, list(FAMILIES).index(family)])
    out = []
    for _ in range(n):
        r = float(rng.choice([0.5, 1.0, 2.5, rng.uniform(0.2, 6.0)]))
        q0, q1 = FAMILIES[family](rng, r)
        out.append((np.asarray(q0, dtype=np.float64), np.asarray(q1, dtype=np.float64), r))
    return out


def _ompl_distance(space_cls: type, pairs: list[Pair]) -> np.ndarray:
    out = np.empty(len(pairs))
    spaces: dict[float, object] = {}
    for i, (q0, q1, r) in enumerate(pairs):
        space = spaces.setdefault(r, space_cls(r))
        s0, s1 = space.allocState(), space.allocState()  # type: ignore[attr-defined]
        for state, q in ((s0, q0), (s1, q1)):
            state.setX(float(q[0]))
            state.setY(float(q[1]))
            state.setYaw(float(q[2]))
        out[i] = space.distance(s0, s1)  # type: ignore[attr-defined]
    return out


# ----------------------------------------------------------------------------- lengths vs OMPL


def _straight_distance(q0: np.ndarray, q1: np.ndarray) -> float:
    return math.hypot(q1[0] - q0[0], q1[1] - q0[1])


@pytest.mark.parametrize("family", list(FAMILIES))
def test_reeds_shepp_length_matches_ompl(family: str) -> None:
    ob = pytest.importorskip("ompl.base")
    pairs = _pairs(family, 300, seed=1)
    ours = np.array([rs_length(*q0, *q1, r) for q0, q1, r in pairs])
    ref = _ompl_distance(ob.ReedsSheppStateSpace, pairs)
    # OMPL checks segment signs to 10 machine epsilons, so when rounding in the start's frame
    # tilts a short straight by ~1e-14 rad it rejects the straight word and reports a longer
    # one. There the straight itself is the answer (the sampling tests check it drives there).
    shorter = ours < ref - 1e-6
    for i in np.flatnonzero(shorter):
        assert family in ("straight_ahead", "straight_behind")
        q0, q1, r = pairs[i]
        assert ours[i] == pytest.approx(_straight_distance(q0, q1), abs=1e-12)
        assert shortest_curve(q0, q1, r).kinds == ("S",)
    assert np.count_nonzero(shorter) <= 3
    np.testing.assert_allclose(ours[~shorter], ref[~shorter], rtol=0, atol=1e-6)


@pytest.mark.parametrize("family", list(FAMILIES))
def test_dubins_length_matches_ompl(family: str) -> None:
    ob = pytest.importorskip("ompl.base")
    pairs = _pairs(family, 300, seed=2)
    ours = np.array([dubins_length(*q0, *q1, r) for q0, q1, r in pairs])
    ref = _ompl_distance(ob.DubinsStateSpace, pairs)
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-6)


def test_straight_goals_give_one_straight_segment() -> None:
    # Straight ahead or behind at any heading, near or far, yaw written with extra turns.
    rng = np.random.default_rng(13)
    for _ in range(2000):
        q0 = rng.uniform([-100, -100, -10], [100, 100, 10])
        d = 10 ** rng.uniform(-2, 2) * rng.choice([-1.0, 1.0])
        turns = 2 * math.pi * rng.integers(-2, 3)
        q1 = np.array([q0[0] + d * math.cos(q0[2]), q0[1] + d * math.sin(q0[2]), q0[2] + turns])
        r = float(rng.uniform(0.2, 6.0))
        for reverse in (True, False) if d > 0 else (True,):
            curve = shortest_curve(q0, q1, r, reverse=reverse)
            assert curve.kinds == ("S",)
            assert curve.lengths[0] == pytest.approx(d, abs=1e-9)


# ----------------------------------------------------------------------------- sampled geometry


def _wrap(a: np.ndarray | float) -> np.ndarray:
    return np.angle(np.exp(1j * np.asarray(a)))


def _check_samples(curve: Curve, q0: np.ndarray, q1: np.ndarray, step: float) -> None:
    """Every property sample_curve promises, checked against the exact motion model."""
    r = curve.radius_m
    poses, direction, curvature = sample_curve(curve, q0, step)
    n = len(poses)
    assert poses.shape == (n, 3) and direction.shape == (n,) and curvature.shape == (n,)
    assert direction.dtype == np.int8 and curvature.dtype == np.float64
    np.testing.assert_array_equal(poses[0], q0)
    assert math.hypot(*(poses[-1, :2] - q1[:2])) <= 1e-9
    assert abs(_wrap(poses[-1, 2] - q1[2])) <= 1e-9
    assert set(direction.tolist()) <= {-1, 1}
    assert np.all(np.abs(curvature) <= 1.0 / r + 1e-15)
    if n == 1:
        assert curve.length_m == 0.0
        return

    # Each step follows the segment that leaves its first pose: signed distance s, turning
    # yaw by k s; the displacement is the closed-form one for that circle (or line).
    yaw = poses[:-1, 2]
    dx, dy, dyaw = np.diff(poses, axis=0).T
    k = curvature[:-1]
    turning = k != 0
    s = np.empty(n - 1)
    s[turning] = dyaw[turning] / k[turning]
    s[~turning] = np.hypot(dx, dy)[~turning] * direction[:-1][~turning]
    assert np.all(dyaw[~turning] == 0.0), "a straight step turned"
    assert np.all(np.abs(s) > 0), "a pose repeats"
    assert np.all(np.sign(s) == direction[:-1]), "a step moved against its gear"
    assert np.all(np.abs(s) <= step * (1 + 1e-12)), "samples too far apart"
    safe_k = np.where(turning, k, 1.0)
    ex = np.where(turning, (np.sin(yaw + k * s) - np.sin(yaw)) / safe_k, s * np.cos(yaw))
    ey = np.where(turning, (np.cos(yaw) - np.cos(yaw + k * s)) / safe_k, s * np.sin(yaw))
    np.testing.assert_allclose(dx, ex, rtol=0, atol=1e-9)
    np.testing.assert_allclose(dy, ey, rtol=0, atol=1e-9)
    # Heading is continuous: no step turns more than its length allows.
    assert np.all(np.abs(dyaw) <= step / r * (1 + 1e-12) + 1e-15)

    # The path is as long as the curve, and every segment boundary is a sample (so each gear
    # change is explicit): the walked distance passes through each cumulative segment length.
    walked = np.concatenate(([0.0], np.cumsum(np.abs(s))))
    tol = 1e-9 * max(1.0, curve.length_m)
    assert abs(walked[-1] - curve.length_m) <= tol
    for boundary in np.cumsum(np.abs(curve.lengths)):
        assert np.min(np.abs(walked - boundary)) <= tol
    changes = int(np.count_nonzero(np.diff(direction[:-1]) != 0))
    assert changes == curve.reversals
    assert direction[-1] == direction[-2] and curvature[-1] == curvature[-2]


@pytest.mark.parametrize("family", list(FAMILIES))
@pytest.mark.parametrize("reverse", [True, False], ids=["reeds_shepp", "dubins"])
def test_sampled_curve_follows_the_car_model(family: str, reverse: bool) -> None:
    length_fn = rs_length if reverse else dubins_length
    for i, (q0, q1, r) in enumerate(_pairs(family, 100, seed=3)):
        curve = shortest_curve(q0, q1, r, reverse=reverse)
        expected = length_fn(*q0, *q1, r)
        assert curve.length_m == pytest.approx(expected, rel=1e-12, abs=1e-9)
        assert len(curve.kinds) <= (5 if reverse else 3)
        if not reverse:
            assert all(v > 0 for v in curve.lengths) and curve.reversals == 0
        # Steps that divide the segments unevenly, and ones longer than whole segments.
        step = (0.037, 0.3, 5.0)[i % 3] * r
        _check_samples(curve, q0, q1, step)


def test_every_reeds_shepp_family_occurs_and_reaches_its_goal() -> None:
    # Goals within a few radii make each family (CSC, CCC, CCCC, CCSC, CCSCC) the shortest
    # somewhere; all of their words, in every gear pattern met, must reach the goal.
    rng = np.random.default_rng(7)
    families = set()
    words = set()
    for _ in range(3000):
        q1 = rng.uniform([-4, -4, -math.pi], [4, 4, math.pi])
        curve = shortest_curve((0.0, 0.0, 0.0), q1, 1.0)
        kinds = "".join(curve.kinds)
        families.add(kinds.replace("L", "C").replace("R", "C"))
        word = tuple(zip(curve.kinds, np.sign(curve.lengths).astype(int).tolist(), strict=True))
        if word not in words:
            words.add(word)
            _check_samples(curve, np.zeros(3), q1, 0.05)
    assert {"CSC", "CCC", "CCCC", "CCSC", "CCSCC"} <= families
    assert len(words) >= 40


# ----------------------------------------------------------------------------- properties


def test_known_answers() -> None:
    straight = shortest_curve(
        (1.0, 2.0, 0.5), (1.0 + 3 * math.cos(0.5), 2 + 3 * math.sin(0.5), 0.5), 1.0
    )
    assert straight.kinds == ("S",) and straight.lengths == pytest.approx((3.0,))
    back = shortest_curve((0.0, 0.0, 0.0), (-3.0, 0.0, 0.0), 2.0)
    assert back.kinds == ("S",) and back.lengths == pytest.approx((-3.0,))
    assert back.reversals == 0
    # The same pose, its yaw written with an extra turn: nothing to drive.
    empty = shortest_curve((5.0, 5.0, 1.0), (5.0, 5.0, 1.0 + 2 * math.pi), 1.0)
    assert empty.kinds == () and empty.length_m == 0.0 and empty.reversals == 0
    poses, direction, curvature = sample_curve(empty, (5.0, 5.0, 1.0), 0.1)
    assert poses.tolist() == [[5.0, 5.0, 1.0]]
    assert direction.tolist() == [1] and curvature.tolist() == [0.0]
    # A quarter circle to the left, forward and (mirrored in time) backward.
    left = shortest_curve((0.0, 0.0, 0.0), (2.0, 2.0, math.pi / 2), 2.0, reverse=False)
    assert left.kinds == ("L",) and left.lengths == pytest.approx((math.pi,))
    right_back = shortest_curve((0.0, 0.0, 0.0), (-2.0, -2.0, math.pi / 2), 2.0)
    assert right_back.kinds == ("R",) and right_back.lengths == pytest.approx((-math.pi,))


def test_curve_properties() -> None:
    curve = Curve(("L", "S", "R", "L"), (1.0, -2.0, -0.5, 3.0), 1.5)
    assert curve.length_m == pytest.approx(6.5)
    assert curve.reversals == 2
    assert Curve((), (), 1.0).reversals == 0


def _moved(q: np.ndarray, angle: float, shift: np.ndarray, turns: int) -> list[float]:
    """Pose ``q`` rotated by ``angle`` and shifted by ``shift``; yaw with ``turns`` extra turns."""
    c, s = math.cos(angle), math.sin(angle)
    xy = np.array([[c, -s], [s, c]]) @ q[:2] + shift
    return [float(xy[0]), float(xy[1]), float(q[2] + angle + 2 * math.pi * turns)]


def test_lengths_are_invariant_symmetric_and_scale() -> None:
    rng = np.random.default_rng(11)
    for _ in range(500):
        q0 = rng.uniform([-5, -5, -math.pi], [5, 5, math.pi])
        q1 = rng.uniform([-5, -5, -math.pi], [5, 5, math.pi])
        r = float(rng.uniform(0.3, 3.0))
        rs = rs_length(*q0, *q1, r)
        db = dubins_length(*q0, *q1, r)
        euclid = math.hypot(*(q1[:2] - q0[:2]))
        assert euclid - 1e-9 <= rs <= db + 1e-9
        # Reeds-Shepp distance is a metric: symmetric.
        assert rs_length(*q1, *q0, r) == pytest.approx(rs, rel=1e-9, abs=1e-9)
        # A rigid motion of both poses, and yaws written with extra turns, change nothing.
        a, t = float(rng.uniform(-math.pi, math.pi)), rng.uniform(-50, 50, 2)
        moved = (*_moved(q0, a, t, -2), *_moved(q1, a, t, 3), r)
        assert rs_length(*moved) == pytest.approx(rs, rel=1e-9, abs=1e-9)
        assert dubins_length(*moved) == pytest.approx(db, rel=1e-9, abs=1e-9)
        # Lengths scale with the world: metres in, metres out.
        scaled = (*(q0 * [3, 3, 1]), *(q1 * [3, 3, 1]), 3 * r)
        assert rs_length(*scaled) == pytest.approx(3 * rs, rel=1e-9)
        assert dubins_length(*scaled) == pytest.approx(3 * db, rel=1e-9)


@numba.njit(cache=False)
def _lengths_in_njit(q: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """rs_length and dubins_length called from compiled code, as a search heuristic would."""
    n = q.shape[0]
    rs = np.empty(n)
    db = np.empty(n)
    for i in range(n):
        rs[i] = rs_length(q[i, 0], q[i, 1], q[i, 2], q[i, 3], q[i, 4], q[i, 5], radius)
        db[i] = dubins_length(q[i, 0], q[i, 1], q[i, 2], q[i, 3], q[i, 4], q[i, 5], radius)
    return rs, db


def test_njit_kernels_agree_with_the_python_api() -> None:
    rng = np.random.default_rng(5)
    q = rng.uniform([-6, -6, -4, -6, -6, -4], [6, 6, 4, 6, 6, 4], (400, 6))
    q[:40, 3:] = q[:40, :3]  # same pose
    q[40:80, 3:5] = q[40:80, :2]  # rotation in place
    radius = 1.3
    rs, db = _lengths_in_njit(q, radius)
    for row, rs_i, db_i in zip(q, rs, db, strict=True):
        q0, q1 = row[:3], row[3:]
        # Equal but for dropped slivers (< 1e-10 turning radii each).
        assert shortest_curve(q0, q1, radius).length_m == pytest.approx(rs_i, abs=1e-9)
        assert shortest_curve(q0, q1, radius, reverse=False).length_m == pytest.approx(
            db_i, abs=1e-9
        )
        kinds, lengths = rs_segments(*q0, *q1, radius)
        assert kinds.dtype == np.int8 and lengths.dtype == np.float64
        assert set(kinds.tolist()) <= {-1, 0, 1}
        assert np.abs(lengths).sum() == pytest.approx(rs_i, abs=1e-9)
        kinds, lengths = dubins_segments(*q0, *q1, radius)
        assert np.all(lengths > 0) and lengths.sum() == pytest.approx(db_i, abs=1e-9)


# ----------------------------------------------------------------------------- errors


@pytest.mark.parametrize("radius", [0.0, -1.0, math.nan, math.inf, "wide"])
def test_bad_radius_is_a_config_error(radius: object) -> None:
    with pytest.raises(ConfigError, match="radius_m") as err:
        shortest_curve((0, 0, 0), (1, 1, 0), radius)  # type: ignore[arg-type]
    assert err.value.hint
    with pytest.raises(ConfigError, match="radius_m"):
        Curve(("S",), (1.0,), radius)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "pose", [(0.0, math.nan, 0.0), (math.inf, 0.0, 0.0), (0.0, 0.0), (0, 0, 0, 0), "abc"]
)
def test_bad_pose_is_a_config_error(pose: object) -> None:
    with pytest.raises(ConfigError, match="q1: expected a pose") as err:
        shortest_curve((0, 0, 0), pose, 1.0)  # type: ignore[arg-type]
    assert err.value.hint
    with pytest.raises(ConfigError, match="q0: expected a pose"):
        sample_curve(Curve(("S",), (1.0,), 1.0), pose, 0.1)  # type: ignore[arg-type]


@pytest.mark.parametrize("step", [0.0, -0.1, math.nan])
def test_bad_step_is_a_config_error(step: float) -> None:
    with pytest.raises(ConfigError, match="step_m") as err:
        sample_curve(Curve(("S",), (1.0,), 1.0), (0, 0, 0), step)
    assert err.value.hint


def test_malformed_curve_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="unknown segment kind 'X'"):
        Curve(("L", "X"), (1.0, 1.0), 1.0)
    with pytest.raises(ConfigError, match="2 kinds but 1 lengths"):
        Curve(("L", "S"), (1.0,), 1.0)
    with pytest.raises(ConfigError, match="finite"):
        Curve(("L",), (math.nan,), 1.0)
