"""Trajectory files: TUM, KITTI and EuRoC ground truth.

Formats (one pose per data line; ``#`` lines and blank lines are skipped):

- ``tum``: ``t tx ty tz qx qy qz qw``, whitespace separated, ``t`` in seconds, quaternion xyzw.
- ``kitti``: 12 numbers, the first three rows of the 4x4 pose, row-major. The format carries no
  time: stamps come from an optional times file (one time in seconds per line, as in the
  KITTI odometry ``times.txt``); without one, pose ``i`` gets the stamp ``i`` seconds.
- ``euroc``: the ``state_groundtruth_estimate0/data.csv`` (or ``vicon0/data.csv``) of the EuRoC
  MAV dataset: comma separated, ``timestamp [ns], p_RS_R_x, p_RS_R_y, p_RS_R_z, q_RS_w, q_RS_x,
  q_RS_y, q_RS_z`` and optionally more columns. Note the quaternion order, wxyz. Read only.

Reading is strict: every problem is a :class:`~slamcli.errors.FormatError` naming ``file:line``.
Quaternions whose norm is off by more than :data:`QUAT_NORM_TOL` are rejected, smaller
deviations (files that print four decimals) are normalised. KITTI rotations must be orthonormal
to :data:`ROTATION_TOL` and are kept as written, so results agree with other tools reading
the same file.

Repeated stamps occur in real files (the TUM ``fr2/desk`` ground truth has one, EuRoC estimates
written by some VIO systems have several). :func:`read_poses` keeps every row, which is what
trajectory evaluation needs to agree with evo; :func:`read_trajectory` returns a
:class:`~slamcli.types.Trajectory`, whose stamps must strictly increase, and by default keeps
the first row of each repeated stamp. Time going backwards is always an error.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from slamcli.atomic import atomic_path
from slamcli.errors import FormatError, InputError, UnknownFormatError
from slamcli.formats.text import (
    format_stamp,
    iter_data_lines,
    parse_count,
    parse_floats,
    parse_stamp_ns,
)
from slamcli.geometry import make_pose, matrix_to_quat_xyzw, quat_wxyz_to_matrix
from slamcli.types import Trajectory

logger = logging.getLogger(__name__)

TRAJECTORY_FORMATS = ("tum", "kitti", "euroc")
"""Formats :func:`read_trajectory` understands (``auto`` picks one of them from the contents)."""

QUAT_NORM_TOL = 1e-2
"""Largest accepted ``| |q| - 1 |``; files printing quaternions with 4 decimals stay below 1e-3."""

ROTATION_TOL = 1e-3
"""Largest accepted entry of ``|R^T R - I|`` for KITTI rotations (6 printed digits give 1e-6)."""

MAX_POSE_VALUE = 1e9
"""Largest magnitude of a pose value: a million kilometres, beyond any geo-referenced
coordinate, and small enough that alignment's sums of squares stay finite."""

_NS_PER_S = 1_000_000_000
_EUROC_MIN_STAMP_NS = 10**12
"""A first CSV column at least this large is read as nanoseconds (EuRoC); 1e12 ns = 16 min."""

TrajectoryFormat = Literal["tum", "kitti", "euroc"]
DuplicatePolicy = Literal["first", "last", "error"]


@dataclass(frozen=True)
class PoseTable:
    """Poses exactly as a file lists them, one per data line, repeated stamps included.

    Attributes:
        stamps_ns: (N,) int64 nanoseconds, non-decreasing.
        world_from_body: (N, 4, 4) float64 poses.
        lines: (N,) int64 1-based line numbers of the rows, for messages.
        path: the file read.
        format: ``tum``, ``kitti`` or ``euroc``.
        timed: False for KITTI poses read without a times file (stamps are frame indices).
    """

    stamps_ns: NDArray[np.int64]
    world_from_body: NDArray[np.float64]
    lines: NDArray[np.int64]
    path: Path
    format: str
    timed: bool = True

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    @property
    def positions(self) -> NDArray[np.float64]:
        """(N, 3) translations in metres."""
        return self.world_from_body[:, :3, 3]

    def repeated(self) -> NDArray[np.int64]:
        """Row indices whose stamp equals the previous row's, (K,) int64."""
        return np.flatnonzero(np.diff(self.stamps_ns) == 0).astype(np.int64) + 1

    def to_trajectory(self, duplicates: DuplicatePolicy = "first") -> Trajectory:
        """A :class:`Trajectory` (strictly increasing stamps) from these rows.

        ``duplicates`` says which row of a repeated stamp survives: ``first``, ``last``, or
        ``error`` to raise a :class:`FormatError` at the first repeated row.
        """
        rep = self.repeated()
        if rep.size == 0:
            return Trajectory(self.stamps_ns, self.world_from_body)
        if duplicates == "error":
            raise FormatError(
                self.path,
                f"timestamp {format_stamp(self.stamps_ns[rep[0]])} s repeats the previous row's",
                int(self.lines[rep[0]]),
                hint=f"{rep.size} repeated stamp(s) in total; remove the extra rows",
            )
        if duplicates not in ("first", "last"):
            raise InputError(f"duplicates must be 'first', 'last' or 'error', got {duplicates!r}")
        keep = np.ones(len(self), dtype=bool)
        keep[rep if duplicates == "first" else rep - 1] = False
        logger.warning(
            "%s: %d row(s) repeat the previous stamp (first at line %d); kept the %s of each",
            self.path,
            rep.size,
            int(self.lines[rep[0]]),
            duplicates,
        )
        return Trajectory(self.stamps_ns[keep], self.world_from_body[keep])


def sniff_trajectory_format(path: str | Path) -> TrajectoryFormat:
    """Guess the format from the first data line: EuRoC, KITTI or TUM.

    A comma-separated line whose first column is an integer of nanosecond size is EuRoC;
    otherwise 12 whitespace-separated columns are KITTI and 8 are TUM.
    """
    p = Path(path)
    for lineno, fields in iter_data_lines(p):
        line = " ".join(fields)
        if "," in line:
            first = line.split(",", 1)[0].strip()
            if first.isdigit() and int(first) >= _EUROC_MIN_STAMP_NS:
                return "euroc"
            raise UnknownFormatError(
                p,
                TRAJECTORY_FORMATS,
                f"line {lineno} is comma separated but its first column {first!r} is not a "
                "nanosecond timestamp",
            )
        if len(fields) == 12:
            return "kitti"
        if len(fields) == 8:
            return "tum"
        raise UnknownFormatError(
            p,
            TRAJECTORY_FORMATS,
            f"line {lineno} has {len(fields)} columns; TUM has 8 (t tx ty tz qx qy qz qw), "
            "KITTI 12",
        )
    raise FormatError(p, "no poses: the file is empty or has only comments")


def read_poses(
    path: str | Path, format: str = "auto", *, times: str | Path | None = None
) -> PoseTable:
    """Read every pose row of a trajectory file, repeated stamps included.

    Args:
        path: the trajectory file.
        format: ``tum``, ``kitti``, ``euroc`` or ``auto`` (decided from the contents,
            see :func:`sniff_trajectory_format`).
        times: KITTI only: a file with one time in seconds per pose.

    Raises:
        FormatError: naming ``file:line`` for any malformed row, time going backwards, or a
            times file whose length differs from the number of poses.
    """
    p = Path(path)
    fmt = sniff_trajectory_format(p) if format == "auto" else format
    if times is not None and fmt != "kitti":
        raise InputError(
            f"{times}: a times file only goes with KITTI poses, but {p} is {fmt}",
            hint="TUM and EuRoC files carry their own timestamps",
        )
    if fmt == "tum":
        table = _read_tum(p)
    elif fmt == "kitti":
        table = _read_kitti(p, None if times is None else Path(times))
    elif fmt == "euroc":
        table = _read_euroc(p)
    else:
        raise UnknownFormatError(p, TRAJECTORY_FORMATS, f"unknown trajectory format {format!r}")
    _check_time_order(table.stamps_ns, table.lines, p)
    return table


def read_trajectory(
    path: str | Path,
    format: str = "auto",
    *,
    times: str | Path | None = None,
    duplicates: DuplicatePolicy = "first",
) -> Trajectory:
    """Read a trajectory file into a :class:`Trajectory` (see :func:`read_poses`).

    ``duplicates`` decides what happens to rows repeating the previous stamp (a Trajectory's
    stamps strictly increase): keep the ``first`` or ``last`` row, or raise (``error``).
    """
    return read_poses(path, format, times=times).to_trajectory(duplicates)


def _collect(
    path: Path, ncols: int | None, delimiter: str | None, what: str
) -> tuple[list[int], list[list[str]]]:
    """Data lines with their numbers; checks the column count (``None``: at least 8, constant)."""
    numbers: list[int] = []
    rows: list[list[str]] = []
    expected = ncols
    for lineno, fields in iter_data_lines(path, delimiter=delimiter):
        if expected is None:
            if len(fields) < 8:
                raise FormatError(
                    path,
                    f"expected at least 8 comma-separated columns ({what}), found {len(fields)}",
                    lineno,
                )
            expected = len(fields)
        if len(fields) != expected:
            raise FormatError(
                path, f"expected {expected} columns ({what}), found {len(fields)}", lineno
            )
        numbers.append(lineno)
        rows.append(fields)
    if not rows:
        raise FormatError(path, "no poses: the file is empty or has only comments")
    return numbers, rows


def _to_floats(
    path: Path, numbers: list[int], rows: list[list[str]], what: str, first_column: int = 1
) -> NDArray[np.float64]:
    """(N, C) float64 from string rows; a bad value is reported at its line and 1-based column
    (``first_column`` is the column of ``rows[i][0]`` in the file)."""
    try:
        values = np.array(rows, dtype=np.float64)
    except ValueError:
        # Slow path only on failure: find the line and column to report.
        for lineno, fields in zip(numbers, rows, strict=True):
            parse_floats(fields, path, lineno, what, first_column)
        raise FormatError(path, f"a {what} is not a number") from None
    bad = ~np.isfinite(values)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise FormatError(
            path,
            f"column {col + first_column}: {what} {rows[row][col]!r} is not finite",
            numbers[row],
        )
    big = np.abs(values) > MAX_POSE_VALUE
    if big.any():
        row, col = np.argwhere(big)[0]
        raise FormatError(
            path,
            f"column {col + first_column}: {what} {rows[row][col]!r} is out of range (at most "
            f"{MAX_POSE_VALUE:g} in magnitude)",
            numbers[row],
        )
    return values


def _rotations_from_quats(
    path: Path, numbers: list[int], quats_wxyz: NDArray[np.float64]
) -> NDArray[np.float64]:
    norms = np.linalg.norm(quats_wxyz, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUAT_NORM_TOL)
    if bad.size:
        i = int(bad[0])
        raise FormatError(
            path,
            f"quaternion norm is {norms[i]:.6g}, expected 1 (tolerance {QUAT_NORM_TOL:g})",
            numbers[i],
            hint="quaternions must be unit length; check the column order",
        )
    return quat_wxyz_to_matrix(quats_wxyz)


def _read_tum(path: Path) -> PoseTable:
    numbers, rows = _collect(path, 8, None, "t tx ty tz qx qy qz qw")
    stamps = np.array(
        [parse_stamp_ns(r[0], path, n) for n, r in zip(numbers, rows, strict=True)], dtype=np.int64
    )
    values = _to_floats(path, numbers, [r[1:] for r in rows], "value", first_column=2)
    quats_wxyz = values[:, [6, 3, 4, 5]]
    poses = make_pose(_rotations_from_quats(path, numbers, quats_wxyz), values[:, :3])
    return PoseTable(stamps, poses, np.array(numbers, dtype=np.int64), path, "tum")


def _read_euroc(path: Path) -> PoseTable:
    numbers, rows = _collect(path, None, ",", "timestamp [ns], p_xyz, q_wxyz, ...")
    stamps_list: list[int] = []
    for lineno, r in zip(numbers, rows, strict=True):
        stamps_list.append(
            parse_count(r[0], path, lineno, "timestamp", "an integer number of nanoseconds")
        )
    values = _to_floats(path, numbers, [r[1:] for r in rows], "value", first_column=2)
    poses = make_pose(_rotations_from_quats(path, numbers, values[:, 3:7]), values[:, :3])
    return PoseTable(
        np.array(stamps_list, dtype=np.int64),
        poses,
        np.array(numbers, dtype=np.int64),
        path,
        "euroc",
    )


def _read_kitti(path: Path, times: Path | None) -> PoseTable:
    numbers, rows = _collect(path, 12, None, "r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz")
    values = _to_floats(path, numbers, rows, "value")
    n = values.shape[0]
    poses = np.zeros((n, 4, 4))
    poses[:, :3, :] = values.reshape(n, 3, 4)
    poses[:, 3, 3] = 1.0
    rot = poses[:, :3, :3]
    ortho = np.abs(np.einsum("nji,njk->nik", rot, rot) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(rot)
    bad = np.flatnonzero((ortho > ROTATION_TOL) | (det <= 0.0))
    if bad.size:
        i = int(bad[0])
        raise FormatError(
            path,
            f"rotation is not orthonormal (|R^T R - I| = {ortho[i]:.3g}, det = {det[i]:.6g}; "
            f"tolerance {ROTATION_TOL:g})",
            numbers[i],
            hint="KITTI rows are the first three rows of a 4x4 pose, row-major",
        )
    line_numbers = np.array(numbers, dtype=np.int64)
    if times is None:
        stamps = np.arange(n, dtype=np.int64) * _NS_PER_S
        return PoseTable(stamps, poses, line_numbers, path, "kitti", timed=False)
    t_numbers: list[int] = []
    t_stamps: list[int] = []
    for lineno, fields in iter_data_lines(times):
        if len(fields) != 1:
            raise FormatError(
                times, f"expected 1 column (time in seconds), found {len(fields)}", lineno
            )
        t_numbers.append(lineno)
        t_stamps.append(parse_stamp_ns(fields[0], times, lineno))
    t_array = np.array(t_stamps, dtype=np.int64)
    _check_time_order(t_array, np.array(t_numbers, dtype=np.int64), times)
    if len(t_stamps) != n:
        raise FormatError(
            times,
            f"has {len(t_stamps)} times but {path} has {n} poses",
            hint="the times file needs exactly one line per pose",
        )
    return PoseTable(t_array, poses, line_numbers, path, "kitti")


def _check_time_order(stamps: NDArray[np.int64], lines: NDArray[np.int64], path: Path) -> None:
    back = np.flatnonzero(np.diff(stamps) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise FormatError(
            path,
            f"time goes backwards: {format_stamp(int(stamps[i]))} s after "
            f"{format_stamp(int(stamps[i - 1]))} s",
            int(lines[i]),
            hint="trajectory rows must be sorted by time",
        )


def tum_lines(
    trajectory: Trajectory | PoseTable, stamp_decimals: int = 9, decimals: int = 9
) -> list[str]:
    """``t tx ty tz qx qy qz qw`` text lines (no header), quaternions with w >= 0."""
    poses = trajectory.world_from_body
    quats = matrix_to_quat_xyzw(poses[:, :3, :3])
    numbers = np.concatenate([poses[:, :3, 3], quats], axis=1)
    # One format per row: a log of 60,000 poses is written in a fraction of a second.
    row_format = " ".join([f"%.{decimals}f"] * 7)
    return [
        format_stamp(s, stamp_decimals) + " " + row_format % tuple(row)
        for s, row in zip(trajectory.stamps_ns.tolist(), numbers.tolist(), strict=True)
    ]


def write_tum(path: str | Path, trajectory: Trajectory | PoseTable) -> Path:
    """Write ``t tx ty tz qx qy qz qw`` lines atomically.

    Stamps are written exactly from int nanoseconds with 9 decimals; translations and
    quaternions with 9 decimals (1e-9 m, ~2e-9 rad).
    """
    return _write_lines(path, ["# timestamp tx ty tz qx qy qz qw", *tum_lines(trajectory)])


def write_kitti(
    path: str | Path, trajectory: Trajectory | PoseTable, times: str | Path | None = None
) -> Path:
    """Write 12-column KITTI rows atomically (13 significant digits), and optionally a times file.

    The times file gets one stamp per line in seconds with 9 decimals.
    """
    poses = trajectory.world_from_body
    rows = poses[:, :3, :].reshape(-1, 12)
    _write_lines(path, [" ".join(f"{v:.12e}" for v in row) for row in rows])
    if times is not None:
        _write_lines(times, [format_stamp(int(s)) for s in trajectory.stamps_ns])
    return Path(path)


def write_trajectory(
    path: str | Path, trajectory: Trajectory | PoseTable, format: str = "tum"
) -> Path:
    """Write a trajectory as ``tum`` or ``kitti`` (see :func:`write_tum`, :func:`write_kitti`)."""
    if format == "tum":
        return write_tum(path, trajectory)
    if format == "kitti":
        return write_kitti(path, trajectory)
    raise InputError(f"cannot write trajectory format {format!r}", hint="use tum or kitti")


def _write_lines(path: str | Path, lines: list[str]) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return Path(path)


__all__ = [
    "QUAT_NORM_TOL",
    "ROTATION_TOL",
    "TRAJECTORY_FORMATS",
    "PoseTable",
    "read_poses",
    "read_trajectory",
    "sniff_trajectory_format",
    "write_kitti",
    "write_trajectory",
    "write_tum",
]
