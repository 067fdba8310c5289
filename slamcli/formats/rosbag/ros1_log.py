"""A ROS 1 bag read as a stream of undecoded messages, for the MCAP source's topic logic.

:class:`Ros1BagLog` offers what :class:`~slamcli.formats.mcap.reader.McapLog` offers (channels,
per-channel statistics, messages in log-time order, a health report), so
:class:`~slamcli.formats.rosbag.source.Ros1BagSource` is the MCAP source over another reader.
Each topic is one channel with message encoding ``ros1`` and its ``ros1msg`` definition as the
bag's connection records store it (types ROS renamed since, such as ``roslib/Header``, under
their current names), so messages are decoded with the definitions the recorder had, not with
a fixed ROS distribution's.

The bag's index (connections, chunk infos, index data) is read with ``rosbags``; message
records are then read where the index points, with a few chunks decompressed at a time. Where
``rosbags`` cannot read the index (a damaged or missing index, a recording cut short) the
records are walked from the start of the file instead
(:class:`~slamcli.formats.rosbag.ros1.BagWalker`), messages put back into log-time order
within a window as for MCAP logs read front to back. A truncated bag is read up to its last
whole message; a chunk that does not decompress or parse is skipped and recorded, as the MCAP
reader does (with ``strict`` both are errors).
"""

from __future__ import annotations

import heapq
import logging
import traceback
from collections import Counter
from collections.abc import Collection, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats.base import Closing
from slamcli.formats.mcap.chunks import BadChunkError, Decompressor, OversizeError, mb
from slamcli.formats.mcap.reader import (
    DEFAULT_MAX_CHUNK_BYTES,
    DEFAULT_REORDER_WINDOW_NS,
    count_stats,
    message_window,
    skip_bad_chunk,
)
from slamcli.formats.mcap.records import ChannelInfo, ChannelStats, RawMessage
from slamcli.formats.rosbag.health import BagHealth, TopicChannels
from slamcli.formats.rosbag.ros1 import (
    CHUNK,
    CONNECTION,
    MSG_DATA,
    RECORD_NAMES,
    RENAMED_TYPES,
    BagConnection,
    BagWalker,
    RecordError,
    TopRecord,
    check_sizes,
    chunk_records,
    current_definition,
    field_str,
    field_time,
    field_u32,
    inflate,
    read_connection,
    read_top_record,
    record_at,
)
from slamcli.formats.sniff import ROSBAG_MAGIC, ROSRECORD_MAGIC
from slamcli.formats.text import format_stamp

logger = logging.getLogger(__name__)

_BLOCK = 4096
"""Index entries turned into Python values at a time."""
_OPEN_CHUNKS = 3
"""Decompressed chunks kept while reading through the index."""
_FIRST_LINE_BYTES = 32
"""Bytes read to tell a bag's format by its first line (``#ROSRECORD V1.2\n`` is 16)."""

_Entry = tuple[int, int, int, ChannelInfo, bytes]
"""(log time, chunk offset, offset in the chunk, channel, data) of a walked message; the first
three are unique, so entries never compare their channels."""


@dataclass(frozen=True)
class BagIndex:
    """What a bag's index holds: its connections, and per connection an (N, 3) int64 table of
    (time ns, chunk offset, offset in the chunk) rows; chunk time spans by chunk offset."""

    connections: list[BagConnection]
    entries: dict[int, NDArray[np.int64]]
    chunk_times: dict[int, tuple[int, int]]


def read_index(path: Path) -> BagIndex:
    """The index of a ROS 1 bag, read with ``rosbags``.

    Raises:
        ImportError: ``rosbags``' ROS 1 reader cannot be loaded (it needs ``lz4``).
        Exception: whatever ``rosbags`` raises on a missing or damaged index.
    """
    from rosbags.rosbag1 import Reader

    reader = Reader(path)
    reader.open()
    try:
        connections = [
            BagConnection(
                conn=c.id,
                topic=c.topic,
                msgtype=ros1_type_name(c.msgtype),
                definition=c.msgdef.data,
                md5sum=c.digest,
                callerid=str(getattr(c.ext, "callerid", None) or ""),
            )
            for c in reader.connections
        ]
        entries = {
            cid: np.array([(e.time, e.chunk_pos, e.offset) for e in idx], dtype=np.int64).reshape(
                -1, 3
            )
            for cid, idx in reader.indexes.items()
        }
        chunk_times = {ci.pos: (ci.start_time, ci.end_time - 1) for ci in reader.chunk_infos}
    finally:
        reader.close()
    return BagIndex(connections, entries, chunk_times)


def ros1_type_name(msgtype: str) -> str:
    """``pkg/msg/Type`` (as ``rosbags`` names ROS 1 types) -> ``pkg/Type`` (as the bag does)."""
    parts = msgtype.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        return f"{parts[0]}/{parts[2]}"
    return msgtype


def _index_problem(exc: BaseException) -> str:
    """What went wrong reading the index, with the ``rosbags`` function it went wrong in."""
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" in rosbags' {frames[-1].name}" if frames else ""
    text = str(exc).strip().splitlines()
    detail = f": {text[0]}" if text else ""
    return f"the bag's index cannot be read ({type(exc).__name__}{where}{detail})"


class Ros1BagLog(Closing):
    """A ROS 1 bag (format 2.0) opened for streaming reads; use it as a context manager.

    Args:
        path: the ``.bag`` file.
        strict: raise :class:`InputError` on a truncated bag or a bad chunk instead of reading
            around it (a damaged index alone loses nothing: the records are walked).
        reorder_window_ns: how far (ns) a walked message may arrive behind the newest one and
            still be put back into log-time order.
        max_chunk_bytes: largest uncompressed chunk or message read (bytes); a larger one is
            skipped as damage (an error with ``strict``).

    Raises:
        InputError: the file is missing, empty or (``strict``) truncated.
        FormatError: the file is not a ROS 1 bag of format 2.0 (a bag of format 1.2 is named
            as one, with how to convert it).
    """

    def __init__(
        self,
        path: str | Path,
        strict: bool = False,
        *,
        reorder_window_ns: int = DEFAULT_REORDER_WINDOW_NS,
        max_chunk_bytes: int = DEFAULT_MAX_CHUNK_BYTES,
    ) -> None:
        if max_chunk_bytes < 1:
            raise ConfigError(
                f"max_chunk_bytes must be >= 1 byte, got {max_chunk_bytes}",
                hint=f"the default is {DEFAULT_MAX_CHUNK_BYTES} ({mb(DEFAULT_MAX_CHUNK_BYTES)})",
            )
        if reorder_window_ns < 0:
            raise ConfigError(f"reorder_window_ns must be >= 0 ns, got {reorder_window_ns}")
        self.path = Path(path)
        self.strict = strict
        self.reorder_window_ns = int(reorder_window_ns)
        self.max_chunk_bytes = int(max_chunk_bytes)
        self.health = BagHealth()
        """What reading found wrong; ``dropped_late`` and ``reordered`` describe the last pass."""
        self._size = _check_file(self.path)
        self._topics = TopicChannels(self.path)
        self._stats: dict[int, ChannelStats] | None = None
        self._warned_conns: set[int] = set()
        self._closed = False
        self._last_good: int | None = None
        self.index = self._open_index()
        """The bag's index as ``rosbags`` reads it; None when the records are walked."""
        self.health.summary_present = self.index is not None
        self._complete = self.index is not None
        if self.index is not None:
            for bc in self.index.connections:
                self._add(bc)
            self._stats = self._index_stats(self.index)

    @property
    def walked(self) -> bool:
        """Whether the records are walked from the start (the index is not used)."""
        return self.index is None

    def close(self) -> None:
        """Refuse further reads; each pass has its own file handle, closed when it ends."""
        self._closed = True

    def channels(self) -> dict[int, ChannelInfo]:
        """One channel per topic, by id. Walking the records needs a full pass (then cached)."""
        if not self._complete:
            self.stats()
        return dict(self._topics.by_id)

    def stats(self) -> dict[int, ChannelStats]:
        """Message count and first/last log time (ns) per channel id: from the index, or
        counted by one full pass when the records are walked."""
        if self._stats is None:
            self._stats = count_stats(self.messages(), lambda: self._topics.by_id)
        return {cid: replace(st) for cid, st in self._stats.items()}

    def messages(
        self,
        topics: Collection[str] | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[RawMessage]:
        """Undecoded messages in log-time order (ties in file order).

        Args:
            topics: only these topics (all when ``None``).
            start_ns: first log time to include (ns, inclusive).
            end_ns: log time to stop at (ns, exclusive).

        Raises:
            InputError: with ``strict``, at a bad chunk or where a truncated bag stops.
            FormatError: (walking) bytes that are not bag records.
        """
        if self._closed:
            raise ValueError(f"{self.path}: Ros1BagLog is closed")
        wanted, lo, hi = message_window(topics, start_ns, end_ns)
        if self.index is not None:
            return self._indexed(self.index, wanted, lo, hi)
        return self._walked(wanted, lo, hi)

    # -- opening ---------------------------------------------------------------------------

    def _open_index(self) -> BagIndex | None:
        try:
            return read_index(self.path)
        except ImportError as exc:
            problem = f"rosbags' ROS 1 reader cannot be loaded ({exc})"
        except Exception as exc:
            # rosbags meets a damaged or missing index with ReaderError, AssertionError,
            # struct.error, KeyError, ...: all mean the records have to be walked instead.
            problem = _index_problem(exc)
        self.health.index_problem = problem
        logger.warning("%s: %s; reading its records from the start", self.path, problem)
        return None

    def _add(self, bc: BagConnection) -> None:
        info = ChannelInfo(
            id=bc.conn,
            topic=bc.topic,
            message_encoding="ros1",
            schema_name=RENAMED_TYPES.get(bc.msgtype, bc.msgtype),
            schema_encoding="ros1msg",
            schema_data=current_definition(bc.definition).encode(),
            metadata={"md5sum": bc.md5sum, "callerid": bc.callerid},
        )
        self._topics.add(bc.conn, info)

    def _index_stats(self, index: BagIndex) -> dict[int, ChannelStats]:
        stats = {cid: ChannelStats() for cid in self._topics.by_id}
        for bc in index.connections:
            channel = self._topics.by_conn.get(bc.conn)
            rows = index.entries.get(bc.conn)
            if channel is None or rows is None or not len(rows):
                continue
            st = stats[channel.id]
            st.count += len(rows)
            first, last = int(rows[:, 0].min()), int(rows[:, 0].max())
            st.first_ns = first if st.first_ns is None else min(st.first_ns, first)
            st.last_ns = last if st.last_ns is None else max(st.last_ns, last)
        return stats

    def _channel(self, conn: int, topics: frozenset[str] | None) -> ChannelInfo | None:
        """The channel of a message's connection if it is wanted (unknown ones warned once)."""
        if conn not in self._topics.by_conn:
            if conn not in self._warned_conns:
                self._warned_conns.add(conn)
                logger.warning(
                    "%s: messages on connection %d, which no connection record defines, are "
                    "ignored",
                    self.path,
                    conn,
                )
            return None
        channel = self._topics.by_conn[conn]
        if channel is None or (topics is not None and channel.topic not in topics):
            return None
        return channel

    # -- reading through the index -----------------------------------------------------------

    def _indexed(
        self, index: BagIndex, topics: frozenset[str] | None, lo: int, hi: int
    ) -> Iterator[RawMessage]:
        tables = [
            index.entries[bc.conn]
            for bc in index.connections
            if bc.conn in index.entries and self._channel(bc.conn, topics) is not None
        ]
        if not tables:
            return
        table = np.concatenate(tables)
        table = table[(table[:, 0] >= lo) & (table[:, 0] < hi)]
        table = table[np.lexsort((table[:, 2], table[:, 1], table[:, 0]))]
        sequence: Counter[int] = Counter()
        cache: dict[str, Decompressor] = {}
        # Chunks that overlap in time are visited in turns: the last few stay decompressed.
        recent: dict[int, bytes | None] = {}
        with self.path.open("rb") as f:
            for start in range(0, len(table), _BLOCK):
                for _, pos, offset in table[start : start + _BLOCK].tolist():
                    if pos not in recent:
                        if len(recent) >= _OPEN_CHUNKS:
                            del recent[next(iter(recent))]
                        recent[pos] = self._load_chunk(f, pos, cache)
                    buf = recent[pos]
                    if buf is None:
                        continue
                    try:
                        conn, log_time, a, b = _message_at(buf, offset)
                    except RecordError as exc:
                        self._bad_chunk(
                            pos,
                            f"holds no message at chunk byte {offset}, where the index "
                            f"points ({exc})",
                        )
                        recent[pos] = None
                        continue
                    channel = self._channel(conn, topics)
                    if channel is not None:
                        sequence[channel.id] += 1
                        yield RawMessage(
                            channel, log_time, log_time, sequence[channel.id], buf[a:b]
                        )

    def _load_chunk(self, f: BinaryIO, pos: int, cache: dict[str, Decompressor]) -> bytes | None:
        """The uncompressed records of the chunk at byte ``pos``; None (recorded) if bad."""
        try:
            rec = read_top_record(f, pos, self._size, self.path)
        except FormatError as exc:
            self._bad_chunk(pos, f"is not where the index points ({exc.msg})")
            return None
        if rec is None or not rec.complete:
            self._bad_chunk(pos, "lies past the end of the file")
            return None
        if rec.op != CHUNK:
            self._bad_chunk(pos, f"is a {RECORD_NAMES[rec.op]} record, not a chunk")
            return None
        try:
            check_sizes(rec, self.max_chunk_bytes)
            compression, size = field_str(rec.fields, "compression"), field_u32(rec.fields, "size")
            f.seek(rec.data_start)
            data = f.read(rec.data_len)
            return inflate(compression, data, size, path=self.path, offset=pos, cache=cache)
        except OversizeError as exc:
            self._bad_chunk(pos, str(exc), oversize=True)
        except (BadChunkError, RecordError) as exc:
            self._bad_chunk(pos, str(exc))
        return None

    # -- walking the records -----------------------------------------------------------------

    def _walked(self, topics: frozenset[str] | None, lo: int, hi: int) -> Iterator[RawMessage]:
        health = self.health
        health.dropped_late = 0
        health.reordered = 0
        window = self.reorder_window_ns
        heap: list[_Entry] = []
        sequence: Counter[int] = Counter()
        newest = -1
        last_out = -1

        def out(entry: _Entry) -> RawMessage:
            channel = entry[3]
            sequence[channel.id] += 1
            return RawMessage(channel, entry[0], entry[0], sequence[channel.id], entry[4])

        with self.path.open("rb") as f:
            for entry in self._walk(f, topics, lo, hi):
                t = entry[0]
                if t < last_out:
                    health.dropped_late += 1
                    logger.debug(
                        "%s: dropped a message at %s s: %s s had already been read",
                        self.path,
                        format_stamp(t),
                        format_stamp(last_out),
                    )
                    continue
                if t < newest:
                    health.reordered += 1
                newest = max(newest, t)
                heapq.heappush(heap, entry)
                while heap and heap[0][0] < newest - window:
                    entry = heapq.heappop(heap)
                    last_out = entry[0]
                    yield out(entry)
            while heap:
                yield out(heapq.heappop(heap))

    def _walk(
        self, f: BinaryIO, topics: frozenset[str] | None, lo: int, hi: int
    ) -> Iterator[_Entry]:
        """Wanted messages in file order; records the walk's findings in :attr:`health`."""
        walker = BagWalker(f, self._size, self.path)
        cache: dict[str, Decompressor] = {}
        self._last_good = None
        for rec in walker:
            if rec.op == CONNECTION and rec.complete:
                self._walk_connection(rec, walker.read(rec))
            elif rec.op == MSG_DATA and rec.complete:
                try:
                    check_sizes(rec, self.max_chunk_bytes)
                    conn, t = field_u32(rec.fields, "conn"), field_time(rec.fields, "time")
                except OversizeError as exc:
                    self._bad_chunk(rec.offset, str(exc), what="message", oversize=True)
                    continue
                except RecordError as exc:
                    self._bad_chunk(rec.offset, f"has a malformed header ({exc})", what="message")
                    continue
                self._seen(t)
                channel = self._channel(conn, topics) if lo <= t < hi else None
                if channel is not None:
                    yield t, rec.offset, 0, channel, walker.read(rec)
            elif rec.op == CHUNK:
                yield from self._walk_chunk(walker, rec, topics, lo, hi, cache)
        if walker.broken_at is not None:
            self._truncated_at(walker.broken_at, self._last_good)
        for note in walker.notes:
            if note not in self.health.notes:
                self.health.notes.append(note)
        self._complete = True

    def _walk_connection(self, rec: TopRecord, data: bytes) -> None:
        try:
            self._add(read_connection(rec.fields, data))
        except RecordError as exc:
            logger.warning(
                "%s: the connection record at byte %d is malformed (%s); its messages are ignored",
                self.path,
                rec.offset,
                exc,
            )

    def _walk_chunk(
        self,
        walker: BagWalker,
        rec: TopRecord,
        topics: frozenset[str] | None,
        lo: int,
        hi: int,
        cache: dict[str, Decompressor],
    ) -> Iterator[_Entry]:
        try:
            check_sizes(rec, self.max_chunk_bytes)
            compression, size = field_str(rec.fields, "compression"), field_u32(rec.fields, "size")
        except OversizeError as exc:
            self._bad_chunk(rec.offset, str(exc), oversize=True)
            return
        except RecordError as exc:
            self._bad_chunk(rec.offset, f"has a malformed header ({exc})")
            return
        try:
            raw = inflate(
                compression,
                walker.read(rec),
                size,
                path=self.path,
                offset=rec.offset,
                cache=cache,
                partial=not rec.complete,
            )
        except BadChunkError as exc:
            self._bad_chunk(rec.offset, str(exc))
            return
        found: list[_Entry] = []
        times: list[int] = []
        try:
            for pos, op, fields, a, b in chunk_records(raw):
                if op == CONNECTION:
                    self._add(read_connection(fields, raw[a:b]))
                elif op == MSG_DATA:
                    conn, t = field_u32(fields, "conn"), field_time(fields, "time")
                    times.append(t)
                    channel = self._channel(conn, topics) if lo <= t < hi else None
                    if channel is not None:
                        found.append((t, rec.offset, pos, channel, raw[a:b]))
        except RecordError as exc:
            # In the last chunk of a truncated bag the records stop where the file does.
            if rec.complete:
                self._bad_chunk(rec.offset, f"holds damaged records ({exc})")
                return
        for t in times:
            self._seen(t)
        yield from found

    def _seen(self, t: int) -> None:
        self._last_good = t if self._last_good is None else max(self._last_good, t)

    # -- damage ------------------------------------------------------------------------------

    def _bad_chunk(
        self, offset: int, reason: str, *, what: str = "chunk", oversize: bool = False
    ) -> None:
        near = 0 if self._last_good is None else self._last_good
        known = self.index.chunk_times.get(offset) if self.index is not None else None
        start, end = known if known is not None else (near, near)
        skip_bad_chunk(self, (start, end, offset), reason, what=what, oversize=oversize, kind="bag")

    def _truncated_at(self, stop: int, last_good: int | None) -> None:
        first = self.health.truncated_at_byte is None
        self.health.truncated = True
        self.health.truncated_at_byte = stop
        self.health.last_good_time_ns = last_good
        upto = (
            "no messages" if last_good is None else f"messages up to {format_stamp(last_good, 3)} s"
        )
        if self.strict:
            raise InputError(
                f"{self.path}: truncated: the bag ends inside the record at byte {stop} of "
                f"{self._size}; {upto} are readable",
                hint="run without --strict to use the readable part",
            )
        if first:
            logger.warning(
                "%s: truncated inside the record at byte %d of %d; read %s",
                self.path,
                stop,
                self._size,
                upto,
            )


def _message_at(buf: bytes, offset: int) -> tuple[int, int, int, int]:
    """``(connection, log time, data start, data end)`` of the message an index entry points
    at: the first message data record from ``offset``, past connection records."""
    pos = offset
    while True:
        op, fields, a, b = record_at(buf, pos)
        if op != CONNECTION:
            break
        pos = b
    if op != MSG_DATA:
        raise RecordError(f"a {RECORD_NAMES[op]} record is there")
    return field_u32(fields, "conn"), field_time(fields, "time"), a, b


def _check_file(path: Path) -> int:
    """The size of a bag file that starts with the bag magic line.

    Raises:
        InputError: missing, a folder, unreadable or empty. FormatError: no bag magic line.
    """
    try:
        size = path.stat().st_size
        with path.open("rb") as fh:
            head = fh.read(_FIRST_LINE_BYTES)
    except FileNotFoundError:
        raise InputError(
            f"{path}: no such file; expected a ROS 1 bag", hint="check the path"
        ) from None
    except IsADirectoryError:
        raise InputError(
            f"{path}: is a folder; expected a ROS 1 .bag file",
            hint="a ROS 2 bag is a folder holding metadata.yaml: check that it has one",
        ) from None
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror})") from None
    if size == 0:
        raise InputError(
            f"{path}: empty file (0 bytes); expected a ROS 1 bag",
            hint="the recording stopped before anything was written; record it again",
        )
    if head.startswith(ROSBAG_MAGIC):
        return size
    if head.startswith(ROSRECORD_MAGIC):
        raise _old_format(path, head.split(b"\n", 1)[0].decode("ascii", "replace"))
    if len(head) < len(ROSBAG_MAGIC) and ROSBAG_MAGIC.startswith(head):
        raise InputError(
            f"{path}: ends after {size} bytes, inside the bag's first line; no message is readable",
            hint="the recording stopped before anything was written; record it again",
        )
    if head.startswith(b"#ROSBAG V"):
        version = head.split(b"\n", 1)[0].decode("ascii", "replace")
        raise FormatError(
            path,
            f"bag format {version[len('#ROSBAG V') :]!r} is not read; expected {ROSBAG_MAGIC!r}",
            hint="rewrite it with a current rosbag ('rosbag filter in.bag out.bag True')",
        )
    raise FormatError(
        path,
        f"not a ROS 1 bag: expected {ROSBAG_MAGIC!r} at byte 0, found "
        f"{head[: len(ROSBAG_MAGIC)]!r}",
        hint="check the path",
    )


def _old_format(path: Path, first_line: str) -> FormatError:
    """The error for a bag of a format before 2.0, named by its first line."""
    version = first_line.removeprefix(ROSRECORD_MAGIC.decode())
    if version == "1.2":
        return FormatError(
            path,
            "is a ROS 1 bag in the older format 1.2 ('#ROSRECORD V1.2', written by ROS 0.5 to "
            "1.0, 2009-2010), which slamcli and rosbags do not read; they read format 2.0 "
            "('#ROSBAG V2.0')",
            hint="convert it to format 2.0 in a ROS 1 install, whose rosbag reads 1.2: "
            "'rosbag fix old.bag new.bag', or, where fix finds no migration rule for an old "
            "message type, 'rosbag filter old.bag new.bag True'",
        )
    return FormatError(
        path,
        f"is a ROS bag in the early format {version[:16]!r} (first line {first_line[:32]!r}), "
        "which slamcli does not read; it reads format 2.0 ('#ROSBAG V2.0')",
        hint="convert it to format 2.0 with the rosbag tools of a ROS release that reads it",
    )


__all__ = ["BagIndex", "Ros1BagLog", "read_index", "ros1_type_name"]
