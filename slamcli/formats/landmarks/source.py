"""What every landmark source holds: odometry, observations, and the frames made of them.

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
"""

from __future__ import annotations

from collections.abc import Collection, Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, InputError
from slamcli.formats.base import Frame, ReadStats, SourceBase, SourceInfo, StreamInfo
from slamcli.formats.landmarks.tables import F64, I64, seconds_text
from slamcli.geometry import interpolate_planar, se3_to_planar
from slamcli.types import LandmarkFrame, LandmarkMap, OdometryFrame, ProgressFn, Trajectory

FRAME_KINDS = ("odometry", "landmarks")
"""The frame kinds a landmark source provides."""

START_POSE_MAX_WAIT_S = 30.0
"""``start_pose`` falls back to the first ground-truth pose if it is at most this late."""

ODOMETRY_GAP_PROBLEM_S = 1.0
"""``info`` reports odometry gaps longer than this as a problem."""

_NS_PER_S = 1_000_000_000


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
                    f"(largest {gaps[k] * 1e-9:.3f} s after {seconds_text(int(odo.stamps_ns[k]))})"
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


def check_ignore_ids(ignore_ids: Any) -> bool:
    """The ``ignore_ids`` option, checked to be a bool."""
    if not isinstance(ignore_ids, bool):
        raise ConfigError(f"ignore_ids must be true or false, got {ignore_ids!r}")
    return ignore_ids


def require_files(folder: Path, names: tuple[str, ...], what: str, hint: str) -> None:
    """Raise InputError naming what is missing when ``folder`` is not a folder holding ``names``."""
    if not folder.is_dir():
        raise InputError(f"{folder}: {what} is a folder", hint=hint)
    missing = [n for n in names if not (folder / n).is_file()]
    if missing:
        raise InputError(f"{folder}: {what} has no {' and no '.join(missing)}", hint=hint)
