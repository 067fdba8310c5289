"""Chunk bytes: bounded decompression, the CRC, and the records inside a chunk.

Memory and time are bounded on hostile input: a chunk whose declared uncompressed size passes
the reader's ``max_chunk_bytes`` is refused before it is read, decompression runs in bounded
steps that stop as soon as the output passes the declared size, and a chunk may hold at most one
record per :data:`BYTES_PER_RECORD` bytes of the limit.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO, Protocol

from mcap.exceptions import McapError
from mcap.records import ChunkIndex

from slamcli.errors import InputError
from slamcli.formats.mcap.layout import (
    CHANNEL,
    CHUNK,
    CHUNK_HEAD,
    MESSAGE,
    MESSAGE_HEAD,
    RECORD,
    SCHEMA,
    U64,
)

MessageEntry = tuple[int, int, int, int, int, int]
"""(log time, channel id, sequence, publish time, data start, data end) inside a chunk."""

DAMAGE = (McapError, struct.error, ValueError, RuntimeError, OSError)
"""What parsing damaged bytes raises: mcap and struct errors, bad UTF-8, lz4's RuntimeError."""
_MB = 2**20
_INFLATE_STEP = 16 * _MB
"""Most output bytes asked of a streaming decompressor per call."""
BYTES_PER_RECORD = 256
"""A chunk may hold one record per this many bytes of ``max_chunk_bytes``: each message costs
about 200 bytes of bookkeeping, and each record parsing time, whatever its own size."""


class Decompressor(Protocol):
    def __call__(self, data: memoryview, uncompressed_size: int) -> bytes: ...


class BadChunkError(Exception):
    """A chunk's bytes are unusable; the message says why."""


class OversizeError(BadChunkError):
    """A chunk or message is larger than ``max_chunk_bytes`` allows; the message says how."""


def over_limit(what: str, size: int, limit: int) -> OversizeError:
    """The error for ``what`` (``"is a chunk record of"``) ``size`` bytes, past ``limit``."""
    return OversizeError(f"{what} {size} bytes ({size / _MB:.1f} MB), over the {mb(limit)} limit")


def mb(n: int) -> str:
    """``n`` bytes in MB (2^20 B), for messages."""
    return f"{n / _MB:g} MB"


def decompressor(compression: str, cache: dict[str, Decompressor], path: Path) -> Decompressor:
    """A bounded decompression function, cached per pass: a zstd context is not thread-safe.

    Each one returns exactly ``uncompressed_size`` bytes or raises :class:`BadChunkError`,
    and never produces more than one byte past that size, whatever the data claims.
    """
    known = cache.get(compression)
    if known is not None:
        return known
    if compression == "":

        def fn(data: memoryview, uncompressed_size: int) -> bytes:
            problem = _size_problem(len(data), False, uncompressed_size)
            if problem is not None:
                raise BadChunkError(problem)
            return bytes(data)

    elif compression == "zstd":
        try:
            import zstandard
        except ImportError:
            raise InputError(
                f"{path}: zstd-compressed chunks need the 'zstandard' package",
                hint="pip install zstandard",
            ) from None
        dctx = zstandard.ZstdDecompressor()

        def fn(data: memoryview, uncompressed_size: int) -> bytes:
            try:
                frame_size = zstandard.frame_content_size(data)
            except zstandard.ZstdError as exc:
                raise BadChunkError(f"does not decompress (zstd: {exc})") from None
            if frame_size == uncompressed_size:
                # The usual case: one frame whose header agrees with the chunk. decompress()
                # sizes its output from that header, so it can write no more than declared.
                try:
                    whole = dctx.decompress(data, max_output_size=uncompressed_size)
                except zstandard.ZstdError as exc:
                    raise BadChunkError(_zstd_problem(exc, uncompressed_size)) from None
                problem = _size_problem(len(whole), False, uncompressed_size)
                if problem is not None:
                    del whole
                    raise BadChunkError(problem)
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
                raise BadChunkError(problem)
            return bytes(out)

    elif compression == "lz4":
        try:
            import lz4.frame
        except ImportError:
            raise InputError(
                f"{path}: lz4-compressed chunks need the 'lz4' package",
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
                raise BadChunkError(problem)
            return b"".join(pieces)

    else:
        raise BadChunkError(f"has unknown compression {compression!r} (expected zstd, lz4)")
    cache[compression] = fn
    return fn


def read_chunk_body(
    f: BinaryIO, ci: ChunkIndex, max_chunk_bytes: int, max_record: int
) -> memoryview:
    """The body of the chunk record a chunk index points at, for :func:`inflate`.

    Raises:
        BadChunkError: no chunk record lies there; :class:`OversizeError` when the index
            declares more than ``max_chunk_bytes`` uncompressed bytes or a record longer than
            ``max_record`` bytes.
    """
    if ci.uncompressed_size > max_chunk_bytes:
        raise over_limit(
            "declares (in the chunk index) an uncompressed size of",
            ci.uncompressed_size,
            max_chunk_bytes,
        )
    if ci.chunk_length > max_record:
        raise over_limit("is a chunk record of", ci.chunk_length, max_chunk_bytes)
    f.seek(ci.chunk_start_offset)
    record = f.read(ci.chunk_length)
    if len(record) != ci.chunk_length:
        raise BadChunkError("lies past the end of the file")
    op, length = RECORD.unpack_from(record)
    if op != CHUNK or RECORD.size + length > len(record):
        raise BadChunkError("is not a chunk record where the index points")
    return memoryview(record)[RECORD.size : RECORD.size + length]


def inflate(
    body: memoryview, cache: dict[str, Decompressor], max_chunk_bytes: int, path: Path
) -> tuple[bytes, int]:
    """Uncompressed records of a chunk record body, and the CRC they should have.

    Raises:
        BadChunkError: the body is damaged; :class:`OversizeError` when it declares more than
            ``max_chunk_bytes`` uncompressed bytes.
        InputError: its compression needs a package that is not installed (``path`` names the log).
    """
    if len(body) < CHUNK_HEAD.size:
        raise BadChunkError(
            f"is {len(body)} bytes long, too short for a chunk header ({CHUNK_HEAD.size})"
        )
    _, _, size, crc, name_len = CHUNK_HEAD.unpack_from(body)
    if size > max_chunk_bytes:
        raise over_limit("declares an uncompressed size of", size, max_chunk_bytes)
    at = CHUNK_HEAD.size
    if at + name_len + U64.size > len(body):
        raise BadChunkError(f"its compression name ({name_len} bytes) runs past the record")
    try:
        compression = str(body[at : at + name_len], "utf-8")
    except UnicodeDecodeError:
        raise BadChunkError(
            f"its compression name {bytes(body[at : at + name_len])!r} is not UTF-8 "
            "(expected zstd, lz4 or empty)"
        ) from None
    at += name_len
    data_len = U64.unpack_from(body, at)[0]
    at += U64.size
    if at + data_len > len(body):
        raise BadChunkError(
            f"its data ({data_len} bytes) runs past the end of the record ({len(body)} bytes)"
        )
    raw = decompressor(compression, cache, path)(body[at : at + data_len], size)
    return raw, crc


def parse_chunk(
    raw: bytes,
    wanted: set[int],
    lo: int,
    hi: int,
    max_chunk_bytes: int,
    on_definition: Callable[[int, memoryview], None],
) -> list[MessageEntry]:
    """Messages of a chunk on the ``wanted`` channel ids with a log time in ``[lo, hi)`` (ns),
    in file order.

    Each Schema or Channel record met is handed to ``on_definition`` (opcode, body) before the
    records after it are parsed, so a channel it adds to ``wanted`` counts from there on.

    Raises:
        BadChunkError: the records are damaged; :class:`OversizeError` when there are more
            than ``max_chunk_bytes`` allows (:data:`BYTES_PER_RECORD`).
    """
    out: list[MessageEntry] = []
    append = out.append
    unpack_record = RECORD.unpack_from
    unpack_message = MESSAGE_HEAD.unpack_from
    pos = 0
    n = len(raw)
    left = max_chunk_bytes // BYTES_PER_RECORD
    while pos < n:
        left -= 1
        if left < 0:
            cap = max_chunk_bytes // BYTES_PER_RECORD
            raise OversizeError(
                f"holds more than {cap} records, the most the {mb(max_chunk_bytes)} "
                f"limit allows (one per {BYTES_PER_RECORD} bytes)"
            )
        if pos + 9 > n:
            raise BadChunkError(
                f"its records end in {n - pos} stray bytes at chunk byte {pos} "
                "(expected a 9-byte record header)"
            )
        op, length = unpack_record(raw, pos)
        if op == 0:
            # Opcode 0 is never written; a run of them is zeroed or foreign data.
            raise BadChunkError(f"holds opcode 0x00 at chunk byte {pos}, not an MCAP record")
        body = pos + 9
        pos = body + length
        if pos > n:
            raise BadChunkError(f"a record at chunk byte {body - 9} runs past its end")
        if op == MESSAGE:
            if length < 22:
                raise BadChunkError(f"a message record at chunk byte {body - 9} is short")
            chan, seq, log, pub = unpack_message(raw, body)
            if chan in wanted and lo <= log < hi:
                append((log, chan, seq, pub, body + 22, pos))
        elif op in (CHANNEL, SCHEMA):
            on_definition(op, memoryview(raw)[body:pos])
    return out


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
