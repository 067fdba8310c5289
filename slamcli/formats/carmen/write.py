"""Writing a CARMEN log: :func:`write_carmen` (see :mod:`slamcli.formats.carmen`)."""

from __future__ import annotations

import contextlib
import gzip
import io
import math
from collections.abc import Iterable
from pathlib import Path
from typing import IO

import numpy as np
from numpy.typing import NDArray

from slamcli.atomic import atomic_path
from slamcli.errors import InputError
from slamcli.formats.carmen.layout import (
    DEFAULT_MAX_RANGE_M,
    F64,
    FLASER_INCREMENT,
    LAYOUT_HINT,
    below,
)
from slamcli.formats.text import format_stamp
from slamcli.geometry import compose_planar
from slamcli.types import ScanFrame

_HEADER = (
    "# CARMEN Logfile",
    "# file format is one message per line",
    "# message_name [message contents] ipc_timestamp ipc_hostname logger_timestamp",
    "# message formats defined: FLASER ROBOTLASER1 RAWLASER1",
    f"# {LAYOUT_HINT['FLASER']}",
    f"# {LAYOUT_HINT['ROBOTLASER']}",
    f"# {LAYOUT_HINT['RAWLASER']}",
)


def write_carmen(
    path: str | Path,
    scans: Iterable[tuple[ScanFrame, NDArray[np.float64] | None]],
    *,
    host: str = "slamcli",
) -> Path:
    """Write scans as a CARMEN log, atomically; gzipped when ``path`` ends in ``.gz``.

    Each item is a scan and the robot's planar pose (3,) x (m), y (m), yaw (rad) at its
    stamp, or None. A scan with a pose becomes an FLASER line when CARMEN's FLASER angles
    reproduce its beams and its maximum range is :data:`DEFAULT_MAX_RANGE_M`, else a
    ROBOTLASER1 line; one without a pose a RAWLASER1 line (see the module docstring).
    :class:`CarmenSource` reads back the same ranges (float32), stamps (to the microsecond),
    poses and mountings (not for RAWLASER1).

    Returns:
        The path written.

    Raises:
        InputError: a scan or pose that cannot be written (no beams, a zero increment,
            non-finite values), or stamps that are not positive and increasing by at least a
            microsecond.
        ExportError: the folder does not exist or cannot be written.
    """
    if not host or any(c.isspace() for c in host):
        raise InputError(f"host must be one word (CARMEN separates fields by spaces), got {host!r}")
    dest = Path(path)
    with atomic_path(dest) as tmp, contextlib.ExitStack() as stack:
        out = _open_text(tmp, dest.suffix.lower() == ".gz", stack)
        out.write("\n".join(_HEADER) + "\n")
        first_us: int | None = None
        last_us = 0
        for k, (scan, pose) in enumerate(scans):
            us = (int(scan.stamp_ns) + 500) // 1000
            if us <= last_us:
                raise InputError(
                    f"scan {k} ({scan.name or 'unnamed'}): stamp {format_stamp(scan.stamp_ns)} s "
                    + ("is not positive" if us <= 0 else "is not after the previous scan's")
                    + " to the microsecond",
                    hint="CARMEN readers take such times as broken: shift or sort the scans",
                )
            first_us = us if first_us is None else first_us
            times = f"{_micro(us)} {host} {_micro(us - first_us)}"
            out.write(f"{_scan_line(scan, pose, k)} {times}\n")
            last_us = us
    return dest


def _open_text(tmp: Path, gzipped: bool, stack: contextlib.ExitStack) -> IO[str]:
    """``tmp`` open for text, through gzip when asked; ``stack`` closes what was opened."""
    if not gzipped:
        return stack.enter_context(tmp.open("w", encoding="utf-8", newline="\n"))
    raw = stack.enter_context(tmp.open("wb"))
    # No name and no time in the gzip header: the same scans give the same bytes.
    packed = stack.enter_context(gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0))
    return stack.enter_context(io.TextIOWrapper(packed, encoding="utf-8", newline="\n"))


def _scan_line(scan: ScanFrame, pose: NDArray[np.float64] | None, k: int) -> str:
    where = f"scan {k} ({scan.name or 'unnamed'})"
    ranges = np.asarray(scan.ranges_m)
    if ranges.ndim != 1 or ranges.size == 0:
        raise InputError(f"{where}: expected (N,) ranges with N >= 1, got shape {ranges.shape}")
    setup = (scan.angle_min_rad, scan.angle_increment_rad, scan.range_max_m)
    if not all(math.isfinite(v) for v in setup) or scan.angle_increment_rad == 0:
        raise InputError(
            f"{where}: angle_min, angle_increment and range_max must be finite and the "
            f"increment non-zero, got {setup}"
        )
    if scan.range_max_m <= 0:
        raise InputError(f"{where}: range_max must be positive, got {scan.range_max_m}")
    robot = None if pose is None else np.asarray(pose, dtype=np.float64)
    mount = np.asarray(scan.body_from_sensor, dtype=np.float64)
    for name, value in (("pose", robot), ("body_from_sensor", mount)):
        if value is not None and (value.shape != (3,) or not np.isfinite(value).all()):
            raise InputError(f"{where}: {name} must be 3 finite numbers (x, y, yaw)")
    n = int(ranges.size)
    if robot is not None and _is_flaser(scan, n):
        text = _ranges_text(scan, DEFAULT_MAX_RANGE_M)
        laser = compose_planar(robot, mount)
        return f"FLASER {n} {text} {_numbers(laser)} {_numbers(robot)}"
    top = float(np.nextafter(np.float32(scan.range_max_m), np.float32(np.inf)))
    fov = scan.angle_increment_rad * (n - 1)
    setup_text = _numbers([scan.angle_min_rad, fov, scan.angle_increment_rad, top])
    head = f"0 {setup_text} 0.01 0 {n} {_ranges_text(scan, top)} 0"
    if robot is None:
        return f"RAWLASER1 {head}"
    laser = compose_planar(robot, mount)
    return f"ROBOTLASER1 {head} {_numbers(laser)} {_numbers(robot)} 0 0 0 0 0"


def _is_flaser(scan: ScanFrame, n: int) -> bool:
    """Whether an FLASER line, read back, gives this scan's angles and maximum range."""
    increment = FLASER_INCREMENT.get(n)
    return (
        increment is not None
        and math.isclose(scan.angle_min_rad, -math.pi / 2, rel_tol=0, abs_tol=1e-9)
        and math.isclose(scan.angle_increment_rad, increment, rel_tol=1e-9)
        and scan.range_max_m == float(below(np.array([DEFAULT_MAX_RANGE_M]))[0])
    )


def _ranges_text(scan: ScanFrame, no_return: float) -> str:
    """Ranges as the shortest text giving their float32 back; no returns as ``no_return``,
    other beams that are not readings as 0."""
    values = np.asarray(scan.ranges_m, dtype=np.float32).copy()
    values[scan.no_returns()] = np.float32(no_return)
    values[~scan.readings() & ~scan.no_returns()] = 0
    return " ".join(np.format_float_positional(v, trim="-") for v in values)


def _numbers(values: Iterable[float] | F64) -> str:
    return " ".join(repr(float(v)) for v in values)


def _micro(us: int) -> str:
    whole, frac = divmod(us, 1_000_000)
    return f"{whole}.{frac:06d}"
