"""Bounded reading of hostile inputs (issue 33): every reader bounds its line, record and list
sizes, and run.json summarises long lists. Each case is small here and runs the code path of
the large one: a line just over the limit, a list of thousands of absent images, an alias bomb
of a few hundred bytes."""

from __future__ import annotations

import gzip
import io
import json
import shutil
import struct
import time
from pathlib import Path

import pytest
from conftest import shared_path
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import FormatError
from slamcli.formats import open_source
from slamcli.formats.carmen import CarmenSource
from slamcli.formats.euroc import EurocSource, read_sensor_yaml
from slamcli.formats.euroc.source import MISSING_KEPT
from slamcli.formats.rosbag.ros2_log import read_layout
from slamcli.formats.text import (
    MAX_LINE_BYTES,
    MAX_YAML_BYTES,
    MAX_YAML_VALUES,
    bounded_lines,
    iter_data_lines,
    parse_count,
    parse_stamp_ns,
)
from slamcli.rundir import LIST_KEPT, LIST_LIMIT, RunDir, summarise_lists
from slamcli.types import ScanFrame

runner = CliRunner()


def _flaser(t: float, beams: int = 181) -> str:
    ranges = " ".join(f"{1.0 + 0.01 * i:.2f}" for i in range(beams))
    return f"FLASER {beams} {ranges} 0 0 0 0 0 0 {t} host {t}"


# -- lines ------------------------------------------------------------------------------------


def test_bounded_lines_yield_none_for_a_line_over_the_limit() -> None:
    data = b"a\n" + b"x" * 10 + b"\n" + b"y" * 25 + b"\nb\n" + b"z" * 8 + b"\nlast"
    got = list(bounded_lines(io.BytesIO(data), limit=8))
    assert got == [
        (1, b"a\n"),
        (2, None),
        (3, None),
        (4, b"b\n"),
        (5, b"z" * 8 + b"\n"),
        (6, b"last"),
    ]


def test_a_carmen_line_over_the_limit_is_a_damaged_line(tmp_path: Path) -> None:
    """The 3 GiB line of the issue, just over the 1 MiB limit: read through, never whole,
    skipped and counted; the lines after it keep their numbers."""
    log = tmp_path / "long.log"
    with log.open("w") as fh:
        fh.write(_flaser(1.0) + "\n")
        fh.write("FLASER " + "1" * MAX_LINE_BYTES + "\n")
        fh.writelines(_flaser(1.0 + 0.1 * k) + "\n" for k in range(1, 4))
    with CarmenSource(log) as source:
        assert [line for line, _ in source.malformed] == [2]
        assert (
            f"long.log:2: the line is longer than {MAX_LINE_BYTES} bytes"
            in (source.malformed[0][1])
        )
        scans = [f for f in source.frames(("scan",)) if isinstance(f, ScanFrame)]
        assert [s.name.split()[0] for s in scans] == [f"long.log:{n}" for n in (1, 3, 4, 5)]
        assert source.stats.skipped == 1
    with pytest.raises(FormatError, match=r"long\.log:2: the line is longer than 1048576 bytes"):
        CarmenSource(log, strict=True)


def test_a_digit_run_past_int64_is_out_of_range_not_a_crash() -> None:
    """Python refuses int() of more than 4300 digits; the parsers refuse past 19 first."""
    with pytest.raises(FormatError, match=r"f:3: beam count '1111.*\(5000 characters\) is out"):
        parse_count("1" * 5000, "f", 3, "beam count")
    with pytest.raises(FormatError, match="out of range"):
        parse_stamp_ns("9" * 5000 + ".5", "f", 3)
    assert parse_count("0" * 5000 + "42", "f", 3, "id") == 42


def test_a_text_list_line_over_the_limit_names_the_line(tmp_path: Path) -> None:
    path = tmp_path / "gt.txt"
    path.write_text("# t x y z qx qy qz qw\n1 0 0 0 0 0 0 1\n" + "2" * (MAX_LINE_BYTES + 1) + "\n")
    with pytest.raises(FormatError, match=r"gt\.txt:3: the line is longer than 1048576 bytes"):
        list(iter_data_lines(path))


def test_a_carmen_line_claiming_two_billion_readings_gives_a_hint_about_lines(
    tmp_path: Path,
) -> None:
    """Exit 3 as before, and the hint talks about the log's lines, not images."""
    head = shared_path("lidar", "carmen", "intel-corrected.log.gz")
    with gzip.open(head, "rt") as fh:
        lines = [next(fh) for _ in range(400)]
    log = tmp_path / "readings.log"
    bad = "FLASER 2000000000 1.0 2.0 3.0 0 0 0 0 0 0 1.0 host 1.0\n"
    log.write_text("".join(lines[:200]) + bad + "".join(lines[200:]))
    res = runner.invoke(app, ["run", "lidar", str(log), "--out", str(tmp_path / "run")])
    assert res.exit_code == 3, res.output
    out = " ".join(res.output.split())
    assert "readings.log:201: FLASER with 2000000000 beams" in out
    assert "the skipped frames are damaged lines of the log" in out
    assert "image" not in out.split("hint:")[-1]
    assert "Traceback" not in res.output


# -- EuRoC lists --------------------------------------------------------------------------------


@pytest.fixture
def euroc_listing_absent_images(tmp_path: Path) -> Path:
    """The shared EuRoC excerpt whose cam0/data.csv lists 50,000 more images that are not
    there (the issue's has 2,000,000)."""
    src = shared_path("stereo", "euroc_V1_01_micro")
    folder = tmp_path / "euroc"
    shutil.copytree(src, folder, copy_function=shutil.copyfile)
    csv = folder / "mav0" / "cam0" / "data.csv"
    last = int(csv.read_text().splitlines()[-1].split(",")[0])
    stamps = (last + 50_000_000 * (k + 1) for k in range(50_000))
    with csv.open("a") as fh:
        fh.writelines(f"{t},{t}.png\n" for t in stamps)
    return folder


def test_euroc_absent_images_are_counted_and_the_first_named(
    euroc_listing_absent_images: Path,
) -> None:
    start = time.monotonic()
    with EurocSource(euroc_listing_absent_images) as source:
        info = source.info()
    assert time.monotonic() - start < 30  # a backstop: 50,000 stat calls are not made
    assert len(source) == 95
    assert source.missing_count == 50_004  # and cam1 lists 4 absent images of its own
    assert len(source.missing) == MISSING_KEPT + 4
    assert info.details["missing_images_count"] == 50_004
    assert len(info.details["missing_images"]) == MISSING_KEPT + 4
    (problem,) = [p for p in info.problems if "missing" in p]
    assert "50004 listed image(s) missing" in problem
    assert "the rows of cam0/data.csv (50000) and cam1/data.csv (4)" in problem
    cam0 = next(s for s in info.streams if s.name == "cam0")
    assert cam0.count == 95 and "50095 listed, 50000 missing" in cam0.detail
    assert len(json.dumps(info.to_dict())) < 20_000


def test_info_on_a_euroc_folder_listing_absent_images_stays_short(
    euroc_listing_absent_images: Path,
) -> None:
    res = runner.invoke(app, ["info", str(euroc_listing_absent_images), "--json"])
    assert res.exit_code == 0, res.output
    assert len(res.output) < 20_000
    assert json.loads(res.output)["details"]["missing_images_count"] == 50_004


def test_run_json_summarises_long_lists_of_names(tmp_path: Path) -> None:
    names = [f"cam0/data/{k}.png" for k in range(LIST_LIMIT + 1)]
    with RunDir(tmp_path / "run") as run:
        run.write_run_json(
            command="run",
            inputs=[{"path": "/data/euroc"}],
            metrics={"per_frame_ms": list(range(500))},
            extra={"source": {"details": {"missing": names, "few": names[:3]}}},
        )
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    missing = record["source"]["details"]["missing"]
    assert missing["count"] == LIST_LIMIT + 1
    assert missing["first"] == names[:LIST_KEPT]
    assert "'slamcli info /data/euroc --json'" in missing["rest"]
    assert record["source"]["details"]["few"] == names[:3]
    assert record["metrics"]["per_frame_ms"] == list(range(500))  # numbers are kept whole
    assert record["outputs"] == ["run.json"]
    assert summarise_lists([names]) == [summarise_lists(names)]


# -- ROS bags -----------------------------------------------------------------------------------


def _record(fields: dict[str, bytes], data: bytes) -> bytes:
    header = b"".join(
        struct.pack("<I", len(name) + 1 + len(value)) + name.encode() + b"=" + value
        for name, value in fields.items()
    )
    return struct.pack("<I", len(header)) + header + struct.pack("<I", len(data)) + data


def _bag_v12(path: Path) -> Path:
    """A ROS bag of format 1.2 as the ROS wiki documents it: the version line, a file header
    record padded to 4 KiB, a message definition and one message."""
    definition = _record(
        {
            "op": b"\x01",
            "topic": b"/scan",
            "md5": b"90c7ef2dc6895d81024acba2ac42f369",
            "type": b"sensor_msgs/LaserScan",
            "def": b"float32 range_min\n",
        },
        b"",
    )
    message = _record(
        {
            "op": b"\x02",
            "topic": b"/scan",
            "md5": b"90c7ef2dc6895d81024acba2ac42f369",
            "type": b"sensor_msgs/LaserScan",
            "sec": struct.pack("<I", 1),
            "nsec": struct.pack("<I", 0),
        },
        struct.pack("<f", 0.1),
    )
    header = _record({"op": b"\x03", "index_pos": struct.pack("<Q", 0)}, b" " * 4000)
    path.write_bytes(b"#ROSRECORD V1.2\n" + header + definition + message)
    return path


def test_a_ros_bag_of_format_1_2_is_named_with_how_to_convert_it(tmp_path: Path) -> None:
    bag = _bag_v12(tmp_path / "2009.bag")
    with pytest.raises(FormatError, match=r"2009\.bag: is a ROS 1 bag in the older format 1\.2"):
        open_source(bag)
    res = runner.invoke(app, ["info", str(bag)])
    assert res.exit_code == 1, res.output
    out = " ".join(res.output.split())
    assert "'rosbag fix old.bag new.bag'" in out and "check the path" not in out
    # Sniffed by its first line as well as by its suffix.
    other = tmp_path / "recording.dat"
    shutil.copyfile(bag, other)
    with pytest.raises(FormatError, match=r"format 1\.2"):
        open_source(other)


def _alias_bomb(levels: int = 9) -> str:
    lines = ['  l0: &l0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for k in range(1, levels + 1):
        lines.append(f"  l{k}: &l{k} [" + ", ".join([f"*l{k - 1}"] * 9) + "]")
    return "laughs:\n" + "\n".join(lines) + "\n"


ROS2_METADATA = """rosbag2_bagfile_information:
  version: 5
  storage_identifier: sqlite3
  relative_file_paths: {paths}
  duration: {{nanoseconds: 0}}
  starting_time: {{nanoseconds_since_epoch: 0}}
  message_count: 0
  topics_with_message_count: []
  compression_format: ''
  compression_mode: ''
"""


def test_a_ros2_metadata_alias_bomb_is_refused_at_once(tmp_path: Path) -> None:
    folder = tmp_path / "bag"
    folder.mkdir()
    (folder / "bag_0.db3").write_bytes(b"")
    meta = folder / "metadata.yaml"
    meta.write_text(_alias_bomb() + ROS2_METADATA.format(paths="*l9"))
    assert meta.stat().st_size < 2000  # 9**10 values once expanded
    start = time.monotonic()
    with pytest.raises(FormatError, match=f"holds more than {MAX_YAML_VALUES} values"):
        read_layout(folder)
    res = runner.invoke(app, ["info", str(folder)])
    assert time.monotonic() - start < 20
    assert res.exit_code == 1, res.output
    assert "ros2 bag reindex" in " ".join(res.output.split())
    meta.write_text(ROS2_METADATA.format(paths="[bag_0.db3]") + "#" * MAX_YAML_BYTES)
    with pytest.raises(FormatError, match=f"larger than {MAX_YAML_BYTES} bytes"):
        read_layout(folder)


def test_a_sensor_yaml_alias_bomb_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "sensor.yaml"
    path.write_text(_alias_bomb() + "T_BS: *l9\n")
    with pytest.raises(FormatError, match=r"sensor\.yaml: holds more than 100000 values"):
        read_sensor_yaml(path)


def test_a_landmark_table_over_the_bulk_limit_is_read_line_by_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The bulk parse holds a file's text several times over (a 512 MiB line took 7.2 GB);
    past FAST_PARSE_MAX_BYTES the bounded line-by-line parse reads it, to the same table."""
    from slamcli.formats.landmarks import tables

    path = tmp_path / "odometry.csv"
    path.write_text("".join(f"{k * 0.1:.1f} 0.5 0.01\n" for k in range(200)))
    whole = tables.read_table(path, ("t", "v", "omega"))
    monkeypatch.setattr(tables, "FAST_PARSE_MAX_BYTES", 1000)
    by_line = tables.read_table(path, ("t", "v", "omega"))
    assert (by_line.stamps_ns == whole.stamps_ns).all()
    assert (by_line.values == whole.values).all()
    with path.open("a") as fh:
        fh.write("1" * (MAX_LINE_BYTES + 1) + "\n")
    with pytest.raises(FormatError, match=r"odometry\.csv:201: the line is longer than"):
        tables.read_table(path, ("t", "v", "omega"))
