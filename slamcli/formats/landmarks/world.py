"""Folders written by ``slamcli synth landmarks`` (layout in :mod:`slamcli.synth.landmarks`).

``odometry.csv`` (t,v,omega), ``measurements.csv`` (t,id,range,bearing), ``groundtruth.tum``
and ``landmarks.csv`` (id,x,y); and the same run in memory (:class:`LandmarkLog`), for writing
it into another container.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from slamcli.formats import sniff
from slamcli.formats.base import ReadStats, SourceInfo
from slamcli.formats.landmarks.source import (
    LandmarkSource,
    Observations,
    Odometry,
    check_ignore_ids,
    require_files,
)
from slamcli.formats.landmarks.tables import F64, I64, read_table
from slamcli.formats.trajectory import read_trajectory
from slamcli.types import LandmarkMap, ProgressFn, Trajectory

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
        self.ignore_ids = check_ignore_ids(ignore_ids)
        self.stats = ReadStats()
        require_files(
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
