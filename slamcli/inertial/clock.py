"""How far the IMU's clock is off the camera's, from the motion both see.

An IMU whose stamps are shifted against the camera's (a driver stamping on arrival, two
clocks never synchronised) still covers every image, so the stamps alone cannot show it
(:mod:`slamcli.formats.imu_checks` finds only an offset that leaves images outside the IMU's
span). The rotation can: the turn the map's poses make between consecutive keyframes is what
the gyroscope integrates over the same interval of *its* clock, once its stamps are moved by
the offset. :func:`estimate_clock_offset` tries every shift on a grid (:data:`SEARCH_S` either
way, :data:`STEP_S` apart), each with the gyroscope bias that fits it best, and keeps the shift
whose turns fit best. The sign is Kalibr's ``timeshift_cam_imu``: ``t_imu = t_cam + shift``.

Rotation vectors are compared after integrating the gyroscope as a sum (not on the manifold):
over keyframe intervals of a few tenths of a second the difference is far below what a shift of
a frame period makes, and the sum makes every shift one interpolation of a cumulative integral.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry.se3 import so3_log

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

SEARCH_S = 0.3
"""Largest shift tried, either way (seconds); a larger offset leaves images outside the IMU's
span at either end of a short log, which the source's checks report."""

STEP_S = 0.0025
"""Grid step of the shifts tried (seconds): a twentieth of a 20 Hz camera's frame period."""

MIN_TURN_DEG = 10.0
"""Least total turn over the keyframes for the shift to be determined: a camera that barely
turns (a drone at rest) shows no offset."""

MIN_GAIN = 2.0
"""How many times worse the unshifted fit must be than the best one for the offset to be
taken as real rather than noise."""


@dataclass(frozen=True)
class ClockOffset:
    """The estimated offset and how sure it is.

    Attributes:
        shift_s: Kalibr's ``timeshift_cam_imu`` (``t_imu = t_cam + shift``), seconds.
        gain: the unshifted fit's squared residual over the best one's.
        turn_deg: the total turn of the keyframes it was estimated on.
    """

    shift_s: float
    gain: float
    turn_deg: float

    def significant(self, frame_s: float) -> bool:
        """Whether the offset is real (:data:`MIN_GAIN`) and larger than a frame period."""
        return self.gain >= MIN_GAIN and abs(self.shift_s) > frame_s


def estimate_clock_offset(
    stamps_ns: I64,
    body_rotations: F64,
    imu_stamps_ns: I64,
    gyro_radps: F64,
) -> ClockOffset | None:
    """The shift of the IMU's clock against the camera's that best explains the keyframes'
    turns (see the module docstring), over the intervals the IMU covers with every shift; None
    when fewer than two are covered or they turn less than :data:`MIN_TURN_DEG` in all.

    Args:
        stamps_ns: (K,) keyframe stamps, increasing.
        body_rotations: (K, 3, 3) world_from_body rotations of the keyframes.
        imu_stamps_ns: (M,) IMU stamps, increasing.
        gyro_radps: (M, 3) gyroscope readings in the body (IMU) frame.
    """
    t = np.asarray(stamps_ns, dtype=np.int64)
    rot = np.asarray(body_rotations, dtype=np.float64)
    it = np.asarray(imu_stamps_ns, dtype=np.int64)
    if t.size < 3 or it.size < 2:
        return None
    origin = int(it[0])
    ts = (it - origin) * 1e-9
    t0 = (t[:-1] - origin) * 1e-9
    t1 = (t[1:] - origin) * 1e-9
    # The intervals the IMU covers with every shift (a run's newest ones it may not yet).
    inside = (t0 - SEARCH_S >= ts[0]) & (t1 + SEARCH_S <= ts[-1])
    if np.count_nonzero(inside) < 2:
        return None
    turns = so3_log(np.swapaxes(rot[:-1], -1, -2) @ rot[1:])[inside]  # body0_from_body1
    t0, t1 = t0[inside], t1[inside]
    turn_deg = float(np.degrees(np.linalg.norm(turns, axis=1).sum()))
    if turn_deg < MIN_TURN_DEG:
        return None
    gyro = np.asarray(gyro_radps, dtype=np.float64)
    # The gyroscope's integral from the first sample, piecewise constant between samples.
    cumulative = np.vstack([np.zeros((1, 3)), np.cumsum(gyro[:-1] * np.diff(ts)[:, None], 0)])
    dt = t1 - t0
    shifts = np.arange(-SEARCH_S, SEARCH_S + STEP_S / 2, STEP_S)
    costs = np.empty(shifts.size)
    for i, shift in enumerate(shifts):
        gyro_turns = np.stack(
            [
                np.interp(t1 + shift, ts, cumulative[:, k])
                - np.interp(t0 + shift, ts, cumulative[:, k])
                for k in range(3)
            ],
            axis=1,
        )
        residual = turns - gyro_turns
        bias = (residual * dt[:, None]).sum(0) / float((dt**2).sum())
        costs[i] = float(((residual - bias * dt[:, None]) ** 2).sum())
    best = int(np.argmin(costs))
    zero = int(np.argmin(np.abs(shifts)))
    gain = float(costs[zero] / costs[best]) if costs[best] > 0 else float("inf")
    return ClockOffset(round(float(shifts[best]), 4), gain, turn_deg)


__all__ = ["MIN_GAIN", "SEARCH_S", "STEP_S", "ClockOffset", "estimate_clock_offset"]
