"""The unicycle motion model against numerical integration, and the χ² quantiles."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slamcli.geometry import integrate_unicycle, sin_ratio, unicycle_step
from slamcli.geometry.chi2 import chi2_quantile


def _rk4(pose: tuple[float, float, float], v: float, w: float, dt: float, n: int) -> np.ndarray:
    """The unicycle ODE x' = v cos θ, y' = v sin θ, θ' = ω by n classic RK4 steps."""

    def f(p: np.ndarray) -> np.ndarray:
        return np.array([v * math.cos(p[2]), v * math.sin(p[2]), w])

    p = np.array(pose, dtype=np.float64)
    h = dt / n
    for _ in range(n):
        k1 = f(p)
        k2 = f(p + 0.5 * h * k1)
        k3 = f(p + 0.5 * h * k2)
        k4 = f(p + h * k3)
        p = p + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return p


@settings(max_examples=40, deadline=None)
@given(
    st.floats(-math.pi, math.pi),
    st.floats(-2.0, 2.0),
    st.floats(-3.0, 3.0),
    st.floats(0.001, 2.0),
)
def test_unicycle_step_matches_tiny_step_integration(
    yaw: float, v: float, w: float, dt: float
) -> None:
    got = unicycle_step(1.5, -0.5, yaw, v, w, dt)
    np.testing.assert_allclose(got, _rk4((1.5, -0.5, yaw), v, w, dt, 400), atol=1e-9)


def test_unicycle_step_straight_line_is_exact() -> None:
    x, y, yaw = unicycle_step(1.0, 2.0, 0.3, 0.7, 0.0, 0.5)
    assert (x, y, yaw) == (1.0 + 0.7 * 0.5 * math.cos(0.3), 2.0 + 0.7 * 0.5 * math.sin(0.3), 0.3)
    # Negative zero is zero too.
    assert unicycle_step(0.0, 0.0, 0.0, 1.0, -0.0, 1.0) == (1.0, 0.0, 0.0)


def test_unicycle_step_is_continuous_as_the_turn_rate_vanishes() -> None:
    straight = np.array(unicycle_step(1.0, 2.0, 0.3, 0.7, 0.0, 0.5))
    for w in (1e-3, 1e-6, 1e-9, 1e-12, 1e-300, -1e-9):
        turned = np.array(unicycle_step(1.0, 2.0, 0.3, 0.7, w, 0.5))
        # The heading moves by ω dt and the end point sideways by about v dt² ω / 2.
        np.testing.assert_allclose(turned, straight, rtol=0.0, atol=0.5 * abs(w) + 1e-15)
    assert sin_ratio(0.0) == 1.0
    np.testing.assert_array_equal(sin_ratio(np.array([0.0, -0.0, 1e-300])), [1.0, 1.0, 1.0])
    a = np.array([1e-8, 1e-4, 0.1, 2.0, -3.0])
    np.testing.assert_array_equal(sin_ratio(a), np.sin(a) / a)


def test_unicycle_step_broadcasts_like_its_scalar_calls() -> None:
    rng = np.random.default_rng(3)
    x, y, yaw, v, w = rng.normal(size=(5, 50))
    w[:10] = 0.0
    got = np.stack(unicycle_step(x, y, yaw, v, w, 0.1), axis=1)
    rows = np.stack([x, y, yaw, v, w], axis=1).tolist()
    one_by_one = [unicycle_step(*row, 0.1) for row in rows]
    np.testing.assert_array_equal(got, np.array(one_by_one, dtype=np.float64))


def test_integrate_unicycle_is_repeated_steps_bit_for_bit() -> None:
    rng = np.random.default_rng(7)
    controls = np.column_stack([rng.uniform(0.0, 1.5, 300), rng.normal(0.0, 0.5, 300)])
    controls[::7, 1] = 0.0
    dts = rng.uniform(0.01, 0.1, 300)
    poses = integrate_unicycle([0.5, -1.0, 3.0], controls, dts)
    assert poses.shape == (301, 3)
    p = (0.5, -1.0, 3.0)
    for k, ((v, w), dt) in enumerate(zip(controls, dts, strict=True)):
        assert tuple(poses[k]) == p
        p = tuple(float(c) for c in unicycle_step(*p, float(v), float(w), float(dt)))
    assert tuple(poses[-1]) == p
    # Heading stays continuous: a full turn in place ends at yaw + 2π, not wrapped.
    spin = integrate_unicycle([0.0, 0.0, 0.0], np.tile([0.0, math.pi], (4, 1)), 0.5)
    assert spin[-1, 2] == pytest.approx(2.0 * math.pi)
    assert integrate_unicycle([1.0, 2.0, 3.0], np.empty((0, 2)), 0.1).tolist() == [[1.0, 2.0, 3.0]]


@pytest.mark.parametrize(
    ("p", "dof", "expected"),
    [
        (0.95, 1, 3.841459),
        (0.95, 2, 5.991465),
        (0.99, 2, 9.210340),
        (0.95, 3, 7.814728),
        (0.999, 4, 18.466827),
        (0.025, 3, 0.215795),
    ],
)
def test_chi2_quantile_known_values(p: float, dof: int, expected: float) -> None:
    assert chi2_quantile(p, dof) == pytest.approx(expected, abs=1e-6)


def test_chi2_quantile_edges_and_bad_arguments() -> None:
    assert chi2_quantile(0.0, 2) == 0.0
    assert chi2_quantile(1.0, 2) == math.inf
    with pytest.raises(ValueError, match="dof >= 1"):
        chi2_quantile(0.5, 0)
    with pytest.raises(ValueError, match="0 <= p <= 1"):
        chi2_quantile(1.5, 3)
