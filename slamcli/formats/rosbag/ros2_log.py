"""A ROS 2 bag read as a stream of undecoded messages, for the MCAP source's topic logic.

rosbag2 stores CDR-encoded messages in sqlite3 (``.db3``) or MCAP files that the folder's
``metadata.yaml`` names. :func:`open_ros2_log` reads a bag of one uncompressed MCAP file as
the MCAP log it is, with :class:`~slamcli.formats.mcap.reader.McapLog` (and so with its salvage
of truncated files and bad chunks). Any other bag (sqlite3 storage, several files, zstd file or
message compression) is read with ``rosbags``' rosbag2 reader through :class:`Ros2BagLog`:
each topic is one channel with message encoding ``cdr`` and the ``ros2msg`` or ``ros2idl``
definition the bag stores (rosbag2 stores them from Iron on); a bag without definitions is
decoded with the ROS 2 Humble types, as schema-less MCAP channels are.
"""

from __future__ import annotations

import logging
import sqlite3
from collections import Counter
from collections.abc import Collection, Iterator
from dataclasses import dataclass, replace
from pathlib import Path, PurePath
from typing import Any

from slamcli.errors import FormatError, InputError
from slamcli.formats.base import Closing
from slamcli.formats.mcap.reader import (
    DEFAULT_MAX_CHUNK_BYTES,
    McapLog,
    MessageLog,
    count_stats,
    message_window,
)
from slamcli.formats.mcap.records import ChannelInfo, ChannelStats, RawMessage
from slamcli.formats.rosbag.health import BagHealth, TopicChannels
from slamcli.formats.sniff import ROSBAG2_METADATA
from slamcli.formats.text import (
    MAX_YAML_BYTES,
    check_yaml_expansion,
    format_stamp,
    read_limited_text,
)

logger = logging.getLogger(__name__)

_SCHEMA_ENCODINGS = {"MSG": "ros2msg", "IDL": "ros2idl"}
"""``rosbags`` message definition formats -> MCAP schema encodings (none: empty)."""


@dataclass(frozen=True)
class Ros2BagLayout:
    """Where a ROS 2 bag keeps its messages, from its ``metadata.yaml``.

    Attributes:
        path: the bag folder (or the ``.db3`` file given alone).
        storage: ``"sqlite3"`` or ``"mcap"``.
        files: the storage files, in recording order.
        compression: ``""``, or mode and format (``"file zstd"``, ``"message zstd"``).
        ros_distro: as recorded (empty when the metadata does not say).
        version: the metadata version (0 for a ``.db3`` file alone).
    """

    path: Path
    storage: str
    files: tuple[Path, ...]
    compression: str = ""
    ros_distro: str = ""
    version: int = 0


def read_layout(path: str | Path) -> Ros2BagLayout:
    """The layout of a ROS 2 bag folder (or of a lone ``.db3`` file).

    Raises:
        InputError: no such folder, or a storage file it names is missing.
        FormatError: ``metadata.yaml`` is not rosbag2 metadata.
    """
    p = Path(path)
    if p.is_file() and p.suffix.lower() == ".db3":
        return Ros2BagLayout(p, "sqlite3", (p,))
    meta_path = p / ROSBAG2_METADATA
    if not meta_path.is_file():
        raise InputError(
            f"{p}: no {ROSBAG2_METADATA}; expected a ROS 2 bag folder",
            hint="a bag whose recording did not finish has none: 'ros2 bag reindex' writes it",
        )
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError

    try:
        text = read_limited_text(meta_path, MAX_YAML_BYTES, "rosbag2 metadata", _METADATA_HINT)
        meta = YAML(typ="safe").load(text)
        # rosbags loads the same file again: it is safe to once this passes.
        check_yaml_expansion(meta_path, meta, hint=_METADATA_HINT)
        info = meta["rosbag2_bagfile_information"]
        storage = str(info["storage_identifier"])
        names = [str(n) for n in info["relative_file_paths"]]
        version = int(info.get("version", 0))
        mode = str(info.get("compression_mode") or "").lower()
        fmt = str(info.get("compression_format") or "").lower()
        distro = str(info.get("ros_distro") or "")
    except (YAMLError, UnicodeDecodeError) as exc:
        raise FormatError(meta_path, f"is not YAML ({_one_line(exc)})") from None
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise FormatError(
            meta_path,
            f"is not rosbag2 metadata ({type(exc).__name__}: {exc}); expected "
            "rosbag2_bagfile_information with storage_identifier and relative_file_paths",
        ) from None
    files = tuple(p / PurePath(name).name for name in names)
    missing = [f.name for f in files if not f.is_file()]
    if missing:
        raise InputError(
            f"{p}: {ROSBAG2_METADATA} names storage files that are missing: {', '.join(missing)}",
            hint="copy the whole bag folder",
        )
    compression = f"{mode} {fmt}" if mode not in ("", "none") else ""
    return Ros2BagLayout(p, storage, files, compression, distro, version)


_METADATA_HINT = (
    "rosbag2 writes a few kilobytes per topic and file, and no YAML aliases: the file is "
    "damaged or hostile; 'ros2 bag reindex' on the folder writes it again"
)


def open_ros2_log(
    layout: Ros2BagLayout, strict: bool = False, max_chunk_bytes: int = DEFAULT_MAX_CHUNK_BYTES
) -> MessageLog:
    """The message log of a ROS 2 bag: its one uncompressed MCAP file as an MCAP log, or a
    :class:`Ros2BagLog` (see the module docstring)."""
    if layout.storage == "mcap" and len(layout.files) == 1 and not layout.compression:
        return McapLog(layout.files[0], strict=strict, max_chunk_bytes=max_chunk_bytes)
    return Ros2BagLog(layout, strict=strict)


class Ros2BagLog(Closing):
    """A ROS 2 bag read with ``rosbags``; use it as a context manager.

    Args:
        layout: the bag (:func:`read_layout`).
        strict: a read that fails part way (a damaged storage file) raises
            :class:`InputError` instead of ending the pass with what was read.

    Raises:
        FormatError: ``rosbags`` cannot open the bag.
    """

    def __init__(self, layout: Ros2BagLayout, strict: bool = False) -> None:
        from rosbags.rosbag2 import Reader

        self.layout = layout
        self.path = layout.path
        self.strict = strict
        self.health = BagHealth()
        """What reading found wrong (``stopped``: a pass that ended early)."""
        try:
            reader = Reader(self.path)
            reader.open()
        except Exception as exc:
            # rosbags reports unreadable metadata, missing tables, unknown storage or
            # serialisation formats with ReaderError, sqlite/apsw or YAML errors alike.
            raise FormatError(
                self.path,
                f"cannot be read as a ROS 2 bag ({_one_line(exc)})",
                hint="'ros2 bag info' on the folder says more; a .db3 file needs its folder",
            ) from None
        self._reader = reader
        self._topics = TopicChannels(self.path)
        for c in reader.connections:
            encoding = _SCHEMA_ENCODINGS.get(c.msgdef.format.name, "")
            self._topics.add(
                c.id,
                ChannelInfo(
                    id=c.id,
                    topic=c.topic,
                    message_encoding="cdr",
                    schema_name=c.msgtype,
                    schema_encoding=encoding,
                    schema_data=c.msgdef.data.encode() if encoding else b"",
                ),
            )
        self._connections = list(reader.connections)
        self._stats: dict[int, ChannelStats] | None = None

    def close(self) -> None:
        """Close the storage files."""
        if self._reader.is_open:
            self._reader.close()

    def channels(self) -> dict[int, ChannelInfo]:
        """One channel per topic, by id."""
        return dict(self._topics.by_id)

    def stats(self) -> dict[int, ChannelStats]:
        """Message count and first/last log time (ns) per channel id: by a query of
        uncompressed sqlite3 storage, else counted by one pass over the messages."""
        if self._stats is None:
            self._stats = self._sqlite_stats() or self._counted_stats()
        return {cid: replace(st) for cid, st in self._stats.items()}

    def messages(
        self,
        topics: Collection[str] | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[RawMessage]:
        """Undecoded messages in log-time order.

        Args:
            topics: only these topics (all when ``None``).
            start_ns: first log time to include (ns, inclusive).
            end_ns: log time to stop at (ns, exclusive).

        Raises:
            InputError: with ``strict``, where a storage file cannot be read on.
        """
        if not self._reader.is_open:
            raise ValueError(f"{self.path}: Ros2BagLog is closed")
        wanted = message_window(topics, start_ns, end_ns)[0]
        by_conn = self._topics.by_conn
        conns = [
            c
            for c in self._connections
            if (ch := by_conn.get(c.id)) is not None and (wanted is None or ch.topic in wanted)
        ]
        if not conns:
            return iter(())
        return self._read(conns, start_ns, end_ns)

    def _read(self, conns: list[Any], start: int | None, stop: int | None) -> Iterator[RawMessage]:
        by_conn = self._topics.by_conn
        sequence: Counter[int] = Counter()
        last: int | None = None
        stream = self._reader.messages(conns, start=start, stop=stop)
        while True:
            try:
                conn, log_time, data = next(stream)
            except StopIteration:
                return
            except Exception as exc:
                # A damaged storage file fails inside sqlite, apsw, the MCAP parser or zstd.
                self._stopped(last, exc)
                return
            channel = by_conn.get(conn.id)
            if channel is None:
                continue
            last = log_time
            sequence[channel.id] += 1
            yield RawMessage(channel, log_time, log_time, sequence[channel.id], bytes(data))

    def _stopped(self, last: int | None, exc: Exception) -> None:
        after = "before the first message" if last is None else f"after {format_stamp(last, 3)} s"
        what = f"reading stopped {after}: {_one_line(exc)}; later messages are lost"
        if self.strict:
            raise InputError(
                f"{self.path}: {what}", hint="run without --strict to use what was read"
            )
        if what != self.health.stopped:
            logger.warning("%s: %s", self.path, what)
        self.health.stopped = what

    def _counted_stats(self) -> dict[int, ChannelStats]:
        return count_stats(self.messages(), lambda: self._topics.by_id)

    def _sqlite_stats(self) -> dict[int, ChannelStats] | None:
        """Per-channel statistics from the sqlite3 files' own tables (None where that is not
        possible: another storage, compression, or a query that fails)."""
        if self.layout.storage != "sqlite3" or self.layout.compression:
            return None
        by_topic = {ch.topic: ch.id for ch in self._topics.by_id.values()}
        stats = {cid: ChannelStats() for cid in self._topics.by_id}
        query = (
            "SELECT topics.name, COUNT(*), MIN(messages.timestamp), MAX(messages.timestamp) "
            "FROM messages JOIN topics ON messages.topic_id = topics.id GROUP BY topics.name"
        )
        try:
            for path in self.layout.files:
                db = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro&immutable=1", uri=True)
                try:
                    rows = db.execute(query).fetchall()
                finally:
                    db.close()
                for name, count, first, last in rows:
                    cid = by_topic.get(name)
                    if cid is None or not count:
                        continue
                    st = stats[cid]
                    st.count += int(count)
                    st.first_ns = int(first) if st.first_ns is None else min(st.first_ns, first)
                    st.last_ns = int(last) if st.last_ns is None else max(st.last_ns, last)
        except sqlite3.Error as exc:
            logger.debug("%s: statistics by query failed (%s); counting instead", self.path, exc)
            return None
        return stats


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


__all__ = ["Ros2BagLayout", "Ros2BagLog", "open_ros2_log", "read_layout"]
