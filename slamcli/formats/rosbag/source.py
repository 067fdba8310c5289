"""ROS 1 bags and ROS 2 bag folders as sources: the MCAP source over the bag readers.

:class:`Ros1BagSource` and :class:`Ros2BagSource` are
:class:`~slamcli.formats.mcap.source.McapSource` reading through another
:class:`~slamcli.formats.mcap.reader.MessageLog`, so topic choice per role and every topic
option, colour/depth pairing, the camera, odometry and landmark order, IMU, ground truth from
a pose topic or tf, ``info()`` and ``slamcli convert`` behave exactly as for MCAP logs; the
decoders and adapters are the MCAP source's, keyed by the bag's type names and definitions.
``info()`` adds a ``bag`` entry to its details: how the bag was read and what was odd about it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from slamcli.formats import sniff
from slamcli.formats.base import SourceInfo
from slamcli.formats.mcap.reader import McapLog, MessageLog
from slamcli.formats.mcap.source import McapSource
from slamcli.formats.rosbag.ros1_log import Ros1BagLog
from slamcli.formats.rosbag.ros2_log import Ros2BagLayout, open_ros2_log, read_layout
from slamcli.types import ProgressFn


class Ros1BagSource(McapSource):
    """A ROS 1 bag (``.bag``, format 2.0) as a :class:`~slamcli.formats.base.Source`.

    Takes the options of :class:`~slamcli.formats.mcap.source.McapSource`; ``max_chunk_mb``
    bounds the bag's chunks and messages. A bag whose index cannot be read, or that has none
    (a recording cut short), is read by walking its records (see
    :class:`~slamcli.formats.rosbag.ros1_log.Ros1BagLog`).
    """

    format_name = "rosbag1"
    bag: Ros1BagLog

    @classmethod
    def sniff(cls, path: str | Path) -> bool:
        """A ``.bag`` file, or any file starting with ``#ROSBAG V``."""
        return sniff.rosbag1(path)

    def _open_log(self, max_chunk_bytes: int) -> MessageLog:
        self.bag = Ros1BagLog(self.path, strict=self.strict, max_chunk_bytes=max_chunk_bytes)
        return self.bag

    def info(self, deep: bool = False, progress: ProgressFn | None = None) -> SourceInfo:
        info = super().info(deep, progress)
        health = self.bag.health
        info.details["bag"] = {
            "format": "ROS 1 bag 2.0",
            "index_used": not self.bag.walked,
            "records_walked": self.bag.walked,
            "index_problem": health.index_problem,
            "notes": list(health.notes),
        }
        return info


class Ros2BagSource(McapSource):
    """A ROS 2 bag folder (``metadata.yaml`` with sqlite3 or MCAP storage), or a lone
    ``.db3`` file, as a :class:`~slamcli.formats.base.Source`.

    Takes the options of :class:`~slamcli.formats.mcap.source.McapSource`. A bag of one
    uncompressed MCAP file is read as that MCAP log; others through ``rosbags`` (see
    :mod:`slamcli.formats.rosbag.ros2_log`).
    """

    format_name = "rosbag2"
    layout: Ros2BagLayout

    @classmethod
    def sniff(cls, path: str | Path) -> bool:
        """A folder whose ``metadata.yaml`` is rosbag2's, or a ``.db3`` file."""
        return sniff.rosbag2(path)

    def _open_log(self, max_chunk_bytes: int) -> MessageLog:
        self.layout = read_layout(self.path)
        return open_ros2_log(self.layout, self.strict, max_chunk_bytes)

    def info(self, deep: bool = False, progress: ProgressFn | None = None) -> SourceInfo:
        info = super().info(deep, progress)
        layout = self.layout
        bag: dict[str, Any] = {
            "format": "ROS 2 bag"
            + (f" (metadata version {layout.version})" if layout.version else ""),
            "storage": layout.storage,
            "files": [f.name for f in layout.files],
            "compression": layout.compression or "none",
            "ros_distro": layout.ros_distro,
            "read_as": "mcap" if isinstance(self.log, McapLog) else "rosbags",
        }
        info.details["bag"] = bag
        return info


__all__ = ["Ros1BagSource", "Ros2BagSource"]
