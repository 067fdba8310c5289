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
