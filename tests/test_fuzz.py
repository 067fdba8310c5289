"""The fuzzer in the suite: a fixed, seeded set of damaged inputs, each run as a subprocess.

Every case must exit 0, 1 or 3, print no traceback and at most one error line, leave no
half-written output, and stay under fuzzing.WALL_LIMIT_S and fuzzing.RSS_LIMIT_MB (with the
virtual memory capped at fuzzing.AS_LIMIT_BYTES). `make fuzz` runs the same checks on 10,000 cases.
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
CI_CASES = 40


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[fuzzing.Target]]:
    shared_path("mcap", "nav2_turtlebot.mcap")
    root = tmp_path_factory.mktemp("fuzz-corpus")
    return root, fuzzing.build_corpus(root)


def _report(outcomes: list[fuzzing.Outcome]) -> str:
    return fuzzing.summarize(outcomes, 0) + "\n" + "\n".join(o.output_head for o in outcomes)


def test_valid_inputs_pass_the_checks_under_the_limits(
    corpus: tuple[Path, list[fuzzing.Target]], tmp_path: Path
) -> None:
    """The heaviest commands on undamaged inputs: the limits leave room for real work."""
    root, _ = corpus
    cases = [
        fuzzing.Case(f"valid-{i}", target, file, "untouched", list(argv), subprocess=True)
        for i, (target, file, argv) in enumerate(
            [
                ("mcap-zstd", "log.mcap", fuzzing.targets()[0].commands[2]),
                ("tum", "rgb.txt", ("info", "{in}", "--deep")),
                ("landmarks", "odometry.csv", ("run", "ekf", "{in}", "--out", "{out}")),
            ]
        )
    ]
    outcomes = fuzzing.run_cases(cases, root, 0, workers=2, keep=tmp_path)
    assert [o.exit_code for o in outcomes] == [0, 0, 0], _report(outcomes)
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
    # Found by `make fuzz` (seed 0 unless named) and fixed in the readers since.
    pytest.param(2, 119, id="png-idat-length-huge"),
    pytest.param(0, 1331, id="tum-list-stamp-huge-integer"),
    pytest.param(0, 1365, id="euroc-stamp-1e308"),
    pytest.param(0, 2683, id="landmark-odometry-1e308"),
    pytest.param(0, 9682, id="g2o-id-huge-integer"),
    pytest.param(0, 47, id="mcap-repeated-message-index"),
    pytest.param(0, 1702, id="tum-list-nul-in-image-path"),
]


@pytest.mark.parametrize(("seed", "index"), FOUND_CASES)
def test_cases_found_by_make_fuzz(
    corpus: tuple[Path, list[fuzzing.Target]], tmp_path: Path, seed: int, index: int
) -> None:
    root, all_targets = corpus
    case = fuzzing.make_case(seed, index, all_targets, 1)
    (outcome,) = fuzzing.run_cases([case], root, seed, workers=1, keep=tmp_path)
    assert not outcome.problems, _report([outcome])


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
    for mutator in (*fuzzing.MCAP, *fuzzing.PNG, *fuzzing.TEXT):
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
