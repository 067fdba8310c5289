"""A source's RGB-D frames, camera, ground truth, IMU readings, laser scans and odometry written
as an MCAP log: a log a robot could have recorded (topics and encodings in
:mod:`~slamcli.formats.mcap.write.messages` and, for scans and odometry,
:mod:`~slamcli.formats.mcap.write.scans`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from slamcli.errors import ConfigError
from slamcli.formats.mcap.write.layer import FLAVORS, McapWriteSummary, check_choice, open_log
from slamcli.formats.mcap.write.messages import FoxgloveWriter, Ros2Writer
from slamcli.formats.mcap.write.scans import ScanWriter
from slamcli.types import ImuFrame, OdometryFrame, ProgressFn, RgbdFrame, ScanFrame, Trajectory

if TYPE_CHECKING:
    from slamcli.formats.base import Source, SourceInfo

log = logging.getLogger(__name__)

IMAGE_COMPRESSIONS = ("none", "jpeg", "png")
DEPTH_ENCODINGS = ("16UC1", "32FC1")

_REORDER_WINDOW_NS = 500_000_000
"""A source's frames arrive in colour-stamp order; a paired depth image (and the readings
between the two stamps) may be stamped up to this long before its colour image."""


class _PoseFeed:
    """Hands out ground-truth poses in time order, interleaved with the frames."""

    def __init__(self, trajectory: Trajectory | None, write: Callable[[int, Any], None]) -> None:
        if trajectory is None:
            self._stamps = np.zeros(0, dtype=np.int64)
            self._poses = np.zeros((0, 4, 4))
        else:
            self._stamps, self._poses = trajectory.stamps_ns, trajectory.world_from_body
        self._write = write
        self._next = 0
        self.written = 0

    def until(self, stamp_ns: int | None) -> None:
        """Write every pose stamped at or before ``stamp_ns`` (None: all that remain)."""
        end = (
            len(self._stamps)
            if stamp_ns is None
            else int(np.searchsorted(self._stamps, stamp_ns, side="right"))
        )
        for i in range(self._next, end):
            self._write(int(self._stamps[i]), self._poses[i])
        self.written += max(0, end - self._next)
        self._next = max(self._next, end)


def write_source_mcap(
    source: Source,
    out: str | Path,
    *,
    flavor: str = "ros2",
    compress_images: str = "none",
    depth_encoding: str = "16UC1",
    jpeg_quality: int = 90,
    max_frames: int | None = None,
    force: bool = False,
    progress: ProgressFn | None = None,
) -> McapWriteSummary:
    """Write a source's RGB-D frames, camera, ground truth, IMU readings, scans and odometry
    as an MCAP log.

    Topics, message types and the depth encodings are listed in the module docstring. Every
    message is stamped with the data's own time (ns): the header stamp, ``log_time`` and
    ``publish_time`` are equal; depth carries the depth image's stamp, the camera info the
    colour image's. Ground-truth poses (the colour camera in ``world``, or the body for a scan
    source) are interleaved with the frames in time order. What is read is decided by
    :func:`convert_kinds`.

    Args:
        source: an open source (e.g. :class:`~slamcli.formats.tum_rgbd.TumRgbdSource`).
        out: the ``.mcap`` file; written to a temporary name and renamed into place when
            complete, so a failure leaves no partial file and an existing one untouched.
        flavor: ``"ros2"`` (CDR, ``ros2msg`` schemas) or ``"foxglove"`` (JSON, Foxglove
            JSON schemas).
        compress_images: ``"none"``, ``"jpeg"`` or ``"png"`` for colour; with ``16UC1`` in the
            ros2 flavour, depth is then written as ``compressedDepth`` PNG (lossless).
        depth_encoding: ``"16UC1"`` (millimetres) or ``"32FC1"`` (metres, exact).
        jpeg_quality: 1-100, for ``compress_images="jpeg"``.
        max_frames: stop after this many RGB-D frames and scans; the log then ends at the last
            one's stamp (ground truth, IMU and odometry after it are left out).
        force: replace an existing ``out``.
        progress: called as ``progress(frames_done, frames_total)`` (RGB-D frames and scans;
            the total is the source's RGB-D frame count, None when it has none).

    Raises:
        ConfigError: a bad option value.
        ExportError: ``out`` exists without ``force``, or cannot be written.
        InputError: the source cannot be read.
    """
    check_choice("flavor", flavor, FLAVORS)
    check_choice("compress_images", compress_images, IMAGE_COMPRESSIONS)
    check_choice("depth_encoding", depth_encoding, DEPTH_ENCODINGS)
    if not 1 <= jpeg_quality <= 100:
        raise ConfigError(f"jpeg_quality must be 1-100, got {jpeg_quality}")
    if max_frames is not None and max_frames < 1:
        raise ConfigError(f"max_frames must be at least 1, got {max_frames}")
    out = Path(out)
    info = source.info()
    kinds = convert_kinds(info)
    total = info.frames if max_frames is None else min(info.frames, max_frames)
    summary = McapWriteSummary(out)
    imu_dropped = 0
    with open_log(out, "ros2" if flavor == "ros2" else "", force) as mcap_log:
        cls = Ros2Writer if flavor == "ros2" else FoxgloveWriter
        writer = cls(mcap_log, compress_images, depth_encoding, jpeg_quality)
        poses = _PoseFeed(source.groundtruth(), writer.pose)
        scans = ScanWriter(mcap_log, flavor) if "scan" in kinds else None
        last_stamp: int | None = None
        stopped_at: int | None = None
        for frame in source.frames(kinds):
            if max_frames is not None and summary.frames >= max_frames:
                stopped_at = last_stamp
                break
            mcap_log.release(frame.stamp_ns - _REORDER_WINDOW_NS)
            if isinstance(frame, RgbdFrame | ScanFrame):
                poses.until(frame.stamp_ns)
                if isinstance(frame, RgbdFrame):
                    writer.rgbd(frame)
                elif scans is not None:
                    scans.scan(frame)
                summary.frames += 1
                last_stamp = frame.stamp_ns
                if progress is not None:
                    progress(summary.frames, total or None)
            elif isinstance(frame, OdometryFrame) and scans is not None:
                poses.until(frame.stamp_ns)
                scans.odometry(frame)
            elif isinstance(frame, ImuFrame):
                poses.until(frame.stamp_ns)
                if not writer.imu(frame):
                    imu_dropped += 1
        poses.until(stopped_at)
        summary.topics = mcap_log.topics()
    summary.skipped = source.stats.skipped
    if imu_dropped:
        log.info("%d IMU readings left out: Foxglove has no IMU schema", imu_dropped)
    log.info("wrote %s: %d frames, %d ground-truth poses", out, summary.frames, poses.written)
    return summary


def convert_kinds(info: SourceInfo) -> list[str]:
    """The frame kinds a conversion reads from a source, by its streams' kinds: ``rgbd``
    (unless it has scans and no images), ``imu``, ``scan`` and, with scans, ``odometry`` when
    it has an odometry stream (or, for an MCAP log, odometry from tf)."""
    have = {s.kind for s in info.streams}
    kinds = ["rgbd"] if "image" in have or "scan" not in have else []
    if "imu" in have:
        kinds.append("imu")
    if "scan" in have:
        kinds.append("scan")
        if "odometry" in have or info.details.get("scan_odometry"):
            kinds.append("odometry")
    return kinds
