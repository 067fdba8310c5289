"""The IMU clock's offset from the camera's, estimated from the turns both see
(:mod:`slamcli.inertial.clock`), on a body turning at a varying rate."""

from __future__ import annotations

import numpy as np
import pytest

from slamcli.geometry.se3 import so3_exp
from slamcli.inertial.clock import MIN_GAIN, estimate_clock_offset


def _turning_body(seed: int, shift_s: float, rate_scale: float = 1.0):
    """8 s of a body turning about all three axes at rates that vary (0.2-1 Hz); keyframes
    every 0.2 s; a 200 Hz gyroscope with EuRoC-like noise and a constant bias, its stamps
    ``shift_s`` late."""
    rng = np.random.default_rng(seed)
    freq = rng.uniform(0.2, 1.0, 3)
    phase = rng.uniform(0, 2 * np.pi, 3)
    amp = rng.uniform(0.3, 0.8, 3) * rate_scale

    def rate(t: np.ndarray) -> np.ndarray:
        return amp * np.sin(2 * np.pi * freq * t[:, None] + phase)

    dt = 0.005
    t = np.arange(0.0, 8.0, dt)
    rotations = [np.eye(3)]
    for w in rate(t[:-1]):
        rotations.append(rotations[-1] @ so3_exp(w * dt))
    rotations = np.array(rotations)
    gyro = rate(t) + 0.01 + rng.normal(0, 1.7e-4 / np.sqrt(dt), (t.size, 3))
    keyframes = np.arange(200, t.size - 200, 40)
    to_ns = 1e9
    imu_stamps = np.round((t + shift_s) * to_ns).astype(np.int64)
    return (
        np.round(t[keyframes] * to_ns).astype(np.int64),
        rotations[keyframes],
        imu_stamps,
        gyro,
    )


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("shift", [-0.12, 0.06, 0.2])
def test_the_offset_is_found_within_a_few_milliseconds(seed: int, shift: float) -> None:
    found = estimate_clock_offset(*_turning_body(seed, shift))
    assert found is not None
    assert found.shift_s == pytest.approx(shift, abs=0.006)
    assert found.gain >= MIN_GAIN
    assert found.significant(0.05)


def test_synchronised_clocks_show_no_offset() -> None:
    found = estimate_clock_offset(*_turning_body(3, 0.0))
    assert found is not None
    assert abs(found.shift_s) <= 0.006
    assert not found.significant(0.05)


def test_a_body_that_barely_turns_gives_no_estimate() -> None:
    assert estimate_clock_offset(*_turning_body(4, 0.1, rate_scale=0.005)) is None
