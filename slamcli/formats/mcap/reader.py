"""Streaming reader for MCAP logs: log-time order from the chunk index, salvage of damaged logs.

:class:`McapLog` never holds the whole file in memory. On an indexed file (footer, summary and
chunk indexes present) it seeks to each chunk it needs, decompresses one chunk at a time and
merges chunks that overlap in time with a heap, so memory stays bounded by the few chunks that
are open at once. Messages compare by ``(log time, chunk offset, position in the chunk)``, the
same total order as ``mcap``'s own ``iter_messages()``.

Anything else (no summary, no chunk index, or a log cut short by a crashed recorder) is read
front to back. Such a log may be out of log-time order, so messages wait in a heap until the
newest one seen is more than ``reorder_window_ns`` ahead of them; a message older than one
already yielded is dropped and counted in :attr:`LogHealth.dropped_late`. A truncated log is
read up to its first broken record.

A chunk that fails to decompress, fails its CRC or does not parse is skipped and recorded in
:attr:`LogHealth.bad_chunks`; with ``strict=True`` it raises :class:`InputError` instead, and
so does a truncated log. Times are int64 nanoseconds.

Memory and time are bounded on hostile input: a chunk or a message whose declared or actual
uncompressed size passes ``max_chunk_bytes`` is refused as damage before it is read, and
decompression runs in bounded steps that stop as soon as the output passes the declared size.

The bytes themselves are read by :mod:`~slamcli.formats.mcap.layout` (records),
:mod:`~slamcli.formats.mcap.summary` (the summary section) and
:mod:`~slamcli.formats.mcap.chunks` (chunk records and their decompression).
"""

from __future__ import annotations

import heapq
import io
import logging
import struct
import zlib
from bisect import bisect_left, bisect_right
from collections.abc import Callable, Collection, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from operator import itemgetter
from pathlib import Path
from typing import BinaryIO, Protocol

from mcap.data_stream import ReadDataStream
from mcap.records import Channel, ChunkIndex, Schema, Statistics

from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats.base import Closing
from slamcli.formats.mcap.chunks import (
    DAMAGE,
    BadChunkError,
    Decompressor,
    MessageEntry,
    OversizeError,
    inflate,
    mb,
    over_limit,
    parse_chunk,
    read_chunk_body,
)
from slamcli.formats.mcap.layout import (
    CHANNEL,
    CHUNK,
    CHUNK_HEAD,
    MESSAGE,
    MESSAGE_HEAD,
    SCHEMA,
    U64,
    RecordWalker,
    find_break,
)
from slamcli.formats.mcap.records import ChannelInfo, ChannelStats, LogHealth, RawMessage
from slamcli.formats.mcap.summary import read_footer, read_summary, stats_from_index
from slamcli.formats.sniff import MCAP_MAGIC as MAGIC
from slamcli.formats.text import format_stamp

logger = logging.getLogger(__name__)

DEFAULT_REORDER_WINDOW_NS = 1_000_000_000
DEFAULT_MAX_CHUNK_BYTES = 256 * 2**20
"""Largest chunk (uncompressed) or message read; larger ones are skipped as damage."""

_NO_END = 1 << 64

_StreamEntry = tuple[int, int, int, int, bytes]
"""(log time, channel id, sequence, publish time, data) of a message read front to back."""


class MessageLog(Protocol):
    """What :class:`~slamcli.formats.mcap.source.McapSource` reads a log through: channels
    with their schemas, per-channel statistics, undecoded messages in log-time order and a
    health report. :class:`McapLog` is one; the ROS bag readers in
    :mod:`slamcli.formats.rosbag` are others."""

    @property
    def health(self) -> LogHealth:
        """What reading found wrong so far (complete after a full pass)."""
        ...

    def channels(self) -> dict[int, ChannelInfo]: ...

    def stats(self) -> dict[int, ChannelStats]: ...

    def messages(
        self,
        topics: Collection[str] | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[RawMessage]: ...

    def close(self) -> None: ...


class DamagedLog(Protocol):
    """What :func:`skip_bad_chunk` records damage in: a log's path, health and strictness."""

    path: Path
    strict: bool

    @property
    def health(self) -> LogHealth: ...


class McapLog(Closing):
    """An MCAP file opened for streaming reads; use it as a context manager.

    Args:
        path: the ``.mcap`` file.
        strict: raise :class:`InputError` on a truncated log or a bad chunk instead of reading
            around it.
        reorder_window_ns: how far (ns) a message of a log read front to back may arrive
            behind the newest one and still be put back into log-time order.
        max_chunk_bytes: largest uncompressed chunk or message read (bytes); a larger one, by
            its declared or its actual size, is skipped as damage (an error with ``strict``).

    Raises:
        InputError: the file is missing or empty, or (``strict``) truncated.
        FormatError: the file is not MCAP.
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
            raise ConfigError(
                f"reorder_window_ns must be >= 0 ns, got {reorder_window_ns}",
                hint="use 0 to keep file order, or a window such as 1_000_000_000 (1 s)",
            )
        self.path = Path(path)
        self.strict = strict
        self.reorder_window_ns = int(reorder_window_ns)
        self.max_chunk_bytes = int(max_chunk_bytes)
        # zstd may expand incompressible data by up to 1/128 plus a few headers; a chunk record
        # longer than this cannot hold an uncompressed size within the limit.
        self._max_chunk_record = self.max_chunk_bytes + self.max_chunk_bytes // 128 + 4096
        self.health = LogHealth()
        """What reading found wrong; ``dropped_late`` and ``reordered`` describe the last pass."""
        self._channels: dict[int, ChannelInfo] = {}
        self._schemas: dict[int, Schema] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._statistics: Statistics | None = None
        self._channels_complete = False
        self._stats: dict[int, ChannelStats] | None = None
        self._warned_channels: set[int] = set()
        try:
            self._size = self.path.stat().st_size
            self._file: BinaryIO = self.path.open("rb")
        except FileNotFoundError:
            raise InputError(
                f"{self.path}: no such file; expected an MCAP log",
                hint="check the path",
            ) from None
        except IsADirectoryError:
            raise InputError(
                f"{self.path}: is a folder; expected an MCAP log file",
                hint="pass the .mcap file inside it",
            ) from None
        except OSError as exc:
            raise InputError(f"{self.path}: cannot be read ({exc.strerror})") from None
        try:
            self._inspect()
        except BaseException:
            self._file.close()
            raise

    def close(self) -> None:
        """Release the file; generators already running keep their own handles."""
        self._file.close()

    @property
    def indexed(self) -> bool:
        """Whether messages are read through the summary's chunk index."""
        return bool(self._chunk_indexes)

    def channels(self) -> dict[int, ChannelInfo]:
        """Channels by id. Without a summary this needs a full pass (then cached)."""
        if not self._channels_complete:
            self.stats()
        return dict(self._channels)

    def stats(self) -> dict[int, ChannelStats]:
        """Message count and first/last log time (ns) per channel id.

        Taken from the message indexes when every chunk has them (the counts then describe
        what was recorded, including chunks a pass would find bad); otherwise counted by one
        full pass over the messages, which also completes :attr:`health`.
        """
        if self._stats is None:
            self._stats = stats_from_index(
                self._file, self._chunk_indexes, self._channels, self.max_chunk_bytes, self.path
            )
        if self._stats is None:
            self._stats = count_stats(self.messages(), lambda: self._channels)
            self._channels_complete = True
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
            end_ns: log time to stop at (ns, exclusive), as ``mcap``'s ``ending_before``.

        Raises:
            InputError: with ``strict``, at a bad chunk or where a truncated log stops.
        """
        if self._file.closed:
            raise ValueError(f"{self.path}: McapLog is closed")
        wanted_topics, lo, hi = message_window(topics, start_ns, end_ns)
        if self._chunk_indexes:
            return self._indexed_messages(wanted_topics, lo, hi)
        return self._streamed_messages(wanted_topics, lo, hi)

    def _inspect(self) -> None:
        """Check the magic, then read the summary through the footer, if there is one."""
        if self._size == 0:
            raise InputError(
                f"{self.path}: empty file (0 bytes); expected an MCAP log",
                hint="the recording stopped before anything was written; record it again",
            )
        head = self._file.read(len(MAGIC))
        if head != MAGIC:
            if len(head) < len(MAGIC) and MAGIC.startswith(head):
                self.health.summary_present = False
                self.health.truncated = True
                self._truncated_at(0, None)
                return
            raise FormatError(
                self.path,
                f"not an MCAP file: expected the magic bytes {MAGIC.hex(' ')} at byte 0, "
                f"found {head.hex(' ')}",
                hint="check the path; ROS 1 .bag files and ROS 2 bag folders are read as bags",
            )
        footer = read_footer(self._file, self._size)
        if footer is None:
            self.health.summary_present = False
            self.health.truncated = True
            if self.strict:
                stop, last = find_break(self._file, self._size)
                self._truncated_at(stop, last)
            return
        summary_start, summary_crc = footer
        if summary_start == 0:
            self.health.summary_present = False
            return
        try:
            summary = read_summary(
                self._file, self._size, summary_start, summary_crc, self.max_chunk_bytes
            )
            self._schemas.update(summary.schemas)
            self._chunk_indexes.extend(summary.chunk_indexes)
            self._statistics = summary.statistics
            for channel in summary.channels:
                self._add_channel(channel)
        except (BadChunkError, *DAMAGE) as exc:
            logger.warning(
                "%s: the summary section is unreadable (%s); reading the log front to back",
                self.path,
                exc,
            )
            self._channels.clear()
            self._schemas.clear()
            self._chunk_indexes.clear()
            self._statistics = None
            self.health.summary_present = False
            return
        referenced: set[int] = set()
        if self._statistics is not None:
            referenced.update(self._statistics.channel_message_counts)
        for ci in self._chunk_indexes:
            referenced.update(ci.message_index_offsets)
        self._channels_complete = bool(self._channels) and referenced <= self._channels.keys()
        ordered = sorted(self._chunk_indexes, key=_chunk_key)
        latest_end = -1
        for ci in ordered:
            if ci.message_start_time < latest_end:
                self.health.chunk_overlap = True
                break
            latest_end = max(latest_end, ci.message_end_time)

    def _add_channel(self, channel: Channel) -> ChannelInfo:
        known = self._channels.get(channel.id)
        if known is not None:
            return known
        schema = self._schemas.get(channel.schema_id)
        if schema is None and channel.schema_id != 0:
            logger.debug(
                "%s: channel %s names schema %d, which the log does not define",
                self.path,
                channel.topic,
                channel.schema_id,
            )
        info = ChannelInfo.from_records(channel, schema)
        self._channels[channel.id] = info
        return info

    def _add_definition(
        self,
        op: int,
        body: bytes | memoryview,
        topics: frozenset[str] | None,
        wanted: set[int],
    ) -> None:
        """Register a Schema or Channel record met inside the data section."""
        stream = ReadDataStream(io.BytesIO(body))
        if op == SCHEMA:
            schema = Schema.read(stream)
            self._schemas.setdefault(schema.id, schema)
            return
        info = self._add_channel(Channel.read(stream))
        if topics is None or info.topic in topics:
            wanted.add(info.id)

    def _inflate(self, body: memoryview, cache: dict[str, Decompressor]) -> tuple[bytes, int]:
        """Uncompressed records of a chunk record body, and the CRC they should have."""
        return inflate(body, cache, self.max_chunk_bytes, self.path)

    def _check_crc(self, raw: bytes, crc: int) -> None:
        """Compare a chunk's uncompressed bytes with its CRC (0 = the writer left it out)."""
        self._compare_crc(crc, zlib.crc32(raw) if crc else 0)

    def _compare_crc(self, expected: int, actual: int) -> None:
        if expected:
            self.health.crc_checked = True
            if actual != expected:
                raise BadChunkError(f"fails its CRC (expected {expected:08x}, found {actual:08x})")

    def _parse_chunk(
        self, raw: bytes, topics: frozenset[str] | None, wanted: set[int], lo: int, hi: int
    ) -> list[MessageEntry]:
        """Wanted messages of a chunk in ``[lo, hi)`` (file order); registers its channels."""

        def define(op: int, body: memoryview) -> None:
            self._add_definition(op, body, topics, wanted)

        return parse_chunk(raw, wanted, lo, hi, self.max_chunk_bytes, define)

    def _bad_chunk(
        self,
        start: int,
        end: int,
        offset: int,
        reason: str,
        *,
        what: str = "chunk",
        oversize: bool = False,
    ) -> None:
        skip_bad_chunk(
            self,
            (start, end, offset),
            reason,
            what=what,
            oversize=oversize,
            kind="log",
            strict_hint="; 'mcap doctor' lists the damage",
        )

    def _truncated_at(self, stop: int, last_good: int | None) -> None:
        first = self.health.truncated_at_byte is None
        self.health.truncated = True
        self.health.summary_present = False
        self.health.truncated_at_byte = stop
        self.health.last_good_time_ns = last_good
        upto = (
            "no messages" if last_good is None else f"messages up to {format_stamp(last_good, 3)} s"
        )
        if self.strict:
            raise InputError(
                f"{self.path}: truncated: the records stop at byte {stop} of {self._size} "
                f"without a footer; {upto} are readable",
                hint=f"repair it with 'mcap recover {self.path} -o recovered.mcap', "
                "or run without --strict to use the readable part",
            )
        if first:
            logger.warning(
                "%s: truncated at byte %d of %d (no footer); read %s (try 'mcap recover')",
                self.path,
                stop,
                self._size,
                upto,
            )

    def _indexed_messages(
        self, topics: frozenset[str] | None, lo: int, hi: int
    ) -> Iterator[RawMessage]:
        self.health.dropped_late = 0
        self.health.reordered = 0
        channels = self._channels
        wanted = {cid for cid, ch in channels.items() if topics is None or ch.topic in topics}
        chunks = sorted(
            (
                ci
                for ci in self._chunk_indexes
                if ci.message_end_time >= lo
                and ci.message_start_time < hi
                and (
                    topics is None
                    or not ci.message_index_offsets
                    or not wanted.isdisjoint(ci.message_index_offsets)
                    or not ci.message_index_offsets.keys() <= channels.keys()
                )
            ),
            key=_chunk_key,
        )
        # Heap items are (log time of the chunk's next message, chunk offset, chunk); offsets
        # are unique, so comparisons never reach the chunk object.
        heap: list[tuple[int, int, _OpenChunk]] = []
        n = len(chunks)
        i = 0
        cache: dict[str, Decompressor] = {}
        # One worker reads and decompresses the next chunk (both release the GIL) while this
        # thread checks, parses and yields the current one; chunks are opened in a fixed
        # order, so the lookahead never changes what is yielded.
        with (
            self.path.open("rb") as f,
            ThreadPoolExecutor(max_workers=1, thread_name_prefix="mcap-read") as pool,
        ):
            ahead = pool.submit(self._fetch, f, chunks[0], cache) if chunks else None
            while True:
                limit: tuple[int, int] | None = None
                if i < n:
                    ci = chunks[i]
                    pending = (ci.message_start_time, ci.chunk_start_offset)
                    if not heap or pending < (heap[0][0], heap[0][1]):
                        i += 1
                        fetched = ahead
                        ahead = pool.submit(self._fetch, f, chunks[i], cache) if i < n else None
                        oc = self._open_chunk(fetched, ci, topics, wanted, lo, hi)
                        if oc is not None:
                            heapq.heappush(heap, (oc.times[0], ci.chunk_start_offset, oc))
                        continue
                    limit = pending
                elif not heap:
                    return
                _, offset, oc = heap[0]
                if len(heap) > 1:
                    other = heap[1] if len(heap) == 2 or heap[1] < heap[2] else heap[2]
                    if limit is None or (other[0], other[1]) < limit:
                        limit = (other[0], other[1])
                # Everything in this chunk before the next competing (time, offset) key can go
                # out in one run; without overlap that is the whole chunk.
                pos = oc.pos
                times = oc.times
                if limit is None:
                    stop = len(times)
                elif offset < limit[1]:
                    stop = bisect_right(times, limit[0], pos)
                else:
                    stop = bisect_left(times, limit[0], pos)
                buf = oc.buf
                for log, chan, seq, pub, a, b in oc.msgs[pos:stop]:
                    yield RawMessage(channels[chan], log, pub, seq, buf[a:b])
                if stop < len(times):
                    oc.pos = stop
                    heapq.heapreplace(heap, (times[stop], offset, oc))
                else:
                    heapq.heappop(heap)

    def _fetch(
        self, f: BinaryIO, ci: ChunkIndex, cache: dict[str, Decompressor]
    ) -> tuple[bytes, int]:
        """Read and decompress one indexed chunk (runs in the lookahead worker).

        The CRC is checked by the caller: decompression here and checksumming there both
        release the GIL, so they overlap on two cores.
        """
        body = read_chunk_body(f, ci, self.max_chunk_bytes, self._max_chunk_record)
        return self._inflate(body, cache)

    def _open_chunk(
        self,
        fetched: Future[tuple[bytes, int]] | None,
        ci: ChunkIndex,
        topics: frozenset[str] | None,
        wanted: set[int],
        lo: int,
        hi: int,
    ) -> _OpenChunk | None:
        """Check and parse one fetched chunk; ``None`` if it is bad or nothing is wanted."""
        if fetched is None:
            return None
        # The worker's exception is read, not re-raised: raising it here would add this frame
        # (which holds the future, which holds the exception) to its traceback, a cycle that
        # keeps the chunk's buffers alive until the garbage collector happens to run.
        failure = fetched.exception()
        if failure is not None:
            reason = str(failure) if isinstance(failure, BadChunkError) else None
            if reason is None and not isinstance(failure, DAMAGE):
                raise failure
            self._bad_chunk(
                ci.message_start_time,
                ci.message_end_time,
                ci.chunk_start_offset,
                reason or f"does not parse ({failure})",
                oversize=isinstance(failure, OversizeError),
            )
            return None
        try:
            raw, crc = fetched.result()
            self._check_crc(raw, crc)
            msgs = self._parse_chunk(raw, topics, wanted, lo, hi)
        except BadChunkError as exc:
            self._bad_chunk(
                ci.message_start_time,
                ci.message_end_time,
                ci.chunk_start_offset,
                str(exc),
                oversize=isinstance(exc, OversizeError),
            )
            return None
        except DAMAGE as exc:
            self._bad_chunk(
                ci.message_start_time,
                ci.message_end_time,
                ci.chunk_start_offset,
                f"does not parse ({exc})",
            )
            return None
        if not msgs:
            return None
        msgs.sort(key=itemgetter(0))
        return _OpenChunk(raw, msgs)

    def _streamed_messages(
        self, topics: frozenset[str] | None, lo: int, hi: int
    ) -> Iterator[RawMessage]:
        health = self.health
        health.dropped_late = 0
        health.reordered = 0
        channels = self._channels
        window = self.reorder_window_ns
        heap: list[tuple[int, int, _StreamEntry]] = []
        arrival = 0
        newest = -1
        last_out = -1
        with self.path.open("rb") as f:
            for batch in self._stream_batches(f, topics, lo, hi):
                for entry in batch:
                    t = entry[0]
                    if t < last_out:
                        health.dropped_late += 1
                        logger.debug(
                            "%s: dropped a message on %s at %s s: %s s had already been read",
                            self.path,
                            channels[entry[1]].topic,
                            format_stamp(t),
                            format_stamp(last_out),
                        )
                        continue
                    if t < newest:
                        health.reordered += 1
                    else:
                        newest = t
                    heapq.heappush(heap, (t, arrival, entry))
                    arrival += 1
                horizon = newest - window
                while heap and heap[0][0] < horizon:
                    last_out, _, (log, chan, seq, pub, data) = heapq.heappop(heap)
                    yield RawMessage(channels[chan], log, pub, seq, data)
            while heap:
                _, _, (log, chan, seq, pub, data) = heapq.heappop(heap)
                yield RawMessage(channels[chan], log, pub, seq, data)

    def _stream_batches(
        self, f: BinaryIO, topics: frozenset[str] | None, lo: int, hi: int
    ) -> Iterator[list[_StreamEntry]]:
        """Wanted messages in file order, one list per chunk or top-level message."""
        wanted = {cid for cid, ch in self._channels.items() if topics is None or ch.topic in topics}
        walker = RecordWalker(f, self._size)
        last_good: int | None = None
        latest_chunk_end = -1
        cache: dict[str, Decompressor] = {}
        for offset, op, length in walker:
            if op == MESSAGE:
                if length < MESSAGE_HEAD.size:
                    walker.broken_at = offset
                    break
                if length > self.max_chunk_bytes:
                    log = MESSAGE_HEAD.unpack(f.read(MESSAGE_HEAD.size))[2]
                    too_big = over_limit("is a message record of", length, self.max_chunk_bytes)
                    self._bad_chunk(log, log, offset, str(too_big), what="message", oversize=True)
                    continue
                body = f.read(length)
                chan, seq, log, pub = MESSAGE_HEAD.unpack_from(body)
                last_good = log if last_good is None else max(last_good, log)
                if chan in wanted and lo <= log < hi:
                    yield [(log, chan, seq, pub, body[MESSAGE_HEAD.size :])]
                elif chan not in self._channels:
                    self._unknown_channel(chan)
            elif op == CHUNK:
                if length < CHUNK_HEAD.size:
                    # Too short to say which times it held: charged to the last time read.
                    near = 0 if last_good is None else last_good
                    self._bad_chunk(
                        near,
                        near,
                        offset,
                        f"is {length} bytes long, too short for a chunk header "
                        f"({CHUNK_HEAD.size} bytes)",
                    )
                    continue
                if length > self._max_chunk_record:
                    start, end = struct.unpack("<QQ", f.read(16))
                    too_big = over_limit("is a chunk record of", length, self.max_chunk_bytes)
                    self._bad_chunk(start, end, offset, str(too_big), oversize=True)
                    continue
                record = memoryview(f.read(length))
                start, end = U64.unpack_from(record)[0], U64.unpack_from(record, 8)[0]
                if start < latest_chunk_end:
                    self.health.chunk_overlap = True
                latest_chunk_end = max(latest_chunk_end, end)
                if end < lo or start >= hi:
                    last_good = end if last_good is None else max(last_good, end)
                    continue
                try:
                    raw, crc = self._inflate(record, cache)
                    del record
                    self._check_crc(raw, crc)
                    msgs = self._parse_chunk(raw, topics, wanted, lo, hi)
                except BadChunkError as exc:
                    self._bad_chunk(
                        start, end, offset, str(exc), oversize=isinstance(exc, OversizeError)
                    )
                    continue
                except DAMAGE as exc:
                    self._bad_chunk(start, end, offset, f"does not parse ({exc})")
                    continue
                last_good = end if last_good is None else max(last_good, end)
                if msgs:
                    yield [(log, chan, seq, pub, raw[a:b]) for log, chan, seq, pub, a, b in msgs]
            elif op in (CHANNEL, SCHEMA):
                try:
                    self._add_definition(op, f.read(length), topics, wanted)
                except DAMAGE:
                    walker.broken_at = offset
                    break
        if walker.broken_at is not None:
            self._truncated_at(walker.broken_at, last_good)
        self._channels_complete = True

    def _unknown_channel(self, chan: int) -> None:
        if chan not in self._warned_channels:
            self._warned_channels.add(chan)
            logger.warning(
                "%s: messages on channel id %d, which no channel record defines, are ignored",
                self.path,
                chan,
            )


class _OpenChunk:
    """A decompressed chunk being merged: its bytes, its messages sorted by log time."""

    __slots__ = ("buf", "msgs", "pos", "times")

    def __init__(self, buf: bytes, msgs: list[MessageEntry]) -> None:
        self.buf = buf
        self.msgs = msgs
        self.times = [m[0] for m in msgs]
        self.pos = 0


def _chunk_key(ci: ChunkIndex) -> tuple[int, int]:
    return ci.message_start_time, ci.chunk_start_offset


def message_window(
    topics: Collection[str] | None, start_ns: int | None, end_ns: int | None
) -> tuple[frozenset[str] | None, int, int]:
    """A ``messages()`` call's arguments as (topics or None for all, first log time included,
    log time to stop at)."""
    if isinstance(topics, str):
        topics = (topics,)
    wanted = None if topics is None else frozenset(topics)
    lo = 0 if start_ns is None else int(start_ns)
    hi = _NO_END if end_ns is None else int(end_ns)
    return wanted, lo, hi


def count_stats(
    messages: Iterable[RawMessage], channel_ids: Callable[[], Iterable[int]]
) -> dict[int, ChannelStats]:
    """Message count and first/last log time per channel id, by one pass over ``messages``;
    the ids ``channel_ids()`` names after the pass (a pass may find channels) get empty
    statistics when they had no message."""
    counted: dict[int, ChannelStats] = {}
    for msg in messages:
        st = counted.setdefault(msg.channel.id, ChannelStats())
        if st.first_ns is None:
            st.first_ns = msg.log_time_ns
        st.count += 1
        st.last_ns = msg.log_time_ns
    for cid in channel_ids():
        counted.setdefault(cid, ChannelStats())
    return counted


def skip_bad_chunk(
    log: DamagedLog,
    entry: tuple[int, int, int],
    reason: str,
    *,
    what: str,
    oversize: bool,
    kind: str,
    strict_hint: str = "",
) -> None:
    """Record a damaged chunk (``entry``: first and last log time, byte offset) of ``log``
    in its health and warn once; with ``strict`` raise instead.

    ``kind`` names the file ("log", "bag") in the hint; ``strict_hint`` is added to the hint
    of a chunk that is damaged, not merely oversized.

    Raises:
        InputError: with ``strict``.
    """
    if entry in log.health.bad_chunks:
        return
    start, end, offset = entry
    span = f"{format_stamp(start, 3)}-{format_stamp(end, 3)} s"
    raise_limit = f"raise the limit with --max-chunk-mb (max_chunk_bytes) if the {kind} is genuine"
    if log.strict:
        skip = "run without --strict to skip it and use the rest"
        raise InputError(
            f"{log.path}: the {what} at byte {offset} (messages {span}) {reason}",
            hint=f"{raise_limit}, or {skip}" if oversize else f"{skip}{strict_hint}",
        )
    log.health.bad_chunks.append(entry)
    if oversize:
        log.health.oversized[offset] = (what, reason)
    logger.warning(
        "%s: skipped the %s at byte %d: it %s; messages %s are lost%s",
        log.path,
        what,
        offset,
        reason,
        span,
        f" ({raise_limit})" if oversize else "",
    )
