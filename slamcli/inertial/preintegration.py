"""IMU preintegration between two instants, on GTSAM's preintegrated measurements.

An IMU reads the body's angular velocity (gyroscope, rad/s) and specific force (accelerometer,
m/s², gravity included with a plus sign: a body at rest reads +9.81 up) a few hundred times a
second. Between two keyframes those readings are summed into one relative-motion measurement,
``ΔR``, ``Δv``, ``Δp`` in the first keyframe's body frame (Forster et al., "On-Manifold
Preintegration", 2017), together with its covariance and its first-order dependence on the
biases. GTSAM's ``PreintegratedImuMeasurements`` does that work; this module feeds it.

The interval [t0, t1] rarely starts or ends on an IMU sample. As ORB-SLAM3's
``Tracking::PreintegrateIMU`` does, the reading at each end is interpolated linearly between the
two samples around it, and each piece between consecutive instants (t0, the samples strictly
inside, t1) is integrated with the mean of its two end readings. The pieces then add up to
exactly ``t1 - t0``, so consecutive intervals share their end instants and no IMU time is lost
or counted twice.

Noise follows the ASL ``imu0/sensor.yaml`` convention: continuous-time densities. GTSAM's
parameters take the covariance of the continuous-time noise (``density² · I``) and divide it by
each step's duration itself. Gravity points along -z of the navigation frame
(``MakeSharedU``), with the standard 9.80665 m/s².
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.errors import InputError
from slamcli.formats.euroc.calibration import IMU_NOISE_KEYS

if TYPE_CHECKING:
    import gtsam

    from slamcli.formats.euroc import ImuSensor

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

GRAVITY_MPS2 = 9.80665
"""Standard gravity, m/s²."""
INTEGRATION_SIGMA = 1e-4
"""Continuous-time noise of integrating velocity into position, m/s/√Hz (GTSAM's
``integrationCovariance`` is its square, 1e-8 as in GTSAM's examples): 0.05 mm over 0.25 s,
a small allowance for the piecewise-constant integration itself."""


@dataclass(frozen=True, eq=False)
class ImuNoise:
    """The IMU's noise model and where it sits on the body.

    Attributes:
        gyro_noise_density: rad / s / √Hz, white noise of the gyroscope.
        gyro_random_walk: rad / s² / √Hz, diffusion of the gyroscope's bias.
        accel_noise_density: m / s² / √Hz, white noise of the accelerometer.
        accel_random_walk: m / s³ / √Hz, diffusion of the accelerometer's bias.
        rate_hz: the nominal sample rate.
        body_from_imu: (4, 4) float64 pose of the IMU on the body (``T_BS``); the identity
            when, as in EuRoC, the body frame is the IMU's.
        gravity_mps2: magnitude of gravity.
    """

    gyro_noise_density: float
    gyro_random_walk: float
    accel_noise_density: float
    accel_random_walk: float
    rate_hz: float = 200.0
    body_from_imu: F64 = field(default_factory=lambda: np.eye(4))
    gravity_mps2: float = GRAVITY_MPS2

    @classmethod
    def from_sensor(cls, sensor: ImuSensor) -> ImuNoise:
        """The noise model of an ASL IMU as :func:`slamcli.formats.euroc.read_imu_sensor`
        returns it."""
        return cls(
            gyro_noise_density=sensor.gyroscope_noise_density,
            gyro_random_walk=sensor.gyroscope_random_walk,
            accel_noise_density=sensor.accelerometer_noise_density,
            accel_random_walk=sensor.accelerometer_random_walk,
            rate_hz=sensor.rate_hz,
            body_from_imu=np.asarray(sensor.body_from_sensor, dtype=np.float64),
        )

    @classmethod
    def has_settings(cls, details: object) -> bool:
        """Whether ``details`` (a source's ``info().details["imu"]``) holds a noise model."""
        return isinstance(details, dict) and all(key in details for key in IMU_NOISE_KEYS)

    @classmethod
    def from_details(cls, details: dict[str, Any]) -> ImuNoise:
        """The noise model a source's ``info`` gives as ``details["imu"]``: the ASL names of
        :meth:`slamcli.formats.euroc.ImuSensor.noise`, ``rate_hz`` and, when the IMU is not
        the body, ``body_from_imu`` (4 rows of 4)."""
        return cls(
            *(float(details[key]) for key in IMU_NOISE_KEYS),
            rate_hz=float(details.get("rate_hz", 200.0)),
            body_from_imu=np.asarray(details.get("body_from_imu", np.eye(4)), dtype=np.float64),
        )

    @classmethod
    def from_yaml(cls, path: str | Path) -> ImuNoise:
        """The noise model of an ASL ``imu0/sensor.yaml``.

        Raises:
            FormatError: a missing key or a bad value (names file and key).
        """
        from slamcli.formats.euroc import read_imu_sensor

        return cls.from_sensor(read_imu_sensor(path))

    def params(self) -> gtsam.PreintegrationParams:
        """GTSAM's parameters for :class:`gtsam.PreintegratedImuMeasurements`: z-up gravity,
        continuous-time covariances, and the IMU's pose on the body unless it is the
        identity."""
        import gtsam

        p = gtsam.PreintegrationParams.MakeSharedU(self.gravity_mps2)
        self._fill(p)
        return p

    def combined_params(self) -> gtsam.PreintegrationCombinedParams:
        """As :meth:`params`, with the bias random walks, for
        :class:`gtsam.PreintegratedCombinedMeasurements` (biases that drift between
        keyframes)."""
        import gtsam

        p = gtsam.PreintegrationCombinedParams.MakeSharedU(self.gravity_mps2)
        self._fill(p)
        p.setBiasAccCovariance(self.accel_random_walk**2 * np.eye(3))
        p.setBiasOmegaCovariance(self.gyro_random_walk**2 * np.eye(3))
        return p

    def _fill(self, p: gtsam.PreintegrationParams) -> None:
        import gtsam

        p.setGyroscopeCovariance(self.gyro_noise_density**2 * np.eye(3))
        p.setAccelerometerCovariance(self.accel_noise_density**2 * np.eye(3))
        p.setIntegrationCovariance(INTEGRATION_SIGMA**2 * np.eye(3))
        if not np.allclose(self.body_from_imu, np.eye(4), atol=1e-12):
            p.setBodyPSensor(gtsam.Pose3(self.body_from_imu))


def check_imu_samples(
    stamps_ns: ArrayLike, gyro: ArrayLike, accel: ArrayLike
) -> tuple[I64, F64, F64]:
    """IMU samples as (M,) int64 strictly increasing stamps and (M, 3) float64 gyro (rad/s)
    and accel (m/s²) readings. It validates the arrays only; a stream's quality (rate, gaps,
    saturation, coverage of the images) is :func:`slamcli.formats.imu_checks.check_imu`'s.

    Raises:
        InputError: mismatched shapes, non-finite readings or stamps that do not increase.
    """
    t = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    g = np.asarray(gyro, dtype=np.float64)
    a = np.asarray(accel, dtype=np.float64)
    if g.shape != (t.size, 3) or a.shape != (t.size, 3):
        raise InputError(
            f"IMU samples: expected (M,) stamps with (M, 3) gyro and accel, got {t.shape}, "
            f"{g.shape} and {a.shape}"
        )
    if not (np.isfinite(g).all() and np.isfinite(a).all()):
        raise InputError("IMU samples: a gyro or accel reading is not finite")
    if t.size > 1 and not (np.diff(t) > 0).all():
        k = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise InputError(
            f"IMU samples: stamps must increase, but sample {k + 1} ({t[k + 1]} ns) does not "
            f"follow sample {k} ({t[k]} ns)",
            hint="sort the samples by time and drop duplicates",
        )
    return t, g, a


def interval_readings(
    stamps_ns: I64, gyro: F64, accel: F64, t0_ns: int, t1_ns: int
) -> tuple[F64, F64, F64]:
    """The piecewise-constant readings that cover [t0, t1] exactly.

    Args:
        stamps_ns: (M,) int64 strictly increasing IMU stamps.
        gyro, accel: (M, 3) readings at those stamps.
        t0_ns, t1_ns: the interval, ``t0 < t1``.

    Returns:
        dt_s: (P,) durations in seconds of the pieces between t0, the samples strictly inside
        and t1 (they sum to ``t1 - t0``); gyro (P, 3) and accel (P, 3): the mean of each piece's
        two end readings, the ends interpolated linearly between their neighbouring samples.

    Raises:
        InputError: ``t1 <= t0``, or no IMU sample at or before ``t0`` or at or after ``t1``.
    """
    where = f"interval [{t0_ns}, {t1_ns}] ns"
    if t1_ns <= t0_ns:
        raise InputError(f"IMU preintegration over {where}: the end must follow the start")
    if stamps_ns.size == 0 or stamps_ns[0] > t0_ns or stamps_ns[-1] < t1_ns:
        found = (
            "no samples"
            if stamps_ns.size == 0
            else f"samples from {stamps_ns[0]} to {stamps_ns[-1]} ns"
        )
        raise InputError(
            f"IMU preintegration over {where}: no IMU samples cover it ({found})",
            hint="the IMU log must start before the first keyframe and end after the last",
        )
    # The last sample at or before t0 to the first at or after t1.
    lo = int(np.searchsorted(stamps_ns, t0_ns, side="right")) - 1
    hi = int(np.searchsorted(stamps_ns, t1_ns, side="left")) + 1
    t = stamps_ns[lo:hi]
    knots = np.concatenate([[t0_ns], t[(t > t0_ns) & (t < t1_ns)], [t1_ns]]).astype(np.int64)
    # Interpolate relative to t0 in float seconds: int64 nanoseconds since 1970 lose their
    # last digits in float64.
    x = (t - t0_ns).astype(np.float64) * 1e-9
    xk = (knots - t0_ns).astype(np.float64) * 1e-9
    g = np.stack([np.interp(xk, x, gyro[lo:hi, c]) for c in range(3)], axis=1)
    a = np.stack([np.interp(xk, x, accel[lo:hi, c]) for c in range(3)], axis=1)
    dt = np.diff(knots).astype(np.float64) * 1e-9
    return dt, 0.5 * (g[1:] + g[:-1]), 0.5 * (a[1:] + a[:-1])


def preintegrate(
    stamps_ns: ArrayLike,
    gyro: ArrayLike,
    accel: ArrayLike,
    t0_ns: int,
    t1_ns: int,
    bias: gtsam.imuBias.ConstantBias | None,
    params: gtsam.PreintegrationParams,
) -> gtsam.PreintegratedImuMeasurements:
    """The IMU's motion over [t0, t1], preintegrated by GTSAM (see the module docstring).

    Args:
        stamps_ns: (M,) int64 strictly increasing IMU stamps.
        gyro: (M, 3) angular velocity, rad/s, IMU frame.
        accel: (M, 3) specific force, m/s², IMU frame.
        t0_ns, t1_ns: the interval; samples must exist at or before t0 and at or after t1.
        bias: the bias estimate to integrate around (None: zero). The measurement corrects
            itself to first order for other biases; integrate again when they move far.
        params: from :meth:`ImuNoise.params`.

    Returns:
        ``gtsam.PreintegratedImuMeasurements`` with ``deltaTij() == (t1 - t0) * 1e-9``.

    Raises:
        InputError: bad samples, ``t1 <= t0``, or no IMU samples covering the interval.
    """
    import gtsam

    t, g, a = check_imu_samples(stamps_ns, gyro, accel)
    pim = gtsam.PreintegratedImuMeasurements(
        params, bias if bias is not None else gtsam.imuBias.ConstantBias()
    )
    return integrate(pim, interval_readings(t, g, a, int(t0_ns), int(t1_ns)))


P = TypeVar("P")


def integrate(pim: P, readings: tuple[F64, F64, F64]) -> P:
    """Feed ``pim`` (GTSAM's plain or combined preintegrated measurements) the
    piecewise-constant ``readings`` of :func:`interval_readings` (durations, gyro, accel);
    returns it."""
    dt, gyro, accel = readings
    # GTSAM turns each piece's specific force by the rotation at the piece's start; the body
    # turns by ω·dt during it. Turned half that way the force gets the piece's mean rotation,
    # exact to second order. Left out, a body pitching at 0.1 rad/s reads gravity askew by
    # ½·ω·dt·g ≈ 2.5 mm/s² at 200 Hz: a false acceleration of 1 % of a gentle motion's.
    accel = accel + 0.5 * dt[:, None] * np.cross(gyro, accel)
    for step, w, f in zip(dt.tolist(), gyro, accel, strict=True):
        pim.integrateMeasurement(f, w, step)  # type: ignore[attr-defined]
    return pim


def bias_of(state: ArrayLike) -> gtsam.imuBias.ConstantBias:
    """GTSAM's bias from (6,) gyroscope (rad/s) then accelerometer (m/s²) biases."""
    import gtsam

    b = np.asarray(state, dtype=np.float64).reshape(6)
    return gtsam.imuBias.ConstantBias(b[3:], b[:3])
