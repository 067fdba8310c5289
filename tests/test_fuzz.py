"""The fuzzer in the suite: a fixed, seeded set of damaged inputs, each run as a subprocess.

Every case must exit 0, 1 or 3, print no traceback and at most one error line, leave no
half-written output, and stay under fuzzing.WALL_LIMIT_S and fuzzing.RSS_LIMIT_MB (with the
virtual memory capped at fuzzing.AS_LIMIT_BYTES). `make fuzz` runs the same checks on 10,000 cases.
Besides the seeded draw, every format meets its own hostile mutations here: bag record and chunk
lengths, bz2 and lz4 bombs, YAML alias bombs and lines over the 1 MiB limit.
"""

from __future__ import annotations

import dataclasses
import json
import random
import shutil
import struct
import zlib
from pathlib import Path

import fuzzing
import pytest
from conftest import shared_path
from typer.testing import CliRunner

from slamcli.cli.app import app

CI_SEED = 20261124
CI_CASES = 60


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[fuzzing.Target]]:
    shared_path("mcap", "nav2_turtlebot.mcap")
    shared_path("lidar", "rosbag1", "ccny_scan_matcher_demo.bag")
    shared_path("lidar", "carmen", "intel-corrected.log.gz")
    shared_path("stereo", "kitti_excerpt_1")
    shared_path("stereo", "euroc_V1_01_micro")
    root = tmp_path_factory.mktemp("fuzz-corpus")
    return root, fuzzing.build_corpus(root)


def _case(
    case_id: str, target: str, file: str, mutation: str, *argv: str, subprocess: bool = True
) -> fuzzing.Case:
    return fuzzing.Case(case_id, target, file, mutation, list(argv), subprocess=subprocess)


def _report(outcomes: list[fuzzing.Outcome]) -> str:
    return fuzzing.summarize(outcomes, 0) + "\n" + "\n".join(o.output_head for o in outcomes)


def test_valid_inputs_pass_the_checks_under_the_limits(
    corpus: tuple[Path, list[fuzzing.Target]], tmp_path: Path
) -> None:
    """The heaviest commands on undamaged inputs: the limits leave room for real work."""
    root, _ = corpus
    out = ("--out", "{out}")
    cases = [
        fuzzing.Case(f"valid-{i}", target, file, "untouched", list(argv), subprocess=True)
        for i, (target, file, argv) in enumerate(
            [
                ("mcap-zstd", "log.mcap", fuzzing.targets()[0].commands[2]),
                ("tum", "rgb.txt", ("info", "{in}", "--deep")),
                ("landmarks", "odometry.csv", ("run", "ekf", "{in}", *out)),
                ("rosbag1-bz2", "scans.bag", ("run", "lidar", "{in}/scans.bag", *out)),
                ("rosbag2-sqlite3", "bag/bag_0.db3", fuzzing._ROS2_BAG_COMMANDS[2]),
                ("carmen", "laser.log", ("run", "lidar", "{in}/laser.log", *out)),
                ("kitti", "calib.txt", fuzzing._STEREO_COMMANDS[2]),
                ("euroc", "mav0/cam0/data.csv", fuzzing._STEREO_COMMANDS[2]),
            ]
        )
    ]
    outcomes = fuzzing.run_cases(cases, root, 0, workers=2, keep=tmp_path)
    outcomes.sort(key=lambda o: int(o.case.case_id.split("-")[1]))
    assert [o.exit_code for o in outcomes] == [0] * len(cases), _report(outcomes)
    assert not any(o.problems for o in outcomes), _report(outcomes)
    assert all(o.peak_rss_mb > 20 for o in outcomes)


def test_seeded_damaged_inputs_fail_cleanly(
    corpus: tuple[Path, list[fuzzing.Target]], tmp_path: Path
) -> None:
    root, all_targets = corpus
    cases = [fuzzing.make_case(CI_SEED, i, all_targets, 1) for i in range(CI_CASES)]
    assert {fuzzing.TARGET_KINDS[c.target] for c in cases} == set(fuzzing.TARGET_KINDS.values())
    outcomes = fuzzing.run_cases(cases, root, CI_SEED, workers=2, keep=tmp_path)
    assert len(outcomes) == CI_CASES
    assert all(o.case.subprocess for o in outcomes)
    assert not any(o.problems for o in outcomes), _report(outcomes)


FOUND_CASES = [
    # Found by `make fuzz` and fixed in the readers since. Each is pinned by its target, file,
    # mutation and command (a corpus with more targets draws other cases from the same seed and
    # index); its seed and case id still give the same damage.
    pytest.param(2, _case("s2-000119", "tum", "depth/0.png", "png_inflate_chunk", "info", "{in}"),
                 id="png-idat-length-huge"),
    pytest.param(0, _case("s0-001331", "tum", "rgb.txt", "text_odd_number", "info", "{in}",
                          "--deep"), id="tum-list-stamp-huge-integer"),
    pytest.param(0, _case("s0-001365", "trajectory-euroc", "est.txt", "text_odd_number", "eval",
                          "{in}/gt.csv", "{in}/est.txt", "--format", "euroc"),
                 id="euroc-stamp-1e308"),
    pytest.param(0, _case("s0-002683", "landmarks", "odometry.csv", "text_odd_number", "run",
                          "ekf", "{in}", "--out", "{out}"), id="landmark-odometry-1e308"),
    pytest.param(0, _case("s0-009682", "g2o", "graph.g2o", "text_odd_number", "info",
                          "{in}/graph.g2o"), id="g2o-id-huge-integer"),
    pytest.param(0, _case("s0-000047", "mcap-nav2", "log.mcap", "mcap_repeat_record", "info",
                          "{in}/log.mcap"), id="mcap-repeated-message-index"),
    pytest.param(0, _case("s0-001702", "tum", "depth.txt", "overwrite_run", "info", "{in}"),
                 id="tum-list-nul-in-image-path"),
    # Found once the corpus's YAML files met alias bombs and its text files 8 MiB lines.
    pytest.param(3, _case("s3-000132", "map", "map.yaml", "yaml_alias_bomb", "map", "show",
                          "{in}/map.yaml"), id="map-yaml-alias-bomb"),
    pytest.param(3, _case("s3-000038", "tum", "camera.yaml", "text_long_line", "info", "{in}",
                          "--deep"), id="camera-yaml-8-mib-line"),
]  # fmt: skip


@pytest.mark.parametrize(("seed", "case"), FOUND_CASES)
def test_cases_found_by_make_fuzz(
    corpus: tuple[Path, list[fuzzing.Target]], tmp_path: Path, seed: int, case: fuzzing.Case
) -> None:
    root, _ = corpus
    (outcome,) = fuzzing.run_cases([dataclasses.replace(case)], root, seed, 1, keep=tmp_path)
    assert not outcome.problems, _report([outcome])


_SCANS = "{in}/scans.bag"
HOSTILE_CASES = [
    # ROS 1 bags: record lengths, a chunk's declared size, bz2 and lz4 bombs (via the index and
    # by walking the records).
    _case("h-01", "rosbag1", "scans.bag", "ros1_inflate_length", "info", _SCANS, "--deep"),
    _case("h-02", "rosbag1-bz2", "scans.bag", "ros1_chunk_size", "run", "lidar", _SCANS,
          "--out", "{out}"),
    _case("h-03", "rosbag1-bz2", "scans.bag", "ros1_bz2_bomb", "info", _SCANS, "--deep"),
    _case("h-04", "rosbag1", "scans.bag", "ros1_bz2_bomb", "run", "lidar", _SCANS, "--out",
          "{out}"),
    _case("h-05", "rosbag1-lz4", "scans.bag", "ros1_lz4_bomb", "info", _SCANS, "--deep"),
    _case("h-06", "rosbag1-bz2", "scans.bag", "ros1_lz4_bomb", "run", "lidar", _SCANS, "--out",
          "{out}"),
    # ROS 2 bag folders: a metadata.yaml full of aliases.
    _case("h-07", "rosbag2-sqlite3", "bag/metadata.yaml", "yaml_alias_bomb", "info", "{in}/bag"),
    _case("h-08", "rosbag2-mcap", "bag/metadata.yaml", "yaml_alias_bomb", "run", "odometry",
          "{in}/bag", "--out", "{out}"),
    # CARMEN logs, KITTI and EuRoC folders: lines over the limit, alias bombs, huge images.
    _case("h-09", "carmen", "laser.log", "text_long_line", "run", "lidar", "{in}/laser.log",
          "--out", "{out}"),
    _case("h-10", "carmen-gz", "laser.log.gz", "truncate", "run", "lidar", "{in}/laser.log.gz",
          "--out", "{out}"),
    _case("h-11", "kitti", "calib.txt", "text_long_line", "info", "{in}"),
    _case("h-12", "kitti", "image_l/000000.png", "png_huge_header", "run", "visual", "{in}",
          "--max-frames", "3", "--out", "{out}"),
    _case("h-13", "euroc", "mav0/cam0/data.csv", "text_long_line", "info", "{in}"),
    _case("h-14", "euroc", "mav0/cam1/sensor.yaml", "yaml_alias_bomb", "run", "visual", "{in}",
          "--max-frames", "3", "--out", "{out}"),
]  # fmt: skip


def test_hostile_mutations_of_every_format_fail_cleanly(
    corpus: tuple[Path, list[fuzzing.Target]], tmp_path: Path
) -> None:
    root, _ = corpus
    cases = [dataclasses.replace(c) for c in HOSTILE_CASES]
    outcomes = fuzzing.run_cases(cases, root, CI_SEED, workers=2, keep=tmp_path)
    assert len(outcomes) == len(HOSTILE_CASES)
    assert not any(o.problems for o in outcomes), _report(outcomes)
    assert {o.exit_code for o in outcomes} <= {1, 3}, _report(outcomes)


def test_ekf_that_diverges_on_absurd_odometry_fails_with_a_message(
    corpus: tuple[Path, list[fuzzing.Target]], tmp_path: Path
) -> None:
    """A speed within the reader's bounds but absurd (9e8 m/s) made a singular covariance."""
    root, _ = corpus
    log = tmp_path / "log"
    shutil.copytree(root / "landmarks", log)
    rows = (log / "odometry.csv").read_text().splitlines(keepends=True)
    stamp, _, omega = rows[29].split(",")
    rows[29] = f"{stamp},9e8,{omega}"
    (log / "odometry.csv").write_text("".join(rows))
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["run", "ekf", str(log), "--out", str(out)])
    assert result.exit_code == 1, result.output
    assert "the EKF diverged" in result.output
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["log"]


def test_cases_are_reproducible_from_seed_and_index() -> None:
    all_targets = fuzzing.targets()
    first = [fuzzing.make_case(7, i, all_targets, 0) for i in range(50)]
    again = [fuzzing.make_case(7, i, all_targets, 0) for i in range(50)]
    other = [fuzzing.make_case(8, i, all_targets, 0) for i in range(50)]
    assert first == again
    assert first != other
    data = bytes(range(256)) * 8
    for mutator in (*fuzzing.MCAP, *fuzzing.PNG, *fuzzing.ROS1, *fuzzing.YAML):
        assert mutator(data, random.Random(3)) == mutator(data, random.Random(3))


def test_huge_png_header_keeps_a_valid_crc(corpus: tuple[Path, list[fuzzing.Target]]) -> None:
    root, _ = corpus
    png = (root / "tum" / "rgb" / "0.png").read_bytes()
    out, what = fuzzing.png_huge_header(png, random.Random(0))
    width, height = struct.unpack(">II", out[16:24])
    assert (width, height) != (320, 240), what
    assert struct.unpack(">I", out[29:33])[0] == zlib.crc32(out[12:29])


def test_mcap_mutations_find_records(corpus: tuple[Path, list[fuzzing.Target]]) -> None:
    root, _ = corpus
    data = (root / "mcap-lz4" / "log.mcap").read_bytes()
    opcodes = {op for _, op, _ in fuzzing._mcap_records(data)}
    assert {0x01, 0x06, 0x07, 0x0F} <= opcodes  # header, chunk, message index, data end
    out, what = fuzzing.mcap_inflate_chunk(data, random.Random(1))
    assert len(out) == len(data) and out != data and "chunk" in what


def test_ros1_mutations_find_records_and_chunks(
    corpus: tuple[Path, list[fuzzing.Target]],
) -> None:
    root, _ = corpus
    data = (root / "rosbag1-bz2" / "scans.bag").read_bytes()
    records = fuzzing._ros1_records(data)
    ops = {r[3][b"op"] for r in records}
    assert {b"\x03", b"\x05", b"\x04", b"\x06", b"\x07"} <= ops  # header, chunk, indexes
    assert sum(r[0] + 8 + r[1] + r[2] for r in records[-1:]) == len(data)
    out, what = fuzzing.ros1_bz2_bomb(data, random.Random(0))
    assert "as bz2" in what
    if "padded" in what:
        assert len(out) == len(data)  # the index still points at every chunk
    out, what = fuzzing.ros1_chunk_size(data, random.Random(1))
    assert out != data and "size" in what


def test_yaml_alias_bomb_keeps_a_directive_first() -> None:
    data = b"%YAML:1.0\nT_BS:\n  rows: 4\nrate_hz: 200\n"
    out, what = fuzzing.yaml_alias_bomb(data, random.Random(2))
    assert out.startswith(b"%YAML:1.0\nlaughs:\n") and "made *l" in what


def test_checks_catch_half_written_outputs(tmp_path: Path) -> None:
    assert fuzzing.check_outputs(tmp_path) == []
    (tmp_path / ".out.staging-123-abc").mkdir()
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "trajectory.tum").write_text("")
    problems = fuzzing.check_outputs(tmp_path)
    assert any("staging" in p for p in problems)
    assert any("half-written" in p for p in problems)
    (tmp_path / "out" / "run.json").write_text(json.dumps({"outputs": ["report.png"]}))
    assert any("misses outputs" in p for p in fuzzing.check_outputs(tmp_path))


def test_checks_catch_tracebacks_codes_and_limits() -> None:
    assert fuzzing.check_result(1, "error: bad\nhint: fix it", 1.0, 100.0) == []
    assert fuzzing.check_result(2, "", 1.0, 100.0)
    assert fuzzing.check_result(None, "", 1.0, 100.0)
    assert fuzzing.check_result(1, "Traceback (most recent call last):\n", 1.0, 100.0)
    assert fuzzing.check_result(1, "error: a\nerror: b", 1.0, 100.0)
    assert fuzzing.check_result(0, "", fuzzing.WALL_LIMIT_S + 1, 100.0)
    assert fuzzing.check_result(0, "", 1.0, fuzzing.RSS_LIMIT_MB + 1)


def test_outcomes_serialise_for_the_saved_case_file() -> None:
    case = fuzzing.make_case(0, 0, fuzzing.targets(), 0)
    outcome = fuzzing.Outcome(case, 1, 0.5, 80.0, ["printed a traceback"])
    assert json.loads(json.dumps(dataclasses.asdict(outcome)))["case"]["case_id"] == "s0-000000"
