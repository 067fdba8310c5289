"""ROS 1 bag files (format 2.0): their records, read front to back without the bag's index.

A bag is the line ``#ROSBAG V2.0`` and then records. Each record is ``header_len`` (uint32),
a header of fields (each a uint32 length and ``name=value``; the one-byte ``op`` field names
the record), ``data_len`` (uint32) and the data:

- 0x03 bag header: where the index starts (``index_pos``), the connection and chunk counts;
- 0x05 chunk: ``compression`` (``none``, ``bz2`` or ``lz4``) and the uncompressed ``size``;
  its data holds connection and message data records;
- 0x04 index data: one 12-byte entry (time, offset in the chunk) per message of the chunk
  before it;
- 0x06 chunk info, 0x07 connection (topic, type, md5sum, message definition), 0x02 message
  data (connection id, receive ``time``; the data is the serialised message).

:class:`BagWalker` reads the records from the start of the file, for bags whose index cannot
be trusted or is missing: it stops where a record is cut short (a truncated bag) and raises
:class:`~slamcli.errors.FormatError` where the bytes are not bag records at all. Chunks are
decompressed within a size limit, as the MCAP reader's are. Times are int64 nanoseconds.
"""

from __future__ import annotations

import bz2
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from slamcli.errors import FormatError, InputError
from slamcli.formats.mcap.chunks import BadChunkError, Decompressor, decompressor, over_limit
from slamcli.formats.sniff import ROSBAG_MAGIC

MSG_DATA = 0x02
BAG_HEADER = 0x03
INDEX_DATA = 0x04
CHUNK = 0x05
CHUNK_INFO = 0x06
CONNECTION = 0x07
RECORD_NAMES = {
    MSG_DATA: "message data",
    BAG_HEADER: "bag header",
    INDEX_DATA: "index data",
    CHUNK: "chunk",
    CHUNK_INFO: "chunk info",
    CONNECTION: "connection",
}
COMPRESSIONS = ("none", "bz2", "lz4")
"""The chunk compressions of ROS 1 bags."""
INDEX_ENTRY_BYTES = 12
"""An index data entry (version 1): time (sec, nsec) and the message's offset in its chunk."""
MAX_HEADER_BYTES = 1 << 20
"""Longest record header read; real ones are tens of bytes (a topic name at most)."""

_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_TIME = struct.Struct("<II")
_ZERO_PROBE = 64
"""Bytes looked at to tell a zero-filled tail (a recording cut short) from foreign data."""


class RecordError(Exception):
    """Bytes that are not a well-formed bag record; the message says why."""


def parse_fields(buf: bytes, declared: int | None = None) -> dict[str, bytes]:
    """The ``name=value`` fields of a record header or a connection header.

    Args:
        buf: the header bytes.
        declared: the header's declared length when ``buf`` is only its start (a truncated
            file): a last field cut short by the end of ``buf`` is then left out, but one that
            runs past the declared length is still an error.

    Raises:
        RecordError: a field length runs past the header, or a field has no ``=``.
    """
    fields: dict[str, bytes] = {}
    pos, n = 0, len(buf)
    limit = n if declared is None else declared
    while pos < n:
        if pos + 4 > limit:
            raise RecordError(f"{limit - pos} stray bytes end the header (a field needs 4)")
        if pos + 4 > n:
            break
        size = _U32.unpack_from(buf, pos)[0]
        pos += 4
        if pos + size > limit:
            raise RecordError(f"a field of {size} bytes runs past the {limit}-byte header")
        if pos + size > n:
            break
        name, sep, value = buf[pos : pos + size].partition(b"=")
        if not sep:
            raise RecordError(f"a header field ({size} bytes) has no '='")
        fields[name.decode("utf-8", "replace")] = value
        pos += size
    return fields


def parse_header(buf: bytes) -> tuple[int, dict[str, bytes]]:
    """``(op, fields)`` of a record header.

    Raises:
        RecordError: malformed fields, no one-byte ``op`` field, or an unknown ``op``.
    """
    fields = parse_fields(buf)
    op = fields.get("op")
    if op is None or len(op) != 1:
        raise RecordError("the header has no one-byte 'op' field")
    if op[0] not in RECORD_NAMES:
        raise RecordError(f"op 0x{op[0]:02x} is not a bag record")
    return op[0], fields


def field_u32(fields: dict[str, bytes], name: str) -> int:
    """A uint32 header field (RecordError when missing or of another size)."""
    return int(_unpack(fields, name, _U32)[0])


def field_u64(fields: dict[str, bytes], name: str) -> int:
    """A uint64 header field (RecordError when missing or of another size)."""
    return int(_unpack(fields, name, _U64)[0])


def field_time(fields: dict[str, bytes], name: str) -> int:
    """A ROS time header field (uint32 seconds, uint32 nanoseconds) in int64 nanoseconds."""
    sec, nsec = _unpack(fields, name, _TIME)
    return int(sec) * 1_000_000_000 + int(nsec)


def field_str(fields: dict[str, bytes], name: str) -> str:
    """A text header field (RecordError when missing or not UTF-8)."""
    if name not in fields:
        raise RecordError(f"the header has no {name!r} field")
    try:
        return fields[name].decode("utf-8")
    except UnicodeDecodeError:
        raise RecordError(f"the {name!r} field is not UTF-8 text") from None


def _unpack(fields: dict[str, bytes], name: str, fmt: struct.Struct) -> tuple[int, ...]:
    value = fields.get(name)
    if value is None:
        raise RecordError(f"the header has no {name!r} field")
    if len(value) != fmt.size:
        raise RecordError(f"the {name!r} field has {len(value)} bytes, expected {fmt.size}")
    return tuple(fmt.unpack(value))


def normalize_topic(name: str) -> str:
    """A topic name without repeated or trailing slashes (``//a/b/`` -> ``/a/b``)."""
    lead = "/" if name.startswith("/") else ""
    return lead + "/".join(part for part in name.split("/") if part)


RENAMED_TYPES = {"roslib/Header": "std_msgs/Header"}
"""ROS 1 message types that ROS renamed, by their old names: bags recorded before ROS
Diamondback (2011) define ``Header`` as ``roslib/Header``; the layout is the same."""


def current_definition(text: str) -> str:
    """A ROS 1 message definition with renamed types (:data:`RENAMED_TYPES`) under their
    current names, so that ``Header`` fields resolve to the block that defines them."""
    for old, new in RENAMED_TYPES.items():
        text = text.replace(f"MSG: {old}\n", f"MSG: {new}\n").replace(f"{old} ", f"{new} ")
    return text


@dataclass(frozen=True)
class BagConnection:
    """A connection record: one publisher's topic with its type and message definition."""

    conn: int
    topic: str
    msgtype: str
    definition: str
    md5sum: str = ""
    callerid: str = ""


def read_connection(fields: dict[str, bytes], data: bytes) -> BagConnection:
    """A connection from its record header and its data (the connection header).

    Raises:
        RecordError: a field is missing or malformed.
    """
    header = parse_fields(data)
    return BagConnection(
        conn=field_u32(fields, "conn"),
        topic=normalize_topic(field_str(fields, "topic")),
        msgtype=field_str(header, "type"),
        definition=field_str(header, "message_definition"),
        md5sum=field_str(header, "md5sum") if "md5sum" in header else "",
        callerid=field_str(header, "callerid") if "callerid" in header else "",
    )


def record_at(buf: bytes, pos: int) -> tuple[int, dict[str, bytes], int, int]:
    """``(op, fields, data start, data end)`` of the record at ``pos`` of an uncompressed chunk.

    Raises:
        RecordError: the record is malformed or runs past the end of ``buf``.
    """
    n = len(buf)
    if pos + 4 > n:
        raise RecordError(f"a record at chunk byte {pos} is cut short")
    header_len = _U32.unpack_from(buf, pos)[0]
    start = pos + 4
    if start + header_len + 4 > n:
        raise RecordError(f"the header of the record at chunk byte {pos} runs past the chunk")
    op, fields = parse_header(buf[start : start + header_len])
    data_len = _U32.unpack_from(buf, start + header_len)[0]
    a = start + header_len + 4
    if a + data_len > n:
        raise RecordError(f"the data of the record at chunk byte {pos} runs past the chunk")
    return op, fields, a, a + data_len


def chunk_records(buf: bytes) -> Iterator[tuple[int, int, dict[str, bytes], int, int]]:
    """``(offset, op, fields, data start, data end)`` of each record of an uncompressed chunk.

    Raises:
        RecordError: at the first malformed record (the records before it have been yielded).
    """
    pos = 0
    while pos < len(buf):
        op, fields, a, b = record_at(buf, pos)
        yield pos, op, fields, a, b
        pos = b


def inflate(
    compression: str,
    data: bytes,
    size: int,
    *,
    path: Path,
    offset: int,
    cache: dict[str, Decompressor],
    partial: bool = False,
) -> bytes:
    """The uncompressed records of a chunk's data.

    Args:
        compression: the chunk's ``compression`` field.
        data: its data, or (``partial``) the part of it a truncated file holds.
        size: the uncompressed size the chunk declares (already checked against the limit).
        path, offset: the bag and the chunk's byte offset, for messages.
        cache: decompressors of this pass.
        partial: return what the data decompresses to so far instead of checking its size.

    Raises:
        BadChunkError: the data does not decompress to ``size`` bytes.
        InputError: ``lz4`` without the ``lz4`` package. FormatError: a compression bags do
            not use.
    """
    if compression not in COMPRESSIONS:
        raise FormatError(
            path,
            f"the chunk at byte {offset} has compression {compression!r}; expected one of "
            f"{', '.join(COMPRESSIONS)}",
            hint="the file is damaged or not a ROS 1 bag",
        )
    if compression == "lz4":
        try:
            import lz4.frame  # noqa: F401  (only whether it is there)
        except ImportError:
            raise InputError(
                f"{path}: the chunk at byte {offset} is lz4-compressed, and reading it needs "
                "the 'lz4' package",
                hint="pip install lz4, or recompress the bag with 'rosbag compress --bz2'",
            ) from None
    if partial:
        return _inflate_partial(compression, data, size)
    if compression == "bz2":
        dec = bz2.BZ2Decompressor()
        try:
            out = dec.decompress(data, max_length=size + 1)
        except (OSError, EOFError, ValueError) as exc:
            raise BadChunkError(f"does not decompress (bz2: {exc})") from None
        if len(out) != size or not dec.eof:
            got = f"more than {size}" if len(out) > size else str(len(out))
            raise BadChunkError(f"decompresses to {got} bytes, expected {size}")
        return out
    # decompressor() names MCAP's "" for uncompressed data; its checks are the same.
    fn = decompressor("" if compression == "none" else compression, cache, path)
    return fn(memoryview(data), size)


def _inflate_partial(compression: str, data: bytes, size: int) -> bytes:
    """What the start of a chunk's data decompresses to (at most ``size`` bytes)."""
    try:
        if compression == "none":
            return bytes(data[:size])
        if compression == "bz2":
            return bz2.BZ2Decompressor().decompress(data, max_length=size)
        import lz4.frame

        out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size)
        return bytes(out)
    except (OSError, EOFError, ValueError, RuntimeError):
        return b""


@dataclass(frozen=True)
class TopRecord:
    """A record of the top level of a bag (not inside a chunk), before its data is read.

    ``complete`` is False for the last record of a truncated bag: the file ends inside its
    data, of which ``available`` bytes are there.
    """

    offset: int
    op: int
    fields: dict[str, bytes]
    data_start: int
    data_len: int
    available: int
    complete: bool = True


def read_top_record(f: BinaryIO, pos: int, size: int, path: Path) -> TopRecord | None:
    """The top-level record at byte ``pos`` of a ``size``-byte bag; None where the file ends
    inside its header (or holds only zeros from there: a recording cut short).

    Raises:
        FormatError: the bytes at ``pos`` are not a bag record.
    """
    f.seek(pos)
    head = f.read(4)
    if len(head) < 4:
        return None
    header_len = _U32.unpack(head)[0]
    if header_len == 0 and not f.read(_ZERO_PROBE).strip(b"\0"):
        return None
    if header_len > MAX_HEADER_BYTES:
        raise _not_a_record(path, pos, f"it declares a {header_len}-byte header")
    header = f.read(header_len)
    if len(header) < header_len:
        try:
            parse_fields(header, declared=header_len)
        except RecordError as exc:
            raise _not_a_record(path, pos, str(exc)) from None
        return None
    try:
        op, fields = parse_header(header)
    except RecordError as exc:
        raise _not_a_record(path, pos, str(exc)) from None
    raw_len = f.read(4)
    if len(raw_len) < 4:
        return None
    data_len = _U32.unpack(raw_len)[0]
    start = pos + 8 + header_len
    available = max(0, min(data_len, size - start))
    return TopRecord(pos, op, fields, start, data_len, available, available == data_len)


def _not_a_record(path: Path, pos: int, why: str) -> FormatError:
    return FormatError(
        path,
        f"the bytes at byte {pos} are not a bag record ({why}); expected a record header "
        "length and name=value fields",
        hint="the file is damaged or not a ROS 1 bag (format 2.0)",
    )


class BagWalker:
    """The top-level records of a bag from just after the magic line to the end of the file.

    Index data records are stepped over by their entry count (12 bytes each) where their
    declared length disagrees and the count leads to the next record; :attr:`notes` says so.
    Iteration stops at a record the file ends inside; :attr:`broken_at` is then its offset.

    Raises:
        FormatError: (while iterating) bytes that are not bag records.
    """

    def __init__(self, f: BinaryIO, size: int, path: Path) -> None:
        self.f = f
        self.size = size
        self.path = path
        self.broken_at: int | None = None
        self.notes: list[str] = []

    def __iter__(self) -> Iterator[TopRecord]:
        pos = len(ROSBAG_MAGIC)
        while pos < self.size:
            rec = read_top_record(self.f, pos, self.size, self.path)
            if rec is None:
                self.broken_at = pos
                return
            if rec.op == INDEX_DATA and rec.complete:
                rec = self._index_entries(rec)
            yield rec
            if not rec.complete:
                self.broken_at = pos
                return
            pos = rec.data_start + rec.data_len

    def _index_entries(self, rec: TopRecord) -> TopRecord:
        """The index data record with its length taken from its entry count where the two
        disagree and the count is right (the next record starts there)."""
        try:
            version, count = field_u32(rec.fields, "ver"), field_u32(rec.fields, "count")
        except RecordError:
            return rec
        held = count * INDEX_ENTRY_BYTES
        if version != 1 or held == rec.data_len or rec.data_start + held > self.size:
            return rec
        end = rec.data_start + held
        if end < self.size:
            try:
                if read_top_record(self.f, end, self.size, self.path) is None:
                    return rec
            except FormatError:
                return rec
        if not self.notes:
            per = f"{rec.data_len / count:g} bytes per entry" if count else f"{rec.data_len} bytes"
            self.notes.append(
                f"index data records declare {per} but hold {INDEX_ENTRY_BYTES} "
                f"(the first at byte {rec.offset})"
            )
        return TopRecord(rec.offset, rec.op, rec.fields, rec.data_start, held, held)

    def read(self, rec: TopRecord) -> bytes:
        """The data of a record (what the file holds of it, for the last of a truncated bag)."""
        self.f.seek(rec.data_start)
        return self.f.read(rec.available)


def check_sizes(rec: TopRecord, max_chunk_bytes: int) -> None:
    """Refuse a chunk or message data record larger than the limit, before it is read.

    Raises:
        OversizeError: the record's data, or a chunk's declared uncompressed size, is larger
            than ``max_chunk_bytes`` (plus a compression allowance for chunk data).
        RecordError: a chunk without a readable ``size`` field.
    """
    if rec.op == CHUNK:
        size = field_u32(rec.fields, "size")
        if size > max_chunk_bytes:
            raise over_limit("declares an uncompressed size of", size, max_chunk_bytes)
        # bz2 and lz4 expand incompressible data by a little; allow for it as the MCAP reader.
        if rec.data_len > max_chunk_bytes + max_chunk_bytes // 128 + 4096:
            raise over_limit("is a chunk record of", rec.data_len, max_chunk_bytes)
    elif rec.op == MSG_DATA and rec.data_len > max_chunk_bytes:
        raise over_limit("is a message record of", rec.data_len, max_chunk_bytes)


__all__ = [
    "BAG_HEADER",
    "CHUNK",
    "CHUNK_INFO",
    "COMPRESSIONS",
    "CONNECTION",
    "INDEX_DATA",
    "MSG_DATA",
    "RECORD_NAMES",
    "RENAMED_TYPES",
    "BagConnection",
    "BagWalker",
    "RecordError",
    "TopRecord",
    "check_sizes",
    "chunk_records",
    "current_definition",
    "field_str",
    "field_time",
    "field_u32",
    "field_u64",
    "inflate",
    "normalize_topic",
    "parse_fields",
    "parse_header",
    "read_connection",
    "read_top_record",
    "record_at",
]
