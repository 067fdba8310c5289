"""What the CARMEN reader and writer share: message layouts, beam angles, range limits."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

DEFAULT_MAX_RANGE_M = 50.0
"""Maximum range of FLASER and RLASER scans (they carry none); ranges at or beyond it are no
return. The ``robot_front_laser_max`` the shared CSAIL log records; below the shared logs'
81.83 and 81.91 m no-return codes, at the ACES log's 50 m clip, above their farthest real
reading (49.91 m)."""

RANGE_MIN_M = 0.01
"""Ranges below this are not readings (a SICK writes 0 for a failed beam)."""

FLASER_INCREMENT = {180: math.pi / 180, 181: math.pi / 180, 360: math.pi / 360, 361: math.pi / 360}
"""Beam spacing (rad) of FLASER/RLASER scans by beam count, as CARMEN's reader guesses it; other
counts span 180 degrees, pi/(n-1). Every such scan starts at -pi/2."""

LAYOUT_HINT = {
    "FLASER": "FLASER n r1..rn x y theta odom_x odom_y odom_theta ipc_time host logger_time",
    "ROBOTLASER": "ROBOTLASERk laser_type start_angle fov angular_res max_range accuracy "
    "remission_mode n r1..rn m rem1..remm laser_x laser_y laser_theta robot_x robot_y "
    "robot_theta tv rv forward_safety side_safety turn_axis ipc_time host logger_time",
    "RAWLASER": "RAWLASERk laser_type start_angle fov angular_res max_range accuracy "
    "remission_mode n r1..rn m rem1..remm ipc_time host logger_time",
    "ODOM": "ODOM x y theta tv rv accel ipc_time host logger_time",
}
"""Each message's fields, for hints and the written header."""


def flaser_increment(n: int) -> float:
    """Beam spacing (rad) of an FLASER/RLASER scan of ``n`` beams."""
    return FLASER_INCREMENT.get(n, math.pi / max(n - 1, 1))


def below(limit: F64) -> F64:
    """The largest float32 below each maximum range: ScanFrame counts range_max_m as a reading,
    CARMEN counts its maximum range as no return."""
    lim32 = np.asarray(limit, dtype=np.float64).astype(np.float32)
    return np.nextafter(lim32, np.float32(0)).astype(np.float64)


def layout_of(keyword: str) -> str:
    """The layout (a key of :data:`LAYOUT_HINT`) a message keyword follows."""
    if keyword.startswith("ROBOTLASER"):
        return "ROBOTLASER"
    if keyword.startswith("RAWLASER"):
        return "RAWLASER"
    return "ODOM" if keyword == "ODOM" else "FLASER"


def xyt(values: Iterable[float] | F64) -> tuple[float, float, float]:
    """Three numbers as a tuple of floats."""
    x, y, t = (float(v) for v in values)
    return x, y, t
