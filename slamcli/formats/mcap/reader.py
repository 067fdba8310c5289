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
"""

from __future__ import annotations

import heapq
import io
import logging
import struct
import zlib
from bisect import bisect_left, bisect_right
from collections.abc import Collection, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from operator import itemgetter
from pathlib import Path
from typing import BinaryIO, Protocol

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, ChunkIndex, Schema, Statistics

from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats.base import Closing
from slamcli.formats.mcap.records import ChannelInfo, ChannelStats, LogHealth, RawMessage
from slamcli.formats.sniff import MCAP_MAGIC as MAGIC
from slamcli.formats.text import format_stamp

logger = logging.getLogger(__name__)

DEFAULT_REORDER_WINDOW_NS = 1_000_000_000
DEFAULT_MAX_CHUNK_BYTES = 256 * 2**20
"""Largest chunk (uncompressed) or message read; larger ones are skipped as damage."""

_HEADER = int(Opcode.HEADER)
_FOOTER = int(Opcode.FOOTER)
_SCHEMA = int(Opcode.SCHEMA)
_CHANNEL = int(Opcode.CHANNEL)
_MESSAGE = int(Opcode.MESSAGE)
_CHUNK = int(Opcode.CHUNK)
_MESSAGE_INDEX = int(Opcode.MESSAGE_INDEX)
_CHUNK_INDEX = int(Opcode.CHUNK_INDEX)
_STATISTICS = int(Opcode.STATISTICS)

_RECORD = struct.Struct("<BQ")
"""Record prefix: opcode, body length."""
_MESSAGE_HEAD = struct.Struct("<HIQQ")
"""Message body prefix: channel id, sequence, log time, publish time."""
_CHUNK_HEAD = struct.Struct("<QQQII")
"""Chunk body prefix: start time, end time, uncompressed size, CRC, compression name length."""
_U64 = struct.Struct("<Q")
_INDEX_HEAD = struct.Struct("<HI")
"""Message index body prefix: channel id, byte length of the (time, offset) pairs."""
_FOOTER_RECORD = struct.Struct("<BQQQI")
_TAIL_SIZE = _FOOTER_RECORD.size + len(MAGIC)
_NO_END = 1 << 64

_MessageEntry = tuple[int, int, int, int, int, int]
"""(log time, channel id, sequence, publish time, data start, data end) inside a chunk."""
_StreamEntry = tuple[int, int, int, int, bytes]
"""(log time, channel id, sequence, publish time, data) of a message read front to back."""

_DAMAGE = (McapError, struct.error, ValueError, RuntimeError, OSError)
"""What parsing damaged bytes raises: mcap and struct errors, bad UTF-8, lz4's RuntimeError."""
_MB = 2**20
_INFLATE_STEP = 16 * _MB
"""Most output bytes asked of a streaming decompressor per call."""
_BYTES_PER_RECORD = 256
"""A chunk may hold one record per this many bytes of ``max_chunk_bytes``: each message costs
about 200 bytes of bookkeeping, and each record parsing time, whatever its own size."""


class _Decompressor(Protocol):
    def __call__(self, data: memoryview, uncompressed_size: int) -> bytes: ...


class _BadChunkError(Exception):
    """A chunk's bytes are unusable; the message says why."""


class _OversizeError(_BadChunkError):
    """A chunk or message is larger than ``max_chunk_bytes`` allows; the message says how."""


def _over(what: str, size: int, limit: int) -> _OversizeError:
    return _OversizeError(f"{what} {size} bytes ({size / _MB:.1f} MB), over the {_mb(limit)} limit")


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
                hint=f"the default is {DEFAULT_MAX_CHUNK_BYTES} ({_mb(DEFAULT_MAX_CHUNK_BYTES)})",
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
            self._stats = self._stats_from_index()
        if self._stats is None:
            counted = {cid: ChannelStats() for cid in self._channels}
            for msg in self.messages():
                st = counted.get(msg.channel.id)
                if st is None:
                    st = counted[msg.channel.id] = ChannelStats()
                if st.first_ns is None:
                    st.first_ns = msg.log_time_ns
                st.count += 1
                st.last_ns = msg.log_time_ns
            for cid in self._channels:
                counted.setdefault(cid, ChannelStats())
            self._channels_complete = True
            self._stats = counted
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
        if isinstance(topics, str):
            topics = (topics,)
        wanted_topics = None if topics is None else frozenset(topics)
        lo = 0 if start_ns is None else int(start_ns)
        hi = _NO_END if end_ns is None else int(end_ns)
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
                hint="check the path; a ROS 2 .db3 bag needs 'ros2 bag convert' to MCAP first",
            )
        footer = self._read_footer()
        if footer is None:
            self.health.summary_present = False
            self.health.truncated = True
            if self.strict:
                stop, last = self._find_break()
                self._truncated_at(stop, last)
            return
        summary_start, summary_crc = footer
        if summary_start == 0:
            self.health.summary_present = False
            return
        try:
            self._read_summary(summary_start, summary_crc)
        except (_BadChunkError, *_DAMAGE) as exc:
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

    def _read_footer(self) -> tuple[int, int] | None:
        """``(summary_start, summary_crc)`` from a well-formed footer, else ``None``."""
        if self._size < len(MAGIC) + _TAIL_SIZE:
            return None
        self._file.seek(self._size - _TAIL_SIZE)
        tail = self._file.read(_TAIL_SIZE)
        if tail[-len(MAGIC) :] != MAGIC:
            return None
        op, length, summary_start, _, summary_crc = _FOOTER_RECORD.unpack_from(tail)
        if op != _FOOTER or length != _FOOTER_RECORD.size - _RECORD.size:
            return None
        if summary_start != 0 and not len(MAGIC) <= summary_start <= self._size - _TAIL_SIZE:
            return None
        return summary_start, summary_crc

    def _read_summary(self, summary_start: int, summary_crc: int) -> None:
        footer_at = self._size - _TAIL_SIZE
        if footer_at - summary_start > self.max_chunk_bytes:
            raise _over("the summary section is", footer_at - summary_start, self.max_chunk_bytes)
        self._file.seek(summary_start)
        data = self._file.read(footer_at - summary_start)
        if summary_crc:
            # The summary CRC runs from the summary start through the footer, minus its CRC.
            footer_fields = self._file.read(_FOOTER_RECORD.size - 4)
            crc = zlib.crc32(footer_fields, zlib.crc32(data))
            if crc != summary_crc:
                raise _BadChunkError(f"summary CRC {crc:08x} != {summary_crc:08x}")
        stream = ReadDataStream(io.BytesIO(data))
        channels: list[Channel] = []
        while stream.count < len(data):
            op = stream.read1()
            length = stream.read8()
            body_start = stream.count
            if op == _SCHEMA:
                schema = Schema.read(stream)
                self._schemas[schema.id] = schema
            elif op == _CHANNEL:
                channels.append(Channel.read(stream))
            elif op == _CHUNK_INDEX:
                self._chunk_indexes.append(ChunkIndex.read(stream))
            elif op == _STATISTICS:
                self._statistics = Statistics.read(stream)
            rest = length - (stream.count - body_start)
            if rest < 0:
                raise _BadChunkError(f"record with opcode {op:#04x} overruns its length")
            if rest > len(data) - stream.count:
                raise _BadChunkError(
                    f"record with opcode {op:#04x} declares {length} bytes, more than the "
                    f"summary section holds"
                )
            stream.read(rest)
        for channel in channels:
            self._add_channel(channel)

    def _find_break(self) -> tuple[int, int | None]:
        """Byte offset of the first broken record, and the last log time before it."""
        walker = _RecordWalker(self._file, self._size)
        last: int | None = None
        for _, op, length in walker:
            if op == _CHUNK and length >= 16:
                end = _U64.unpack_from(self._file.read(16), 8)[0]
                last = end if last is None else max(last, end)
            elif op == _MESSAGE and length >= _MESSAGE_HEAD.size:
                log = _MESSAGE_HEAD.unpack(self._file.read(_MESSAGE_HEAD.size))[2]
                last = log if last is None else max(last, log)
        return (self._size if walker.broken_at is None else walker.broken_at), last

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
        if op == _SCHEMA:
            schema = Schema.read(stream)
            self._schemas.setdefault(schema.id, schema)
            return
        info = self._add_channel(Channel.read(stream))
        if topics is None or info.topic in topics:
            wanted.add(info.id)

    def _decompressor(self, compression: str, cache: dict[str, _Decompressor]) -> _Decompressor:
        """A bounded decompression function, cached per pass: a zstd context is not thread-safe.

        Each one returns exactly ``uncompressed_size`` bytes or raises :class:`_BadChunkError`,
        and never produces more than one byte past that size, whatever the data claims.
        """
        known = cache.get(compression)
        if known is not None:
            return known
        if compression == "":

            def fn(data: memoryview, uncompressed_size: int) -> bytes:
                problem = _size_problem(len(data), False, uncompressed_size)
                if problem is not None:
                    raise _BadChunkError(problem)
                return bytes(data)

        elif compression == "zstd":
            try:
                import zstandard
            except ImportError:
                raise InputError(
                    f"{self.path}: zstd-compressed chunks need the 'zstandard' package",
                    hint="pip install zstandard",
                ) from None
            dctx = zstandard.ZstdDecompressor()

            def fn(data: memoryview, uncompressed_size: int) -> bytes:
                try:
                    frame_size = zstandard.frame_content_size(data)
                except zstandard.ZstdError as exc:
                    raise _BadChunkError(f"does not decompress (zstd: {exc})") from None
                if frame_size == uncompressed_size:
                    # The usual case: one frame whose header agrees with the chunk. decompress()
                    # sizes its output from that header, so it can write no more than declared.
                    try:
                        whole = dctx.decompress(data, max_output_size=uncompressed_size)
                    except zstandard.ZstdError as exc:
                        raise _BadChunkError(_zstd_problem(exc, uncompressed_size)) from None
                    problem = _size_problem(len(whole), False, uncompressed_size)
                    if problem is not None:
                        del whole
                        raise _BadChunkError(problem)
                    return whole
                # Otherwise the frame header is missing or lies, and decompress() would trust it
                # (or the declared size) for its allocation; a stream reader fills a buffer of
                # the declared size step by step and stops one byte past it.
                out = bytearray(uncompressed_size)
                view = memoryview(out)
                got = 0
                problem = None
                try:
                    reader = dctx.stream_reader(data, read_across_frames=True)
                    while got < uncompressed_size:
                        n = reader.readinto(view[got : got + _INFLATE_STEP])
                        if not n:
                            break
                        got += n
                    problem = _size_problem(got, bool(reader.read(1)), uncompressed_size)
                except zstandard.ZstdError as exc:
                    problem = _zstd_problem(exc, uncompressed_size)
                del view
                if problem is not None:
                    # Not raised while the buffer is alive: the traceback would keep it.
                    del out
                    raise _BadChunkError(problem)
                return bytes(out)

        elif compression == "lz4":
            try:
                import lz4.frame
            except ImportError:
                raise InputError(
                    f"{self.path}: lz4-compressed chunks need the 'lz4' package",
                    hint="pip install lz4",
                ) from None

            def fn(data: memoryview, uncompressed_size: int) -> bytes:
                pieces: list[bytes] = []
                got = 0
                feed: bytes | memoryview = data
                dec = lz4.frame.LZ4FrameDecompressor()
                problem = None
                try:
                    while got <= uncompressed_size:
                        step = min(_INFLATE_STEP, uncompressed_size + 1 - got)
                        piece = dec.decompress(feed, max_length=step)
                        feed = b""
                        got += len(piece)
                        pieces.append(piece)
                        if dec.eof:
                            if not dec.unused_data:
                                break
                            # Concatenated frames: the next one starts where this one ended.
                            feed = dec.unused_data
                            dec = lz4.frame.LZ4FrameDecompressor()
                        elif not piece:
                            problem = "does not decompress (lz4: the frame is cut short)"
                            break
                    problem = problem or _size_problem(got, False, uncompressed_size)
                except RuntimeError as exc:
                    problem = f"does not decompress (lz4: {exc})"
                if problem is not None:
                    # Not raised while the pieces are alive: the traceback would keep them.
                    del pieces
                    raise _BadChunkError(problem)
                return b"".join(pieces)

        else:
            raise _BadChunkError(f"has unknown compression {compression!r} (expected zstd, lz4)")
        cache[compression] = fn
        return fn

    def _inflate(self, body: memoryview, cache: dict[str, _Decompressor]) -> tuple[bytes, int]:
        """Uncompressed records of a chunk record body, and the CRC they should have."""
        if len(body) < _CHUNK_HEAD.size:
            raise _BadChunkError(
                f"is {len(body)} bytes long, too short for a chunk header ({_CHUNK_HEAD.size})"
            )
        _, _, size, crc, name_len = _CHUNK_HEAD.unpack_from(body)
        if size > self.max_chunk_bytes:
            raise _over("declares an uncompressed size of", size, self.max_chunk_bytes)
        at = _CHUNK_HEAD.size
        if at + name_len + _U64.size > len(body):
            raise _BadChunkError(f"its compression name ({name_len} bytes) runs past the record")
        try:
            compression = str(body[at : at + name_len], "utf-8")
        except UnicodeDecodeError:
            raise _BadChunkError(
                f"its compression name {bytes(body[at : at + name_len])!r} is not UTF-8 "
                "(expected zstd, lz4 or empty)"
            ) from None
        at += name_len
        data_len = _U64.unpack_from(body, at)[0]
        at += _U64.size
        if at + data_len > len(body):
            raise _BadChunkError(
                f"its data ({data_len} bytes) runs past the end of the record ({len(body)} bytes)"
            )
        raw = self._decompressor(compression, cache)(body[at : at + data_len], size)
        return raw, crc

    def _check_crc(self, raw: bytes, crc: int) -> None:
        """Compare a chunk's uncompressed bytes with its CRC (0 = the writer left it out)."""
        self._compare_crc(crc, zlib.crc32(raw) if crc else 0)

    def _compare_crc(self, expected: int, actual: int) -> None:
        if expected:
            self.health.crc_checked = True
            if actual != expected:
                raise _BadChunkError(f"fails its CRC (expected {expected:08x}, found {actual:08x})")

    def _parse_chunk(
        self,
        raw: bytes,
        topics: frozenset[str] | None,
        wanted: set[int],
        lo: int,
        hi: int,
    ) -> list[_MessageEntry]:
        """Wanted messages of a chunk in ``[lo, hi)`` (file order); registers its channels."""
        out: list[_MessageEntry] = []
        append = out.append
        unpack_record = _RECORD.unpack_from
        unpack_message = _MESSAGE_HEAD.unpack_from
        pos = 0
        n = len(raw)
        left = self.max_chunk_bytes // _BYTES_PER_RECORD
        while pos < n:
            left -= 1
            if left < 0:
                cap = self.max_chunk_bytes // _BYTES_PER_RECORD
                raise _OversizeError(
                    f"holds more than {cap} records, the most the {_mb(self.max_chunk_bytes)} "
                    f"limit allows (one per {_BYTES_PER_RECORD} bytes)"
                )
            if pos + 9 > n:
                raise _BadChunkError(
                    f"its records end in {n - pos} stray bytes at chunk byte {pos} "
                    "(expected a 9-byte record header)"
                )
            op, length = unpack_record(raw, pos)
            if op == 0:
                # Opcode 0 is never written; a run of them is zeroed or foreign data.
                raise _BadChunkError(f"holds opcode 0x00 at chunk byte {pos}, not an MCAP record")
            body = pos + 9
            pos = body + length
            if pos > n:
                raise _BadChunkError(f"a record at chunk byte {body - 9} runs past its end")
            if op == _MESSAGE:
                if length < 22:
                    raise _BadChunkError(f"a message record at chunk byte {body - 9} is short")
                chan, seq, log, pub = unpack_message(raw, body)
                if chan in wanted and lo <= log < hi:
                    append((log, chan, seq, pub, body + 22, pos))
            elif op in (_CHANNEL, _SCHEMA):
                self._add_definition(op, memoryview(raw)[body:pos], topics, wanted)
        return out

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
        entry = (start, end, offset)
        if entry in self.health.bad_chunks:
            return
        span = f"{format_stamp(start, 3)}-{format_stamp(end, 3)} s"
        raise_limit = "raise the limit with --max-chunk-mb (max_chunk_bytes) if the log is genuine"
        if self.strict:
            skip = "run without --strict to skip it and use the rest"
            raise InputError(
                f"{self.path}: the {what} at byte {offset} (messages {span}) {reason}",
                hint=f"{raise_limit}, or {skip}"
                if oversize
                else f"{skip}; 'mcap doctor' lists the damage",
            )
        self.health.bad_chunks.append(entry)
        if oversize:
            self.health.oversized[offset] = (what, reason)
        logger.warning(
            "%s: skipped the %s at byte %d: it %s; messages %s are lost%s",
            self.path,
            what,
            offset,
            reason,
            span,
            f" ({raise_limit})" if oversize else "",
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

    def _stats_from_index(self) -> dict[int, ChannelStats] | None:
        """Per-channel stats from the message indexes, or ``None`` where some are missing."""
        if not self._chunk_indexes or not all(
            ci.message_index_offsets for ci in self._chunk_indexes
        ):
            return None
        stats = {cid: ChannelStats() for cid in self._channels}
        try:
            for ci in self._chunk_indexes:
                if ci.message_index_length > self.max_chunk_bytes:
                    return None
                first_at = min(ci.message_index_offsets.values())
                self._file.seek(first_at)
                block = self._file.read(ci.message_index_length)
                pos = 0
                while pos < len(block):
                    op, length = _RECORD.unpack_from(block, pos)
                    body = pos + 9
                    pos = body + length
                    if op != _MESSAGE_INDEX:
                        continue
                    chan, pairs_len = _INDEX_HEAD.unpack_from(block, body)
                    n = pairs_len // 16
                    if not n:
                        continue
                    pairs = struct.unpack_from(f"<{2 * n}Q", block, body + _INDEX_HEAD.size)
                    times = pairs[0::2]
                    st = stats.get(chan)
                    if st is None:
                        return None
                    st.count += n
                    lo, hi = min(times), max(times)
                    st.first_ns = lo if st.first_ns is None else min(st.first_ns, lo)
                    st.last_ns = hi if st.last_ns is None else max(st.last_ns, hi)
        except struct.error:
            logger.debug("%s: unreadable message index; counting messages instead", self.path)
            return None
        return stats

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
        cache: dict[str, _Decompressor] = {}
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
        self, f: BinaryIO, ci: ChunkIndex, cache: dict[str, _Decompressor]
    ) -> tuple[bytes, int]:
        """Read and decompress one indexed chunk (runs in the lookahead worker).

        The CRC is checked by the caller: decompression here and checksumming there both
        release the GIL, so they overlap on two cores.
        """
        if ci.uncompressed_size > self.max_chunk_bytes:
            raise _over(
                "declares (in the chunk index) an uncompressed size of",
                ci.uncompressed_size,
                self.max_chunk_bytes,
            )
        if ci.chunk_length > self._max_chunk_record:
            raise _over("is a chunk record of", ci.chunk_length, self.max_chunk_bytes)
        f.seek(ci.chunk_start_offset)
        record = f.read(ci.chunk_length)
        if len(record) != ci.chunk_length:
            raise _BadChunkError("lies past the end of the file")
        op, length = _RECORD.unpack_from(record)
        if op != _CHUNK or _RECORD.size + length > len(record):
            raise _BadChunkError("is not a chunk record where the index points")
        return self._inflate(memoryview(record)[_RECORD.size : _RECORD.size + length], cache)

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
            reason = str(failure) if isinstance(failure, _BadChunkError) else None
            if reason is None and not isinstance(failure, _DAMAGE):
                raise failure
            self._bad_chunk(
                ci.message_start_time,
                ci.message_end_time,
                ci.chunk_start_offset,
                reason or f"does not parse ({failure})",
                oversize=isinstance(failure, _OversizeError),
            )
            return None
        try:
            raw, crc = fetched.result()
            self._check_crc(raw, crc)
            msgs = self._parse_chunk(raw, topics, wanted, lo, hi)
        except _BadChunkError as exc:
            self._bad_chunk(
                ci.message_start_time,
                ci.message_end_time,
                ci.chunk_start_offset,
                str(exc),
                oversize=isinstance(exc, _OversizeError),
            )
            return None
        except _DAMAGE as exc:
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
        walker = _RecordWalker(f, self._size)
        last_good: int | None = None
        latest_chunk_end = -1
        cache: dict[str, _Decompressor] = {}
        for offset, op, length in walker:
            if op == _MESSAGE:
                if length < _MESSAGE_HEAD.size:
                    walker.broken_at = offset
                    break
                if length > self.max_chunk_bytes:
                    log = _MESSAGE_HEAD.unpack(f.read(_MESSAGE_HEAD.size))[2]
                    too_big = _over("is a message record of", length, self.max_chunk_bytes)
                    self._bad_chunk(log, log, offset, str(too_big), what="message", oversize=True)
                    continue
                body = f.read(length)
                chan, seq, log, pub = _MESSAGE_HEAD.unpack_from(body)
                last_good = log if last_good is None else max(last_good, log)
                if chan in wanted and lo <= log < hi:
                    yield [(log, chan, seq, pub, body[_MESSAGE_HEAD.size :])]
                elif chan not in self._channels:
                    self._unknown_channel(chan)
            elif op == _CHUNK:
                if length < _CHUNK_HEAD.size:
                    # Too short to say which times it held: charged to the last time read.
                    near = 0 if last_good is None else last_good
                    self._bad_chunk(
                        near,
                        near,
                        offset,
                        f"is {length} bytes long, too short for a chunk header "
                        f"({_CHUNK_HEAD.size} bytes)",
                    )
                    continue
                if length > self._max_chunk_record:
                    start, end = struct.unpack("<QQ", f.read(16))
                    too_big = _over("is a chunk record of", length, self.max_chunk_bytes)
                    self._bad_chunk(start, end, offset, str(too_big), oversize=True)
                    continue
                record = memoryview(f.read(length))
                start, end = _U64.unpack_from(record)[0], _U64.unpack_from(record, 8)[0]
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
                except _BadChunkError as exc:
                    self._bad_chunk(
                        start, end, offset, str(exc), oversize=isinstance(exc, _OversizeError)
                    )
                    continue
                except _DAMAGE as exc:
                    self._bad_chunk(start, end, offset, f"does not parse ({exc})")
                    continue
                last_good = end if last_good is None else max(last_good, end)
                if msgs:
                    yield [(log, chan, seq, pub, raw[a:b]) for log, chan, seq, pub, a, b in msgs]
            elif op in (_CHANNEL, _SCHEMA):
                try:
                    self._add_definition(op, f.read(length), topics, wanted)
                except _DAMAGE:
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

    def __init__(self, buf: bytes, msgs: list[_MessageEntry]) -> None:
        self.buf = buf
        self.msgs = msgs
        self.times = [m[0] for m in msgs]
        self.pos = 0


class _RecordWalker:
    """Iterate ``(offset, opcode, length)`` over the records of a file from after the magic.

    Before each item the file is positioned at the record body; the consumer may read any part
    of it. Stops at the footer (``found_footer``) or at the first record that cannot be whole
    (``broken_at``): a cut record header, a body running past the end of the file, or opcode 0.
    """

    def __init__(self, f: BinaryIO, size: int) -> None:
        self._f = f
        self._size = size
        self.broken_at: int | None = None
        self.found_footer = False

    def __iter__(self) -> Iterator[tuple[int, int, int]]:
        f = self._f
        size = self._size
        if size < len(MAGIC):
            return
        pos = len(MAGIC)
        f.seek(pos)
        while True:
            head = f.read(_RECORD.size)
            if len(head) < _RECORD.size:
                self.broken_at = pos
                return
            op, length = _RECORD.unpack(head)
            end = pos + _RECORD.size + length
            if op == 0 or end > size:
                self.broken_at = pos
                return
            if op == _FOOTER:
                self.found_footer = True
                return
            yield pos, op, length
            if self.broken_at is not None:
                return
            f.seek(end)
            pos = end


def _size_problem(got: int, more: bool, size: int) -> str | None:
    """Why ``got`` decompressed bytes (``more`` if there was still output) are not ``size``."""
    if got > size or more:
        return f"decompresses to more than the {size} bytes it declares"
    if got < size:
        return f"decompresses to {got} bytes, expected {size}"
    return None


def _zstd_problem(exc: Exception, size: int) -> str:
    if "too small" in str(exc):
        # libzstd's words for output that would pass the declared size.
        return f"decompresses to more than the {size} bytes it declares"
    return f"does not decompress (zstd: {exc})"


def _mb(n: int) -> str:
    return f"{n / _MB:g} MB"


def _chunk_key(ci: ChunkIndex) -> tuple[int, int]:
    return ci.message_start_time, ci.chunk_start_offset
