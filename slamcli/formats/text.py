"""Line-oriented text files: comments, blank lines, CRLF, and exact timestamps."""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from pathlib import Path

from slamcli.errors import FormatError, InputError

# ASCII only: \d would also take other scripts' digits, which int() reads but a file format
# never means.
_STAMP = re.compile(r"^[+-]?(\d+)(?:\.(\d*))?(?:[eE]([+-]?\d+))?$", re.ASCII)
_INT64_MAX = 2**63 - 1


def iter_data_lines(
    path: str | Path, comment: str = "#", delimiter: str | None = None
) -> Iterator[tuple[int, list[str]]]:
    """Yield ``(line_number, fields)`` for every non-blank, non-comment line (1-based numbers).

    Handles CRLF and a UTF-8 byte-order mark. ``delimiter=None`` splits on any whitespace.
    """
    p = Path(path)
    try:
        with p.open("r", encoding="utf-8-sig", newline=None) as fh:
            for number, line in enumerate(fh, start=1):
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
        raise FormatError(path, f"timestamp {text!r} is not a number", line)
    whole, frac, exp = m.group(1), m.group(2) or "", m.group(3)
    if exp is not None:
        value = float(text)
        if not math.isfinite(value):
            raise FormatError(path, f"timestamp {text!r} is not finite", line)
        if abs(value) * 1e9 > _INT64_MAX:
            raise FormatError(path, f"timestamp {text!r} is out of range", line)
        return round(value * 1e9)
    ns = int(whole) * 1_000_000_000 + int((frac + "000000000")[:9])
    if len(frac) > 9 and int(frac[9]) >= 5:
        ns += 1
    if ns > _INT64_MAX:
        raise FormatError(
            path, f"timestamp {text!r} is out of range (at most about 9.2e9 seconds)", line
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
        raise FormatError(path, f"{what} {text!r} is not {expected}", line)
    value = int(text)
    if value > _INT64_MAX:
        raise FormatError(path, f"{what} {text!r} is out of range", line)
    return value


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
            raise FormatError(path, f"column {col}: {what} {f!r} is not a number", line) from None
        if not math.isfinite(v):
            raise FormatError(path, f"column {col}: {what} {f!r} is not finite", line)
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
