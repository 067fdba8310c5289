"""What the ROS bag readers share: their health report and one channel per topic."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from pathlib import Path

from slamcli.formats.mcap.decode import normalize_ros_type
from slamcli.formats.mcap.records import ChannelInfo, LogHealth

logger = logging.getLogger(__name__)


@dataclass
class BagHealth(LogHealth):
    """What reading a bag found wrong with it: :class:`LogHealth`'s fields, in a bag's terms.

    ``summary_present`` says whether the bag's index was used; ``index_problem`` says why it
    was not (the records were then walked from the start), ``notes`` what the walk found odd
    without losing data, and ``stopped`` why a read ended before the end of the bag.
    """

    index_problem: str = ""
    notes: list[str] = field(default_factory=list)
    stopped: str = ""

    @property
    def data_lost(self) -> bool:
        return super().data_lost or bool(self.stopped)

    def loss_problems(self) -> list[str]:
        """The problems that lost data (truncation, bad chunks, late messages, a stop)."""
        out = LogHealth.loss_problems(replace(self, truncated=False))
        if self.truncated:
            at = self.truncated_at_byte
            where = f" at byte {at}" if at is not None else ""
            read = (
                "no message could be read"
                if self.last_good_time_ns is None
                else f"messages up to {self.last_good_time_ns * 1e-9:.3f} s were read"
            )
            out.insert(
                0,
                f"truncated: the bag ends inside a record{where}; {read} "
                "(try 'rosbag reindex' on a copy)",
            )
        if self.stopped:
            out.append(self.stopped)
        return out

    def problems(self) -> list[str]:
        """One-line descriptions for ``info`` and run reports."""
        out = self.loss_problems()
        if self.index_problem:
            out.append(f"{self.index_problem}; its records were walked from the start")
        out.extend(self.notes)
        return out


class TopicChannels:
    """One channel per topic, for bags whose topics have several connections (publishers).

    The first connection of a topic gives the channel (its id, type and definition); later
    connections of the same type share it, and one of another type is left out with a warning.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.by_id: dict[int, ChannelInfo] = {}
        self.by_conn: dict[int, ChannelInfo | None] = {}
        self._by_topic: dict[str, ChannelInfo] = {}

    def add(self, conn: int, info: ChannelInfo) -> ChannelInfo | None:
        """The channel of connection ``conn`` (described by ``info``); None if left out."""
        if conn in self.by_conn:
            return self.by_conn[conn]
        known = self._by_topic.get(info.topic)
        chosen: ChannelInfo | None = known
        if known is None:
            chosen = self._by_topic[info.topic] = self.by_id[info.id] = info
        elif normalize_ros_type(known.schema_name) != normalize_ros_type(info.schema_name):
            logger.warning(
                "%s: topic %s has connections of types %s and %s; the messages of type %s "
                "are ignored",
                self.path,
                info.topic,
                known.schema_name,
                info.schema_name,
                info.schema_name,
            )
            chosen = None
        self.by_conn[conn] = chosen
        return chosen


__all__ = ["BagHealth", "TopicChannels"]
