"""The MCAP binary layout as the reader meets it: opcodes, record structs, and a walk over a
file's records that stops at the first one that cannot be whole (a log cut short)."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from typing import BinaryIO

from mcap.opcode import Opcode

from slamcli.formats.sniff import MCAP_MAGIC as MAGIC

FOOTER = int(Opcode.FOOTER)
SCHEMA = int(Opcode.SCHEMA)
CHANNEL = int(Opcode.CHANNEL)
MESSAGE = int(Opcode.MESSAGE)
CHUNK = int(Opcode.CHUNK)
MESSAGE_INDEX = int(Opcode.MESSAGE_INDEX)
CHUNK_INDEX = int(Opcode.CHUNK_INDEX)
STATISTICS = int(Opcode.STATISTICS)

RECORD = struct.Struct("<BQ")
"""Record prefix: opcode, body length."""
MESSAGE_HEAD = struct.Struct("<HIQQ")
"""Message body prefix: channel id, sequence, log time, publish time."""
CHUNK_HEAD = struct.Struct("<QQQII")
"""Chunk body prefix: start time, end time, uncompressed size, CRC, compression name length."""
U64 = struct.Struct("<Q")
INDEX_HEAD = struct.Struct("<HI")
"""Message index body prefix: channel id, byte length of the (time, offset) pairs."""
FOOTER_RECORD = struct.Struct("<BQQQI")
TAIL_SIZE = FOOTER_RECORD.size + len(MAGIC)
"""The footer record and the closing magic."""


class RecordWalker:
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
            head = f.read(RECORD.size)
            if len(head) < RECORD.size:
                self.broken_at = pos
                return
            op, length = RECORD.unpack(head)
            end = pos + RECORD.size + length
            if op == 0 or end > size:
                self.broken_at = pos
                return
            if op == FOOTER:
                self.found_footer = True
                return
            yield pos, op, length
            if self.broken_at is not None:
                return
            f.seek(end)
            pos = end


def find_break(f: BinaryIO, size: int) -> tuple[int, int | None]:
    """Byte offset of the first broken record of a ``size``-byte file (``size`` when there is
    none), and the last log time (ns) before it."""
    walker = RecordWalker(f, size)
    last: int | None = None
    for _, op, length in walker:
        if op == CHUNK and length >= 16:
            end = U64.unpack_from(f.read(16), 8)[0]
            last = end if last is None else max(last, end)
        elif op == MESSAGE and length >= MESSAGE_HEAD.size:
            log = MESSAGE_HEAD.unpack(f.read(MESSAGE_HEAD.size))[2]
            last = log if last is None else max(last, log)
    return (size if walker.broken_at is None else walker.broken_at), last
