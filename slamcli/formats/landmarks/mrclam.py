"""UTIAS MRCLAM folders (Multi-Robot Cooperative Localization and Mapping, one
``MRCLAM_DatasetN`` folder).

``Barcodes.dat`` (subject, barcode), ``Landmark_Groundtruth.dat`` (subject, x, y, x std-dev,
y std-dev), and per robot ``RobotN_Odometry.dat`` (t, v, omega), ``RobotN_Measurement.dat`` (t,
barcode, range, bearing; the header calls the barcode column "Subject #") and
``RobotN_Groundtruth.dat`` (t, x, y, theta). Times are seconds, fields are whitespace
separated, ``#`` lines are comments. Barcodes are mapped to subjects; the robots are subjects
1-5 (the real datasets' five) and every K with a ``RobotK_Odometry.dat`` (a synthetic folder may
have up to 16), less any subject of ``Landmark_Groundtruth.dat``. Sightings of robots are
dropped from the landmark frames (counted in ``info().details["robot_sightings"]``). Landmarks
are the subjects of ``Landmark_Groundtruth.dat`` (without it, every subject of ``Barcodes.dat``
that is no robot's). Measurements of barcodes in no table (the real data has a few: 34, 43, 50,
52) or of subjects that are neither are ignored (not data loss: the log is intact), listed in
``MrclamSource.ignored`` with their file:line and summarised in one warning; with ``strict``
they are a :class:`FormatError`.
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

from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats import sniff
from slamcli.formats.base import Frame, ReadStats, SourceInfo
from slamcli.formats.landmarks.source import (
    FRAME_KINDS,
    LandmarkSource,
    Observations,
    Odometry,
    check_ignore_ids,
    require_files,
)
from slamcli.formats.landmarks.tables import Table, read_table
from slamcli.geometry import planar_to_se3
from slamcli.types import LandmarkFrame, LandmarkMap, OdometryFrame, ProgressFn, Trajectory

log = logging.getLogger(__name__)

MRCLAM_ROBOT_SUBJECTS = frozenset(range(1, 6))
"""MRCLAM subject numbers of the real datasets' five robots; a folder's robots are these and
those with a ``RobotK_Odometry.dat`` (:attr:`MrclamSource.robot_subjects`)."""


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
        self.ignore_ids = check_ignore_ids(ignore_ids)
        self.strict = bool(strict)
        self.stats = ReadStats()
        self.ignored: list[str] = []
        require_files(self.path, ("Barcodes.dat",), "an MRCLAM input", _MRCLAM_HINT)
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
        require_files(self.path, (prefix + "Measurement.dat",), "an MRCLAM input", _MRCLAM_HINT)
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
