"""``slamcli info``: output, JSON, exit codes and one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import typer
from click.testing import Result
from test_tum_rgbd import write_tum_folder
from typer.testing import CliRunner

from slamcli.cli import info as info_cmd
from slamcli.cli.source_options import DEFAULTS, SourceOptions

runner = CliRunner()


def _app() -> typer.Typer:
    """The info command alone, so these tests do not depend on the other command modules."""
    app = typer.Typer(pretty_exceptions_enable=False)

    @app.callback()
    def _root() -> None:
        """Root with a callback, so ``info`` stays a subcommand as in the real app."""

    info_cmd.register(app)
    return app


def invoke(*args: str | Path) -> Result:
    return runner.invoke(_app(), ["info", *map(str, args)])


def _assert_one_line_error(stderr: str, text: str) -> None:
    assert "Traceback" not in stderr
    lines = [line for line in stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and text in lines[0], stderr


def test_excerpt_human_output(tum_excerpt: Path) -> None:
    res = invoke(tum_excerpt)
    assert res.exit_code == 0, res.output
    for text in ("rgb", "depth", "groundtruth", "accelerometer", "150 paired", "517.306", "fr1"):
        assert text in res.stdout
    assert "no problems found" in res.stdout


def test_excerpt_json(tum_excerpt: Path) -> None:
    res = invoke(tum_excerpt, "--json")
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert {"format", "streams", "frames", "groundtruth", "camera", "problems"} <= set(data)
    assert data["format"] == "tum" and data["frames"] == 150 and data["groundtruth"] == 598
    assert {s["name"]: s["count"] for s in data["streams"]}["rgb"] == 150
    assert data["camera"]["fx"] == 517.306408
    assert data["problems"] == []


def test_source_options_reach_the_source(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d", depth_delay_s=0.1)
    res = invoke(folder, "--json", "--dt-offset", "-0.1", "--depth-factor", "5000")
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["frames"] == 4
    assert data["details"]["depth_factor_source"] == "given"
    res = invoke(folder, "--json", "--fx", "40", "--fy", "41", "--cx", "16", "--cy", "12")
    assert json.loads(res.stdout)["camera"]["fy"] == 41.0


def test_open_kwargs_pass_only_what_was_set() -> None:
    assert DEFAULTS.open_kwargs() == {}
    opts = SourceOptions(max_dt=0.03, camera="fr2", strict=True)
    assert opts.open_kwargs() == {"max_dt": 0.03, "camera": "fr2", "strict": True}


def test_missing_colour_list_exits_1(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d")
    (folder / "rgb.txt").unlink()
    res = invoke(folder)
    assert res.exit_code == 1
    _assert_one_line_error(res.stderr, "no rgb.txt")


def test_colour_only_folder_is_described_with_its_limit(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d")
    (folder / "depth.txt").unlink()
    res = invoke(folder)
    assert "no depth.txt: colour only" in res.output + res.stderr


def test_missing_input_and_bad_camera_exit_1(tmp_path: Path) -> None:
    res = invoke(tmp_path / "nothing")
    assert res.exit_code == 1
    _assert_one_line_error(res.stderr, "no such file or folder")
    res = invoke(write_tum_folder(tmp_path / "d"), "--camera", "fr9")
    assert res.exit_code == 1
    _assert_one_line_error(res.stderr, "neither a preset nor an existing camera file")


def test_malformed_list_exits_1_naming_file_and_line(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d")
    with (folder / "depth.txt").open("a") as fh:
        fh.write("not-a-stamp depth/x.png\n")
    res = invoke(folder, "--json")
    assert res.exit_code == 1 and res.stdout == ""
    _assert_one_line_error(res.stderr, "depth.txt:7: timestamp 'not-a-stamp' is not a number")


def test_missing_image_exits_3_and_strict_exits_1(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d")
    missing = sorted((folder / "rgb").iterdir())[0]
    missing.unlink()
    res = invoke(folder, "--json")
    assert res.exit_code == 3
    data = json.loads(res.stdout)
    assert any(missing.name in p for p in data["problems"])
    _assert_one_line_error(res.stderr, "1 listed image(s) missing or unreadable")
    res = invoke(folder, "--strict")
    assert res.exit_code == 1
    _assert_one_line_error(res.stderr, f"rgb.txt:4: lists rgb/{missing.name}, which does not exist")


@pytest.mark.parametrize("json_flag", [[], ["--json"]])
def test_deep_finds_corrupt_png_exit_3(tmp_path: Path, json_flag: list[str]) -> None:
    folder = write_tum_folder(tmp_path / "d")
    corrupt = sorted((folder / "rgb").iterdir())[3]
    corrupt.write_bytes(b"not a png")
    assert invoke(folder, *json_flag).exit_code == 0
    res = invoke(folder, "--deep", *json_flag)
    assert res.exit_code == 3
    assert corrupt.name in res.stdout
    if json_flag:
        assert json.loads(res.stdout)["details"]["deep"] is True
    _assert_one_line_error(res.stderr, "1 listed image(s) missing or unreadable")
    res = invoke(folder, "--deep", "--strict", *json_flag)
    assert res.exit_code == 1 and res.stdout == ""
    _assert_one_line_error(res.stderr, f"{corrupt.name}: cannot be decoded")


def test_millimetre_depth_problem_is_shown(tmp_path: Path) -> None:
    mm = np.tile(np.linspace(800, 3000, 32), (24, 1)).astype(np.uint16)
    folder = write_tum_folder(tmp_path / "d", depth_raw=mm)
    res = invoke(folder)
    assert res.exit_code == 0
    assert "problem:" in res.stdout and "millimetres" in res.stdout
