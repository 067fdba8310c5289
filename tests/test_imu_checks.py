"""check_imu on EuRoC's real IMU streams (MH_05 in flight, V1_01's static start) and on
copies of MH_05 spoiled one way each, plus a synthetic tilting IMU with a known answer."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path
from numpy.typing import NDArray

from slamcli.formats.euroc import read_image_csv, read_imu_csv
from slamcli.formats.imu_checks import AXES, check_imu

Imu = tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]
MS = 1_000_000


def _read(mav: Path) -> tuple[Imu, NDArray[np.int64]]:
    imu = read_imu_csv(mav / "imu0" / "data.csv")
    return imu, read_image_csv(mav / "cam0" / "data.csv").stamps_ns


@pytest.fixture(scope="module")
def mh05() -> tuple[Imu, NDArray[np.int64]]:
    """MH_05's IMU (1 s before the first image to 1 s after the last) and cam0's stamps."""
    return _read(shared_path("vi", "euroc_MH05_a", "mav0"))


def _tilting(seconds: float = 10.0, rate: float = 200.0) -> Imu:
    """An IMU rocking about its x axis by 0.5 rad at 0.5 Hz, in rad/s and m/s^2, with noise."""
    rng = np.random.default_rng(7)
    s = np.arange(round(seconds * rate)) / rate
    angle = 0.5 * np.sin(math.pi * s)
    rate_x = 0.5 * math.pi * np.cos(math.pi * s)
    gyro = np.stack([rate_x, np.zeros_like(s), np.zeros_like(s)], axis=1)
    accel = 9.81 * np.stack([np.zeros_like(s), np.sin(angle), np.cos(angle)], axis=1)
    gyro += rng.normal(0.0, 0.005, gyro.shape) + np.array([0.01, -0.02, 0.005])
    accel += rng.normal(0.0, 0.05, accel.shape)
    return (np.round(s * 1e9).astype(np.int64) + 10**18, gyro, accel)


def test_real_mh05_is_clean(mh05: tuple[Imu, NDArray[np.int64]]) -> None:
    (t, gyro, accel), images = mh05
    report = check_imu(t, gyro, accel, images, rate_hz=200.0)
    assert report.problems == []
    assert report.samples == 1791 and report.images == 140
    assert report.rate_hz is not None and abs(report.rate_hz / 200.0 - 1) < 0.01
    assert report.span_s == pytest.approx(8.95, abs=0.001)
    assert report.imu_before_first_image_s == pytest.approx(1.0, abs=0.001)
    assert report.imu_after_last_image_s == pytest.approx(1.0, abs=0.001)
    assert report.uncovered_images == 0 and report.camera_offset_s == 0.0
    assert report.gaps == report.duplicates == report.backwards == 0
    assert report.gyro_tilt_ratio is not None and 0.5 < report.gyro_tilt_ratio < 2.0
    assert report.accel_mean_mps2 == pytest.approx(9.81, abs=0.1)
    assert set(report.saturated) == set(AXES) and not any(report.saturated.values())
    assert json.loads(json.dumps(report.to_dict()))["rate_hz"] == report.rate_hz


def test_real_v1_01_static_start_is_clean() -> None:
    (t, gyro, accel), images = _read(shared_path("stereo", "euroc_V1_01_micro", "mav0"))
    report = check_imu(t, gyro, accel, images, rate_hz=200.0, where="mav0/imu0/data.csv")
    assert report.problems == []
    assert report.imu_before_first_image_s == 0.0 and report.uncovered_images == 0
    assert report.gyro_tilt_ratio is not None and report.gyro_tilt_ratio < 2.0


def test_a_gap_is_reported_with_its_length_and_stamp(mh05: tuple[Imu, NDArray[np.int64]]) -> None:
    (t, gyro, accel), images = mh05
    keep = (t < t[800]) | (t >= t[800] + 200 * MS)
    report = check_imu(t[keep], gyro[keep], accel[keep], images, rate_hz=200.0)
    assert report.gaps == 1
    assert report.largest_gap_s == pytest.approx(0.205, abs=0.001)
    gap = next(p for p in report.problems if "gap(s)" in p)
    assert gap.startswith("imu0/data.csv: 1 gap(s)")
    assert f"0.205 s after sample 799 (t={t[799]} ns)" in gap
    # The images inside the hole have no IMU around them either.
    assert report.uncovered_images == 4
    assert any("fall in gaps" in p for p in report.problems)


def test_duplicate_stamps_are_named(mh05: tuple[Imu, NDArray[np.int64]]) -> None:
    (t, gyro, accel), images = mh05
    t = t.copy()
    t[600] = t[599]
    report = check_imu(t, gyro, accel, images, rate_hz=200.0)
    assert report.duplicates == 1 and report.backwards == 0 and report.gaps == 0
    assert report.problems == [
        f"imu0/data.csv: 1 sample(s) repeat an earlier stamp: sample 600 (t={t[600]} ns); drop "
        "the repeated rows, or re-stamp them if their readings differ: two readings at one "
        "instant cannot be integrated"
    ]


def test_backwards_stamps_are_named_in_file_order(mh05: tuple[Imu, NDArray[np.int64]]) -> None:
    (t, gyro, accel), images = mh05
    rows = np.arange(t.size)
    rows[[500, 501]] = rows[[501, 500]]
    report = check_imu(t[rows], gyro[rows], accel[rows], images, rate_hz=200.0)
    assert report.backwards == 1 and report.duplicates == 0 and report.gaps == 0
    assert len(report.problems) == 1
    assert f"sample 501 (t={t[500]} ns, after t={t[501]} ns)" in report.problems[0]
    far = np.arange(t.size)
    far[[300, 900]] = far[[900, 300]]
    assert check_imu(t[far], gyro[far], accel[far]).backwards == 2


def test_gyro_in_deg_per_s_is_suspected(mh05: tuple[Imu, NDArray[np.int64]]) -> None:
    (t, gyro, accel), images = mh05
    # MH_05's 99th percentile in deg/s is 33: under 2000 deg/s, so the tilt comparison tells.
    report = check_imu(t, np.degrees(gyro), accel, images, rate_hz=200.0)
    assert report.gyro_units_suspect and not report.accel_units_suspect
    assert report.gyro_p99_radps is not None and report.gyro_p99_radps < 35.0
    assert report.gyro_tilt_ratio is not None and report.gyro_tilt_ratio > 30.0
    assert len(report.problems) == 1
    assert "convert the gyro to rad/s" in report.problems[0]
    fast = check_imu(t, gyro * 100.0, accel)
    assert fast.gyro_units_suspect and "99th percentile of |w| is 58.0" in fast.gyro_units_reason


def test_accel_in_g_is_suspected(mh05: tuple[Imu, NDArray[np.int64]]) -> None:
    (t, gyro, accel), images = mh05
    report = check_imu(t, gyro, accel / 9.80665, images, rate_hz=200.0)
    assert report.accel_units_suspect and not report.gyro_units_suspect
    assert report.accel_mean_mps2 == pytest.approx(1.0, abs=0.02)
    assert len(report.problems) == 1 and "multiply by 9.80665" in report.problems[0]
    milli_g = check_imu(t, gyro, accel * 1000 / 9.80665)
    assert milli_g.accel_units_suspect and "neither gravity" in milli_g.accel_units_reason


def test_a_clipped_axis_counts_as_saturated(mh05: tuple[Imu, NDArray[np.int64]]) -> None:
    (t, gyro, accel), images = mh05
    clipped = gyro.copy()
    clipped[:, 0] = np.minimum(clipped[:, 0], 0.3)
    over = np.concatenate([[False], gyro[:, 0] >= 0.3, [False]])
    starts, ends = np.flatnonzero(over[1:] & ~over[:-1]), np.flatnonzero(~over[1:] & over[:-1])
    expected = int(sum(e - s for s, e in zip(starts, ends, strict=True) if e - s >= 3))
    report = check_imu(t, clipped, accel, images, rate_hz=200.0)
    assert expected > 100
    assert report.saturated == dict.fromkeys(AXES, 0) | {"gyro_x": expected}
    assert len(report.problems) == 1
    assert report.problems[0].startswith("imu0/data.csv: gyroscope x sticks at its extreme 0.3")


def test_an_imu_clock_offset_by_more_than_a_frame(mh05: tuple[Imu, NDArray[np.int64]]) -> None:
    (t, gyro, accel), images = mh05
    # As recorded together: the IMU over the images' span only.
    inside = (t >= images[0]) & (t <= images[-1])
    t, gyro, accel = t[inside], gyro[inside], accel[inside]
    late = check_imu(t + 200 * MS, gyro, accel, images, rate_hz=200.0)
    assert late.camera_offset_s == pytest.approx(0.2)
    assert late.images_before_imu == 4 and late.uncovered_images == 4
    assert len(late.problems) == 1
    assert late.problems[0].startswith("imu0/data.csv: the IMU starts 0.200 s after")
    assert "late against the camera's by at least 0.200 s" in late.problems[0]
    assert "timeshift_cam_imu" in late.problems[0]
    early = check_imu(t - 200 * MS, gyro, accel, images, rate_hz=200.0)
    assert early.camera_offset_s == pytest.approx(-0.2)
    assert early.images_after_imu == 4
    assert "the IMU ends 0.200 s before the last image" in early.problems[0]
    # Within a frame: at most the first or the last image lacks IMU on one side.
    for shift in (MS, -MS):
        slight = check_imu(t + shift, gyro, accel, images, rate_hz=200.0)
        assert slight.problems == [] and slight.uncovered_images == 1


def test_clean_stamps_shifted_by_1_ms_have_no_problem(
    mh05: tuple[Imu, NDArray[np.int64]],
) -> None:
    (t, gyro, accel), images = mh05
    report = check_imu(t + MS, gyro, accel, images, rate_hz=200.0)
    assert report.problems == [] and report.uncovered_images == 0
    # An offset that leaves every image inside the IMU's span shows only in the margins.
    shifted = check_imu(t + 200 * MS, gyro, accel, images, rate_hz=200.0)
    assert shifted.imu_before_first_image_s == pytest.approx(0.8)
    assert shifted.imu_after_last_image_s == pytest.approx(1.2)


def test_a_stated_rate_that_the_stamps_do_not_have(mh05: tuple[Imu, NDArray[np.int64]]) -> None:
    (t, gyro, accel), _ = mh05
    report = check_imu(t, gyro, accel, rate_hz=100.0, where="/imu topic")
    assert report.nominal_rate_hz == 100.0
    assert report.problems == [
        "/imu topic: the stamps give 200.0 Hz but the sensor file states 100 Hz; correct the "
        "stated rate (the noise densities are per square-root hertz and are scaled with it), or "
        "check the stamps' unit"
    ]
    micro = check_imu(t // 1000, gyro, accel)
    assert micro.rate_hz == pytest.approx(2e5, rel=0.01)
    assert "not nanoseconds" in micro.problems[0]


def test_a_synthetic_tilting_imu() -> None:
    t, gyro, accel = _tilting()
    report = check_imu(t, gyro, accel, t[::10][1:-1], rate_hz=200.0)
    assert report.problems == []
    assert report.gyro_tilt_ratio == pytest.approx(1.0, abs=0.25)
    in_degrees = check_imu(t, np.degrees(gyro), accel)
    assert in_degrees.gyro_units_suspect
    assert in_degrees.gyro_tilt_ratio == pytest.approx(57.3, rel=0.25)


def test_bursts_and_held_readings_are_neither_gaps_nor_saturation() -> None:
    t, gyro, accel = _tilting(seconds=6.0)
    # Samples delivered in threes, 1, 1 then 4 ms apart (500 Hz on average), each reading held
    # for three samples as by a driver that polls faster than its sensor updates.
    steps = np.tile([MS, MS, 4 * MS], t.size // 3)
    bursty = t[0] + np.concatenate([[0], np.cumsum(steps[:-1])]).astype(np.int64)
    held = np.repeat(np.arange(t.size)[::3], 3)
    report = check_imu(bursty, gyro[held], accel[held], rate_hz=500.0)
    assert report.rate_hz == pytest.approx(1000.0)
    assert report.mean_rate_hz == pytest.approx(500.0, rel=0.01)
    assert report.gaps == 0 and not any(report.saturated.values())
    assert report.problems == []


def test_empty_single_and_non_finite_streams_do_not_crash() -> None:
    t, gyro, accel = _tilting(seconds=2.0)
    empty = check_imu(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), t)
    assert empty.samples == 0 and "the IMU stream is empty" in empty.problems[0]
    json.dumps(empty.to_dict())
    single = check_imu(t[:1], gyro[:1], accel[:1], rate_hz=200.0)
    assert single.rate_hz is None and "a single sample" in single.problems[0]
    gyro = gyro.copy()
    gyro[5, 1] = np.nan
    gyro[9, 0] = np.inf
    spoiled = check_imu(t, gyro, accel, rate_hz=200.0)
    assert spoiled.non_finite == 2 and len(spoiled.problems) == 1
    assert f"first: sample 5, t={t[5]} ns" in spoiled.problems[0]
    nothing = check_imu(t, np.full_like(gyro, np.nan), accel, t[10:20])
    assert nothing.uncovered_images == 10
    assert "no usable IMU sample for the 10 image(s)" in nothing.problems[-1]


def test_arrays_of_the_wrong_shape_are_a_caller_error() -> None:
    t, gyro, accel = _tilting(seconds=1.0)
    with pytest.raises(ValueError, match=r"gyro_radps must be \(200, 3\)"):
        check_imu(t, gyro[:-1], accel)
