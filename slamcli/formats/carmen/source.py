"""Reading a CARMEN log: :class:`CarmenSource` (see :mod:`slamcli.formats.carmen`)."""

from __future__ import annotations

import gzip
import logging
import math
import re
import zlib
from collections import Counter
from collections.abc import Collection, Generator, Iterator
from pathlib import Path
from typing import IO, Any, NamedTuple, cast

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats import sniff
from slamcli.formats.base import Frame, ReadStats, SourceBase, SourceInfo, StreamInfo
from slamcli.formats.carmen.layout import (
    DEFAULT_MAX_RANGE_M,
    F64,
    LAYOUT_HINT,
    RANGE_MIN_M,
    below,
    flaser_increment,
    layout_of,
    xyt,
)
from slamcli.formats.carmen.stamps import repair_stamps
from slamcli.formats.text import (
    MAX_LINE_BYTES,
    bounded_lines,
    line_too_long,
    parse_count,
    parse_floats,
    parse_stamp_ns,
)
from slamcli.geometry import between_planar, planar_to_se3, wrap_angle
from slamcli.types import OdometryFrame, ProgressFn, ScanFrame, Trajectory

log = logging.getLogger(__name__)

FRAME_KINDS = ("scan", "odometry")
"""The frame kinds a CARMEN log provides."""

ODOMETRY_CHOICES = ("log", "none")
"""Values of the ``odometry`` option: the log's poses as odometry, or no odometry frames."""

GROUNDTRUTH_CHOICES = (None, "log")
"""Values of the ``groundtruth`` option: none, or the log's robot pose at each scan."""

_INT64_MAX = 2**63 - 1
_ROBOTLASER = re.compile(r"ROBOTLASER\d", re.ASCII)
_RAWLASER = re.compile(r"RAWLASER\d", re.ASCII)
_LINES = Generator[tuple[int, bytes | None], None, None]


class _Entry(NamedTuple):
    """One frame-giving line of the log, without its ranges."""

    line: int
    keyword: str
    laser: bool
    ipc_ns: int
    logger_ns: int
    robot: tuple[float, float, float] | None
    sensor: tuple[float, float, float] = (0.0, 0.0, 0.0)
    beams: int = 0
    first_range: int = 0
    angle_min: float = 0.0
    increment: float = 0.0
    max_range: float | None = None


class CarmenSource(SourceBase):
    """A CARMEN laser log as a :class:`~slamcli.formats.base.Source` (see the module docstring).

    The log is read once at open (ranges are checked, not kept); ``frames()`` reads the scans'
    ranges again as it goes, so memory holds one scan at a time.

    Args:
        path: the ``.log`` / ``.clf`` file, plain or gzipped.
        odometry: ``"log"`` feeds the log's poses (ODOM lines and each scan's robot pose) as
            odometry; ``"none"`` gives no odometry frames.
        groundtruth: ``"log"`` makes :meth:`groundtruth` the robot's pose at each scan (the
            reference path of a corrected log); None gives no ground truth.
        max_range: metres; ranges at or beyond it are no return. None: each message's own
            maximum, :data:`DEFAULT_MAX_RANGE_M` for FLASER and RLASER.
        strict: a damaged line or gzip stream is a :class:`FormatError` instead of skipped.

    Raises:
        InputError: the file is missing or unreadable.
        FormatError: (``strict``) a damaged line, naming ``file:line``.
        ConfigError: a bad option value.
    """

    format_name = "carmen"
    OPTIONS = ("odometry", "groundtruth", "max_range", "strict")

    def __init__(
        self,
        path: str | Path,
        *,
        odometry: str = "log",
        groundtruth: str | None = None,
        max_range: float | None = None,
        strict: bool = False,
    ) -> None:
        self.path = Path(path)
        self.odometry = _check_choice("odometry", odometry, ODOMETRY_CHOICES)
        self.groundtruth_choice = _check_choice("groundtruth", groundtruth, GROUNDTRUTH_CHOICES)
        self.max_range = _check_max_range(max_range)
        if not isinstance(strict, bool):
            raise ConfigError(f"strict must be true or false, got {strict!r}")
        self.strict = strict
        self.stats = ReadStats()
        self.comments = 0
        self.other_messages: Counter[str] = Counter()
        self.malformed: list[tuple[int, str]] = []
        self.damage: str | None = None
        entries = self._index()
        self._arrays(entries)
        self.clock = repair_stamps(self._laser, self._ipc, self._logger)
        self._warn()

    @classmethod
    def sniff(cls, path: str | Path) -> bool:
        """A ``.log``/``.clf`` file (or gzipped) whose first message is a CARMEN one."""
        return sniff.carmen(path)

    # -- reading the log once ----------------------------------------------------------------

    def _index(self) -> list[_Entry]:
        entries: list[_Entry] = []
        number = 0
        lines = _raw_lines(self.path)
        try:
            for number, raw in lines:
                entry = self._entry(number, raw)
                if entry is not None:
                    entries.append(entry)
        except (EOFError, zlib.error, gzip.BadGzipFile) as exc:
            what = f"the compressed data is damaged or cut short after line {number} ({exc})"
            if self.strict:
                raise FormatError(
                    self.path, what, hint="run without --strict to read the part before it"
                ) from None
            self.damage = what
        finally:
            lines.close()
        return entries

    def _entry(self, number: int, raw: bytes | None) -> _Entry | None:
        """The entry of one line; None for blank lines, comments, skipped and damaged ones
        (``raw`` None: a line longer than :data:`MAX_LINE_BYTES`, damaged)."""
        if raw is None:
            return self._damaged(line_too_long(self.path, number))
        try:
            text = raw.decode("utf-8").strip()
        except UnicodeDecodeError as exc:
            return self._damaged(
                FormatError(self.path, f"not text ({exc.reason} at byte {exc.start})", number)
            )
        if number == 1:
            text = text.lstrip("\ufeff")
        if not text:
            return None
        if text.startswith("#"):
            self.comments += 1
            return None
        fields = text.split()
        keyword = fields[0]
        try:
            if keyword == "ODOM":
                return self._odom(fields, number)
            if keyword in ("FLASER", "RLASER"):
                return self._flaser(fields, number)
            if _ROBOTLASER.fullmatch(keyword) or _RAWLASER.fullmatch(keyword):
                return self._robotlaser(fields, number)
        except FormatError as exc:
            return self._damaged(exc)
        self.other_messages[keyword] += 1
        return None

    def _damaged(self, exc: FormatError) -> _Entry | None:
        """None after noting a damaged line; raises it with ``strict``."""
        if self.strict:
            raise exc
        self.malformed.append((exc.line or 0, exc.msg))
        return None

    def _odom(self, fields: list[str], line: int) -> _Entry:
        self._expect_fields(fields, 10, line, "ODOM", "ODOM")
        x, y, theta = parse_floats(fields[1:4], self.path, line, "pose value", first_column=2)
        parse_floats(fields[4:7], self.path, line, "velocity", first_column=5)
        ipc, logger = self._times(fields, line)
        return _Entry(line, "ODOM", False, ipc, logger, (x, y, theta))

    def _flaser(self, fields: list[str], line: int) -> _Entry:
        keyword = fields[0]
        n = self._beams(fields, 1, line, keyword)
        self._expect_fields(fields, n + 11, line, f"{keyword} with {n} beams", "FLASER")
        self._ranges(fields, 2, n, line)
        poses = parse_floats(fields[2 + n : 8 + n], self.path, line, "pose value", 3 + n)
        sensor = between_planar(poses[3:6], poses[0:3])
        if keyword == "RLASER" and abs(float(sensor[2])) < math.pi / 2:
            sensor[2] = wrap_angle(sensor[2] + math.pi)
        increment = flaser_increment(n)
        ipc, logger = self._times(fields, line)
        robot = xyt(poses[3:6])
        return _Entry(
            line, keyword, True, ipc, logger, robot, xyt(sensor), n, 2, -math.pi / 2, increment
        )

    def _robotlaser(self, fields: list[str], line: int) -> _Entry:
        keyword = fields[0]
        layout = layout_of(keyword)
        if len(fields) < 9:
            raise FormatError(
                self.path,
                f"{keyword} needs at least 9 fields before its ranges, found {len(fields)}",
                line,
                hint=LAYOUT_HINT[layout],
            )
        config = parse_floats(fields[1:8], self.path, line, "laser setting", first_column=2)
        n = self._beams(fields, 8, line, keyword)
        m = self._beams(fields, 9 + n, line, keyword, "remission count", least=0)
        want = n + m + (24 if layout == "ROBOTLASER" else 13)
        self._expect_fields(fields, want, line, f"{keyword} with {n} beams", layout)
        _, start, _, resolution, max_range, _, _ = config
        if resolution == 0 or max_range <= 0:
            raise FormatError(
                self.path,
                f"angular resolution {resolution:g} and maximum range {max_range:g}: expected "
                "a non-zero resolution and a positive range",
                line,
                hint=LAYOUT_HINT[layout],
            )
        self._ranges(fields, 9, n, line)
        robot: tuple[float, float, float] | None = None
        sensor = (0.0, 0.0, 0.0)
        if layout == "ROBOTLASER":
            at = 10 + n + m
            poses = parse_floats(fields[at : at + 11], self.path, line, "pose value", at + 1)
            robot, sensor = xyt(poses[3:6]), xyt(between_planar(poses[3:6], poses[0:3]))
        ipc, logger = self._times(fields, line)
        return _Entry(
            line, keyword, True, ipc, logger, robot, sensor, n, 9, start, resolution, max_range
        )

    def _beams(
        self,
        fields: list[str],
        at: int,
        line: int,
        keyword: str,
        what: str = "beam count",
        least: int = 1,
    ) -> int:
        if at >= len(fields):
            raise FormatError(
                self.path,
                f"{keyword} ends before its {what} (the line is cut short)",
                line,
                hint=LAYOUT_HINT[layout_of(keyword)],
            )
        n = parse_count(fields[at], self.path, line, f"column {at + 1}: {keyword} {what}")
        if n < least:
            raise FormatError(
                self.path, f"{keyword} {what} is {n}, expected at least {least}", line
            )
        return n

    def _expect_fields(
        self, fields: list[str], want: int, line: int, what: str, layout: str
    ) -> None:
        if len(fields) != want:
            cut = " (the line is cut short)" if len(fields) < want else ""
            raise FormatError(
                self.path,
                f"{what} has {want} fields, found {len(fields)}{cut}",
                line,
                hint=LAYOUT_HINT[layout],
            )

    def _ranges(self, fields: list[str], first: int, n: int, line: int) -> F64:
        try:
            ranges = np.asarray(fields[first : first + n], dtype=np.float64)
        except ValueError:
            values = parse_floats(fields[first : first + n], self.path, line, "range", first + 1)
            ranges = np.asarray(values, dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(ranges))
        if bad.size:
            col = first + 1 + int(bad[0])
            raise FormatError(
                self.path, f"column {col}: range {fields[col - 1]!r} is not finite", line
            )
        return ranges

    def _times(self, fields: list[str], line: int) -> tuple[int, int]:
        """ipc_time and logger_time in ns, -1 where not a usable time (zero, negative, huge)."""
        out: list[int] = []
        for col in (len(fields) - 3, len(fields) - 1):
            text = fields[col]
            try:
                value = float(text)
            except ValueError:
                raise FormatError(
                    self.path, f"column {col + 1}: time {text!r} is not a number", line
                ) from None
            ns = -1
            if math.isfinite(value) and 0 < value < _INT64_MAX * 1e-9:
                try:
                    ns = parse_stamp_ns(text, self.path, line)
                except FormatError:
                    raise FormatError(
                        self.path, f"column {col + 1}: time {text!r} is not a number", line
                    ) from None
            out.append(ns if ns > 0 else -1)
        return out[0], out[1]

    def _arrays(self, entries: list[_Entry]) -> None:
        m = len(entries)
        self._lines = np.array([e.line for e in entries], dtype=np.int64)
        self._keywords = [e.keyword for e in entries]
        self._laser = np.array([e.laser for e in entries], dtype=bool)
        self._ipc = np.array([e.ipc_ns for e in entries], dtype=np.int64)
        self._logger = np.array([e.logger_ns for e in entries], dtype=np.int64)
        self._has_pose = np.array([e.robot is not None for e in entries], dtype=bool)
        self._robot = np.array(
            [e.robot if e.robot is not None else (np.nan,) * 3 for e in entries], dtype=np.float64
        ).reshape(m, 3)
        self._sensor = np.array([e.sensor for e in entries], dtype=np.float64).reshape(m, 3)
        self._beams_n = np.array([e.beams for e in entries], dtype=np.int64)
        self._first_range = np.array([e.first_range for e in entries], dtype=np.int64)
        self._angle_min = np.array([e.angle_min for e in entries], dtype=np.float64)
        self._increment = np.array([e.increment for e in entries], dtype=np.float64)
        limit = [self.max_range or e.max_range or DEFAULT_MAX_RANGE_M for e in entries]
        self._range_max = below(np.asarray(limit, dtype=np.float64))

    def _warn(self) -> None:
        clock = self.clock
        if clock.replaced.any():
            first = int(self._lines[int(np.argmax(clock.replaced))])
            log.warning("%s:%d: %s", self.path, first, self._stamp_problem())
        if self.malformed:
            log.warning(
                "%s: skipped %d damaged line(s); the first: %s",
                self.path,
                len(self.malformed),
                self.malformed[0][1],
            )
        if self.damage:
            log.warning("%s: %s; read the lines before it", self.path, self.damage)

    def _stamp_problem(self) -> str:
        clock = self.clock
        bad, total = int(clock.replaced.sum()), int(clock.replaced.size)
        step = clock.step_ns * 1e-9
        if not clock.trusted:
            return (
                f"only {total - bad} of {total} message times are usable (the others are zero, "
                "negative, repeated or out of order; the first on this line): the log's clock "
                f"is ignored and every message is stamped {step:.3f} s after the one before"
            )
        return (
            f"{bad} of {total} message times are broken (zero, negative, repeated or out of "
            "order; the first on this line) and were replaced by times interpolated between "
            f"their neighbours, or {step:.3f} s apart where no good time follows"
        )

    # -- frames ------------------------------------------------------------------------------

    @property
    def _odometry_kept(self) -> NDArray[np.bool_]:
        """Lines whose pose is yielded as odometry: ODOM lines not at a scan pose's stamp, and
        every laser line with a pose."""
        stamps = self.clock.stamps_ns
        scan_pose = self._laser & self._has_pose
        superseded = ~self._laser & np.isin(stamps, stamps[scan_pose])
        return self._has_pose & ~superseded

    def groundtruth(self) -> Trajectory | None:
        """The robot's pose at each scan (``groundtruth="log"``), planar in the z = 0 plane;
        None without that option or when no scan carries a pose."""
        if self.groundtruth_choice != "log":
            return None
        sel = self._laser & self._has_pose
        if not sel.any():
            return None
        return Trajectory(self.clock.stamps_ns[sel], planar_to_se3(self._robot[sel]))

    def start_pose(self) -> F64 | None:
        """(3,) x, y, yaw of the ground truth's first pose (the robot at the first scan)."""
        sel = np.flatnonzero(self._laser & self._has_pose)
        if self.groundtruth_choice != "log" or sel.size == 0:
            return None
        return np.asarray(self._robot[sel[0]], dtype=np.float64).copy()

    def frames(self, kinds: Collection[str] = FRAME_KINDS) -> Iterator[Frame]:
        """Yield odometry and/or scan frames in file (= time) order; a scan's own pose comes
        just before it.

        Raises:
            ConfigError: a kind other than ``scan`` and ``odometry``.
            InputError: the file changed since it was opened.
        """
        wanted = set([kinds] if isinstance(kinds, str) else kinds)
        other = sorted(wanted - set(FRAME_KINDS))
        if other:
            raise ConfigError(
                f"{self.path}: CARMEN logs have no {', '.join(other)} frames",
                hint=f"this source gives: {', '.join(FRAME_KINDS)}",
            )
        self._count_skipped()
        odometry = "odometry" in wanted and self.odometry == "log"
        return self._frames(odometry, "scan" in wanted)

    def _count_skipped(self) -> None:
        if self.malformed:
            self.stats.skipped_hint = (
                f"the skipped frames are damaged lines of the log: 'slamcli info {self.path}' "
                "counts them and names the first, with what is wrong with its fields or "
                "readings; --strict stops at the first instead"
            )
        self.stats.skipped += len(self.malformed)
        self.stats.skipped_names.extend(f"{self.path.name}:{line}" for line, _ in self.malformed)
        for loss in self._losses():
            if loss not in self.stats.data_loss:
                self.stats.data_loss.append(loss)

    def _losses(self) -> list[str]:
        out: list[str] = []
        if self.malformed:
            out.append(
                f"{len(self.malformed)} damaged line(s) skipped, the first: {self.malformed[0][1]}"
            )
        if self.damage:
            out.append(f"{self.path}: {self.damage}; the rest of the log is lost")
        return out

    def _frames(self, odometry: bool, scans: bool) -> Iterator[Frame]:
        keep_odometry = self._odometry_kept if odometry else np.zeros(len(self._lines), bool)
        stamps = self.clock.stamps_ns.tolist()
        lines = _raw_lines(self.path) if scans else None
        try:
            for k in range(len(stamps)):
                if keep_odometry[k]:
                    pose = planar_to_se3(self._robot[k])[0]
                    self.stats.read += 1
                    yield OdometryFrame(stamps[k], world_from_body=pose)
                if lines is not None and self._laser[k]:
                    fields = _fields_at(lines, int(self._lines[k]), self.path)
                    self.stats.read += 1
                    yield self._scan(k, stamps[k], fields)
        finally:
            if lines is not None:
                lines.close()

    def _scan(self, k: int, stamp_ns: int, fields: list[str]) -> ScanFrame:
        line = int(self._lines[k])
        if not fields or fields[0] != self._keywords[k]:
            raise InputError(
                f"{self.path}:{line}: the file changed since it was opened "
                f"(expected a {self._keywords[k]} line)",
                hint="open the log again",
            )
        first, n = int(self._first_range[k]), int(self._beams_n[k])
        ranges = np.asarray(fields[first : first + n], dtype=np.float64).astype(np.float32)
        return ScanFrame(
            stamp_ns,
            ranges,
            float(self._angle_min[k]),
            float(self._increment[k]),
            RANGE_MIN_M,
            float(self._range_max[k]),
            self._sensor[k].copy(),
            f"{self.path.name}:{line} {self._keywords[k]}",
        )

    # -- info --------------------------------------------------------------------------------

    def info(self, deep: bool = False, progress: ProgressFn | None = None) -> SourceInfo:
        """Streams (one per laser message kind, and odometry), counts and problems; cheap: the
        log was read at open."""
        stamps = self.clock.stamps_ns
        streams: list[StreamInfo] = []
        keywords = np.array(self._keywords, dtype=str)
        for keyword in sorted(set(keywords[self._laser].tolist())):
            sel = self._laser & (keywords == keyword)
            streams.append(
                StreamInfo.from_stamps(keyword, "scan", stamps[sel], self._scan_detail(sel))
            )
        kept = self._odometry_kept
        odometry = 0
        if self.odometry == "log":
            odometry = int(kept.sum())
            poses = int((kept & self._laser).sum())
            detail = f"{odometry - poses} ODOM lines, {poses} scans' poses"
            streams.append(StreamInfo.from_stamps("odometry", "odometry", stamps[kept], detail))
        gt = self.groundtruth()
        scans = int(self._laser.sum())
        if progress is not None:
            progress(1, 1)
        return SourceInfo(
            format=self.format_name,
            path=str(self.path),
            streams=streams,
            frames=scans + odometry,
            groundtruth=len(gt) if gt is not None else 0,
            problems=self._problems(scans),
            details=self._details(kept),
        )

    def _scan_detail(self, sel: NDArray[np.bool_]) -> str:
        beams = sorted(set(self._beams_n[sel].tolist()))
        k = int(np.argmax(sel))
        n = int(self._beams_n[k])
        fov = math.degrees(float(self._increment[k]) * (n - 1))
        start = math.degrees(float(self._angle_min[k]))
        return f"{'/'.join(map(str, beams))} beams, {fov:g} deg from {start:g} deg"

    def _problems(self, scans: int) -> list[str]:
        problems: list[str] = []
        if self.clock.replaced.any():
            first = int(self._lines[int(np.argmax(self.clock.replaced))])
            problems.append(f"{self.path.name}:{first}: {self._stamp_problem()}")
        problems.extend(self._losses())
        if scans == 0:
            problems.append("no laser scans (FLASER, RLASER, ROBOTLASERk or RAWLASERk lines)")
        if self.groundtruth_choice == "log" and not (self._laser & self._has_pose).any():
            problems.append("groundtruth=log, but no scan carries a robot pose")
        return problems

    def _details(self, kept: NDArray[np.bool_]) -> dict[str, Any]:
        sel = self._laser & self._has_pose
        xy = self._robot[sel, :2]
        clock = self.clock
        first_bad = (
            f"{self.path.name}:{int(self._lines[int(np.argmax(clock.replaced))])}"
            if clock.replaced.any()
            else None
        )
        start = self.start_pose()
        return {
            "messages": dict(Counter(self._keywords)),
            "skipped_messages": dict(self.other_messages),
            "comments": self.comments,
            "damaged_lines": len(self.malformed),
            "beams_per_scan": sorted(set(self._beams_n[self._laser].tolist())),
            "max_range_m": self.max_range if self.max_range is not None else "per message",
            "stamps_replaced": int(clock.replaced.sum()),
            "first_replaced_stamp": first_bad,
            "clock": "as logged"
            if not clock.replaced.any()
            else ("repaired" if clock.trusted else "ignored (fixed step)"),
            "stamp_step_s": clock.step_ns * 1e-9,
            "odometry": self.odometry,
            "odometry_superseded": int((self._has_pose & ~self._laser & ~kept).sum()),
            "groundtruth": self.groundtruth_choice,
            "scan_pose_path_length_m": float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()),
            "start_pose": start.tolist() if start is not None else None,
        }


# -- helpers ---------------------------------------------------------------------------------------


def _check_choice(name: str, value: Any, choices: tuple[str | None, ...]) -> Any:
    if value not in choices or (value is not None and not isinstance(value, str)):
        allowed = ", ".join("none given" if c is None else c for c in choices)
        raise ConfigError(f"{name} must be one of: {allowed}; got {value!r}")
    return value


def _check_max_range(value: Any) -> float | None:
    if value is None:
        return None
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not (math.isfinite(value) and value > 0)
    ):
        raise ConfigError(f"max_range must be a positive number of metres, got {value!r}")
    return float(value)


def _open_binary(path: Path) -> IO[bytes]:
    """The file, decompressed when it starts with the gzip magic."""
    try:
        with path.open("rb") as fh:
            gzipped = fh.read(2) == sniff.GZIP_MAGIC
        return cast(IO[bytes], gzip.open(path, "rb")) if gzipped else path.open("rb")
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, expected a CARMEN log file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None


def _raw_lines(path: Path) -> _LINES:
    """Each line's number and bytes; None for a line over :data:`MAX_LINE_BYTES`, read through
    without being held."""
    with _open_binary(path) as fh:
        yield from bounded_lines(fh, MAX_LINE_BYTES)


def _fields_at(lines: _LINES, wanted: int, path: Path) -> list[str]:
    try:
        for number, raw in lines:
            if number == wanted and raw is not None:
                return raw.decode("utf-8", errors="replace").split()
    except (EOFError, zlib.error, gzip.BadGzipFile):
        pass
    raise InputError(
        f"{path}:{wanted}: the file changed since it was opened (the line is gone)",
        hint="open the log again",
    )
