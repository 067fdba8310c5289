"""Planar landmark logs for EKF-SLAM: UTIAS MRCLAM folders, Victoria Park files, synth folders.

One module per format, on what they share:

- :mod:`~slamcli.formats.landmarks.source`: the frames every landmark source yields (odometry
  and landmark observations merged in time order), its start pose and the common ``info``;
- :mod:`~slamcli.formats.landmarks.tables`: the text tables the logs are made of;
- :mod:`~slamcli.formats.landmarks.mrclam`: UTIAS MRCLAM folders (one robot or several);
- :mod:`~slamcli.formats.landmarks.victoria`: Victoria Park in GTSAM's text format;
- :mod:`~slamcli.formats.landmarks.world`: ``slamcli synth landmarks`` folders.

Reading is strict: a line with the wrong number of fields, a non-number, or time going
backwards is a :class:`~slamcli.errors.FormatError` naming ``file:line``. Repeated odometry
stamps are kept (a control that lasted no time).
"""

from __future__ import annotations

from slamcli.formats.landmarks.mrclam import MRCLAM_ROBOT_SUBJECTS, MrclamSource, RobotFrame
from slamcli.formats.landmarks.source import (
    FRAME_KINDS,
    ODOMETRY_GAP_PROBLEM_S,
    START_POSE_MAX_WAIT_S,
    LandmarkSource,
    Observations,
    Odometry,
)
from slamcli.formats.landmarks.tables import MAX_TABLE_VALUE, Table, read_table
from slamcli.formats.landmarks.victoria import VICTORIA_STEP_NS, VictoriaParkSource
from slamcli.formats.landmarks.world import LandmarkLog, LandmarkWorldSource, read_landmark_log

__all__ = [
    "FRAME_KINDS",
    "MAX_TABLE_VALUE",
    "MRCLAM_ROBOT_SUBJECTS",
    "ODOMETRY_GAP_PROBLEM_S",
    "START_POSE_MAX_WAIT_S",
    "VICTORIA_STEP_NS",
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
