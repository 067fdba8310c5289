"""CARMEN laser logs (``.log``, ``.clf``, plain or gzipped): 2-D scans and the robot's poses.

A CARMEN log holds one message per line, ``KEYWORD fields... ipc_time host logger_time``, times
in seconds. The messages read are:

- ``FLASER`` / ``RLASER`` (front / rear laser): ``n r1..rn x y theta odom_x odom_y odom_theta``;
  ``x y theta`` is the laser's pose and ``odom_*`` the robot's, in the log's world frame;
- ``ROBOTLASER<k>``: ``laser_type start_angle fov angular_res max_range accuracy remission_mode
  n r1..rn m rem1..remm laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv
  forward_safety side_safety turn_axis``;
- ``RAWLASER<k>``: as ROBOTLASER up to the remissions, then the times: no pose;
- ``ODOM x y theta tv rv accel``.

Other messages (``PARAM``, ``SYNC``, ``TRUEPOS``, ``NMEA...``, a corrected log's ``NEFF``, ...)
and ``#`` comments are skipped and counted in ``info()``.

**Frames.** Each laser line gives a :class:`~slamcli.types.ScanFrame`; a line that carries the
robot's pose also gives an :class:`~slamcli.types.OdometryFrame` at the same stamp, yielded
just before the scan (one pose per scan, always). ``ODOM`` lines give odometry frames. A scan's
``body_from_sensor`` is the laser's pose in the robot's frame (the planar ``between`` of the two
poses on its line; zero for RAWLASER). Frames come in file order, which after the stamp repair
below is time order; an ``ODOM`` line whose stamp equals that of a scan's pose is dropped (the
scan's pose is the odometry at that instant) and counted in ``info()``.

**Beam angles.** FLASER and RLASER lines carry no angles. CARMEN's own reader (``readlog.c``,
``carmen_laser_guess_fov`` / ``carmen_laser_guess_angle_increment``) starts every such scan at
-90 degrees with 1 degree between beams for 180 and 181 beams and 0.5 degree for 360 and 361:
the increment is pi/(n-1) for 181 and 361 beams (both ends at +-90 degrees) but pi/n for 180
and 360, a SICK sweep without its last beam (-90 to +89 or +89.5 degrees). Other counts span
180 degrees with both ends included, pi/(n-1), as CARMEN guesses. GMapping's reader instead
spreads 180 beams symmetrically with no beam at 0; this reader follows CARMEN, whose drivers
wrote the logs. ROBOTLASER and RAWLASER lines give their start angle and resolution. A rear
laser points backwards: when an RLASER line's laser heading is within 90 degrees of the robot's
(the log gives the robot's heading), pi is added to the mounting yaw; a heading already turned
round is taken as written.

**Ranges.** A scanner writes its maximum range where nothing echoes: the shared SICK logs write
81.83 or 81.91 m (the 8191 cm code) and the corrected ACES log 50 m. Following CARMEN, a range
at or beyond the maximum range is no return, so ``range_max_m`` is the largest float32 below it
(:class:`~slamcli.types.ScanFrame` counts ``range_max_m`` itself as a reading). FLASER and
RLASER carry no maximum: :data:`DEFAULT_MAX_RANGE_M` (50 m, the ``robot_front_laser_max`` the
CSAIL log records) treats all three codes as no return and keeps every real reading of the
shared logs (at most 49.91 m); ROBOTLASER and RAWLASER lines give theirs. The ``max_range``
option replaces both. Ranges below :data:`RANGE_MIN_M` (a SICK writes 0 for a dazzled or
failed beam) are not readings.

**Stamps** are the ``ipc_time``, else the ``logger_time`` where that fits. Many logs have broken
times: the shared corrected logs write 0 for the ODOM line after each scan, print times with six
significant digits (repeats, a clock that steps back a few milliseconds, ten-second steps in
the CSAIL log) and hold a few garbage values. Scan times are judged first, among themselves: a
time is usable when it is positive, after the last usable one, and not a lone jump ahead (the
next time falls back between the last usable one and it). An ODOM time is usable when it is
positive, after the last usable ODOM time, not before the last usable time of either kind, not
after the next usable scan time, and not a lone jump ahead: so a scan keeps its own time when
the ODOM lines before it run late. The others are replaced: evenly spaced between the usable
times around them, or, where no later usable time follows (a clock that wrapped at 2**32 s), at
the log's typical spacing (the median time per message between usable times;
:data:`DEFAULT_STEP_S` without enough of them). When fewer than half the scan times are usable
the log's clock is ignored: every message is stamped at that spacing from the first usable
time. One warning names the first replaced line, and ``info()`` reports the count. Scan
stamps, and odometry stamps, are strictly increasing, and never decrease in file order.

**Options** (keyword arguments of :meth:`CarmenSource.open`): ``odometry="log"`` (the default)
feeds the log's poses as odometry, ``"none"`` gives no odometry frames; ``groundtruth="log"``
makes :meth:`CarmenSource.groundtruth` the robot's pose at each scan (the reference path of a
corrected log; a SLAM run judged against it should use ``odometry="none"``), None (the default)
gives none; ``max_range`` (metres) is above; ``strict`` is below.

**Damage.** A line with the wrong number of fields, a non-number, a beam count that does not
match its fields, undecodable bytes, or more than
:data:`~slamcli.formats.text.MAX_LINE_BYTES` (1 MiB: the line is read through in pieces, never
held whole) is skipped and counted (``info()``, ``stats.skipped`` and
``stats.data_loss``, so a run ends with exit code 3), as is the end of a cut-off gzip stream:
the MCAP and TUM sources read around damage the same way. With ``strict=True`` it is a
:class:`~slamcli.errors.FormatError` naming ``file:line`` and what was expected, at open.

**Writing** (:func:`write_carmen`): a scan with a pose becomes an FLASER line when CARMEN's
angles above reproduce its beams (180, 181, 360 or 361 beams from -90 degrees) and its maximum
range is the FLASER default, else a ROBOTLASER1 line, which carries start angle, field of view,
resolution and maximum range; a scan without a pose becomes a RAWLASER1 line (no pose, so no
mounting: the reader gives it zero). Beams that are no return are written as the maximum range,
other beams that are not readings as 0. Ranges are written as the shortest text giving their
float32 back, poses exactly, times to the microsecond, the logger time relative to the first
scan as CARMEN's logger does. A ``.gz`` suffix writes gzip.

Modules: :mod:`~slamcli.formats.carmen.source` reads, :mod:`~slamcli.formats.carmen.write`
writes, :mod:`~slamcli.formats.carmen.stamps` repairs times, and
:mod:`~slamcli.formats.carmen.layout` holds what reading and writing share.
"""

from __future__ import annotations

from slamcli.formats.carmen.layout import DEFAULT_MAX_RANGE_M, RANGE_MIN_M
from slamcli.formats.carmen.source import (
    FRAME_KINDS,
    GROUNDTRUTH_CHOICES,
    ODOMETRY_CHOICES,
    CarmenSource,
)
from slamcli.formats.carmen.stamps import DEFAULT_STEP_S
from slamcli.formats.carmen.write import write_carmen

__all__ = [
    "DEFAULT_MAX_RANGE_M",
    "DEFAULT_STEP_S",
    "FRAME_KINDS",
    "GROUNDTRUTH_CHOICES",
    "ODOMETRY_CHOICES",
    "RANGE_MIN_M",
    "CarmenSource",
    "write_carmen",
]
