"""Error paths of the CLI: the right exit code, and a message that says what to do."""

from __future__ import annotations

from pathlib import Path

from conftest import shared_path
from typer.testing import CliRunner

from slamcli.cli.app import app

runner = CliRunner()


def test_ekf_on_a_log_without_landmarks_lists_the_topics(tmp_path: Path) -> None:
    log = shared_path("mcap", "nav2_turtlebot.mcap")
    res = runner.invoke(app, ["run", "ekf", str(log), "--out", str(tmp_path / "run")])
    assert res.exit_code == 1, res.output
    assert "no landmarks topics found; choose one with --landmark-topic" in res.output
    assert "Candidates" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "run").exists()


def test_a_log_truncated_before_its_first_message_says_so(tmp_path: Path) -> None:
    from slamcli.demo import default_sample
    from slamcli.formats import open_source
    from slamcli.formats.mcap.write import write_source_mcap

    whole = tmp_path / "room.mcap"
    with open_source(default_sample()) as source:
        write_source_mcap(source, whole, flavor="ros2", max_frames=1)
    short = tmp_path / "short.mcap"
    short.write_bytes(whole.read_bytes()[:64])
    res = runner.invoke(app, ["info", str(short)])
    assert "no message could be read" in res.output, res.output
    assert "up to ?" not in res.output and "Traceback" not in res.output


def test_info_on_missing_images_summarises_them_without_opencv_warnings(tmp_path: Path) -> None:
    import shutil
    import subprocess
    import sys

    from slamcli.demo import default_sample

    folder = tmp_path / "room"
    shutil.copytree(default_sample(), folder)
    for png in (folder / "rgb").glob("*.png"):
        png.unlink()
    # A subprocess: OpenCV writes its warnings to the process's own stderr, past CliRunner.
    res = subprocess.run(
        [sys.executable, "-m", "slamcli", "info", str(folder)], capture_output=True, text=True
    )
    assert res.returncode == 3
    assert "[ WARN" not in res.stderr and "[ WARN" not in res.stdout
    out = " ".join(res.stdout.split())
    assert "30 listed image(s) missing or unreadable" in out
    assert "and 27 more" in out
    assert out.count("does not exist") == 3
