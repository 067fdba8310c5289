"""Planar landmark logs for EKF-SLAM: UTIAS MRCLAM folders, Victoria Park files, synth folders.

Every landmark source yields two frame kinds, merged in time order (at equal stamps the
odometry frame comes first, frames of one kind keep their file order):

- ``odometry``: :class:`~slamcli.types.OdometryFrame`. Velocity logs (MRCLAM, synth) give
  ``v`` (m/s) and ``omega`` (rad/s): the control applied from this stamp until the next
  odometry stamp. Relative-pose logs (Victoria Park) give ``world_from_body``: the
  composition of every increment so far, starting from the identity (dead reckoning).
- ``landmarks``: :class:`~slamcli.types.LandmarkFrame`, all observations of one stamp, with
  landmark ids (-1 with ``ignore_ids``: the filter associates them itself), ranges (m) and
  bearings (rad, counter-clockwise from the heading).

Besides ``groundtruth()`` each source has ``landmark_truth()`` (surveyed landmark positions)
and ``start_pose()`` (where the robot is at the first frame, to initialise a filter in the
ground-truth world); see :meth:`LandmarkSource.start_pose`.

Formats:

- **MRCLAM** (UTIAS Multi-Robot Cooperative Localization and Mapping, one ``MRCLAM_DatasetN``
  folder): ``Barcodes.dat`` (subject, barcode), ``Landmark_Groundtruth.dat`` (subject, x, y,
  x std-dev, y std-dev), and per robot ``RobotN_Odometry.dat`` (t, v, omega),
  ``RobotN_Measurement.dat`` (t, barcode, range, bearing; the header calls the barcode column
  "Subject #") and ``RobotN_Groundtruth.dat`` (t, x, y, theta). Times are seconds, fields are
  whitespace separated, ``#`` lines are comments. Barcodes are mapped to subjects; the robots
  are subjects 1-5 (the real datasets' five) and every K with a ``RobotK_Odometry.dat`` (a
  synthetic folder may have up to 16), less any subject of ``Landmark_Groundtruth.dat``.
  Sightings of robots are dropped from the landmark frames (counted in
  ``info().details["robot_sightings"]``). Landmarks are the subjects of
  ``Landmark_Groundtruth.dat`` (without it, every subject of ``Barcodes.dat`` that is no
  robot's). Measurements of barcodes
  in no table (the real data has a few: 34, 43, 50, 52) or of subjects that are neither are
  ignored (not data loss: the log is intact), listed in ``MrclamSource.ignored`` with their
  file:line and summarised in one warning; with ``strict`` they are a :class:`FormatError`.
- **Victoria Park** in GTSAM's text format: ``ODOMETRY i j dx dy dtheta c11 c12 c13 c22 c23
  c33`` (motion from pose key i to pose key j in pose i's frame, and the upper triangle of its
  covariance) and ``LANDMARK i l x y c11 c12 c22`` (landmark l seen from pose key i at x
  forward, y left). GTSAM numbers poses and landmarks from one counter, so pose keys skip the
  numbers given to landmarks (``ODOMETRY 4 6`` after landmark 5 first appears): each ODOMETRY
  line must start at the key the previous one ended at and end at a larger key, and a LANDMARK
  line must be seen from the current pose. The file has no times: the ``k``-th pose of the
  chain (not its key) gets the stamp ``k`` seconds (:data:`VICTORIA_STEP_NS`); pose 0 (key
  0) is the origin and is yielded first. No ground truth.
- **synth landmarks** folders written by ``slamcli synth landmarks`` (layout in
  :mod:`slamcli.synth.landmarks`): ``odometry.csv`` (t,v,omega), ``measurements.csv``
  (t,id,range,bearing), ``groundtruth.tum`` and ``landmarks.csv`` (id,x,y).

Reading is strict: a line with the wrong number of fields, a non-number, or time going
backwards is a :class:`FormatError` naming ``file:line``. Repeated odometry stamps are kept (a
control that lasted no time). Text tables are parsed in bulk with numpy and fall back to a
line-by-line parse only to name the first bad line.
"""

from __future__ import annotations

import heapq
import logging
from collections import Counter
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats import sniff
from slamcli.formats.base import Frame, ReadStats, SourceBase, SourceInfo, StreamInfo
from slamcli.formats.text import (
    format_stamp,
    iter_data_lines,
    parse_count,
    parse_floats,
    parse_stamp_ns,
)
from slamcli.formats.trajectory import read_trajectory
from slamcli.geometry import interpolate_planar, planar_to_se3, se3_to_planar, wrap_angle
from slamcli.types import (
    LandmarkFrame,
    LandmarkMap,
    OdometryFrame,
    ProgressFn,
    Trajectory,
)

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

FRAME_KINDS = ("odometry", "landmarks")
"""The frame kinds a landmark source provides."""

MRCLAM_ROBOT_SUBJECTS = frozenset(range(1, 6))
"""MRCLAM subject numbers of the real datasets' five robots; a folder's robots are these and
those with a ``RobotK_Odometry.dat`` (:attr:`MrclamSource.robot_subjects`)."""

START_POSE_MAX_WAIT_S = 30.0
"""``start_pose`` falls back to the first ground-truth pose if it is at most this late."""

VICTORIA_STEP_NS = 1_000_000_000
"""Victoria Park files have no times: the k-th pose gets the stamp ``k * VICTORIA_STEP_NS``."""

ODOMETRY_GAP_PROBLEM_S = 1.0
"""``info`` reports odometry gaps longer than this as a problem."""

_NS_PER_S = 1_000_000_000
_POW10 = np.array([10**k for k in range(19)], dtype=np.int64)


MAX_TABLE_VALUE = 1e9
"""Largest magnitude of a table value (metres, m/s, radians, ids): far beyond any real
reading, and small enough that the filters' squares and products stay finite."""


@dataclass(frozen=True)
class RobotFrame:
    """A frame of one robot in a several-robot selection (``--robot 1,2,3``).

    Attributes:
        robot: the robot's number.
        frame: its :class:`~slamcli.types.OdometryFrame` or :class:`~slamcli.types.LandmarkFrame`.
        sighting: ``frame`` is a LandmarkFrame of sightings of other robots: its ids are their
            numbers, ranges and bearings as for landmarks.
    """

    robot: int
    frame: OdometryFrame | LandmarkFrame
    sighting: bool = False

    @property
    def stamp_ns(self) -> int:
        return self.frame.stamp_ns


def parse_robots(robot: Any, available: list[int]) -> list[int]:
    """The robots a ``robot`` option selects: a number, ``"N"``, ``"1,2,3"`` or ``"all"``.

    Raises:
        ConfigError: not such a selection, or a robot the folder does not have (both named).
    """
    listed = ", ".join(map(str, available)) or "none"
    hint = f"--robot N, --robot 1,2,3 or --robot all (robots here: {listed})"
    if isinstance(robot, bool) or not isinstance(robot, int | str):
        raise ConfigError(
            f"robot must be a robot number, a list or 'all', got {robot!r}", hint=hint
        )
    if isinstance(robot, int):
        picked = [robot]
    elif robot.strip().lower() == "all":
        picked = list(available)
    else:
        parts = [p.strip() for p in robot.split(",")]
        if not parts or not all(p.isdigit() for p in parts):
            raise ConfigError(f"robot: {robot!r} is not a robot number, a list or 'all'", hint=hint)
        picked = [int(p) for p in parts]
    if len(set(picked)) != len(picked):
        raise ConfigError(f"robot: {robot!r} names a robot twice", hint=hint)
    missing = [r for r in picked if r not in available]
    if missing:
        raise ConfigError(
            f"robot: no robot {', '.join(map(str, missing))} in this MRCLAM folder "
            f"(robots: {listed})",
            hint=hint,
        )
    return picked


# --- Text tables -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Table:
    """The data lines of one text table.

    Attributes:
        path: the file.
        lines: (N,) int64 1-based line numbers, for messages.
        stamps_ns: (N,) int64 nanoseconds of the first column (empty for unstamped tables).
        values: (N, K) float64 the other columns (all columns for unstamped tables).
    """

    path: Path
    lines: I64
    stamps_ns: I64
    values: F64

    def __len__(self) -> int:
        return int(self.lines.shape[0])

    def where(self, k: int) -> str:
        """``"Robot1_Odometry.dat:12"``: where row ``k`` was read."""
        return f"{self.path.name}:{int(self.lines[k])}"

    def integers(self, col: int, what: str) -> I64:
        """Column ``col`` of :attr:`values` as int64; a non-integer is a FormatError."""
        v = self.values[:, col]
        bad = np.flatnonzero(v != np.round(v))
        if bad.size:
            k = int(bad[0])
            raise FormatError(self.path, f"{what} {v[k]:g} is not an integer", int(self.lines[k]))
        return v.astype(np.int64)

    def check_time_order(self) -> None:
        """Stamps must not decrease (repeats are allowed)."""
        back = np.flatnonzero(np.diff(self.stamps_ns) < 0)
        if back.size:
            k = int(back[0]) + 1
            raise FormatError(
                self.path,
                f"time goes backwards from {_seconds(int(self.stamps_ns[k - 1]))} to "
                f"{_seconds(int(self.stamps_ns[k]))}",
                int(self.lines[k]),
                hint="the rows of this file must be sorted by time",
            )


def read_table(
    path: str | Path,
    columns: tuple[str, ...],
    *,
    stamped: bool = True,
    delimiter: str | None = None,
) -> Table:
    """Read a table of numbers: ``#`` comments and blank lines skipped, CRLF and BOM allowed.

    Args:
        path: the file.
        columns: the column names, for messages; a first data line equal to them is a header
            and skipped (CSV files).
        stamped: the first column is a time in seconds, converted exactly to int64 ns.
        delimiter: None for whitespace, else e.g. ``","``.

    Raises:
        InputError: the file is missing or unreadable.
        FormatError: a wrong field count, a non-number, a non-finite value or one beyond
            :data:`MAX_TABLE_VALUE` (names file:line).
    """
    p = Path(path)
    table = _read_table_fast(p, columns, stamped, delimiter) or _read_table_slow(
        p, columns, stamped, delimiter
    )
    rows, cols = np.nonzero(np.abs(table.values) > MAX_TABLE_VALUE)
    if rows.size:
        k, c = int(rows[0]), int(cols[0])
        name = columns[c + 1 if stamped else c]
        raise FormatError(
            p,
            f"column {c + (2 if stamped else 1)} ({name}): {table.values[k, c]:g} is out of "
            f"range (at most {MAX_TABLE_VALUE:g} in magnitude)",
            int(table.lines[k]),
        )
    return table


def _read_table_fast(
    path: Path, columns: tuple[str, ...], stamped: bool, delimiter: str | None
) -> Table | None:
    """Bulk parse; None when anything is unusual (the slow parse then names the bad line).

    Fields are counted per line on the bytes (token starts, or delimiters), so that the one
    ``split`` of the whole text can be trusted to line up with the columns.
    """
    try:
        with path.open("r", encoding="utf-8-sig", newline=None) as fh:
            text = fh.read()
    except (OSError, UnicodeDecodeError):
        return None
    stripped = list(map(str.strip, text.split("\n")))
    numbers = [i for i, line in enumerate(stripped, start=1) if line and line[0] != "#"]
    data = [stripped[i - 1] for i in numbers]
    if data and [f.strip() for f in data[0].split(delimiter)] == list(columns):
        numbers, data = numbers[1:], data[1:]
    n, ncol = len(data), len(columns)
    joined = "\n".join(data)
    if n == 0 or not joined.isascii():
        return None
    b = np.frombuffer(joined.encode("ascii"), dtype=np.uint8)
    # Every data line is non-empty, so each segment of reduceat is one line's bytes.
    line_start = np.concatenate([[0], np.flatnonzero(b == 10) + 1])
    if delimiter is None:
        if np.any((b < 32) & (b != 9) & (b != 10)):
            return None
        sep = (b == 32) | (b == 9) | (b == 10)
        start = ~sep
        start[1:] &= sep[:-1]
        counts = np.add.reduceat(start, line_start, dtype=np.int64)
        flat = joined.split()
    else:
        counts = np.add.reduceat(b == ord(delimiter), line_start, dtype=np.int64) + 1
        flat = joined.replace("\n", delimiter).split(delimiter)
    if counts.size != n or np.any(counts != ncol):
        return None
    first = 1 if stamped else 0
    try:
        values = np.array([flat[c::ncol] for c in range(first, ncol)], dtype=np.float64)
    except ValueError:
        return None
    values = values.T.reshape(n, ncol - first)
    if not np.all(np.isfinite(values)):
        return None
    stamps = _stamps_fast(flat[0::ncol]) if stamped else np.zeros(0, dtype=np.int64)
    if stamps is None:
        return None
    return Table(path, np.asarray(numbers, dtype=np.int64), stamps, values)


def _stamps_fast(texts: list[str]) -> I64 | None:
    """Exact ns from plain ``123.456`` strings (<= 10 integer and <= 9 decimal digits), else None.

    Works on the bytes: each digit contributes ``digit * 10**(9 + place)``.
    """
    if not texts:
        return np.zeros(0, dtype=np.int64)
    try:
        a = np.array(texts, dtype="S")
    except UnicodeEncodeError:
        return None
    width = a.dtype.itemsize
    m = a.view(np.uint8).reshape(-1, width)
    digit = (m >= 48) & (m <= 57)
    dot = m == 46
    pad = m == 0
    length = width - pad.sum(axis=1)
    if not np.all(digit | dot | pad) or np.any(dot.sum(axis=1) > 1) or np.any(length == 0):
        return None
    col = np.arange(width)
    if np.any(pad & (col[None, :] < length[:, None])):
        return None
    dot_at = np.where(dot.any(axis=1), dot.argmax(axis=1), length)
    if np.any(dot_at == 0) or np.any(dot_at > 10) or np.any(length - dot_at - 1 > 9):
        return None
    if np.any((dot_at == 10) & (m[:, 0] > ord("8"))):
        return None  # 9e9 s and more could overflow int64 ns
    # Place of each character: 9 + (dot_at - 1 - col) before the dot, 9 - (col - dot_at) after.
    place = 9 + dot_at[:, None] - col[None, :] - (col[None, :] < dot_at[:, None])
    place = np.clip(place, 0, 18)
    contrib = np.where(digit, (m.astype(np.int64) - 48) * _POW10[place], 0)
    return np.asarray(contrib.sum(axis=1), dtype=np.int64)


def _read_table_slow(
    path: Path, columns: tuple[str, ...], stamped: bool, delimiter: str | None
) -> Table:
    numbers: list[int] = []
    stamps: list[int] = []
    rows: list[list[float]] = []
    ncol = len(columns)
    first = True
    for number, fields in iter_data_lines(path, delimiter=delimiter):
        if first:
            first = False
            if fields == list(columns):
                continue
        if len(fields) != ncol:
            raise FormatError(
                path,
                f"expected {ncol} fields ({', '.join(columns)}), found {len(fields)}",
                number,
            )
        if stamped:
            stamps.append(parse_stamp_ns(fields[0], path, number))
            rows.append(parse_floats(fields[1:], path, number, first_column=2))
        else:
            rows.append(parse_floats(fields, path, number))
        numbers.append(number)
    width = ncol - 1 if stamped else ncol
    return Table(
        path,
        np.asarray(numbers, dtype=np.int64),
        np.asarray(stamps, dtype=np.int64),
        np.asarray(rows, dtype=np.float64).reshape(len(rows), width),
    )


def _seconds(ns: int) -> str:
    """Exact decimal seconds without trailing zeros: ``1248444187.156``."""
    text = format_stamp(ns).rstrip("0")
    return text + "0" if text.endswith(".") else text


# --- What every landmark source holds ----------------------------------------------------------


@dataclass(frozen=True)
class Odometry:
    """Odometry records in file order.

    Attributes:
        stamps_ns: (N,) int64, non-decreasing.
        v, omega: (N,) float64 m/s and rad/s (velocity logs), else None.
        world_from_body: (N, 4, 4) float64 dead-reckoned poses (relative-pose logs), else None.
    """

    stamps_ns: I64
    v: F64 | None = None
    omega: F64 | None = None
    world_from_body: F64 | None = None

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    @property
    def kind(self) -> str:
        return "velocity" if self.v is not None else "relative pose"


@dataclass(frozen=True)
class Observations:
    """Landmark observations in file order (the dropped and skipped ones removed).

    Attributes:
        stamps_ns: (M,) int64, non-decreasing.
        ids: (M,) int64 landmark ids as the log gives them (never -1 from a log with ids).
        ranges_m, bearings_rad: (M,) float64.
    """

    stamps_ns: I64
    ids: I64
    ranges_m: F64
    bearings_rad: F64

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    @cached_property
    def group_starts(self) -> NDArray[np.intp]:
        """(F + 1,) row index where each stamp's group starts, and M at the end."""
        change = np.flatnonzero(np.diff(self.stamps_ns) != 0) + 1
        if len(self) == 0:
            return np.zeros(1, dtype=np.intp)
        return np.concatenate([[0], change, [len(self)]]).astype(np.intp)

    @property
    def frames(self) -> int:
        return int(self.group_starts.size - 1)


class LandmarkSource(SourceBase):
    """What the landmark sources share: frames, start pose and the common ``info`` parts.

    Subclasses set :attr:`path`, :attr:`stats`, :attr:`ignore_ids`, :attr:`odometry` and
    :attr:`observations` in their constructor.
    """

    format_name = ""
    OPTIONS: tuple[str, ...] = ()
    path: Path
    stats: ReadStats
    ignore_ids: bool
    odometry: Odometry
    observations: Observations

    def groundtruth(self) -> Trajectory | None:
        """Planar robot poses (z = 0, yaw about +z) in the world frame, or None."""
        return None

    def landmark_truth(self) -> LandmarkMap | None:
        """Surveyed landmark positions (ids as in the frames), or None."""
        return None

    def frames(self, kinds: Collection[str] = FRAME_KINDS) -> Iterator[Frame]:
        """Yield odometry and/or landmark frames in time order (odometry first at a tie).

        Raises:
            ConfigError: a kind other than ``odometry`` and ``landmarks``.
        """
        wanted = set([kinds] if isinstance(kinds, str) else kinds)
        other = sorted(wanted - set(FRAME_KINDS))
        if other:
            raise ConfigError(
                f"{self.path}: {self.format_name} inputs have no {', '.join(other)} frames",
                hint=f"this source gives: {', '.join(FRAME_KINDS)}",
            )
        if "landmarks" in wanted:
            self._count_skipped()
        return self._merged("odometry" in wanted, "landmarks" in wanted)

    def first_stamp_ns(self) -> int | None:
        """Stamp of the first frame ``frames()`` yields (both kinds), or None if it yields none."""
        firsts = [int(s.stamps_ns[0]) for s in (self.odometry, self.observations) if len(s) > 0]
        return min(firsts) if firsts else None

    def start_pose(self) -> F64 | None:
        """(3,) float64 x (m), y (m), yaw (rad) at the first frame, from the ground truth.

        The ground truth is interpolated (:func:`~slamcli.geometry.interpolate_planar`) at the
        stamp of the first frame :meth:`frames` yields. When the ground truth starts after that
        stamp, but by at most :data:`START_POSE_MAX_WAIT_S`, its first pose is returned (the
        robot has barely moved in a log's first seconds). None without ground truth, when it
        starts later than that, or when it ends before the first frame.
        """
        gt = self.groundtruth()
        first = self.first_stamp_ns()
        if gt is None or len(gt) == 0 or first is None:
            return None
        planar = se3_to_planar(gt.world_from_body)
        pose = interpolate_planar(gt.stamps_ns, planar, [first])[0]
        if np.all(np.isfinite(pose)):
            return np.asarray(pose, dtype=np.float64)
        late_ns = int(gt.stamps_ns[0]) - first
        if 0 < late_ns <= round(START_POSE_MAX_WAIT_S * _NS_PER_S):
            return np.asarray(planar[0], dtype=np.float64)
        return None

    def _count_skipped(self) -> None:
        """Add what reading frames skips to :attr:`stats` (nothing by default)."""

    def _merged(self, odometry: bool, landmarks: bool) -> Iterator[Frame]:
        odo, obs = self.odometry, self.observations
        starts = obs.group_starts
        n_odo = len(odo) if odometry else 0
        n_obs = obs.frames if landmarks else 0
        stamps = np.concatenate([odo.stamps_ns[:n_odo], obs.stamps_ns[starts[:n_obs]]])
        codes = np.concatenate([np.zeros(n_odo, np.int64), np.ones(n_obs, np.int64)])
        # lexsort is stable: frames of one kind at one stamp keep their file order.
        order = np.lexsort((codes, stamps)).tolist()
        stamp_list = stamps.tolist()
        poses = odo.world_from_body
        v: list[Any] = odo.v.tolist() if odo.v is not None else [None] * len(odo)
        omega: list[Any] = odo.omega.tolist() if odo.omega is not None else [None] * len(odo)
        for k in order:
            frame: Frame
            if k < n_odo:
                pose = poses[k].copy() if poses is not None else None
                frame = OdometryFrame(stamp_list[k], v[k], omega[k], pose)
            else:
                a, b = int(starts[k - n_odo]), int(starts[k - n_odo + 1])
                ids = np.full(b - a, -1, dtype=np.int64) if self.ignore_ids else obs.ids[a:b].copy()
                frame = LandmarkFrame(
                    stamp_list[k], ids, obs.ranges_m[a:b].copy(), obs.bearings_rad[a:b].copy()
                )
            self.stats.read += 1
            yield frame

    def _info(
        self,
        streams: list[StreamInfo],
        gt: Trajectory | None,
        details: dict[str, Any],
        problems: list[str],
        progress: ProgressFn | None,
    ) -> SourceInfo:
        """The SourceInfo every landmark source returns, from its streams and findings."""
        if progress is not None:
            progress(1, 1)
        return SourceInfo(
            format=self.format_name,
            path=str(self.path),
            streams=streams,
            frames=len(self.odometry) + self.observations.frames,
            groundtruth=len(gt) if gt is not None else 0,
            problems=problems,
            details=details,
        )

    def _common_info(self) -> tuple[dict[str, Any], list[str]]:
        """Details and problems every landmark source reports."""
        odo, obs = self.odometry, self.observations
        details: dict[str, Any] = {
            "odometry": len(odo),
            "odometry_kind": odo.kind,
            "landmark_observations": len(obs),
            "landmark_frames": obs.frames,
            "landmark_ids_seen": int(np.unique(obs.ids[obs.ids >= 0]).size),
            "ignore_ids": self.ignore_ids,
        }
        problems: list[str] = []
        if len(odo) > 1:
            gaps = np.diff(odo.stamps_ns)
            k = int(np.argmax(gaps))
            details["odometry_max_gap_s"] = float(gaps[k]) * 1e-9
            details["odometry_repeated_stamps"] = int(np.count_nonzero(gaps == 0))
            long_gaps = int(np.count_nonzero(gaps > ODOMETRY_GAP_PROBLEM_S * _NS_PER_S))
            if long_gaps:
                problems.append(
                    f"{long_gaps} odometry gap(s) longer than {ODOMETRY_GAP_PROBLEM_S:g} s "
                    f"(largest {gaps[k] * 1e-9:.3f} s after {_seconds(int(odo.stamps_ns[k]))})"
                )
        if len(odo) == 0:
            problems.append("no odometry")
        if len(obs) == 0:
            problems.append("no landmark observations")
        truth = self.landmark_truth()
        details["landmarks"] = len(truth) if truth is not None else None
        if truth is not None and len(obs):
            unknown = np.setdiff1d(obs.ids, truth.ids)
            if unknown.size:
                problems.append(
                    f"landmark id(s) {', '.join(map(str, unknown.tolist()[:10]))} are observed "
                    "but not in the landmark ground truth"
                )
        self._groundtruth_span(details, problems)
        start = self.start_pose()
        details["start_pose"] = start.tolist() if start is not None else None
        return details, problems

    def _groundtruth_span(self, details: dict[str, Any], problems: list[str]) -> None:
        gt = self.groundtruth()
        first = self.first_stamp_ns()
        if gt is None or len(gt) == 0 or first is None:
            return
        last = max(int(s.stamps_ns[-1]) for s in (self.odometry, self.observations) if len(s))
        g0, g1 = int(gt.stamps_ns[0]), int(gt.stamps_ns[-1])
        covered = min(g1, last) - max(g0, first)
        span = last - first
        details["groundtruth_span_coverage"] = (
            max(covered, 0) / span if span > 0 else float(g0 <= first <= g1)
        )
        if g0 > first:
            problems.append(
                f"ground truth starts {(g0 - first) * 1e-9:.1f} s after the first frame"
            )
        if g1 < last:
            problems.append(
                f"ground truth ends {(last - g1) * 1e-9:.1f} s before the last frame; "
                "later poses cannot be evaluated"
            )

    def _stream(self, name: str, kind: str, stamps_ns: I64, detail: str = "") -> StreamInfo:
        n = int(stamps_ns.size)
        if n == 0:
            return StreamInfo(name, kind, 0, detail=detail)
        span = (int(stamps_ns[-1]) - int(stamps_ns[0])) * 1e-9
        return StreamInfo(
            name,
            kind,
            n,
            (n - 1) / span if n > 1 and span > 0 else None,
            float(stamps_ns[0]) * 1e-9,
            float(stamps_ns[-1]) * 1e-9,
            detail,
        )


def _check_ignore_ids(ignore_ids: Any) -> bool:
    if not isinstance(ignore_ids, bool):
        raise ConfigError(f"ignore_ids must be true or false, got {ignore_ids!r}")
    return ignore_ids


def _require_files(folder: Path, names: tuple[str, ...], what: str, hint: str) -> None:
    if not folder.is_dir():
        raise InputError(f"{folder}: {what} is a folder", hint=hint)
    missing = [n for n in names if not (folder / n).is_file()]
    if missing:
        raise InputError(f"{folder}: {what} has no {' and no '.join(missing)}", hint=hint)


# --- MRCLAM ------------------------------------------------------------------------------------

_MRCLAM_HINT = (
    "an MRCLAM folder holds Barcodes.dat, Landmark_Groundtruth.dat and RobotN_Odometry.dat, "
    "RobotN_Measurement.dat, RobotN_Groundtruth.dat for each robot N"
)


class MrclamSource(LandmarkSource):
    """One robot's log in a UTIAS MRCLAM folder (see the module docstring).

    Args:
        path: the ``MRCLAM_DatasetN`` folder.
        robot: which robot's odometry, measurements and ground truth to read (a number K with
            a ``RobotK_Odometry.dat``), or several (``"1,2,3"``, ``"all"``).
        ignore_ids: landmark ids become -1 (unknown correspondences).
        strict: a measurement of a barcode that is no landmark's and no robot's is a
            :class:`FormatError` instead of being skipped.

    Attributes:
        robots: the numbers K with a ``RobotK_Odometry.dat`` in the folder, sorted.
        robot_subjects: the subjects that are robots: 1-5 and :attr:`robots`, less the
            subjects of ``Landmark_Groundtruth.dat``.
        landmark_subjects: the subjects that are landmarks.

    Raises:
        InputError: not an MRCLAM folder, or no such robot (the message lists the robots).
        FormatError: a malformed line, or time going backwards (names file:line).
        ConfigError: a bad option value.
    """

    format_name = "mrclam"
    OPTIONS = ("robot", "ignore_ids", "strict")

    def __init__(
        self,
        path: str | Path,
        *,
        robot: int | str = 1,
        ignore_ids: bool = False,
        strict: bool = False,
    ) -> None:
        self.path = Path(path)
        if isinstance(robot, bool) or not isinstance(robot, int | str):
            raise ConfigError(f"robot must be a robot number, got {robot!r}")
        self.ignore_ids = _check_ignore_ids(ignore_ids)
        self.strict = bool(strict)
        self.stats = ReadStats()
        self.ignored: list[str] = []
        _require_files(self.path, ("Barcodes.dat",), "an MRCLAM input", _MRCLAM_HINT)
        self.robots = sniff.mrclam_robots(self.path)
        self.selection = [robot] if isinstance(robot, int) else parse_robots(robot, self.robots)
        self.others: list[MrclamSource] = []
        if len(self.selection) > 1:
            if self.ignore_ids:
                raise ConfigError(
                    f"robot: several robots ({robot}) need landmark ids to share a map",
                    hint="leave out --ignore-ids, or choose one robot",
                )
            self.others = [
                MrclamSource(self.path, robot=r, strict=strict) for r in self.selection[1:]
            ]
        robot = self.selection[0]
        if robot not in self.robots:
            listed = ", ".join(map(str, self.robots)) or "none"
            raise InputError(
                f"{self.path}: no robot {robot} in this MRCLAM folder (robots: {listed})",
                hint="choose one with --robot N",
            )
        self.robot = robot
        prefix = f"Robot{robot}_"
        _require_files(self.path, (prefix + "Measurement.dat",), "an MRCLAM input", _MRCLAM_HINT)
        barcodes = read_table(self.path / "Barcodes.dat", ("subject", "barcode"), stamped=False)
        subjects = barcodes.integers(0, "subject")
        self.barcode_subject = dict(
            zip(barcodes.integers(1, "barcode").tolist(), subjects.tolist(), strict=True)
        )
        truth = self.landmark_truth()
        surveyed = frozenset(truth.ids.tolist()) if truth is not None else frozenset()
        self.robot_subjects = (MRCLAM_ROBOT_SUBJECTS | frozenset(self.robots)) - surveyed
        self.landmark_subjects = (
            surveyed
            if truth is not None
            else frozenset(s for s in subjects.tolist() if s not in self.robot_subjects)
        )
        odo = read_table(self.path / (prefix + "Odometry.dat"), ("time", "v", "omega"))
        odo.check_time_order()
        self.odometry_table = odo
        self.odometry = Odometry(odo.stamps_ns, odo.values[:, 0], odo.values[:, 1])
        meas = read_table(
            self.path / (prefix + "Measurement.dat"), ("time", "barcode", "range", "bearing")
        )
        meas.check_time_order()
        self.measurement_table = meas
        self.observations = self._classify(meas)

    @classmethod
    def sniff(cls, path: str | Path) -> bool:
        """A folder with ``Barcodes.dat`` and at least one ``RobotN_Odometry.dat``."""
        return sniff.mrclam(path)

    def _classify(self, meas: Table) -> Observations:
        """Map barcodes to subjects; drop robot sightings and set aside unknown barcodes."""
        barcodes = meas.integers(0, "barcode")
        subject = np.array(
            [self.barcode_subject.get(b, -1) for b in barcodes.tolist()], dtype=np.int64
        )
        robot = np.isin(subject, list(self.robot_subjects))
        landmark = np.isin(subject, list(self.landmark_subjects))
        other = ~(robot | landmark)
        self.robot_sightings = int(np.count_nonzero(robot))
        self.sightings = Observations(
            meas.stamps_ns[robot], subject[robot], meas.values[robot, 1], meas.values[robot, 2]
        )
        self.unknown_rows = np.flatnonzero(other)
        if self.strict and self.unknown_rows.size:
            k = int(self.unknown_rows[0])
            raise FormatError(
                meas.path,
                self._unknown_reason(int(barcodes[k]), int(subject[k])),
                int(meas.lines[k]),
                hint="without --strict such measurements are skipped and counted",
            )
        self.unknown_barcodes = dict(sorted(Counter(barcodes[self.unknown_rows].tolist()).items()))
        self._skipped_names = [
            f"{meas.where(k)} barcode {barcodes[k]}" for k in self.unknown_rows.tolist()
        ]
        return Observations(
            meas.stamps_ns[landmark],
            subject[landmark],
            meas.values[landmark, 1],
            meas.values[landmark, 2],
        )

    def frames(self, kinds: Collection[str] = FRAME_KINDS) -> Iterator[Frame]:
        """One robot's frames as :meth:`LandmarkSource.frames`; with several robots selected,
        every robot's frames as :class:`RobotFrame` records in one time order (odometry, then
        landmarks, then sightings of other robots at a tie; robots in selection order), the
        sightings only when landmark frames are asked for."""
        if not self.others:
            return super().frames(kinds)
        wanted = set([kinds] if isinstance(kinds, str) else kinds)
        streams = [
            self._robot_frames(src, super(MrclamSource, src).frames(kinds), "landmarks" in wanted)
            for src in [self, *self.others]
        ]
        return self._count(heapq.merge(*streams, key=lambda item: item[0]))

    def _count(
        self, items: Iterator[tuple[tuple[int, int, int, int], RobotFrame]]
    ) -> Iterator[Any]:
        # The first robot's own frames are counted by its reading, the rest here.
        for _, frame in items:
            if frame.robot != self.robot or frame.sighting:
                self.stats.read += 1
            yield frame

    def _robot_frames(
        self, src: MrclamSource, frames: Iterator[Frame], sightings: bool
    ) -> Iterator[tuple[tuple[int, int, int, int], RobotFrame]]:
        """(sort key, frame) of one robot: its own frames with its sightings merged in."""
        order = self.selection.index(src.robot)
        own = (
            (
                (f.stamp_ns, 0 if isinstance(f, OdometryFrame) else 1, order, k),
                RobotFrame(src.robot, cast(OdometryFrame | LandmarkFrame, f)),
            )
            for k, f in enumerate(frames)
        )
        if not sightings:
            yield from own
            return
        obs = src.sightings
        starts = obs.group_starts
        seen = (
            (
                (int(obs.stamps_ns[a]), 2, order, i),
                RobotFrame(
                    src.robot,
                    LandmarkFrame(
                        int(obs.stamps_ns[a]),
                        obs.ids[a:b].copy(),
                        obs.ranges_m[a:b].copy(),
                        obs.bearings_rad[a:b].copy(),
                    ),
                    sighting=True,
                ),
            )
            for i, (a, b) in enumerate(zip(starts[:-1].tolist(), starts[1:].tolist(), strict=True))
        )
        yield from heapq.merge(own, seen, key=lambda item: item[0])

    def groundtruths(self) -> dict[int, Trajectory]:
        """Each selected robot's ground truth (robots without one are left out)."""
        out = {}
        for src in [self, *self.others]:
            gt = src.groundtruth()
            if gt is not None:
                out[src.robot] = gt
        return out

    def _unknown_reason(self, barcode: int, subject: int) -> str:
        if subject < 0:
            return f"barcode {barcode} is not in Barcodes.dat"
        return f"barcode {barcode} is subject {subject}, neither a robot nor a landmark"

    def _count_skipped(self) -> None:
        # Not data loss (the log is intact, the codes just name nothing): a warning, and the
        # counts in info's details, but no exit code 3.
        if not self._skipped_names:
            return
        self.ignored = list(self._skipped_names)
        log.warning(
            "%s: ignored %d measurement(s) of barcodes that are no landmark's or robot's: %s",
            self.measurement_table.path,
            len(self._skipped_names),
            _counts(self.unknown_barcodes),
        )

    @cached_property
    def _groundtruth(self) -> Trajectory | None:
        p = self.path / f"Robot{self.robot}_Groundtruth.dat"
        if not p.is_file():
            return None
        gt = read_table(p, ("time", "x", "y", "theta"))
        if len(gt) == 0:
            raise FormatError(p, "holds no ground-truth rows (time x y theta)")
        gt.check_time_order()
        # A Trajectory's stamps strictly increase: keep the first row of a repeated stamp.
        keep = np.concatenate([[True], np.diff(gt.stamps_ns) > 0])
        return Trajectory(gt.stamps_ns[keep], planar_to_se3(gt.values[keep]))

    def groundtruth(self) -> Trajectory | None:
        """``RobotN_Groundtruth.dat`` (motion capture), or None without that file."""
        return self._groundtruth

    @cached_property
    def _landmark_truth(self) -> LandmarkMap | None:
        p = self.path / "Landmark_Groundtruth.dat"
        if not p.is_file():
            return None
        t = read_table(p, ("subject", "x", "y", "x_std", "y_std"), stamped=False)
        n = len(t)
        cov = np.zeros((n, 2, 2))
        cov[:, 0, 0], cov[:, 1, 1] = t.values[:, 3] ** 2, t.values[:, 4] ** 2
        return LandmarkMap(t.integers(0, "subject"), t.values[:, 1:3].copy(), cov)

    def landmark_truth(self) -> LandmarkMap | None:
        """``Landmark_Groundtruth.dat``: ids are subject numbers, cov = diag(std-devs²)."""
        return self._landmark_truth

    def info(self, deep: bool = False, progress: ProgressFn | None = None) -> SourceInfo:
        """Streams (odometry, measurements, ground truth), counts and problems.

        ``deep`` changes nothing: everything is read at open.
        """
        details, problems = self._common_info()
        gt = self.groundtruth()
        prefix = f"Robot{self.robot}_"
        streams = [
            self._stream(
                prefix + "Odometry.dat", "odometry", self.odometry.stamps_ns, "t, v, omega"
            ),
            self._stream(
                prefix + "Measurement.dat",
                "landmarks",
                self.measurement_table.stamps_ns,
                "t, barcode, range, bearing",
            ),
        ]
        if gt is not None:
            streams.append(
                self._stream(prefix + "Groundtruth.dat", "pose", gt.stamps_ns, "t, x, y, theta")
            )
            details["groundtruth_from"] = prefix + "Groundtruth.dat"
        details.update(
            robot=self.robot,
            robots=self.robots,
            selection=self.selection,
            robot_sightings=self.robot_sightings,
            unknown_barcodes={str(b): c for b, c in self.unknown_barcodes.items()},
        )
        if self.unknown_barcodes:
            problems.append(
                f"{int(self.unknown_rows.size)} measurement(s) of barcodes that are no "
                f"landmark's or robot's are ignored: {_counts(self.unknown_barcodes)}"
            )
        return self._info(streams, gt, details, problems, progress)


def _counts(counter: dict[int, int]) -> str:
    """``"34 (2x), 43 (1x)"``."""
    return ", ".join(f"{k} ({v}x)" for k, v in counter.items())


# --- Victoria Park (GTSAM text format) ---------------------------------------------------------

_VICTORIA_HINT = (
    "a Victoria Park file has 'ODOMETRY i j dx dy dtheta c11 c12 c13 c22 c23 c33' lines "
    "chained in pose order (each i is the previous j, j > i), and 'LANDMARK i l x y c11 c12 "
    "c22' lines after the ODOMETRY line ending at pose i"
)
_VICTORIA_FIELDS = {"ODOMETRY": 12, "LANDMARK": 8}


class VictoriaParkSource(LandmarkSource):
    """A Victoria Park file in GTSAM's ODOMETRY/LANDMARK text format (see the module docstring).

    Args:
        path: the text file.
        ignore_ids: landmark ids become -1 (unknown correspondences).

    Attributes:
        pose_keys: (N + 1,) int64 the file's key of each pose (frame k is pose ``pose_keys[k]``).
        odometry_covariances: (N, 3, 3) float64 covariance of each increment (dx, dy, dtheta)
            from pose k to pose k + 1, in pose k's frame.

    Raises:
        InputError: the file is missing or unreadable.
        FormatError: a malformed line, or poses out of order (names file:line).
    """

    format_name = "victoria"
    OPTIONS = ("ignore_ids",)

    def __init__(self, path: str | Path, *, ignore_ids: bool = False) -> None:
        self.path = Path(path)
        self.ignore_ids = _check_ignore_ids(ignore_ids)
        self.stats = ReadStats()
        if self.path.is_dir():
            raise InputError(f"{self.path}: a Victoria Park input is a file", hint=_VICTORIA_HINT)
        steps: list[list[float]] = []
        seen: list[list[float]] = []
        seen_pose: list[int] = []
        keys = [0]
        pose = 0
        for number, fields in iter_data_lines(self.path):
            tag = fields[0]
            if tag not in _VICTORIA_FIELDS:
                raise FormatError(
                    self.path,
                    f"unknown record {tag!r}, expected ODOMETRY or LANDMARK",
                    number,
                    hint=_VICTORIA_HINT,
                )
            if len(fields) != _VICTORIA_FIELDS[tag]:
                raise FormatError(
                    self.path,
                    f"{tag} has {_VICTORIA_FIELDS[tag] - 1} values, found {len(fields) - 1}",
                    number,
                    hint=_VICTORIA_HINT,
                )
            i, j = self._index(fields[1], number, "pose"), self._index(fields[2], number, tag)
            values = parse_floats(fields[3:], self.path, number, first_column=4)
            for col, v in enumerate(values, start=4):
                if abs(v) > MAX_TABLE_VALUE:
                    raise FormatError(
                        self.path,
                        f"column {col}: {v:g} is out of range (at most {MAX_TABLE_VALUE:g} in "
                        "magnitude)",
                        number,
                    )
            if tag == "ODOMETRY":
                if i != pose or j <= i:
                    raise FormatError(
                        self.path,
                        f"expected ODOMETRY from pose {pose} to a later pose, found "
                        f"ODOMETRY {i} {j}",
                        number,
                        hint=_VICTORIA_HINT,
                    )
                pose = j
                keys.append(j)
                steps.append(values)
            else:
                if i != pose:
                    raise FormatError(
                        self.path,
                        f"LANDMARK seen from pose {i} while the current pose is {pose}",
                        number,
                        hint=_VICTORIA_HINT,
                    )
                seen.append([float(j), *values])
                seen_pose.append(len(keys) - 1)
        step = np.asarray(steps, dtype=np.float64).reshape(-1, 9)
        obs = np.asarray(seen, dtype=np.float64).reshape(-1, 6)
        self.odometry_covariances = _upper_to_cov3(step[:, 3:])
        self.pose_keys = np.asarray(keys, dtype=np.int64)
        self._planar = _dead_reckon(step[:, :3])
        self.odometry = Odometry(
            np.arange(step.shape[0] + 1, dtype=np.int64) * VICTORIA_STEP_NS,
            world_from_body=planar_to_se3(self._planar),
        )
        self.observations = Observations(
            np.asarray(seen_pose, dtype=np.int64).reshape(-1) * VICTORIA_STEP_NS,
            obs[:, 0].astype(np.int64),
            np.hypot(obs[:, 1], obs[:, 2]),
            np.arctan2(obs[:, 2], obs[:, 1]),
        )

    def _index(self, text: str, line: int, what: str) -> int:
        index = parse_count(text, self.path, line, f"{what} index")
        if index > MAX_TABLE_VALUE:
            limit = f"at most {MAX_TABLE_VALUE:g}"
            raise FormatError(self.path, f"{what} index {index} is out of range ({limit})", line)
        return index

    @classmethod
    def sniff(cls, path: str | Path) -> bool:
        """A file whose first non-blank, non-comment line starts with ODOMETRY or LANDMARK."""
        return sniff.victoria_park(path)

    def info(self, deep: bool = False, progress: ProgressFn | None = None) -> SourceInfo:
        """Streams (ODOMETRY and LANDMARK lines), counts and problems."""
        details, problems = self._common_info()
        name = self.path.name
        details.update(
            poses=len(self.odometry),
            stamps="k-th pose at k s (the file has no times)",
            dead_reckoning_length_m=float(
                np.linalg.norm(np.diff(self._planar[:, :2], axis=0), axis=1).sum()
            ),
        )
        streams = [
            self._stream("ODOMETRY", "odometry", self.odometry.stamps_ns[1:], name),
            self._stream("LANDMARK", "landmarks", self.observations.stamps_ns, name),
        ]
        return self._info(streams, None, details, problems, progress)


def _dead_reckon(steps: F64) -> F64:
    """(N, 3) increments (dx, dy, dtheta), each in the previous pose's frame -> (N + 1, 3) poses.

    Pose 0 is the origin; pose k + 1 = pose k ⊕ step k.
    """
    theta = np.concatenate([[0.0], np.cumsum(steps[:, 2])])
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    x = np.concatenate([[0.0], np.cumsum(c * steps[:, 0] - s * steps[:, 1])])
    y = np.concatenate([[0.0], np.cumsum(s * steps[:, 0] + c * steps[:, 1])])
    return np.stack([x, y, wrap_angle(theta)], axis=1)


def _upper_to_cov3(upper: F64) -> F64:
    """(N, 6) c11 c12 c13 c22 c23 c33 -> (N, 3, 3) symmetric."""
    cov = np.zeros((upper.shape[0], 3, 3))
    for k, (r, c) in enumerate(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
        cov[:, r, c] = cov[:, c, r] = upper[:, k]
    return cov


# --- slamcli synth landmarks folders -----------------------------------------------------------

_WORLD_HINT = (
    "a landmarks folder (written by 'slamcli synth landmarks') holds odometry.csv and "
    "measurements.csv, and optionally groundtruth.tum and landmarks.csv"
)


class LandmarkWorldSource(LandmarkSource):
    """A folder written by ``slamcli synth landmarks`` (layout in :mod:`slamcli.synth.landmarks`).

    Args:
        path: the folder.
        ignore_ids: landmark ids become -1 (unknown correspondences).

    Raises:
        InputError: not such a folder.
        FormatError: a malformed line, or time going backwards (names file:line).
    """

    format_name = "landmarks"
    OPTIONS = ("ignore_ids",)

    def __init__(self, path: str | Path, *, ignore_ids: bool = False) -> None:
        self.path = Path(path)
        self.ignore_ids = _check_ignore_ids(ignore_ids)
        self.stats = ReadStats()
        _require_files(
            self.path, ("odometry.csv", "measurements.csv"), "a landmarks input", _WORLD_HINT
        )
        odo = read_table(self.path / "odometry.csv", ("t", "v", "omega"), delimiter=",")
        odo.check_time_order()
        self.odometry = Odometry(odo.stamps_ns, odo.values[:, 0], odo.values[:, 1])
        meas = read_table(
            self.path / "measurements.csv", ("t", "id", "range", "bearing"), delimiter=","
        )
        meas.check_time_order()
        self.observations = Observations(
            meas.stamps_ns, meas.integers(0, "id"), meas.values[:, 1], meas.values[:, 2]
        )

    @classmethod
    def sniff(cls, path: str | Path) -> bool:
        """A folder with ``odometry.csv`` and ``measurements.csv``."""
        return sniff.landmark_world(path)

    @cached_property
    def _groundtruth(self) -> Trajectory | None:
        p = self.path / "groundtruth.tum"
        return read_trajectory(p, "tum") if p.is_file() else None

    def groundtruth(self) -> Trajectory | None:
        """``groundtruth.tum`` (true poses, one more than odometry rows), or None."""
        return self._groundtruth

    @cached_property
    def _landmark_truth(self) -> LandmarkMap | None:
        p = self.path / "landmarks.csv"
        if not p.is_file():
            return None
        t = read_table(p, ("id", "x", "y"), stamped=False, delimiter=",")
        return LandmarkMap(t.integers(0, "id"), t.values[:, 1:3].copy())

    def landmark_truth(self) -> LandmarkMap | None:
        """``landmarks.csv`` (no covariances), or None."""
        return self._landmark_truth

    def info(self, deep: bool = False, progress: ProgressFn | None = None) -> SourceInfo:
        """Streams (odometry, measurements, ground truth), counts and problems."""
        details, problems = self._common_info()
        gt = self.groundtruth()
        streams = [
            self._stream("odometry.csv", "odometry", self.odometry.stamps_ns, "t, v, omega"),
            self._stream(
                "measurements.csv",
                "landmarks",
                self.observations.stamps_ns,
                "t, id, range, bearing",
            ),
        ]
        if gt is not None:
            streams.append(self._stream("groundtruth.tum", "pose", gt.stamps_ns, "TUM poses"))
            details["groundtruth_from"] = "groundtruth.tum"
        return self._info(streams, gt, details, problems, progress)


@dataclass
class LandmarkLog:
    """A landmark run in memory, as :func:`~slamcli.formats.mcap.write.write_landmark_log`
    writes it: velocity odometry, range-bearing observations and ground truth.

    Attributes:
        odometry_stamps_ns: (K,) int64 odometry stamps.
        odometry: (K, 2) float64 v (m/s) and omega (rad/s) applied from each stamp to the next.
        measurement_stamps_ns: (M,) int64 stamp of each observation.
        measurement_ids: (M,) int64 landmark ids, -1 = unknown.
        measurement_ranges: (M,) float64 metres.
        measurement_bearings: (M,) float64 radians, counter-clockwise from the heading.
        groundtruth: true poses (world_from_body), or None.
    """

    odometry_stamps_ns: I64
    odometry: F64
    measurement_stamps_ns: I64
    measurement_ids: I64
    measurement_ranges: F64
    measurement_bearings: F64
    groundtruth: Trajectory | None = None


def read_landmark_log(folder: str | Path) -> LandmarkLog:
    """A ``slamcli synth landmarks`` folder (read by :class:`LandmarkWorldSource`) in memory.

    Raises:
        InputError: not such a folder. FormatError: a malformed line (names file:line).
    """
    with LandmarkWorldSource(folder) as source:
        odo, obs = source.odometry, source.observations
        # A landmarks folder always holds velocities (t, v, omega); the source checked that.
        assert odo.v is not None and odo.omega is not None
        return LandmarkLog(
            odometry_stamps_ns=odo.stamps_ns,
            odometry=np.stack([odo.v, odo.omega], axis=1),
            measurement_stamps_ns=obs.stamps_ns,
            measurement_ids=obs.ids,
            measurement_ranges=obs.ranges_m,
            measurement_bearings=obs.bearings_rad,
            groundtruth=source.groundtruth(),
        )


__all__ = [
    "FRAME_KINDS",
    "LandmarkLog",
    "LandmarkSource",
    "LandmarkWorldSource",
    "MrclamSource",
    "Observations",
    "Odometry",
    "RobotFrame",
    "Table",
    "VictoriaParkSource",
    "read_landmark_log",
    "read_table",
]
