"""Line-oriented text files: comments, blank lines, CRLF, and exact timestamps."""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from slamcli.errors import FormatError, InputError

# ASCII only: \d would also take other scripts' digits, which int() reads but a file format
# never means.
_STAMP = re.compile(r"^[+-]?(\d+)(?:\.(\d*))?(?:[eE]([+-]?\d+))?$", re.ASCII)
_INT64_MAX = 2**63 - 1
_INT64_DIGITS = 19
"""Digits of the largest int64; a longer run of digits is out of range before ``int()`` reads
it (Python refuses to convert more than 4300 digits, and a million take seconds)."""

MAX_LINE_BYTES = 1 << 20
"""Longest line a text reader takes (1 MiB). The longest real lines are CARMEN laser lines of a
few thousand beams with remissions, tens of kilobytes; a longer line is damage, and reading it
whole could take gigabytes."""


def line_too_long(path: str | Path, line: int, limit: int = MAX_LINE_BYTES) -> FormatError:
    """The error for a line longer than ``limit`` bytes, naming ``path:line`` and the limit."""
    return FormatError(
        path,
        f"the line is longer than {limit} bytes ({limit / 2**20:g} MiB), the limit for a line",
        line,
        hint="the file is damaged or not this format: no line of it should be that long",
    )


def bounded_lines(fh: IO[bytes], limit: int = MAX_LINE_BYTES) -> Iterator[tuple[int, bytes | None]]:
    """Yield ``(line_number, line)`` for each line of a binary file, 1-based, newline kept.

    A line longer than ``limit`` bytes (newline excluded) is read through in pieces of at most
    ``limit`` bytes and yielded as None, so memory stays bounded and the line numbers after it
    stay right.
    """
    number = 0
    while True:
        line = fh.readline(limit + 1)
        if not line:
            return
        number += 1
        if len(line) <= limit or line.endswith(b"\n"):
            yield number, line
            continue
        while line and not line.endswith(b"\n"):
            line = fh.readline(limit)
        yield number, None


MAX_YAML_BYTES = 1 << 20
"""Largest YAML file read (1 MiB): calibration, camera and bag metadata files are kilobytes."""
MAX_YAML_VALUES = 100_000
"""Most values (mappings, lists, keys and scalars) a YAML document may hold once its aliases
are expanded. A few hundred bytes of nested aliases expand to billions of values, which any
code walking the document would take hours and gigabytes over."""


def read_limited_text(path: str | Path, limit: int, what: str, hint: str) -> str:
    """The UTF-8 text of a small file, refused when it is larger than ``limit`` bytes.

    Raises:
        FormatError: the file is larger than ``limit`` (``what`` names the limit, ``hint``
            says what to do).
        OSError, UnicodeDecodeError: as reading the file raises them (the caller reports them).
    """
    p = Path(path)
    with p.open("rb") as fh:
        data = fh.read(limit + 1)
    if len(data) > limit:
        raise FormatError(p, f"is larger than {limit} bytes, the limit for {what}", hint=hint)
    return data.decode("utf-8-sig")


def check_yaml_expansion(
    path: str | Path, document: object, limit: int = MAX_YAML_VALUES, hint: str | None = None
) -> None:
    """Refuse a loaded YAML document holding more than ``limit`` values with its aliases
    expanded. Counting stops at the limit, so an alias bomb costs what a valid file does.

    Raises:
        FormatError: naming the file and the limit.
    """
    count = 0
    stack = [document]
    while stack:
        item = stack.pop()
        count += 1
        if count > limit:
            raise FormatError(
                path,
                f"holds more than {limit} values once its YAML aliases (*name) are expanded",
                hint=hint or "the file is damaged or hostile: write it again without aliases",
            )
        if isinstance(item, dict):
            stack.extend(item)
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)


def iter_data_lines(
    path: str | Path, comment: str = "#", delimiter: str | None = None
) -> Iterator[tuple[int, list[str]]]:
    """Yield ``(line_number, fields)`` for every non-blank, non-comment line (1-based numbers).

    Handles CRLF and a UTF-8 byte-order mark. ``delimiter=None`` splits on any whitespace.

    Raises:
        InputError: the file is missing or unreadable.
        FormatError: not UTF-8 text, or a line longer than :data:`MAX_LINE_BYTES` (counted in
            characters), naming the line.
    """
    p = Path(path)
    try:
        with p.open("r", encoding="utf-8-sig", newline=None) as fh:
            number = 0
            while line := fh.readline(MAX_LINE_BYTES + 1):
                number += 1
                if len(line) > MAX_LINE_BYTES and not line.endswith("\n"):
                    raise line_too_long(p, number)
                text = line.strip()
                if not text or text.startswith(comment):
                    continue
                fields = text.split(delimiter) if delimiter else text.split()
                yield number, [f.strip() for f in fields]
    except FileNotFoundError:
        raise InputError(f"{p}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{p}: is a folder, expected a file") from None
    except UnicodeDecodeError as exc:
        raise FormatError(p, f"not a text file ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror})") from None


def parse_stamp_ns(text: str, path: str | Path, line: int) -> int:
    """Parse a timestamp in seconds (``1305031235.861603``, ``1.3e9``) to exact int64 ns.

    Decimal strings are converted digit by digit, so no precision is lost to float64.
    """
    m = _STAMP.match(text)
    if not m:
        raise FormatError(path, f"timestamp {_clip(text)} is not a number", line)
    whole, frac, exp = m.group(1), m.group(2) or "", m.group(3)
    if exp is None and len(whole.lstrip("0")) > _INT64_DIGITS:
        raise FormatError(
            path, f"timestamp {_clip(text)} is out of range (at most about 9.2e9 seconds)", line
        )
    if exp is not None:
        value = float(text)
        if not math.isfinite(value):
            raise FormatError(path, f"timestamp {_clip(text)} is not finite", line)
        if abs(value) * 1e9 > _INT64_MAX:
            raise FormatError(path, f"timestamp {_clip(text)} is out of range", line)
        return round(value * 1e9)
    ns = int(whole.lstrip("0") or "0") * 1_000_000_000 + int((frac + "000000000")[:9])
    if len(frac) > 9 and int(frac[9]) >= 5:
        ns += 1
    if ns > _INT64_MAX:
        raise FormatError(
            path, f"timestamp {_clip(text)} is out of range (at most about 9.2e9 seconds)", line
        )
    return -ns if text.startswith("-") else ns


def parse_count(
    text: str,
    path: str | Path,
    line: int,
    what: str,
    expected: str = "a non-negative whole number",
) -> int:
    """A non-negative whole number written in ASCII digits that fits in int64."""
    if not (text.isascii() and text.isdigit()):
        raise FormatError(path, f"{what} {_clip(text)} is not {expected}", line)
    if len(text.lstrip("0")) > _INT64_DIGITS:
        raise FormatError(path, f"{what} {_clip(text)} is out of range", line)
    value = int(text.lstrip("0") or "0")
    if value > _INT64_MAX:
        raise FormatError(path, f"{what} {_clip(text)} is out of range", line)
    return value


def _clip(text: str, keep: int = 40) -> str:
    """``text`` quoted, its middle left out when it is longer than ``keep`` characters, so a
    message about a megabyte-long field stays one short line."""
    if len(text) <= keep:
        return repr(text)
    half = keep // 2
    return f"{text[:half]!r}...{text[-half:]!r} ({len(text)} characters)"


def parse_floats(
    fields: list[str], path: str | Path, line: int, what: str = "value", first_column: int = 1
) -> list[float]:
    """Convert fields to finite floats, naming the file, line and column on failure.

    ``first_column`` is the 1-based column of ``fields[0]`` in the line (2 when the caller has
    split off a leading timestamp), so the message points at the column a text editor shows.
    """
    out: list[float] = []
    for col, f in enumerate(fields, start=first_column):
        try:
            v = float(f)
        except ValueError:
            raise FormatError(
                path, f"column {col}: {what} {_clip(f)} is not a number", line
            ) from None
        if not math.isfinite(v):
            raise FormatError(path, f"column {col}: {what} {_clip(f)} is not finite", line)
        out.append(v)
    return out


def format_stamp(stamp_ns: int, decimals: int = 9) -> str:
    """Exact decimal seconds from int nanoseconds, rounded half up to ``decimals`` (0 to 9)."""
    ns = int(stamp_ns)
    unit = 10 ** (9 - decimals)
    ticks = (abs(ns) + unit // 2) // unit
    whole, frac = divmod(ticks, 10**decimals)
    sign = "-" if ns < 0 else ""
    return f"{sign}{whole}.{frac:0{decimals}d}" if decimals else f"{sign}{whole}"


def yaml_problem(exc: Exception, text: str) -> tuple[str, int | None]:
    """A PyYAML error as one line of text and the 1-based line it points at (None if unknown).

    PyYAML's own messages span several lines and quote the input; a scanner or parser error
    carries a ``problem_mark``, a reader error (a control character) only the character's code
    and its offset into ``text``.
    """
    mark = getattr(exc, "problem_mark", None)
    if mark is not None:
        problem = " ".join(str(getattr(exc, "problem", None) or "syntax error").split())
        return f"{problem} at column {mark.column + 1}", mark.line + 1
    position = getattr(exc, "position", None)
    character = getattr(exc, "character", None)
    if isinstance(position, int) and isinstance(character, int):
        line = text.count("\n", 0, position) + 1
        return f"character #x{character:04x} is not allowed", line
    return " ".join(str(exc).split()), None
