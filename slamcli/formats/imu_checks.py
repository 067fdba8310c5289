"""Checks of an IMU stream before a visual-inertial run, from plain arrays.

Any reader can call :func:`check_imu` with what it read: the stamps in the order the file or
log holds them, the gyroscope and accelerometer readings, and optionally the camera's stamps
and the rate the sensor file states. It never raises on bad data: every finding is a fact in
the returned :class:`ImuReport` and, when it would spoil a run, one line in
:attr:`ImuReport.problems` that names the stream (``where``), the sample or stamp, and what to
do. Sample numbers in messages are 0-based positions in the arrays as given (so, in file
order); stamps are printed in whole nanoseconds so they can be searched for in the file.

What is checked, and why:

Time
    A visual-inertial system integrates the gyroscope and accelerometer between camera frames,
    so it needs stamps that increase, at a steady rate, without holes.

    * ``backwards``: stamps earlier than the one before them, in file order. The readers sort
      by time, so a run still sees ordered samples, but a stamp that goes back means rows were
      written out of order (two writer threads) or the clock jumped (a clock reset); the
      stream's times are then not to be trusted.
    * ``duplicates``: samples whose stamp another sample already has. Two readings at one
      instant give a zero interval, which an integrator cannot use.
    * ``rate_hz``: the median of the positive intervals between time-ordered stamps, which
      one late sample or one gap does not move; ``mean_rate_hz`` counts the distinct stamps
      over the span, which bursts of samples (a driver that delivers them in pairs, short and
      long intervals in turn) do not move. The rate the sensor file states is wrong when both
      differ from it by more than :data:`RATE_TOLERANCE`: the noise densities are per
      square-root hertz, so a wrong stated rate mis-weights every IMU term. A rate outside
      :data:`PLAUSIBLE_RATE_HZ` means the stamps are not nanoseconds (microseconds give a
      thousand times the rate) or the IMU is too slow to integrate between frames.
    * ``gaps``: intervals longer than :data:`GAP_FACTOR` times the stream's usual longest
      interval, the 90th percentile of the positive ones. On a regular stream that is the
      median plus jitter: one dropped sample doubles an interval, 2.5 intervals means at least
      two samples in a row are missing, and a late sample (one interval up to about twice the
      usual and a short one after it) does not reach it. On a bursty stream it is the long
      interval of the bursts, so the bursts are not taken for gaps.

Camera coverage
    Every image needs IMU samples close before and after it, within :data:`COVER_INTERVALS`
    nominal IMU intervals: the integration between two frames starts and ends there. Images
    outside the IMU's span cannot be used; when the streams are recorded together they start
    and end within about a frame of each other, so an IMU that starts more than a camera frame
    after the first image (or ends more than a frame before the last) means its clock is offset
    from the camera's, or it started late. Stamps alone cannot show an offset that keeps every
    image inside the IMU's span: ``camera_offset_s`` is the smallest shift of the IMU's stamps
    that brings every image inside it, a lower bound of the true offset.

Units
    * Gyroscope in deg/s read as rad/s: common MEMS gyroscopes measure up to 2000 deg/s
      (34.9 rad/s), so a 99th percentile of ``|w|`` above :data:`GYRO_MAX_RADPS` cannot be
      rad/s. Slower motion read in deg/s stays within that range, so the gyroscope is also held
      against the accelerometer: gravity's direction, as the accelerometer sees it, turns when
      the IMU tilts, and the gyroscope must account for that turn. A gyroscope in deg/s
      accounts for 57.3 times as much (:data:`TILT_RATIO`). Linear acceleration only adds to
      what the accelerometer sees, so a rad/s gyroscope never looks too large this way; a
      gyroscope whose axes are not the accelerometer's can, and the message says so.
    * Accelerometer in g: the mean ``|a|`` over a recording is close to gravity whatever the
      motion, since a rig cannot accelerate one way for long. Near 1 it reads in g; near 9.81
      in m/s^2; far from both (:data:`ACCEL_BAND`), the scale is wrong (milli-g, raw counts) or
      gravity was removed, and visual-inertial systems need it in.
    * Saturation: a sensor driven past its range outputs its full-scale value for as long as
      it is exceeded. Per axis, samples in runs of at least :data:`SATURATION_RUN` equal
      readings at the axis' largest or smallest value are counted, when that value's longest
      run is longer than any run of equal readings elsewhere on the axis: a stream that holds
      each reading for several samples (sampled faster than its sensor updates) or a coarse
      one at rest repeats values anywhere, and there a flat stretch at an extreme says
      nothing.

Non-finite readings are counted and left out of every check on values. An empty stream or a
single sample is a problem of its own.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

GAP_FACTOR = 2.5
"""An interval longer than this many usual intervals (the 90th percentile) is a gap: two or
more samples lost."""

COVER_INTERVALS = 2.0
"""An image is covered when IMU samples lie within this many nominal IMU intervals before and
after it."""

RATE_TOLERANCE = 0.05
"""Largest relative difference between a measured rate and the stated one. Sensor clocks are
off by parts per million and neither the median nor the mean follows jitter, so 5 % only
catches a wrong setting (100 Hz for 200 Hz) or stamps in another unit."""

PLAUSIBLE_RATE_HZ = (20.0, 10_000.0)
"""Measured rates an IMU stream can have: slower cannot be integrated between camera frames,
faster means the stamps are not nanoseconds."""

GYRO_MAX_RADPS = 35.0
"""A 99th percentile of ``|w|`` above this is not rad/s: 2000 deg/s (34.9 rad/s) is the
largest range of common MEMS gyroscopes, and hand-held rigs, drones and cars rarely turn
faster than 10 rad/s."""

TILT_WINDOW_S = 0.25
"""Length of the windows over which the accelerometer's gravity direction is averaged: long
enough to average out vibration and noise, short enough to follow a tilt."""

TILT_MIN_RAD = math.radians(1.0)
"""A window pair counts in the tilt comparison when gravity's direction turns at least this
much between them: far above accelerometer noise averaged over a window."""

TILT_MIN_WINDOWS = 4
"""Window pairs with a tilt needed before the gyroscope is judged against the accelerometer."""

TILT_RATIO = 8.0
"""The gyroscope is suspected of deg/s when it accounts for more than this many times the tilt
the accelerometer sees: about the geometric middle of 1 (rad/s) and 57.3 (deg/s)."""

STANDARD_GRAVITY = 9.80665
"""m/s^2 in one g."""

ACCEL_BAND = 1.25
"""Mean ``|a|`` within this factor of 1 reads in g, within it of :data:`STANDARD_GRAVITY` in
m/s^2 (room for vibration, bias and scale error); outside both, the units are suspect."""

SATURATION_RUN = 3
"""Fewest equal readings in a row at an axis' extreme that count as saturation."""

NAMED = 3
"""Samples, gaps or images named in one problem line; the others are counted."""

AXES = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
"""The keys of :attr:`ImuReport.saturated`."""


@dataclass(frozen=True)
class ImuReport:
    """What :func:`check_imu` found in one IMU stream.

    Times are seconds; ``None`` where a figure cannot be had (too few samples, no images).

    Attributes:
        where: the stream, as messages name it (a file, or a log's topic).
        samples: rows given, finite or not.
        rate_hz: measured rate: 1 / the median positive interval between time-ordered stamps.
        mean_rate_hz: distinct stamps less one, over the span.
        nominal_rate_hz: the rate the sensor file states, as given.
        span_s: last stamp minus first.
        gaps: intervals longer than ``gap_threshold_s``.
        gap_threshold_s: :data:`GAP_FACTOR` times the 90th percentile of the intervals.
        largest_gap_s: the longest interval between time-ordered stamps (a gap only when it
            exceeds ``gap_threshold_s``).
        duplicates: samples whose stamp an earlier one already has.
        backwards: samples stamped earlier than the sample before them, in file order.
        non_finite: samples with a NaN or infinite reading (left out of the value checks).
        images: camera stamps given.
        imu_before_first_image_s: IMU time before the first image (negative: the IMU starts
            after it).
        imu_after_last_image_s: IMU time after the last image (negative: it ends before it).
        images_before_imu: images stamped before the first IMU sample.
        images_after_imu: images stamped after the last IMU sample.
        uncovered_images: images without an IMU sample within :data:`COVER_INTERVALS` nominal
            intervals before and after them (those outside the IMU's span included).
        camera_offset_s: the smallest shift to subtract from the IMU's stamps that brings every
            image inside the IMU's span: 0 when they already are, positive when the IMU's
            stamps run late; ``None`` when no shift can (the IMU is shorter than the images'
            span) or there are no images.
        gyro_p99_radps: 99th percentile of ``|w|`` as given.
        gyro_tilt_ratio: how many times the tilt the accelerometer sees the gyroscope accounts
            for (about 1 in rad/s, 57 in deg/s); ``None`` without enough tilting motion.
        gyro_units_suspect: the gyroscope looks like deg/s; ``gyro_units_reason`` says why.
        accel_mean_mps2: mean ``|a|`` as given.
        accel_units_suspect: the accelerometer is not in m/s^2; ``accel_units_reason`` says why.
        saturated: per axis (:data:`AXES`), samples stuck at the axis' extreme value.
        problems: one line per problem, naming ``where``, the sample or stamp and what to do.
    """

    where: str
    samples: int
    rate_hz: float | None = None
    mean_rate_hz: float | None = None
    nominal_rate_hz: float | None = None
    span_s: float = 0.0
    gaps: int = 0
    gap_threshold_s: float | None = None
    largest_gap_s: float | None = None
    duplicates: int = 0
    backwards: int = 0
    non_finite: int = 0
    images: int = 0
    imu_before_first_image_s: float | None = None
    imu_after_last_image_s: float | None = None
    images_before_imu: int = 0
    images_after_imu: int = 0
    uncovered_images: int = 0
    camera_offset_s: float | None = None
    gyro_p99_radps: float | None = None
    gyro_tilt_ratio: float | None = None
    gyro_units_suspect: bool = False
    gyro_units_reason: str = ""
    accel_mean_mps2: float | None = None
    accel_units_suspect: bool = False
    accel_units_reason: str = ""
    saturated: dict[str, int] = field(default_factory=lambda: dict.fromkeys(AXES, 0))
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """No problems."""
        return not self.problems

    def to_dict(self) -> dict[str, Any]:
        """The report as JSON-ready types (for run.json and ``info --json``)."""
        d = asdict(self)
        d["saturated"] = dict(self.saturated)
        d["problems"] = list(self.problems)
        return d


def check_imu(
    stamps_ns: ArrayLike,
    gyro_radps: ArrayLike,
    accel_mps2: ArrayLike,
    camera_stamps_ns: ArrayLike | None = None,
    rate_hz: float | None = None,
    where: str = "imu0/data.csv",
) -> ImuReport:
    """Check an IMU stream the way a visual-inertial run needs it (see the module docstring).

    Args:
        stamps_ns: (N,) int64 stamps in nanoseconds, in file order (not sorted).
        gyro_radps: (N, 3) float64 angular rates as recorded, meant to be rad/s.
        accel_mps2: (N, 3) float64 specific forces as recorded, meant to be m/s^2.
        camera_stamps_ns: (M,) int64 image stamps, or None to skip the coverage checks.
        rate_hz: the rate the sensor file states, or None.
        where: how messages name the stream (``imu0/data.csv``, a topic).

    Returns:
        The facts and the problems; bad data never raises.

    Raises:
        ValueError: the arrays' shapes disagree (a caller's mistake, not the data's).
    """
    t = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    n = int(t.size)
    gyro = np.asarray(gyro_radps, dtype=np.float64)
    accel = np.asarray(accel_mps2, dtype=np.float64)
    for name, a in (("gyro_radps", gyro), ("accel_mps2", accel)):
        if a.shape != (n, 3) and not (n == 0 and a.size == 0):
            raise ValueError(f"{name} must be ({n}, 3) for {n} stamps, got {a.shape}")
    nominal = None if rate_hz is None else float(rate_hz)
    if n == 0:
        return ImuReport(
            where,
            0,
            nominal_rate_hz=nominal,
            problems=[
                f"{where}: the IMU stream is empty; record the IMU with the cameras, or run "
                "without it"
            ],
        )
    gyro, accel = gyro.reshape(n, 3), accel.reshape(n, 3)
    problems: list[str] = []
    facts: dict[str, Any] = {}

    finite = np.asarray(np.isfinite(np.hstack([gyro, accel])).all(axis=1))
    facts["non_finite"] = n - int(finite.sum())
    if facts["non_finite"]:
        first = int(np.flatnonzero(~finite)[0])
        problems.append(
            f"{where}: {facts['non_finite']} sample(s) hold a reading that is not a finite "
            f"number (first: sample {first}, t={t[first]} ns); repair or drop those rows"
        )

    order = np.argsort(t, kind="stable")
    facts |= _order_checks(t, order, where, problems)
    median_ns = facts.pop("median_ns")
    if n == 1 or median_ns is None:
        problems.append(
            f"{where}: {'a single sample' if n == 1 else 'every sample has one stamp'}; a "
            "visual-inertial run needs the IMU sampled over the whole recording"
        )
    else:
        _rate_checks(facts, nominal, where, problems)

    # A valid stated rate sets the coverage window: a measured rate that strays from it is
    # reported above, and the window should not stretch with the stream's faults.
    stated = nominal if nominal is not None and math.isfinite(nominal) and nominal > 0 else None
    interval_s = 1.0 / stated if stated else (median_ns or 0.0) * 1e-9
    usable = order[finite[order]]
    if usable.size:
        facts |= _gyro_units(t[usable], gyro[usable], accel[usable], where, problems)
        facts |= _accel_units(accel[usable], where, problems)
        facts["saturated"] = _saturation(
            np.hstack([gyro[usable], accel[usable]]), usable, t, where, problems
        )
    if camera_stamps_ns is not None:
        facts |= _coverage(
            np.unique(t[usable]),
            np.sort(np.asarray(camera_stamps_ns, dtype=np.int64).reshape(-1)),
            COVER_INTERVALS * interval_s,
            where,
            problems,
        )
    return ImuReport(where, n, nominal_rate_hz=nominal, problems=problems, **facts)


def _order_checks(t: I64, order: I64, where: str, problems: list[str]) -> dict[str, Any]:
    """Backwards stamps (file order), duplicates, the median interval, gaps and the span."""
    back = np.flatnonzero(t[1:] < t[:-1]) + 1
    if back.size:
        named = "; ".join(f"sample {k} (t={t[k]} ns, after t={t[k - 1]} ns)" for k in back[:NAMED])
        problems.append(
            f"{where}: {back.size} stamp(s) earlier than the sample before: {named}"
            f"{_more(back.size)}; the rows are out of time order or the clock jumped back: "
            "if only the rows are shuffled, sort the file by its stamps, else re-stamp it"
        )
    ts = t[order]
    dup = np.sort(order[1:][ts[1:] == ts[:-1]])
    if dup.size:
        named = "; ".join(f"sample {k} (t={t[k]} ns)" for k in dup[:NAMED])
        problems.append(
            f"{where}: {dup.size} sample(s) repeat an earlier stamp: {named}{_more(dup.size)}; "
            "drop the repeated rows, or re-stamp them if their readings differ: two readings "
            "at one instant cannot be integrated"
        )
    facts: dict[str, Any] = {
        "backwards": int(back.size),
        "duplicates": int(dup.size),
        "span_s": (int(ts[-1]) - int(ts[0])) * 1e-9,
        "median_ns": None,
    }
    steps = np.diff(ts)
    positive = steps[steps > 0]
    if not positive.size:
        return facts
    median_ns = float(np.median(positive))
    threshold = GAP_FACTOR * float(np.percentile(positive, 90))
    gaps = np.flatnonzero(steps > threshold)
    facts |= {
        "median_ns": median_ns,
        "rate_hz": 1e9 / median_ns,
        "mean_rate_hz": positive.size / facts["span_s"],
        "gaps": int(gaps.size),
        "gap_threshold_s": threshold * 1e-9,
        "largest_gap_s": float(steps.max()) * 1e-9,
    }
    if gaps.size:
        longest = gaps[np.argsort(-steps[gaps], kind="stable")][:NAMED]
        named = "; ".join(
            f"{steps[k] * 1e-9:.3f} s after sample {order[k]} (t={ts[k]} ns)" for k in longest
        )
        problems.append(
            f"{where}: {gaps.size} gap(s) longer than {threshold * 1e-6:.1f} ms "
            f"({GAP_FACTOR:g} times the usual interval): {named}"
            f"{_more(gaps.size)}; samples were dropped (a busy bus or disk): re-record, or "
            "cut the sequence at the gap, as a run integrates blindly across it"
        )
    return facts


def _rate_checks(
    facts: dict[str, Any], nominal: float | None, where: str, problems: list[str]
) -> None:
    """The measured rates against the stated one and against what an IMU can have; a rate is
    wrong only when the median and the mean rate both say so (see the module docstring)."""
    rates = (facts["rate_hz"], facts["mean_rate_hz"])
    given = f"{rates[0]:.1f} Hz"
    if abs(rates[1] / rates[0] - 1.0) > RATE_TOLERANCE:
        given += f" by the median interval and {rates[1]:.1f} Hz on average"
    low, high = PLAUSIBLE_RATE_HZ
    if min(rates) > high:
        problems.append(
            f"{where}: the stamps give {given}, faster than an IMU runs: the stamps are "
            "probably not nanoseconds (microseconds give 1000 times the rate); convert them"
        )
    elif max(rates) < low:
        problems.append(
            f"{where}: the stamps give {given}, too slow to integrate between camera frames "
            f"(under {low:g} Hz); check the stamps' unit, or record the IMU faster"
        )
    if nominal is None:
        return
    if not (math.isfinite(nominal) and nominal > 0):
        problems.append(
            f"{where}: the stated rate {nominal!r} Hz is not a positive number; give the "
            f"IMU's rate (the stamps give {given})"
        )
    elif all(abs(r / nominal - 1.0) > RATE_TOLERANCE for r in rates):
        problems.append(
            f"{where}: the stamps give {given} but the sensor file states {nominal:g} Hz; "
            "correct the stated rate (the noise densities are per square-root hertz and are "
            "scaled with it), or check the stamps' unit"
        )


def _gyro_units(
    stamps: I64, gyro: F64, accel: F64, where: str, problems: list[str]
) -> dict[str, Any]:
    """Whether the gyroscope reads deg/s: its 99th percentile, then the tilt comparison."""
    p99 = float(np.percentile(np.linalg.norm(gyro, axis=1), 99))
    ratio = _tilt_ratio(stamps, gyro, accel)
    reason = ""
    if p99 > GYRO_MAX_RADPS:
        reason = (
            f"99th percentile of |w| is {p99:.1f} rad/s, above the {GYRO_MAX_RADPS:g} rad/s "
            "(2000 deg/s) common MEMS gyroscopes measure"
        )
    elif ratio is not None and ratio > TILT_RATIO:
        reason = (
            f"it turns gravity's direction {ratio:.1f} times as far as the accelerometer sees "
            "it turn (deg/s read as rad/s gives 57.3; or its axes are not the accelerometer's)"
        )
    if reason:
        problems.append(
            f"{where}: the gyroscope looks like deg/s, not rad/s: {reason}; convert the gyro "
            "to rad/s (multiply by pi/180)"
        )
    return {
        "gyro_p99_radps": p99,
        "gyro_tilt_ratio": ratio,
        "gyro_units_suspect": bool(reason),
        "gyro_units_reason": reason,
    }


def _tilt_ratio(stamps: I64, gyro: F64, accel: F64) -> float | None:
    """How many times the tilt the accelerometer sees the gyroscope accounts for.

    The accelerometer is averaged over windows of :data:`TILT_WINDOW_S`; between two window
    centres gravity's direction ``g`` turns by an angle the accelerometer sees, and by
    ``|r x g|`` by the gyroscope's rotation ``r`` (each reading times the interval to the next
    stamp, summed over the same stretch, with the median reading taken off as a bias). Only
    window pairs with a tilt of at least :data:`TILT_MIN_RAD` count; fewer than
    :data:`TILT_MIN_WINDOWS` give ``None``.

    Args:
        stamps: (K,) int64 nanoseconds, time-ordered.
        gyro, accel: (K, 3) float64 finite readings at those stamps.
    """
    steps = np.diff(stamps)
    positive = steps[steps > 0]
    if not positive.size:
        return None
    typical = float(np.median(positive))
    w = max(2, round(TILT_WINDOW_S * 1e9 / typical))
    windows = gyro.shape[0] // w
    if windows <= TILT_MIN_WINDOWS:
        return None
    mean = accel[: windows * w].reshape(windows, w, 3).mean(axis=1)
    norm = np.linalg.norm(mean, axis=1)
    valid = norm > 0
    down = mean / np.where(valid, norm, 1.0)[:, None]
    half = w // 2
    held = np.append(steps, typical) * 1e-9
    rotation = (gyro - np.median(gyro, axis=0)) * held[:, None]
    turn = rotation[half : half + (windows - 1) * w].reshape(windows - 1, w, 3).sum(axis=1)
    seen = np.arccos(np.clip(np.einsum("ij,ij->i", down[1:], down[:-1]), -1.0, 1.0))
    told = np.linalg.norm(np.cross(turn, down[:-1]), axis=1)
    tilting = (seen >= TILT_MIN_RAD) & valid[1:] & valid[:-1]
    if int(tilting.sum()) < TILT_MIN_WINDOWS:
        return None
    return float(told[tilting].sum() / seen[tilting].sum())


def _accel_units(accel: F64, where: str, problems: list[str]) -> dict[str, Any]:
    """Whether the accelerometer reads m/s^2, from its mean ``|a|``."""
    mean = float(np.linalg.norm(accel, axis=1).mean())
    reason = todo = ""
    if 1.0 / ACCEL_BAND <= mean <= ACCEL_BAND:
        reason = f"mean |a| is {mean:.3f}, gravity in g"
        todo = "convert the accelerometer to m/s^2 (multiply by 9.80665)"
    elif not STANDARD_GRAVITY / ACCEL_BAND <= mean <= STANDARD_GRAVITY * ACCEL_BAND:
        reason = (
            f"mean |a| is {mean:.4g}, neither gravity in m/s^2 ({STANDARD_GRAVITY:g}) nor in g (1)"
        )
        todo = (
            "check the accelerometer's unit and scale (milli-g? raw counts?) and that gravity "
            "is not removed: a visual-inertial run needs it in, in m/s^2"
        )
    if reason:
        problems.append(f"{where}: the accelerometer is not in m/s^2: {reason}; {todo}")
    return {
        "accel_mean_mps2": mean,
        "accel_units_suspect": bool(reason),
        "accel_units_reason": reason,
    }


def _saturation(values: F64, rows: I64, t: I64, where: str, problems: list[str]) -> dict[str, int]:
    """Samples stuck at each axis' extreme (see the module docstring).

    Args:
        values: (K, 6) float64 finite readings in time order, gyro then accel.
        rows: (K,) their sample numbers in the arrays as given.
        t: (N,) the stamps as given.
    """
    counts = dict.fromkeys(AXES, 0)
    for axis, name in enumerate(AXES):
        v = values[:, axis]
        starts = np.concatenate([[0], np.flatnonzero(v[1:] != v[:-1]) + 1])
        lengths = np.diff(np.append(starts, v.size))
        rails = np.unique([v.min(), v.max()])
        on_rail = np.isin(v[starts], rails)
        elsewhere = int(lengths[~on_rail].max()) if (~on_rail).any() else 0
        # A rail is a sensor's limit when its longest run beats every run off it; then each of
        # its runs of SATURATION_RUN or more is the sensor held there.
        stuck = np.zeros(starts.size, dtype=bool)
        for rail in rails:
            here = v[starts] == rail
            if lengths[here].max() > elsewhere:
                stuck |= here & (lengths >= SATURATION_RUN)
        if not stuck.any():
            continue
        counts[name] = int(lengths[stuck].sum())
        first = int(starts[stuck][0])
        values_at = " and ".join(f"{x:.6g}" for x in np.unique(v[starts[stuck]]))
        sensor, unit = ("gyroscope", "rad/s") if axis < 3 else ("accelerometer", "m/s^2")
        if rails.size == 1:
            problems.append(
                f"{where}: {sensor} {name[-1]} reads {values_at} {unit} in every sample: the "
                "axis is dead or was not recorded; check the sensor and the recorder's fields"
            )
            continue
        problems.append(
            f"{where}: {sensor} {name[-1]} sticks at its extreme {values_at} {unit} for "
            f"{counts[name]} samples in runs of {SATURATION_RUN} or more (first: sample "
            f"{rows[first]}, t={t[rows[first]]} ns): the sensor saturated and its readings "
            "there are wrong; re-record with a larger measurement range or gentler motion"
        )
    return counts


def _coverage(
    imu: I64, images: I64, window_s: float, where: str, problems: list[str]
) -> dict[str, Any]:
    """How the IMU's samples cover the images (see the module docstring).

    Args:
        imu: (K,) sorted, distinct stamps of the finite IMU samples.
        images: (M,) sorted image stamps.
        window_s: how close a sample must be before and after an image, seconds.
    """
    m = int(images.size)
    facts: dict[str, Any] = {"images": m}
    if m == 0:
        return facts
    if imu.size == 0:
        problems.append(f"{where}: no usable IMU sample for the {m} image(s)")
        return facts | {"uncovered_images": m}
    window = round(window_s * 1e9)
    before = np.searchsorted(imu, images, side="right") - 1
    after = np.searchsorted(imu, images, side="left")
    has_before, has_after = before >= 0, after < imu.size
    covered = (
        has_before
        & has_after
        & (images - imu[np.maximum(before, 0)] <= window)
        & (imu[np.minimum(after, imu.size - 1)] - images <= window)
    )
    lead = int(images[0]) - int(imu[0])
    trail = int(imu[-1]) - int(images[-1])
    facts |= {
        "imu_before_first_image_s": lead * 1e-9,
        "imu_after_last_image_s": trail * 1e-9,
        "images_before_imu": int((~has_before).sum()),
        "images_after_imu": int((~has_after).sum()),
        "uncovered_images": int((~covered).sum()),
        "camera_offset_s": _offset(lead, trail),
    }
    steps = np.diff(images)
    steps = steps[steps > 0]
    tolerance = int(np.median(steps)) if steps.size else window
    frame = f"a camera frame ({tolerance * 1e-9:.3f} s)" if steps.size else "two IMU intervals"
    offset = facts["camera_offset_s"]
    shift = (
        f"; if the streams were recorded together, the IMU's stamps run "
        f"{'late' if offset > 0 else 'early'} against the camera's by at least "
        f"{abs(offset):.3f} s: give the camera-IMU time offset (Kalibr's timeshift_cam_imu) "
        "or re-stamp the IMU"
        if offset
        else ""
    )
    if -lead > tolerance:
        problems.append(
            f"{where}: the IMU starts {-lead * 1e-9:.3f} s after the first image (image "
            f"t={images[0]} ns, first IMU sample t={imu[0]} ns), more than {frame}: "
            f"{facts['images_before_imu']} image(s) have no IMU data before them{shift}; "
            "otherwise trim the images to the IMU's span"
        )
    if -trail > tolerance:
        problems.append(
            f"{where}: the IMU ends {-trail * 1e-9:.3f} s before the last image (image "
            f"t={images[-1]} ns, last IMU sample t={imu[-1]} ns), more than {frame}: "
            f"{facts['images_after_imu']} image(s) have no IMU data after them{shift}; "
            "otherwise trim the images to the IMU's span"
        )
    inside = ~covered & has_before & has_after
    if inside.any():
        named = ", ".join(f"t={s} ns" for s in images[inside][:NAMED])
        problems.append(
            f"{where}: {int(inside.sum())} image(s) have no IMU sample within "
            f"{window_s * 1e3:.1f} ms before and after them ({named}{_more(int(inside.sum()))}): "
            "they fall in gaps of the IMU stream; re-record, or leave those images out"
        )
    return facts


def _offset(lead: int, trail: int) -> float | None:
    """The smallest shift, in seconds, to subtract from the IMU's stamps so that the IMU starts
    before the first image and ends after the last one, given how long it runs before the first
    (``lead``) and after the last (``trail``), in nanoseconds; None when no shift does (the IMU
    runs for a shorter time than the images)."""
    if lead >= 0 and trail >= 0:
        return 0.0
    if lead + trail < 0:
        return None
    return (-lead if lead < 0 else trail) * 1e-9


def _more(count: int, named: int = NAMED) -> str:
    """``", and 4 more"`` when ``count`` exceeds the ``named`` ones."""
    return f", and {count - named} more" if count > named else ""


__all__ = [
    "ACCEL_BAND",
    "AXES",
    "COVER_INTERVALS",
    "GAP_FACTOR",
    "GYRO_MAX_RADPS",
    "PLAUSIBLE_RATE_HZ",
    "RATE_TOLERANCE",
    "SATURATION_RUN",
    "TILT_RATIO",
    "ImuReport",
    "check_imu",
]
