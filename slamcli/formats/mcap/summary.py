"""The summary section of an MCAP log: its footer, the schemas, channels, chunk indexes and
statistics it holds, and per-channel message statistics from the chunks' message indexes."""

from __future__ import annotations

import io
import logging
import struct
import zlib
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.records import Channel, ChunkIndex, Schema, Statistics

from slamcli.formats.mcap.chunks import BadChunkError, over_limit
from slamcli.formats.mcap.layout import (
    CHANNEL,
    CHUNK_INDEX,
    FOOTER,
    FOOTER_RECORD,
    INDEX_HEAD,
    MESSAGE_INDEX,
    RECORD,
    SCHEMA,
    STATISTICS,
    TAIL_SIZE,
)
from slamcli.formats.mcap.records import ChannelStats
from slamcli.formats.sniff import MCAP_MAGIC as MAGIC

logger = logging.getLogger(__name__)


@dataclass
class Summary:
    """The records of a summary section, in file order.

    Attributes:
        schemas: by schema id.
        channels: channel records (their schemas may come later in the section).
        chunk_indexes: one per chunk.
        statistics: the statistics record, or None.
    """

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: list[Channel] = field(default_factory=list)
    chunk_indexes: list[ChunkIndex] = field(default_factory=list)
    statistics: Statistics | None = None


def read_footer(f: BinaryIO, size: int) -> tuple[int, int] | None:
    """``(summary_start, summary_crc)`` from a well-formed footer of a ``size``-byte file, else
    ``None``."""
    if size < len(MAGIC) + TAIL_SIZE:
        return None
    f.seek(size - TAIL_SIZE)
    tail = f.read(TAIL_SIZE)
    if tail[-len(MAGIC) :] != MAGIC:
        return None
    op, length, summary_start, _, summary_crc = FOOTER_RECORD.unpack_from(tail)
    if op != FOOTER or length != FOOTER_RECORD.size - RECORD.size:
        return None
    if summary_start != 0 and not len(MAGIC) <= summary_start <= size - TAIL_SIZE:
        return None
    return summary_start, summary_crc


def read_summary(
    f: BinaryIO, size: int, summary_start: int, summary_crc: int, max_bytes: int
) -> Summary:
    """The summary section from ``summary_start`` to the footer of a ``size``-byte file.

    Raises:
        BadChunkError: the section fails its CRC or a record overruns it;
            :class:`~slamcli.formats.mcap.chunks.OversizeError` when it is longer than
            ``max_bytes``. The ``mcap`` record parsers raise on damaged bytes too.
    """
    summary = Summary()
    footer_at = size - TAIL_SIZE
    if footer_at - summary_start > max_bytes:
        raise over_limit("the summary section is", footer_at - summary_start, max_bytes)
    f.seek(summary_start)
    data = f.read(footer_at - summary_start)
    if summary_crc:
        # The summary CRC runs from the summary start through the footer, minus its CRC.
        footer_fields = f.read(FOOTER_RECORD.size - 4)
        crc = zlib.crc32(footer_fields, zlib.crc32(data))
        if crc != summary_crc:
            raise BadChunkError(f"summary CRC {crc:08x} != {summary_crc:08x}")
    stream = ReadDataStream(io.BytesIO(data))
    while stream.count < len(data):
        op = stream.read1()
        length = stream.read8()
        body_start = stream.count
        if op == SCHEMA:
            schema = Schema.read(stream)
            summary.schemas[schema.id] = schema
        elif op == CHANNEL:
            summary.channels.append(Channel.read(stream))
        elif op == CHUNK_INDEX:
            summary.chunk_indexes.append(ChunkIndex.read(stream))
        elif op == STATISTICS:
            summary.statistics = Statistics.read(stream)
        rest = length - (stream.count - body_start)
        if rest < 0:
            raise BadChunkError(f"record with opcode {op:#04x} overruns its length")
        if rest > len(data) - stream.count:
            raise BadChunkError(
                f"record with opcode {op:#04x} declares {length} bytes, more than the "
                f"summary section holds"
            )
        stream.read(rest)
    return summary


def stats_from_index(
    f: BinaryIO,
    chunk_indexes: list[ChunkIndex],
    channel_ids: Collection[int],
    max_bytes: int,
    path: Path,
) -> dict[int, ChannelStats] | None:
    """Per-channel stats from the message indexes, or ``None`` where some are missing, longer
    than ``max_bytes``, unreadable, or name a channel not in ``channel_ids``."""
    if not chunk_indexes or not all(ci.message_index_offsets for ci in chunk_indexes):
        return None
    stats = {cid: ChannelStats() for cid in channel_ids}
    try:
        for ci in chunk_indexes:
            if ci.message_index_length > max_bytes:
                return None
            first_at = min(ci.message_index_offsets.values())
            f.seek(first_at)
            block = f.read(ci.message_index_length)
            pos = 0
            while pos < len(block):
                op, length = RECORD.unpack_from(block, pos)
                body = pos + 9
                pos = body + length
                if op != MESSAGE_INDEX:
                    continue
                chan, pairs_len = INDEX_HEAD.unpack_from(block, body)
                n = pairs_len // 16
                if not n:
                    continue
                pairs = struct.unpack_from(f"<{2 * n}Q", block, body + INDEX_HEAD.size)
                times = pairs[0::2]
                st = stats.get(chan)
                if st is None:
                    return None
                st.count += n
                lo, hi = min(times), max(times)
                st.first_ns = lo if st.first_ns is None else min(st.first_ns, lo)
                st.last_ns = hi if st.last_ns is None else max(st.last_ns, hi)
    except struct.error:
        logger.debug("%s: unreadable message index; counting messages instead", path)
        return None
    return stats
