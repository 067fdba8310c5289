"""The bound on a trajectory's metric scale (slamcli.inertial.observability) against a
Monte-Carlo: the IMU's own estimate of the scale, over many noise draws of the rendered rig's
IMU along its exact path, spreads as the bound says and centres on the truth."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from slamcli.errors import InputError
from slamcli.inertial import ImuNoise
from slamcli.inertial.observability import scale_information
from slamcli.synth.stereo import (
    ACCEL_NOISE_DENSITY,
    ACCEL_RANDOM_WALK,
    GYRO_NOISE_DENSITY,
    GYRO_RANDOM_WALK,
    StereoWorld,
    build_stereo_world,
)

NOISE = ImuNoise(GYRO_NOISE_DENSITY, GYRO_RANDOM_WALK, ACCEL_NOISE_DENSITY, ACCEL_RANDOM_WALK)
DRAWS = 40


@functools.cache
def _world(frames: int) -> StereoWorld:
    return build_stereo_world(frames, size=(64, 48))


def _information(frames: int, seed: int | None, every: int = 50) -> tuple[float, float]:
    """The scale and its bound from keyframes every ``every`` IMU samples of the exact path,
    with the IMU noise-free (``seed`` None) or drawn with ``seed``."""
    imu = _world(frames).imu_track(noise=seed is not None, seed=seed or 0)
    at = np.arange(0, imu.stamps_ns.size, every)
    got = scale_information(
        imu.stamps_ns[at],
        imu.world_from_body[at],
        (imu.stamps_ns, imu.gyro_radps, imu.accel_mps2),
        NOISE,
        gyro_bias=imu.gyro_bias[0],
    )
    return got.scale, got.std


def test_noise_free_imu_gives_the_exact_scale() -> None:
    scale, std = _information(200, None)
    assert scale == pytest.approx(1.0, abs=1e-4)
    assert 0.005 < std < 0.02


def test_bound_matches_the_spread_of_the_imus_own_estimate() -> None:
    draws = np.array([_information(200, seed) for seed in range(DRAWS)])
    bound = float(np.median(draws[:, 1]))
    spread = float(np.std(draws[:, 0] - 1.0))
    # The sample deviation of 40 draws is within ±25 % of the true one at 95 %.
    assert 0.75 * bound < spread < 1.3 * bound
    assert abs(float(np.mean(draws[:, 0])) - 1.0) < 3 * bound / np.sqrt(DRAWS)


def test_gentler_motion_leaves_the_scale_less_determined() -> None:
    """The loop runs once over any length: 5 s of it accelerates four times as hard as 10 s."""
    assert _information(100, None)[1] < 0.6 * _information(200, None)[1]


def test_keyframe_spacing_hardly_changes_the_bound() -> None:
    """The information is the IMU's: more poses along the same path add little."""
    assert _information(200, None, every=10)[1] == pytest.approx(
        _information(200, None, every=50)[1], rel=0.05
    )


def test_too_few_poses_are_refused() -> None:
    imu = build_stereo_world(20, size=(64, 48)).imu_track()
    samples = (imu.stamps_ns, imu.gyro_radps, imu.accel_mps2)
    with pytest.raises(InputError, match="3 or more poses"):
        scale_information(imu.stamps_ns[:2], imu.world_from_body[:2], samples, NOISE)
    with pytest.raises(InputError, match="must increase"):
        scale_information(imu.stamps_ns[[0, 2, 1]], imu.world_from_body[:3], samples, NOISE)
