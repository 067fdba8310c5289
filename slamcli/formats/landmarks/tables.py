"""Text tables of numbers, as the landmark logs hold them: one record a line.

Fields are whitespace or comma separated, ``#`` lines and blank lines are comments, CRLF and a
BOM are allowed, and a first line equal to the column names is a header. A stamped table's
first column is a time in seconds, converted exactly to int64 nanoseconds. Tables are parsed in
bulk with numpy and fall back to a line-by-line parse only to name the first bad line.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import FormatError
from slamcli.formats.text import format_stamp, iter_data_lines, parse_floats, parse_stamp_ns

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

MAX_TABLE_VALUE = 1e9
"""Largest magnitude of a table value (metres, m/s, radians, ids): far beyond any real
reading, and small enough that the filters' squares and products stay finite."""

_POW10 = np.array([10**k for k in range(19)], dtype=np.int64)


@dataclass(frozen=True)
class Table:
    """The data lines of one text table.

    Attributes:
        path: the file.
        lines: (N,) int64 1-based line numbers, for messages.
        stamps_ns: (N,) int64 nanoseconds of the first column (empty for unstamped tables).
        values: (N, K) float64 the other columns (all columns for unstamped tables).
    """

    path: Path
    lines: I64
    stamps_ns: I64
    values: F64

    def __len__(self) -> int:
        return int(self.lines.shape[0])

    def where(self, k: int) -> str:
        """``"Robot1_Odometry.dat:12"``: where row ``k`` was read."""
        return f"{self.path.name}:{int(self.lines[k])}"

    def integers(self, col: int, what: str) -> I64:
        """Column ``col`` of :attr:`values` as int64; a non-integer is a FormatError."""
        v = self.values[:, col]
        bad = np.flatnonzero(v != np.round(v))
        if bad.size:
            k = int(bad[0])
            raise FormatError(self.path, f"{what} {v[k]:g} is not an integer", int(self.lines[k]))
        return v.astype(np.int64)

    def check_time_order(self) -> None:
        """Stamps must not decrease (repeats are allowed)."""
        back = np.flatnonzero(np.diff(self.stamps_ns) < 0)
        if back.size:
            k = int(back[0]) + 1
            raise FormatError(
                self.path,
                f"time goes backwards from {seconds_text(int(self.stamps_ns[k - 1]))} to "
                f"{seconds_text(int(self.stamps_ns[k]))}",
                int(self.lines[k]),
                hint="the rows of this file must be sorted by time",
            )


def read_table(
    path: str | Path,
    columns: tuple[str, ...],
    *,
    stamped: bool = True,
    delimiter: str | None = None,
) -> Table:
    """Read a table of numbers: ``#`` comments and blank lines skipped, CRLF and BOM allowed.

    Args:
        path: the file.
        columns: the column names, for messages; a first data line equal to them is a header
            and skipped (CSV files).
        stamped: the first column is a time in seconds, converted exactly to int64 ns.
        delimiter: None for whitespace, else e.g. ``","``.

    Raises:
        InputError: the file is missing or unreadable.
        FormatError: a wrong field count, a non-number, a non-finite value or one beyond
            :data:`MAX_TABLE_VALUE` (names file:line).
    """
    p = Path(path)
    table = _read_table_fast(p, columns, stamped, delimiter) or _read_table_slow(
        p, columns, stamped, delimiter
    )
    rows, cols = np.nonzero(np.abs(table.values) > MAX_TABLE_VALUE)
    if rows.size:
        k, c = int(rows[0]), int(cols[0])
        name = columns[c + 1 if stamped else c]
        raise FormatError(
            p,
            f"column {c + (2 if stamped else 1)} ({name}): {table.values[k, c]:g} is out of "
            f"range (at most {MAX_TABLE_VALUE:g} in magnitude)",
            int(table.lines[k]),
        )
    return table


FAST_PARSE_MAX_BYTES = 64 << 20
"""Largest table parsed in bulk (64 MiB; the MRCLAM tables are 3 MB): the bulk parse holds the
whole text several times over, so a larger file, or one long damaged line, is read line by
line, where a line is bounded (:data:`~slamcli.formats.text.MAX_LINE_BYTES`)."""


def _read_table_fast(
    path: Path, columns: tuple[str, ...], stamped: bool, delimiter: str | None
) -> Table | None:
    """Bulk parse; None when anything is unusual (the slow parse then names the bad line).

    Fields are counted per line on the bytes (token starts, or delimiters), so that the one
    ``split`` of the whole text can be trusted to line up with the columns.
    """
    try:
        if path.stat().st_size > FAST_PARSE_MAX_BYTES:
            return None
        with path.open("r", encoding="utf-8-sig", newline=None) as fh:
            text = fh.read()
    except (OSError, UnicodeDecodeError):
        return None
    stripped = list(map(str.strip, text.split("\n")))
    numbers = [i for i, line in enumerate(stripped, start=1) if line and line[0] != "#"]
    data = [stripped[i - 1] for i in numbers]
    if data and [f.strip() for f in data[0].split(delimiter)] == list(columns):
        numbers, data = numbers[1:], data[1:]
    n, ncol = len(data), len(columns)
    joined = "\n".join(data)
    if n == 0 or not joined.isascii():
        return None
    b = np.frombuffer(joined.encode("ascii"), dtype=np.uint8)
    # Every data line is non-empty, so each segment of reduceat is one line's bytes.
    line_start = np.concatenate([[0], np.flatnonzero(b == 10) + 1])
    if delimiter is None:
        if np.any((b < 32) & (b != 9) & (b != 10)):
            return None
        sep = (b == 32) | (b == 9) | (b == 10)
        start = ~sep
        start[1:] &= sep[:-1]
        counts = np.add.reduceat(start, line_start, dtype=np.int64)
        flat = joined.split()
    else:
        counts = np.add.reduceat(b == ord(delimiter), line_start, dtype=np.int64) + 1
        flat = joined.replace("\n", delimiter).split(delimiter)
    if counts.size != n or np.any(counts != ncol):
        return None
    first = 1 if stamped else 0
    try:
        values = np.array([flat[c::ncol] for c in range(first, ncol)], dtype=np.float64)
    except ValueError:
        return None
    values = values.T.reshape(n, ncol - first)
    if not np.all(np.isfinite(values)):
        return None
    stamps = _stamps_fast(flat[0::ncol]) if stamped else np.zeros(0, dtype=np.int64)
    if stamps is None:
        return None
    return Table(path, np.asarray(numbers, dtype=np.int64), stamps, values)


def _stamps_fast(texts: list[str]) -> I64 | None:
    """Exact ns from plain ``123.456`` strings (<= 10 integer and <= 9 decimal digits), else None.

    Works on the bytes: each digit contributes ``digit * 10**(9 + place)``.
    """
    if not texts:
        return np.zeros(0, dtype=np.int64)
    try:
        a = np.array(texts, dtype="S")
    except UnicodeEncodeError:
        return None
    width = a.dtype.itemsize
    m = a.view(np.uint8).reshape(-1, width)
    digit = (m >= 48) & (m <= 57)
    dot = m == 46
    pad = m == 0
    length = width - pad.sum(axis=1)
    if not np.all(digit | dot | pad) or np.any(dot.sum(axis=1) > 1) or np.any(length == 0):
        return None
    col = np.arange(width)
    if np.any(pad & (col[None, :] < length[:, None])):
        return None
    dot_at = np.where(dot.any(axis=1), dot.argmax(axis=1), length)
    if np.any(dot_at == 0) or np.any(dot_at > 10) or np.any(length - dot_at - 1 > 9):
        return None
    if np.any((dot_at == 10) & (m[:, 0] > ord("8"))):
        return None  # 9e9 s and more could overflow int64 ns
    # Place of each character: 9 + (dot_at - 1 - col) before the dot, 9 - (col - dot_at) after.
    place = 9 + dot_at[:, None] - col[None, :] - (col[None, :] < dot_at[:, None])
    place = np.clip(place, 0, 18)
    contrib = np.where(digit, (m.astype(np.int64) - 48) * _POW10[place], 0)
    return np.asarray(contrib.sum(axis=1), dtype=np.int64)


def _read_table_slow(
    path: Path, columns: tuple[str, ...], stamped: bool, delimiter: str | None
) -> Table:
    numbers: list[int] = []
    stamps: list[int] = []
    rows: list[list[float]] = []
    ncol = len(columns)
    first = True
    for number, fields in iter_data_lines(path, delimiter=delimiter):
        if first:
            first = False
            if fields == list(columns):
                continue
        if len(fields) != ncol:
            raise FormatError(
                path,
                f"expected {ncol} fields ({', '.join(columns)}), found {len(fields)}",
                number,
            )
        if stamped:
            stamps.append(parse_stamp_ns(fields[0], path, number))
            rows.append(parse_floats(fields[1:], path, number, first_column=2))
        else:
            rows.append(parse_floats(fields, path, number))
        numbers.append(number)
    width = ncol - 1 if stamped else ncol
    return Table(
        path,
        np.asarray(numbers, dtype=np.int64),
        np.asarray(stamps, dtype=np.int64),
        np.asarray(rows, dtype=np.float64).reshape(len(rows), width),
    )


def seconds_text(ns: int) -> str:
    """Exact decimal seconds without trailing zeros: ``1248444187.156``."""
    text = format_stamp(ns).rstrip("0")
    return text + "0" if text.endswith(".") else text
