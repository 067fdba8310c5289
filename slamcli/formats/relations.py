"""Relations files: the reference relative motions of Kümmerle et al. (2009).

"On measuring the accuracy of SLAM algorithms" scores a trajectory by relative motions between
pairs of its poses. A ``.relations`` file lists them, one per data line (``#`` lines and blank
lines are skipped)::

    t1 t2 x y z roll pitch yaw

``t1`` and ``t2`` are stamps in seconds; ``x y z`` (metres) and ``roll pitch yaw`` (radians)
are the motion from the pose at ``t1`` to the pose at ``t2``, expressed in the frame of the pose
at ``t1`` (``first_from_second``). The rotation is ``Rz(yaw) Ry(pitch) Rx(roll)``; files of
planar data have ``z = roll = pitch = 0``.

Reading is strict: every problem is a :class:`~slamcli.errors.FormatError` naming ``file:line``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from slamcli.atomic import atomic_path
from slamcli.errors import FormatError, InputError
from slamcli.formats.text import format_stamp, iter_data_lines, parse_floats, parse_stamp_ns

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

COLUMNS = "t1 t2 x y z roll pitch yaw"
"""The columns of a data line."""


@dataclass(frozen=True)
class Relations:
    """Reference relative motions between pairs of stamped poses.

    Attributes:
        t1_ns: (N,) int64 stamps of the first pose of each relation.
        t2_ns: (N,) int64 stamps of the second pose.
        first_from_second: (N, 4, 4) float64 motion from the pose at ``t1`` to the pose at
            ``t2``, in the frame of the pose at ``t1``.
        lines: (N,) int64 1-based line numbers in ``path`` (empty when built in memory).
        path: the file read, or None.
    """

    t1_ns: I64
    t2_ns: I64
    first_from_second: F64
    lines: I64 = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    path: Path | None = None

    def __post_init__(self) -> None:
        t1 = np.asarray(self.t1_ns, dtype=np.int64).reshape(-1)
        t2 = np.asarray(self.t2_ns, dtype=np.int64).reshape(-1)
        motion = np.asarray(self.first_from_second, dtype=np.float64)
        if t2.shape != t1.shape or motion.shape != (t1.size, 4, 4):
            raise InputError(
                f"relations need (N,) t1, (N,) t2 and (N, 4, 4) motions, got {t1.shape}, "
                f"{t2.shape} and {motion.shape}"
            )
        object.__setattr__(self, "t1_ns", t1)
        object.__setattr__(self, "t2_ns", t2)
        object.__setattr__(self, "first_from_second", motion)

    def __len__(self) -> int:
        return int(self.t1_ns.shape[0])

    def where(self, row: int) -> str:
        """``file:line`` of relation ``row`` for messages (its row number when built in memory)."""
        if self.path is not None and self.lines.size == len(self):
            return f"{self.path}:{int(self.lines[row])}"
        return f"relation {row}"


def rotation_from_rpy(roll: F64, pitch: F64, yaw: F64) -> F64:
    """(N, 3, 3) rotations ``Rz(yaw) Ry(pitch) Rx(roll)`` of (N,) angles in radians."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    rows = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def rpy_from_rotation(rotation: F64) -> F64:
    """(N, 3) roll, pitch, yaw in radians of (N, 3, 3) rotations ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    r = np.asarray(rotation, dtype=np.float64).reshape(-1, 3, 3)
    pitch = np.arcsin(np.clip(-r[:, 2, 0], -1.0, 1.0))
    roll = np.arctan2(r[:, 2, 1], r[:, 2, 2])
    yaw = np.arctan2(r[:, 1, 0], r[:, 0, 0])
    return np.stack([roll, pitch, yaw], axis=1)


def read_relations(path: str | Path) -> Relations:
    """Read a ``.relations`` file (see the module docstring).

    Raises:
        FormatError: a line without 8 columns, a value that is not a finite number, or a file
            with no relations; the message names ``file:line``.
        InputError: the file is missing or unreadable.
    """
    p = Path(path)
    t1: list[int] = []
    t2: list[int] = []
    values: list[list[float]] = []
    lines: list[int] = []
    for number, fields in iter_data_lines(p):
        if len(fields) != 8:
            raise FormatError(
                p,
                f"expected 8 columns ({COLUMNS}), found {len(fields)}",
                number,
                hint="one relation per line: two stamps in seconds, then the motion from the "
                "first pose to the second in the first pose's frame (m, rad)",
            )
        t1.append(parse_stamp_ns(fields[0], p, number))
        t2.append(parse_stamp_ns(fields[1], p, number))
        values.append(parse_floats(fields[2:], p, number, first_column=3))
        lines.append(number)
    if not lines:
        raise FormatError(p, f"no relations: the file is empty or has only comments ({COLUMNS})")
    v = np.array(values, dtype=np.float64)
    motion = np.zeros((v.shape[0], 4, 4))
    motion[:, :3, :3] = rotation_from_rpy(v[:, 3], v[:, 4], v[:, 5])
    motion[:, :3, 3] = v[:, :3]
    motion[:, 3, 3] = 1.0
    return Relations(
        np.array(t1, dtype=np.int64),
        np.array(t2, dtype=np.int64),
        motion,
        np.array(lines, dtype=np.int64),
        p,
    )


def write_relations(path: str | Path, relations: Relations) -> Path:
    """Write ``t1 t2 x y z roll pitch yaw`` lines atomically, under a ``#`` header.

    Stamps are written exactly from int nanoseconds with 9 decimals, the motion with 9
    decimals (1e-9 m, 1e-9 rad).
    """
    m = relations.first_from_second
    numbers = np.concatenate([m[:, :3, 3], rpy_from_rotation(m[:, :3, :3])], axis=1)
    numbers = np.round(numbers, 9) + 0.0  # no "-0.000000000"
    row_format = " ".join(["%.9f"] * 6)
    rows = [
        f"{format_stamp(a)} {format_stamp(b)} " + row_format % tuple(row)
        for a, b, row in zip(
            relations.t1_ns.tolist(), relations.t2_ns.tolist(), numbers.tolist(), strict=True
        )
    ]
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join([f"# {COLUMNS}", *rows]) + "\n", encoding="utf-8")
    return Path(path)


__all__ = [
    "COLUMNS",
    "Relations",
    "read_relations",
    "rotation_from_rpy",
    "rpy_from_rotation",
    "write_relations",
]
