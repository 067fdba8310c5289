"""Exact timestamp parsing and formatting at the text-file edges."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from slamcli.errors import FormatError
from slamcli.formats.text import format_stamp, iter_data_lines, parse_stamp_ns


@given(st.integers(min_value=-(10**18), max_value=10**18))
def test_nanosecond_stamps_round_trip_through_text(ns: int) -> None:
    assert parse_stamp_ns(format_stamp(ns), "f", 1) == ns


def test_stamp_parsing_is_exact_beyond_float_precision() -> None:
    assert parse_stamp_ns("1305031235.861603", "f", 1) == 1_305_031_235_861_603_000
    assert parse_stamp_ns("1305031235.8616031239", "f", 1) == 1_305_031_235_861_603_124
    assert parse_stamp_ns("1.5e9", "f", 1) == 1_500_000_000_000_000_000
    with pytest.raises(FormatError, match=r"^f:7: timestamp 'x1' is not a number"):
        parse_stamp_ns("x1", "f", 7)


def test_format_stamp_rounds_half_up_and_carries() -> None:
    assert format_stamp(1_700_000_000_033_333_333, 6) == "1700000000.033333"
    assert format_stamp(1_999_999_999_500, 6) == "2000.000000"
    assert format_stamp(-1_500_000_000, 9) == "-1.500000000"
    assert format_stamp(2_400_000_000, 0) == "2"


def test_data_lines_skip_comments_blanks_and_crlf(tmp_path: Path) -> None:
    f = tmp_path / "list.txt"
    f.write_bytes(b"# header\r\n\r\n1.0 a\r\n  # indented comment\r\n2.0 b\r\n")
    assert list(iter_data_lines(f)) == [(3, ["1.0", "a"]), (5, ["2.0", "b"])]
