"""Victoria Park in GTSAM's text format: a chain of planar odometry and landmark sightings.

``ODOMETRY i j dx dy dtheta c11 c12 c13 c22 c23 c33`` (motion from pose key i to pose key j in
pose i's frame, and the upper triangle of its covariance) and ``LANDMARK i l x y c11 c12 c22``
(landmark l seen from pose key i at x forward, y left). GTSAM numbers poses and landmarks from
one counter, so pose keys skip the numbers given to landmarks (``ODOMETRY 4 6`` after landmark 5
first appears): each ODOMETRY line must start at the key the previous one ended at and end at a
larger key, and a LANDMARK line must be seen from the current pose. The file has no times: the
``k``-th pose of the chain (not its key) gets the stamp ``k`` seconds
(:data:`VICTORIA_STEP_NS`); pose 0 (key 0) is the origin and is yielded first. No ground truth.

Reading is strict: a line with the wrong number of fields, a non-number, or poses out of order
is a :class:`FormatError` naming ``file:line``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slamcli.errors import FormatError, InputError
from slamcli.formats import sniff
from slamcli.formats.base import ReadStats, SourceInfo
from slamcli.formats.landmarks.source import (
    LandmarkSource,
    Observations,
    Odometry,
    check_ignore_ids,
)
from slamcli.formats.landmarks.tables import F64, MAX_TABLE_VALUE
from slamcli.formats.text import iter_data_lines, parse_count, parse_floats
from slamcli.geometry import planar_to_se3, wrap_angle
from slamcli.types import ProgressFn

VICTORIA_STEP_NS = 1_000_000_000
"""Victoria Park files have no times: the k-th pose gets the stamp ``k * VICTORIA_STEP_NS``."""


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
        self.ignore_ids = check_ignore_ids(ignore_ids)
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
